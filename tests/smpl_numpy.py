"""An independent NumPy derivation of the SMPL forward pass, for tests only.

Written the way the original SMPL release computes it: 4x4 homogeneous transforms
chained along kintree_table, `G_j · [I | -J_j]` skinning matrices, rotations from SciPy.
It shares no code with jaxmocap.
"""

import numpy as np
from scipy.spatial.transform import Rotation


def smpl_forward_numpy(model: dict, pose: np.ndarray, betas: np.ndarray, trans: np.ndarray):
    """model: SMPL-family dict; pose (J, 3); betas (B,); trans (3,) -> (verts, joints, rots)."""
    parents = model["kintree_table"][0].astype(np.int64)
    num_joints = len(parents)
    v_shaped = model["v_template"] + model["shapedirs"][:, :, : len(betas)].dot(betas)
    J = model["J_regressor"].dot(v_shaped)
    R = Rotation.from_rotvec(pose).as_matrix()
    pose_feature = (R[1:] - np.eye(3)).ravel()
    v_posed = v_shaped + model["posedirs"].reshape(len(v_shaped), 3, -1).dot(pose_feature)

    def homogeneous(rotation, translation):
        out = np.eye(4)
        out[:3, :3] = rotation
        out[:3, 3] = translation
        return out

    G = [homogeneous(R[0], J[0])]
    for i in range(1, num_joints):
        G.append(G[parents[i]].dot(homogeneous(R[i], J[i] - J[parents[i]])))
    G = np.stack(G)
    skinning = np.stack([G[i].dot(homogeneous(np.eye(3), -J[i])) for i in range(num_joints)])
    T = np.tensordot(model["weights"], skinning, axes=[[1], [0]])  # (V, 4, 4)
    rest_h = np.concatenate([v_posed, np.ones((len(v_posed), 1))], 1)
    verts = np.einsum("vab,vb->va", T, rest_h)[:, :3] + trans
    return verts, G[:, :3, 3] + trans, G[:, :3, :3]
