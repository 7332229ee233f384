"""A body cut down to the points a fit reads: its keypoints, its joints, a few vertices.

Linear blend skinning is linear in the rest vertices per joint, so a keypoint
𝒦_k v = Σ_j A_j Σ_i 𝒦_ki w_ij t_i (A_j the skinning transforms, t_i the rest vertices
T̄ + B_s β + B_p θ) is, exactly, a sum of one rigidly skinned point per joint j with
c_kj = Σ_i 𝒦_ki w_ij ≠ 0, at the rest position Σ_i 𝒦_ki w_ij t_i / c_kj (whose blend shapes
are the same mixture). A fit that reads only keypoints, joints and a few vertices can
therefore pose a body of those points instead of the mesh: same energies, a fraction of
the forward pass. Keypoints at joints (`geometry.keypoints`) read the posed joints
directly; on the default body COCO-18's five face points are 5 skinned points, with the 24
joints 29 points against 1229 vertices.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

from .model import Body, StaticArray

__all__ = ["compact_body"]


def compact_body(body: Body, regressor, keep=None):
    """(small body, its keypoint regressor, has_pose_blend) for `regressor` (K, V + J) or (K, V).

    The small body has, in this order: the vertices `keep` (indices, default none), one
    point per (keypoint, joint) pair of the regressor's skinning mixture, and one point per
    joint at J(β) = 𝒥(T̄ + B_s β), so that its joints, and with them the skinning
    transforms, are the full body's. Posing it gives exactly the full body's joints, joint
    rotations, keypoints (through the new regressor, (K, V_small + J): its joint columns
    are the full one's, read from the posed joints) and kept vertices. has_pose_blend:
    whether the body has pose blend shapes at all (a caller may then skip B_p).
    """
    a = {k: np.asarray(getattr(body, k), np.float64) for k in ("v_template", "shapedirs", "J_regressor", "weights")}
    posedirs = np.asarray(body.posedirs)
    pose_blend = bool(np.any(posedirs != 0))
    reg_dtype = regressor.dtype
    reg = np.asarray(regressor, np.float64)
    V, J = a["weights"].shape
    if reg.ndim != 2 or reg.shape[1] not in (V, V + J):
        raise ValueError(f"regressor has shape {reg.shape}; expected (K, {V + J}) or (K, {V}) for this body.")
    on_joints = reg[:, V:] if reg.shape[1] == V + J else np.zeros((len(reg), J))
    reg = reg[:, :V]
    keep = np.zeros(0, np.int64) if keep is None else np.asarray(keep, np.int64)
    mix = np.einsum("kv,vj->kj", reg, a["weights"])  # c_kj
    k_idx, j_idx = np.nonzero(np.abs(mix) > 1e-12)
    per = reg[k_idx] * a["weights"][:, j_idx].T / mix[k_idx, j_idx][:, None]  # (P, V): rest mixture of each point
    Jr = a["J_regressor"]
    P, n = len(k_idx), len(keep)

    def points(x):  # (V, 3) or (B, V, 3) per-vertex arrays -> the small body's
        x = np.moveaxis(x, -2, 0)
        out = np.concatenate([x[keep], np.einsum("pv,v...->p...", per, x), np.einsum("jv,v...->j...", Jr, x)])
        return np.moveaxis(out, 0, -2)

    weights = np.concatenate([a["weights"][keep], np.eye(J)[j_idx], np.eye(J)])
    small_regressor = np.zeros((len(reg), n + P + J + J))
    small_regressor[k_idx, n + np.arange(P)] = mix[k_idx, j_idx]
    small_regressor[:, n + P + J :] = on_joints
    J_regressor = np.concatenate([np.zeros((J, n + P)), np.eye(J)], 1)
    dtype = body.dtype
    size = n + P + J
    small_posedirs = points(posedirs.astype(np.float64)) if pose_blend else np.zeros((len(posedirs), size, 3))
    small = dataclasses.replace(
        body, v_template=jnp.asarray(points(a["v_template"]), dtype), shapedirs=jnp.asarray(points(a["shapedirs"]), dtype),
        posedirs=jnp.asarray(small_posedirs, dtype), J_regressor=jnp.asarray(J_regressor, dtype),
        weights=jnp.asarray(weights, dtype), faces_static=StaticArray(np.zeros((1, 3), np.int32)),
    )  # fmt: skip
    return small, jnp.asarray(small_regressor, reg_dtype), pose_blend
