"""3DPW sequence files (issue 16): the reader, the world conversion and VIP inputs built from them.

The file is written here in 3DPW's layout (a protocol-2 pickle of numpy arrays and lists,
2 people, 20 frames) from known motions on the default body, so that jointPositions and
poses2d are exact functions of poses, trans and the camera.
"""

import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from jaxmocap.body.io import default_body
from jaxmocap.body.kinematics import shaped_joints
from jaxmocap.formats.threedpw import load_threedpw, valid_span
from jaxmocap.geometry.camera import project
from jaxmocap.methods.visual_inertial import vip_data
from jaxmocap.motion.amass import Z_UP_TO_Y_UP
from jaxmocap.motion.skeleton import MotionFileError
from jaxmocap.rotation import axis_angle_to_matrix
from jaxmocap.sensors.threedpw import vip_inputs
from threedpw_file import joints_and_keypoints, threedpw_dict, write_threedpw

T = 20


@pytest.fixture(scope="module")
def body():
    return default_body("low")


@pytest.fixture(scope="module")
def raw(body):
    """The dict of a 3DPW sequence file, y up, and the arrays it was made from."""
    return threedpw_dict(body, T)


def _write(tmp_path, data, name="seq.pkl"):
    return write_threedpw(tmp_path / name, data)


@pytest.fixture(scope="module")
def seq_path(raw, tmp_path_factory):
    return _write(tmp_path_factory.mktemp("threedpw"), raw[0])


def test_round_trip(seq_path, raw):
    data, truth = raw
    seq = load_threedpw(seq_path)
    assert (seq.name, seq.genders, seq.num_people, seq.num_frames) == (
        "courtyard_synthetic_00",
        ("male", "female"),
        2,
        T,
    )
    np.testing.assert_array_equal(seq.poses, truth["poses"])
    np.testing.assert_array_equal(seq.trans, truth["trans"])
    np.testing.assert_array_equal(seq.betas, [data["betas"][0], data["betas"][1][:10]])
    np.testing.assert_array_equal(seq.keypoints, np.swapaxes(np.stack(truth["poses2d"]), -1, -2))
    np.testing.assert_array_equal(seq.valid, np.stack(data["campose_valid"]))
    np.testing.assert_array_equal(seq.cam_R, data["cam_poses"][:, :3, :3])
    np.testing.assert_array_equal(seq.cam_t, data["cam_poses"][:, :3, 3])
    np.testing.assert_array_equal(seq.K, data["cam_intrinsics"])
    np.testing.assert_array_equal(seq.joints, truth["joints"])
    assert (seq.width, seq.height) == (1080, 1920)  # from the principal point
    assert (load_threedpw(seq_path, image_size=(1920, 1080)).width, seq.poses_60hz[1].shape) == (1920, (2 * T, 24, 3))
    np.testing.assert_allclose(
        seq.camera_to_world @ data["cam_poses"], np.broadcast_to(np.eye(4), (T, 4, 4)), atol=1e-12
    )
    assert seq.motion(1).gender == "female" and seq.motion(1).poses.shape == (T, 24, 3)
    assert valid_span(seq.valid[0]) == slice(0, T - 3)


def test_joint_positions_and_keypoints_follow_from_the_read_motion(seq_path, body):
    seq = load_threedpw(seq_path)
    for p in range(2):
        joints, kp = joints_and_keypoints(body, seq.poses[p], seq.trans[p], seq.betas[p])
        np.testing.assert_allclose(joints, seq.joints[p], atol=1e-9)
        uv, z = project(jnp.asarray(seq.K), jnp.asarray(seq.cam_R)[:, None], jnp.asarray(seq.cam_t)[:, None],
                        jnp.asarray(kp)[:, None])  # fmt: skip
        seen = seq.keypoints[p, ..., 2] > 0
        assert (np.asarray(z) > 0).all() and seen.mean() > 0.9
        np.testing.assert_allclose(np.asarray(uv)[:, 0][seen], seq.keypoints[p, ..., :2][seen], atol=1e-6)


