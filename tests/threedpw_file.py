"""A 3DPW sequence file written in 3DPW's layout from known motions (shared by the tests).

Two people (the library's walk and arm raises) on the default body, a camera moving past
them; jointPositions and poses2d are exact functions of poses, trans and the camera.
"""

import pickle

import jax.numpy as jnp
import numpy as np

from jaxmocap.body import forward
from jaxmocap.geometry.camera import intrinsics, look_at, project
from jaxmocap.geometry.keypoints import keypoint_regressor, regress_keypoints
from jaxmocap.motion import library


def joints_and_keypoints(body, poses, trans, betas):
    out = forward(body, jnp.asarray(poses), jnp.asarray(betas), jnp.asarray(trans))
    kp = regress_keypoints(keypoint_regressor(body, "coco18"), out.vertices, out.joints)
    return np.asarray(out.joints), np.asarray(kp)


def threedpw_dict(body, T: int = 20) -> tuple[dict, dict]:
    """The dict of a 3DPW sequence file, y up, and the arrays it was made from."""
    walk = library.MOTIONS["walk"](num_frames=T, fps=30.0, body=body)
    raise_ = library.MOTIONS["arm_raises"](num_frames=T, fps=30.0, body=body)
    poses = np.stack([walk.poses, raise_.poses])
    trans = np.stack([walk.trans, raise_.trans + [1.2, 0.0, 0.5]])
    betas = [np.linspace(-1.0, 1.0, 10), np.r_[0.5, np.zeros(299)]]  # 3DPW: 10 or 300 values
    K = intrinsics(1080, 1920, 55.0)  # portrait: principal point (540, 960)
    s = np.arange(T) / T
    eyes = np.stack([0.6 + 1.5 * s, np.full(T, 1.5), np.full(T, 4.0)], -1)
    R, t = look_at(eyes, np.broadcast_to([0.6, 0.9, 0.0], (T, 3)))
    cam = np.zeros((T, 4, 4))
    cam[:, :3, :3], cam[:, :3, 3], cam[:, 3, 3] = R, t, 1.0
    joints, poses2d = [], []
    for p in range(2):
        j, kp = joints_and_keypoints(body, poses[p], trans[p], betas[p][:10])
        uv, _ = project(jnp.asarray(K), jnp.asarray(R)[:, None], jnp.asarray(t)[:, None], jnp.asarray(kp)[:, None])
        rows = np.concatenate([np.asarray(uv)[:, 0], np.full((T, 18, 1), 0.8)], -1)
        rows[::5, 3] = 0.0  # an undetected joint, as OpenPose writes it
        joints.append(j.reshape(T, 72))
        poses2d.append(np.ascontiguousarray(np.swapaxes(rows, 1, 2)))  # 3DPW stores (T, 3, 18)
    data = {
        "sequence": "courtyard_synthetic_00", "genders": [b"m", b"f"], "betas": betas,
        "poses": [x.reshape(T, 72) for x in poses], "trans": list(trans),
        "poses_60Hz": [np.repeat(x.reshape(T, 72), 2, 0) for x in poses], "trans_60Hz": [np.repeat(x, 2, 0) for x in trans],
        "betas_clothed": [b[:10] for b in betas], "v_template_clothed": [np.zeros((6890, 3))] * 2,
        "jointPositions": joints, "poses2d": poses2d, "cam_poses": cam, "cam_intrinsics": K,
        "campose_valid": [np.r_[np.ones(T - 3), np.zeros(3)].astype(bool), np.ones(T, bool)],
        "img_frame_ids": 2 * np.arange(T),
    }  # fmt: skip
    return data, {"poses": poses, "trans": trans, "joints": np.stack(joints).reshape(2, T, 24, 3), "poses2d": poses2d}


def write_threedpw(path, data):
    """Write `data` as 3DPW's files are: Python-2 pickles (protocol 2) of NumPy 1 arrays, whose
    reconstructor lives in numpy.core (numpy._core since NumPy 2)."""
    path.write_bytes(pickle.dumps(data, protocol=2).replace(b"numpy._core.", b"numpy.core."))
    return path
