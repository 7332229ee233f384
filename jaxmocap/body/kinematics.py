"""Forward kinematics and the SMPL forward pass (shape and pose blend shapes + LBS).

All functions take arbitrary leading batch axes; nothing is mutated. The maths follows
SMPL (Loper et al. 2015) as summarised in Huang §2.1 and von Marcard §2.2.1-2.2.3.
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..rotation import axis_angle_to_matrix
from .model import Body

__all__ = ["BodyOutput", "forward", "forward_rotations", "forward_kinematics", "chain_transforms", "mat3_apply", "mat3_mul", "shaped_joints", "as_float_array"]


class BodyOutput(eqx.Module):
    """Result of `forward` / `forward_rotations`: posed vertices, joints and global joint rotations."""

    vertices: Array  # (..., V, 3)
    joints: Array  # (..., J, 3) posed joint centres, translation included
    joint_rotations: Array  # (..., J, 3, 3) global (world-from-bone) rotations


def as_float_array(x, dtype, name: str) -> Array:
    """`x` as a JAX array of `dtype`; a ValueError names `name` if it is not numeric."""
    x = jnp.asarray(x)
    if not (jnp.issubdtype(x.dtype, jnp.floating) or jnp.issubdtype(x.dtype, jnp.integer)):
        raise ValueError(f"{name} must be a numeric array, got dtype {x.dtype}.")
    return x.astype(dtype)


def mat3_mul(a: Array, b: Array) -> Array:
    """a @ b for (..., 3, 3) as broadcast products and sums.

    XLA-CPU runs batched 3x3 `dot_general`s one tiny matrix at a time; as elementwise
    arithmetic they fuse into one loop, which made the JVPs of an SIP linearisation
    several times faster (benchmarks/sip_speed.py).
    """
    return jnp.sum(a[..., :, :, None] * b[..., None, :, :], axis=-2)


def mat3_apply(a: Array, v: Array) -> Array:
    """a @ v for (..., 3, 3) and (..., 3)."""
    return jnp.sum(a * v[..., None, :], axis=-1)


def chain_transforms(
    parents: Sequence[int], local_rotations: Array, rest_joints: Array, needed=None
) -> tuple[dict[int, Array], dict[int, Array]]:
    """Global rotation and position of each joint in `needed` and its ancestors.

    Von Marcard eq. 2.29-2.32: G_j = G_parent(j) · [R_j | J_j - J_parent(j)], root at
    J_0. Rotation and translation are kept apart instead of 4x4 products, which halves
    the work; energies that see only a few bones ask for just those (`needed`).

    Args:
        parents: parent index per joint, root first (-1).
        local_rotations: (..., J, 3, 3) joint rotations relative to the parent.
        rest_joints: (..., J, 3) joint centres in the rest pose.
        needed: joint indices to compute (default: all).
    Returns:
        ({joint: (..., 3, 3)}, {joint: (..., 3)}) for the needed joints and ancestors.
    """
    keep = set(range(len(parents))) if needed is None else set()
    for j in needed or ():
        while j >= 0:
            keep.add(j)
            j = parents[j]
    rest = rest_joints.astype(local_rotations.dtype)
    batch = jnp.broadcast_shapes(local_rotations.shape[:-3], rest.shape[:-2])
    rotations = {0: jnp.broadcast_to(local_rotations[..., 0, :, :], (*batch, 3, 3))}
    positions = {0: jnp.broadcast_to(rest[..., 0, :], (*batch, 3))}
    for j in range(1, len(parents)):
        if j in keep:
            p = parents[j]
            rotations[j] = mat3_mul(rotations[p], local_rotations[..., j, :, :])
            positions[j] = positions[p] + mat3_apply(rotations[p], rest[..., j, :] - rest[..., p, :])
    return rotations, positions


def forward_kinematics(
    parents: Sequence[int], local_rotations: Array, rest_joints: Array
) -> tuple[Array, Array]:
    """Global rotations (..., J, 3, 3) and positions (..., J, 3) of every joint.

    See `chain_transforms` (von Marcard eq. 2.29-2.32).
    """
    rotations, positions = chain_transforms(parents, local_rotations, rest_joints)
    order = range(len(parents))
    return jnp.stack([rotations[j] for j in order], -3), jnp.stack([positions[j] for j in order], -2)


def shaped_joints(body: Body, betas: Array) -> Array:
    """Rest-pose joints J(β) = 𝒥 (T̄ + 𝒮 β), (..., B) -> (..., J, 3).

    For large batches uses linearity, 𝒥 T̄ + (𝒥 𝒮) β, so the per-sample cost does not
    grow with V; for small batches (static shape) regressing the shaped mesh is cheaper.
    """
    nb = betas.shape[-1]
    if int(np.prod(betas.shape[:-1])) < nb:
        v_shaped = body.v_template + jnp.einsum("kvc,...k->...vc", body.shapedirs[:nb], betas)
        return jnp.einsum("jv,...vc->...jc", body.J_regressor, v_shaped)
    joint_template = body.J_regressor @ body.v_template
    joint_shapedirs = jnp.einsum("jv,kvc->jck", body.J_regressor, body.shapedirs[:nb])
    return joint_template + jnp.einsum("jck,...k->...jc", joint_shapedirs, betas)


def _check_inputs(body: Body, local_rotations, betas, trans) -> tuple[Array, Array, Array]:
    local_rotations = jnp.asarray(local_rotations)
    dtype = local_rotations.dtype if jnp.issubdtype(local_rotations.dtype, jnp.floating) else body.dtype
    J = body.num_joints
    if local_rotations.ndim < 3 or local_rotations.shape[-3:] != (J, 3, 3):
        raise ValueError(
            f"local_rotations has shape {local_rotations.shape}; expected (..., {J}, 3, 3) "
            f"rotation matrices, one per joint of this {body.kind} body."
        )
    local_rotations = local_rotations.astype(dtype)
    betas = jnp.zeros((body.num_betas,), dtype) if betas is None else as_float_array(betas, dtype, "betas")
    if betas.ndim < 1 or betas.shape[-1] > body.num_betas:
        raise ValueError(
            f"betas has shape {betas.shape}; expected (..., B) with B <= {body.num_betas}, "
            "the number of shape components of this body."
        )
    if betas.shape[-1] == 0:
        # No shape components (CMU motions carry none): the template shape, β = 0.
        betas = jnp.zeros(betas.shape[:-1] + (1,), dtype)
    trans = jnp.zeros((3,), dtype) if trans is None else as_float_array(trans, dtype, "trans")
    if trans.ndim < 1 or trans.shape[-1] != 3:
        raise ValueError(f"trans has shape {trans.shape}; expected (..., 3).")
    try:
        batch = np.broadcast_shapes(local_rotations.shape[:-3], betas.shape[:-1], trans.shape[:-1])
    except ValueError:
        raise ValueError(
            f"batch shapes do not broadcast: pose {local_rotations.shape[:-3]}, betas {betas.shape[:-1]}, "
            f"trans {trans.shape[:-1]}."
        ) from None
    return (
        jnp.broadcast_to(local_rotations, (*batch, J, 3, 3)),
        jnp.broadcast_to(betas, (*batch, betas.shape[-1])),
        jnp.broadcast_to(trans, (*batch, 3)),
    )


def _skin(body: Body, transforms: Array, v_posed: Array) -> Array:
    """Linear blend skinning v = Σ_j w_vj (R_j v_posed + t_j) for (N, J, 3, 4) transforms.

    Blending the J transforms first (one (V, J) x (J, 12N) product) costs 12 multiply-adds
    per vertex and joint. A gather over each vertex's few non-zero weights was measured
    5-9x slower on XLA-CPU (benchmarks/body_forward.py history), so skinning is dense.
    """
    N, J, V = transforms.shape[0], body.num_joints, body.num_vertices
    # Full float32 here: GPUs' default TF32 products moved vertices by ~0.5 mm
    # (benchmarks/results/body_forward_gpu.json); this product is memory-bound anyway.
    blended = jnp.matmul(
        body.weights, transforms.reshape(N, J, 12), precision=jax.lax.Precision.HIGHEST
    ).reshape(N, V, 3, 4)
    return jnp.einsum("nvab,nvb->nva", blended[..., :3], v_posed) + blended[..., 3]


def forward(body: Body, pose, betas=None, trans=None) -> BodyOutput:
    """The SMPL function M(β, θ) + translation, θ as axis-angle vectors.

    `forward_rotations` after `axis_angle_to_matrix`; computation happens in the dtype
    of `pose` (the body is cast if needed).

    Args:
        body: the body model.
        pose: (..., J, 3) axis-angle joint rotations, root first.
        betas: (..., B) shape coefficients, B <= body.num_betas (default: zeros).
        trans: (..., 3) root translation in metres (default: zeros).
    Returns:
        BodyOutput with vertices (..., V, 3), joints (..., J, 3) and global
        joint_rotations (..., J, 3, 3); batch axes broadcast across the inputs.

    Memory grows with the batch (about 1.4 GiB per 1000 frames on the full default body):
    pose long sequences in chunks with `jaxmocap.body.posed_vertices(body, motion,
    chunk=256)`.
    """
    pose = jnp.asarray(pose)
    J = body.num_joints
    if pose.ndim < 2 or pose.shape[-2:] != (J, 3):
        raise ValueError(
            f"pose has shape {pose.shape}; expected (..., {J}, 3) axis-angle vectors, one per "
            f"joint of this {body.kind} body. Reshape a flat (..., {3 * J}) pose with "
            f"pose.reshape(*pose.shape[:-1], {J}, 3)."
        )
    dtype = pose.dtype if jnp.issubdtype(pose.dtype, jnp.floating) else body.dtype
    return forward_rotations(body, axis_angle_to_matrix(pose.astype(dtype)), betas, trans)


def forward_rotations(body: Body, local_rotations, betas=None, trans=None) -> BodyOutput:
    """The SMPL function M(β, θ) + translation, θ as local rotation matrices.

    Huang eq. 2.1-2.4: T(β, θ) = T̄ + B_s(β) + B_p(θ), joints J(β) = 𝒥 (T̄ + B_s(β)),
    pose blend shapes linear in vec(R(θ_j) - I) for the J-1 non-root joints, then linear
    blend skinning v_i = Σ_j w_ij G_j(θ, J) G_j(0, J)⁻¹ t_i.

    Computation happens in the dtype of `local_rotations` (the body is cast if needed).

    Args:
        body: the body model.
        local_rotations: (..., J, 3, 3) joint rotations relative to the parent, root first.
        betas: (..., B) shape coefficients, B <= body.num_betas (default: zeros).
        trans: (..., 3) root translation in metres (default: zeros).
    Returns:
        BodyOutput with vertices (..., V, 3), joints (..., J, 3) and global
        joint_rotations (..., J, 3, 3); batch axes broadcast across the inputs.
    """
    local, betas, trans = _check_inputs(body, local_rotations, betas, trans)
    dtype = local.dtype
    if body.dtype != dtype:
        body = body.astype(dtype)
    batch, V, nb = local.shape[:-3], body.num_vertices, betas.shape[-1]
    # Work on a flat batch of N samples: 2-D matrix products are what CPU and GPU BLAS
    # run fastest (a 3-D einsum against posedirs made XLA-CPU transpose it every call).
    local, betas, trans = local.reshape(-1, body.num_joints, 3, 3), betas.reshape(-1, nb), trans.reshape(-1, 3)

    pose_feature = (local[:, 1:] - jnp.eye(3, dtype=dtype)).reshape(len(local), -1)
    v_posed = (
        body.v_template.reshape(-1)
        + betas @ body.shapedirs[:nb].reshape(nb, 3 * V)
        + pose_feature @ body.posedirs.reshape(-1, 3 * V)
    ).reshape(-1, V, 3)

    rest = shaped_joints(body, betas)
    global_rot, global_pos = forward_kinematics(body.parents, local, rest)
    # Skinning transform A_j = G_j(θ) G_j(0)⁻¹ = [G_R | G_t - G_R J_j].
    offsets = global_pos - jnp.einsum("njab,njb->nja", global_rot, rest)
    transforms = jnp.concatenate([global_rot, offsets[..., None]], -1)  # (N, J, 3, 4)
    vertices = _skin(body, transforms, v_posed) + trans[:, None]
    unflat = lambda x: x.reshape(*batch, *x.shape[1:])  # noqa: E731
    return BodyOutput(
        vertices=unflat(vertices),
        joints=unflat(global_pos + trans[:, None]),
        joint_rotations=unflat(global_rot),
    )