def test_world_rotation_converts_a_z_up_file_exactly(raw, body, tmp_path):
    # The same sequence written with z up (p_z = Rᵀ p_y, R = Z_UP_TO_Y_UP): the root turns
    # about the rest pelvis j0, so trans_z = Rᵀ(trans + j0) - j0. Check that file against
    # forward kinematics, then read it back into y up.
    data, truth = raw
    R = Z_UP_TO_Y_UP
    z = dict(data)
    poses_z, trans_z = [], []
    for p in range(2):
        j0 = np.asarray(shaped_joints(body, jnp.asarray(data["betas"][p][:10])))[0]
        root = np.asarray(axis_angle_to_matrix(jnp.asarray(truth["poses"][p, :, 0])))
        pz = truth["poses"][p].copy()
        pz[:, 0] = Rotation.from_matrix(R.T @ root).as_rotvec()
        poses_z.append(pz)
        trans_z.append((truth["trans"][p] + j0) @ R - j0)
        joints_z, _ = joints_and_keypoints(body, pz, trans_z[p], data["betas"][p][:10])
        np.testing.assert_allclose(joints_z, truth["joints"][p] @ R, atol=1e-9)  # the file is consistent
    cam = data["cam_poses"].copy()
    cam[:, :3, :3] = cam[:, :3, :3] @ R  # p_c = R_c p_y + t = (R_c R) p_z + t
    z.update(poses=[x.reshape(T, 72) for x in poses_z], trans=trans_z, cam_poses=cam,
             jointPositions=[(j @ R).reshape(T, 72) for j in truth["joints"]])  # fmt: skip
    del z["poses_60Hz"], z["trans_60Hz"]
    seq = load_threedpw(_write(tmp_path, z), world_rotation=R, body=body)
    # 1e-6 m: the reader's j0 comes from a float32 forward pass of the default body.
    np.testing.assert_allclose(seq.trans, truth["trans"], atol=1e-6)
    np.testing.assert_allclose(seq.joints, truth["joints"], atol=1e-12)
    np.testing.assert_allclose(seq.cam_R, data["cam_poses"][:, :3, :3], atol=1e-12)
    for p in range(2):
        np.testing.assert_allclose(joints_and_keypoints(body, seq.poses[p], seq.trans[p], seq.betas[p])[0],
                                   truth["joints"][p], atol=1e-6)  # fmt: skip
    with pytest.raises(ValueError, match="rotation matrix"):
        load_threedpw(_write(tmp_path, z), world_rotation=2 * np.eye(3))


def test_bad_files_are_named(raw, tmp_path):
    data, _ = raw
    junk = tmp_path / "junk.pkl"
    junk.write_bytes(b"\x00\x01 not a pickle")
    with pytest.raises(MotionFileError, match="not a 3DPW sequence pickle"):
        load_threedpw(junk)
    with pytest.raises(MotionFileError, match=r"missing key\(s\) \['poses2d', 'cam_poses'\]"):
        load_threedpw(_write(tmp_path, {k: v for k, v in data.items() if k not in ("poses2d", "cam_poses")}))
    with pytest.raises(MotionFileError, match="inconsistent person counts"):
        load_threedpw(_write(tmp_path, {**data, "trans": data["trans"][:1]}))
    with pytest.raises(MotionFileError, match=r"poses\[1\] has shape \(19, 72\); expected \(20, 72\) \(T = 20"):
        load_threedpw(_write(tmp_path, {**data, "poses": [data["poses"][0], data["poses"][1][:19]]}))
    with pytest.raises(MotionFileError, match="holds a list"):
        load_threedpw(_write(tmp_path, [data]))
    with pytest.raises(FileNotFoundError):
        load_threedpw(tmp_path / "absent.pkl")
    # The readme's spellings ("gender", "poses2D") are read as well.
    renamed = {("gender" if k == "genders" else "poses2D" if k == "poses2d" else k): v for k, v in data.items()}
    assert load_threedpw(_write(tmp_path, renamed)).genders == ("male", "female")


def test_vip_inputs(seq_path, body):
    seq = load_threedpw(seq_path)
    inputs, truth = vip_inputs(seq, 0, body)
    n = T - 3  # the longest run of campose_valid frames
    assert truth["frames"] == slice(0, n)
    S = len(inputs["bones"])
    assert S == 13 and inputs["orientation"].shape == (n, S, 3, 3) and inputs["acceleration"].shape == (n, S, 3)
    assert inputs["cam_orientation"].shape == (n, 3, 3) and inputs["cam_acceleration"].shape == (n, 3)
    assert inputs["keypoints"].shape == (n, 18, 3) and inputs["image_height"] == 1920
    for k in ("orientation", "acceleration", "cam_orientation", "cam_acceleration", "keypoints", "x0", "betas"):
        assert np.isfinite(inputs[k]).all(), k
    np.testing.assert_allclose(inputs["cam_orientation"], np.swapaxes(seq.cam_R[:n], 1, 2), atol=1e-12)
    np.testing.assert_array_equal(inputs["betas"], np.zeros(body.num_betas))  # SMPL betas mean nothing here
    data = vip_data(**inputs)
    assert data.orientation.shape == (n, S, 3, 3) and data.keypoints.shape == (n, 18, 2)
    assert np.isfinite(np.asarray(data.acceleration)).all() and np.isfinite(np.asarray(data.cam_acceleration)).all()
    with pytest.raises(ValueError, match="person 2"):
        vip_inputs(seq, 2, body)
