"""Forward kinematics and the SMPL forward pass (shape and pose blend shapes + LBS).

All functions take arbitrary leading batch axes; nothing is mutated. The maths follows
SMPL (Loper et al. 2015) as summarised in Huang §2.1 and von Marcard §2.2.1-2.2.3.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.custom_derivatives import SymbolicZero

from .._checks import check_finite, concrete
from ..rotation import axis_angle_to_matrix
from .model import Body

__all__ = [
    "BodyOutput",
    "forward",
    "forward_rotations",
    "forward_kinematics",
    "chain_transforms",
    "mat3_apply",
    "mat3_mul",
    "shaped_joints",
    "as_float_array",
]


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
    """See `_chain_transforms`."""
    return _chain_transforms(
        tuple(int(p) for p in parents),
        local_rotations,
        rest_joints,
        None if needed is None else tuple(sorted({int(j) for j in needed})),
    )


@functools.partial(jax.jit, static_argnums=(0, 3))
def _chain_transforms(
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
    rotations, positions = {}, {}
    for joints, R, p in _by_level(parents, local_rotations, rest_joints, frozenset(keep)):
        for i, j in enumerate(joints):
            rotations[j], positions[j] = R[..., i, :, :], p[..., i, :]
    return rotations, positions


def _by_level(parents, local_rotations: Array, rest_joints: Array, keep: frozenset):
    """[(joints, rotations (..., n, 3, 3), positions (..., n, 3))] of the root and then of
    the joints of `keep` one tree depth at a time: each level's parents are the level
    above, so the chain is ~9 batched products instead of 23 sequential ones (fewer
    operations to compile; every entry is the same arithmetic as joint by joint)."""
    rest = rest_joints.astype(local_rotations.dtype)
    batch = jnp.broadcast_shapes(local_rotations.shape[:-3], rest.shape[:-2])
    R = jnp.broadcast_to(local_rotations[..., :1, :, :], (*batch, 1, 3, 3))
    p = jnp.broadcast_to(rest[..., :1, :], (*batch, 1, 3))
    out = [((0,), R, p)]
    for joints in _levels(parents, keep):
        at = [out[-1][0].index(parents[j]) for j in joints]
        R_p = _take(R, at, -3)
        p = _take(p, at, -2) + mat3_apply(R_p, _take(rest, joints, -2) - _take(rest, [parents[j] for j in joints], -2))
        R = mat3_mul(R_p, _take(local_rotations, joints, -3))
        out.append((joints, R, p))
    return out


@functools.lru_cache(maxsize=None)
def _levels(parents: tuple[int, ...], keep) -> tuple[tuple[int, ...], ...]:
    """The joints of `keep` but the root, grouped by depth in the tree (depth 1 first)."""
    depth = {0: 0}
    for j in range(1, len(parents)):
        depth[j] = depth[parents[j]] + 1
    out: dict[int, list] = {}
    for j in sorted(keep):
        if j:
            out.setdefault(depth[j], []).append(j)
    return tuple(tuple(out[d]) for d in sorted(out))


@functools.partial(jax.jit, static_argnums=0)
def _forward_kinematics(parents: tuple[int, ...], local_rotations: Array, rest_joints: Array) -> tuple[Array, Array]:
    """Every joint's global rotation and position, stacked in joint order."""
    levels = _by_level(parents, local_rotations, rest_joints, frozenset(range(len(parents))))
    order = np.argsort([j for joints, _, _ in levels for j in joints])
    R = _take(jnp.concatenate([R for _, R, _ in levels], -3), order, -3)
    p = _take(jnp.concatenate([p for _, _, p in levels], -2), order, -2)
    return R, p


def _take(x: Array, indices, axis: int) -> Array:
    """x at the static `indices` along `axis`, as slices of their contiguous runs: XLA's
    CPU gather with constant indices made the chain of 30 frames 2.9x slower (168 against
    58 µs)."""
    runs, start = [], 0
    for k in range(1, len(indices) + 1):
        if k == len(indices) or indices[k] != indices[k - 1] + 1:
            runs.append(jax.lax.slice_in_dim(x, int(indices[start]), int(indices[k - 1]) + 1, axis=axis))
            start = k
    return runs[0] if len(runs) == 1 else jnp.concatenate(runs, axis)


def forward_kinematics(parents: Sequence[int], local_rotations: Array, rest_joints: Array) -> tuple[Array, Array]:
    """Global rotations (..., J, 3, 3) and positions (..., J, 3) of every joint.

    See `chain_transforms` (von Marcard eq. 2.29-2.32).
    """
    return _forward_kinematics(tuple(int(p) for p in parents), local_rotations, rest_joints)


def ancestors(parents: Sequence[int], bones) -> tuple[int, ...]:
    """The joints `bones` and all their ancestors in the tree `parents`, sorted: the joints
    whose rotation moves any of the bones."""
    keep = set()
    for j in bones:
        while j >= 0:
            keep.add(int(j))
            j = parents[j]
    return tuple(sorted(keep))


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


#: Sparse skinning gathers 12 values per influence and vertex where the dense product does
#: 12 multiply-adds per joint; measured faster with 4 and 6 influences on an H200
#: (benchmarks/body_forward.py). Past this many the dense product is kept, unmeasured.
_SPARSE_MAX_INFLUENCES = 8
#: From this many samples in a call the shape and pose blend shapes are one matrix product
#: against the stacked bases (copying the bases each call costs more for fewer).
_JOINT_BLEND_MIN_BATCH = 256


def _apply_blended(blended: Array, v_posed: Array) -> Array:
    """v = R v_posed + t for per-vertex (N, V, 3, 4) transforms [R | t].

    Written as column products and sums rather than an einsum: XLA-CPU runs the einsum's
    (N·V)-batched 3x4 matrix-vector products one at a time (4x slower at N = 64,
    benchmarks/body_forward.py), while this fuses into one elementwise loop.
    """
    x, y, z = (v_posed[..., c, None] for c in range(3))
    return blended[..., 0] * x + blended[..., 1] * y + blended[..., 2] * z + blended[..., 3]


def _blend_dense(weights: Array, transforms: Array, v_posed: Array) -> Array:
    """Σ_j w_vj (R_j v_posed + t_j) for (V, J) weights, blending all J transforms first."""
    N, J = transforms.shape[:2]
    # Full float32 here: GPUs' default TF32 products moved vertices by ~0.5 mm
    # (benchmarks/results/body_forward_gpu.json).
    blended = jnp.matmul(weights, transforms.reshape(N, J, 12), precision=jax.lax.Precision.HIGHEST).reshape(
        N, weights.shape[0], 3, 4
    )
    return _apply_blended(blended, v_posed)


def _sparse_terms(weights: Array, influences: int):
    """Each vertex's K largest weights and their joints, (V, K) each, and a gather of
    (N, J) planes at those joints."""
    # The barrier keeps XLA from constant-folding the sort when the body is a jit
    # constant (seconds of compile time for 6890 vertices).
    w, joints = jax.lax.top_k(jax.lax.optimization_barrier(weights), influences)

    def take(plane: Array, k: int) -> Array:  # (N, J) -> (N, V)
        return plane.at[:, joints[:, k]].get(mode="promise_in_bounds")

    return w, take


def _blend_sparse(weights: Array, transforms: Array, v_posed: Array, influences: int) -> Array:
    """Σ_k w_vk (R_{j_vk} v_posed + t_{j_vk}) over each vertex's K largest weights."""
    w, take = _sparse_terms(weights, influences)
    # One (N, J) plane per entry of [R | t], gathered as scalars per output coordinate:
    # 2.4x faster on an H200 than gathering whole 3x4 blocks (benchmarks/body_forward.py).
    planes = [transforms[..., a, b] for a in range(3) for b in range(4)]
    x, y, z = v_posed[..., 0], v_posed[..., 1], v_posed[..., 2]
    coordinates = []
    for a in range(3):
        total = 0
        for k in range(influences):
            row = [take(p, k) for p in planes[4 * a : 4 * a + 4]]
            total = total + w[:, k] * (row[0] * x + row[1] * y + row[2] * z + row[3])
        coordinates.append(total)
    return jnp.stack(coordinates, -1)


def _blended_rotations(weights: Array, transforms: Array, influences: int) -> Array:
    """Σ_k w_vk R_{j_vk}, (N, V, 3, 3): the derivative of `_blend_sparse` along v_posed."""
    w, take = _sparse_terms(weights, influences)
    entries = [
        sum(w[:, k] * take(transforms[..., a, b], k) for k in range(influences)) for a in range(3) for b in range(3)
    ]
    return jnp.stack(entries, -1).reshape(*entries[0].shape, 3, 3)


@functools.partial(jax.custom_jvp, nondiff_argnums=(3,))
def _blend_sparse_dense_tangents(weights: Array, transforms: Array, v_posed: Array, influences: int) -> Array:
    """`_blend_sparse`, differentiated as the dense blend in the transforms and weights.

    Its derivative along the transforms, transposed (reverse mode, `linear_transpose`),
    would be a scatter-add of (N, V, K) terms into (N, J, 3, 4): 4-5x slower gradients
    on an H200 and 5-12x slower on XLA-CPU than the dense product's transpose, a matrix
    product (benchmarks/body_forward.py). Along v_posed the derivative is the blended
    rotation Σ_k w_vk R_{j_vk} of each vertex, gathered as in the primal; its transpose is
    elementwise.
    """
    return _blend_sparse(weights, transforms, v_posed, influences)


def _blend_sparse_jvp(influences, primals, tangents):
    weights, transforms, v_posed = primals
    d_weights, d_transforms, d_v_posed = tangents
    out = _blend_sparse_dense_tangents(weights, transforms, v_posed, influences)
    terms = []
    if not isinstance(d_transforms, SymbolicZero):
        terms.append(_blend_dense(weights, d_transforms, v_posed))
    if not isinstance(d_v_posed, SymbolicZero):
        terms.append(mat3_apply(_blended_rotations(weights, transforms, influences), d_v_posed))
    if not isinstance(d_weights, SymbolicZero):
        # The dense formula's derivative: every joint, not only the non-zero weights.
        terms.append(_blend_dense(d_weights, transforms, v_posed))
    return out, sum(terms) if terms else jnp.zeros_like(out)


_blend_sparse_dense_tangents.defjvp(_blend_sparse_jvp, symbolic_zeros=True)


def _skin_dense(body: Body, transforms: Array, v_posed: Array) -> Array:
    """Linear blend skinning v = Σ_j w_vj (R_j v_posed + t_j) for (N, J, 3, 4) transforms.

    Huang eq. 2.4 / von Marcard eq. 2.33, blending all J transforms first: one (V, J) x
    (J, 12N) product, 12 multiply-adds per vertex and joint, then one affine map per
    vertex. This is the CPU path: on XLA-CPU `_skin_sparse` was slower below a few
    hundred samples (the top_k sort and element-wise gathers) and 2.4-5.5x slower in
    linearize + transpose, though 1.5x faster forward at 1024 (benchmarks/body_forward.py).
    """
    return _blend_dense(body.weights, transforms, v_posed)


def _skin_sparse(body: Body, transforms: Array, v_posed: Array, influences: int | None = None) -> Array:
    """Linear blend skinning over each vertex's `influences` largest weights only.

    The same sum as `_skin_dense`, exact whenever no vertex has more non-zero weights
    than `influences` (default `body.max_influences`): v = Σ_k w_vk A_{j_vk} [v_posed; 1]
    with (w_vk, j_vk) the vertex's K largest weights (`lax.top_k`, once per call, not per
    sample). Every term gathers from the small (N, J, 3, 4) transforms, so on a GPU the
    whole blend is one loop that reads the rest-pose vertices and writes the posed ones,
    instead of materialising the (N, V, 12) blended transforms of the dense product.
    Derivatives along the transforms and weights are the dense product's
    (`_blend_sparse_dense_tangents`).
    """
    K = body.max_influences if influences is None else influences
    if K is None:
        raise ValueError("sparse skinning needs a number of influences: body.max_influences is None.")
    return _blend_sparse_dense_tangents(body.weights, transforms, v_posed, K)


def _skin(body: Body, transforms: Array, v_posed: Array, skinning: str = "auto") -> Array:
    """Skinning by `skinning`: "dense", "sparse", or "auto" (dense on CPUs, sparse elsewhere).

    "auto" stages both out with `lax.platform_dependent`, so one traced function is right
    on any backend; bodies with unknown or many influences stay dense everywhere.
    """
    K = body.max_influences
    if skinning == "dense" or (skinning == "auto" and (K is None or K > _SPARSE_MAX_INFLUENCES)):
        return _skin_dense(body, transforms, v_posed)
    if skinning == "sparse":
        return _skin_sparse(body, transforms, v_posed)
    if skinning != "auto":
        raise ValueError(f"skinning must be 'auto', 'dense' or 'sparse', got {skinning!r}.")
    return jax.lax.platform_dependent(body, transforms, v_posed, cpu=_skin_dense, default=_skin_sparse)


def _blend_shapes(
    body: Body,
    betas: Array,
    pose_feature: Array | None,
    joint: bool | None = None,
    blend_dtype=None,
    pad_columns: bool = True,
) -> Array:
    """Rest-pose vertices T(β, θ) = T̄ + B_s(β) + B_p(θ) (Huang eq. 2.2-2.3), (N, V, 3).

    The offsets are matrix products in the default precision (TF32 on GPUs); the template
    is added afterwards in full precision (TF32 on a ~1 m template would cost ~1 mm).
    `joint` (default: from the batch size) stacks [β, pose feature] against the stacked
    bases for one product instead of two; `blend_dtype` (e.g. bfloat16, a benchmark
    variant) multiplies in that dtype with float32 accumulation; `pad_columns` widens the
    stacked product on accelerators (below; False is a benchmark variant). `pose_feature`
    None: B_p ≡ 0 (a body whose posedirs are all zero), the product skipped.
    """
    N, nb, V = betas.shape[0], betas.shape[-1], body.num_vertices
    dtype = body.v_template.dtype
    shapedirs = body.shapedirs[:nb].reshape(nb, 3 * V)
    if pose_feature is None:
        offsets = jnp.matmul(betas.astype(shapedirs.dtype), shapedirs, preferred_element_type=dtype)
        return (body.v_template.reshape(-1) + offsets).reshape(N, V, 3)
    posedirs = body.posedirs.reshape(-1, 3 * V)
    if blend_dtype is not None:
        shapedirs, posedirs = shapedirs.astype(blend_dtype), posedirs.astype(blend_dtype)
        betas, pose_feature = betas.astype(blend_dtype), pose_feature.astype(blend_dtype)
    product = lambda a, b: jnp.matmul(a, b, preferred_element_type=dtype)  # noqa: E731
    if joint is None:
        joint = N >= _JOINT_BLEND_MIN_BATCH
    if not joint:
        offsets = product(betas, shapedirs) + product(pose_feature, posedirs)
        return (body.v_template.reshape(-1) + offsets).reshape(N, V, 3)
    # Zero rows up to a multiple of 32 coefficients: cuBLAS ran the odd 217-deep
    # product 1.35x slower on an H200 (unaligned rows keep it off its fast kernels).
    pad = -(nb + posedirs.shape[0]) % 32
    coeffs = jnp.concatenate([betas, pose_feature, jnp.zeros((N, pad), betas.dtype)], -1)
    bases = jnp.concatenate([shapedirs, posedirs, jnp.zeros((pad, 3 * V), posedirs.dtype)])
    # On accelerators, zero columns up to a multiple of 384 (3 coordinates x 128): an
    # H200 ran the (16384, 224) x (224, 20670) TF32 product of the 6890-vertex body in
    # 1.68 ms and the 20736-wide one in 1.07 ms. The slice fuses into skinning's loop.
    return jax.lax.platform_dependent(
        coeffs, bases, body.v_template.reshape(-1), cpu=functools.partial(_stacked_blend, columns=0),
        default=functools.partial(_stacked_blend, columns=-3 * V % 384 if pad_columns else 0),
    )  # fmt: skip


def _stacked_blend(coeffs: Array, bases: Array, template: Array, columns: int) -> Array:
    """template + coeffs @ bases as (N, V, 3), the product `columns` zero columns (padded
    vertices) wider than the 3V real ones, which are sliced off after."""
    V = template.shape[0] // 3
    if columns:
        bases = jnp.concatenate([bases, jnp.zeros((len(bases), columns), bases.dtype)], -1)
        template = jnp.concatenate([template, jnp.zeros((columns,), template.dtype)])
    offsets = jnp.matmul(coeffs, bases, preferred_element_type=template.dtype)
    return (template + offsets).reshape(len(coeffs), -1, 3)[:, :V]


def _unfolded(body: Body) -> Body:
    """On accelerators, the body's arrays behind an optimisation barrier. A body that jit
    closes over is a constant that XLA folds into the blend product and skinning, and the
    folded program ran 2.5x slower on an H200 (1.95e6 against 4.94e6 passes/s at 16384
    samples; with the barrier 5.0e6, as a body passed as an argument). On CPUs the barrier
    cost up to 2.8x at one sample (the folded constants are cheaper there), so not there."""
    return jax.lax.platform_dependent(body, cpu=lambda b: b, default=jax.lax.optimization_barrier)


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

    Raises ValueError for a NaN/inf, complex or empty input; checked on concrete inputs
    only, so a call inside the user's `jit` costs nothing and is not checked.

    Memory grows with the batch (about 1.4 GiB per 1000 frames on the full default body):
    pose long sequences in chunks with `jaxmocap.body.posed_vertices(body, motion,
    chunk=256)`.
    """
    _check_values("pose", pose, betas, trans)
    pose = jnp.asarray(pose)
    J = body.num_joints
    if pose.ndim < 2 or pose.shape[-2:] != (J, 3):
        raise ValueError(
            f"pose has shape {pose.shape}; expected (..., {J}, 3) axis-angle vectors, one per "
            f"joint of this {body.kind} body. Reshape a flat (..., {3 * J}) pose with "
            f"pose.reshape(*pose.shape[:-1], {J}, 3)."
        )
    dtype = pose.dtype if jnp.issubdtype(pose.dtype, jnp.floating) else body.dtype
    return forward_rotations(body, axis_angle_to_matrix(pose.astype(dtype)), betas, trans)  # a jit of its own


def forward_rotations(body: Body, local_rotations, betas=None, trans=None) -> BodyOutput:
    """The SMPL function M(β, θ) + translation, θ as local rotation matrices.

    Huang eq. 2.1-2.4: T(β, θ) = T̄ + B_s(β) + B_p(θ), joints J(β) = 𝒥 (T̄ + B_s(β)),
    pose blend shapes linear in vec(R(θ_j) - I) for the J-1 non-root joints, then linear
    blend skinning v_i = Σ_j w_ij G_j(θ, J) G_j(0, J)⁻¹ t_i.

    Computation happens in the dtype of `local_rotations` (the body is cast if needed).
    On GPUs and other accelerators skinning sums over each vertex's `body.max_influences`
    non-zero weights only, on CPUs over all joints; both are the same sum up to rounding.

    Args:
        body: the body model.
        local_rotations: (..., J, 3, 3) joint rotations relative to the parent, root first.
        betas: (..., B) shape coefficients, B <= body.num_betas (default: zeros).
        trans: (..., 3) root translation in metres (default: zeros).
    Returns:
        BodyOutput with vertices (..., V, 3), joints (..., J, 3) and global
        joint_rotations (..., J, 3, 3); batch axes broadcast across the inputs.
    """
    _check_values("local_rotations", local_rotations, betas, trans)
    if _all_concrete(body, local_rotations, betas, trans):
        return _forward_rotations_jit(body, local_rotations, betas, trans)
    return forward_rotations_unchecked(body, local_rotations, betas, trans)


def _all_concrete(*trees) -> bool:
    """No tracer among the leaves: a call outside any jit/grad/vmap of the caller's."""
    return not any(isinstance(x, jax.core.Tracer) for x in jax.tree_util.tree_leaves(trees))


# Called outside a trace (scripts, tests, host-side helpers), the forward pass ran as ~100
# eager operations, each compiled at every new shape; as one program per shape it compiles
# once. Inside a caller's trace the plain functions are inlined as before; the shape checks
# (`_check_inputs`) raise the same errors at trace time.
@jax.jit
def _forward_rotations_jit(body, local_rotations, betas, trans):
    return forward_rotations_unchecked(body, local_rotations, betas, trans)


def _check_values(pose_name: str, pose, betas, trans) -> None:
    """The value checks of the public entry points, on concrete inputs only (a traced
    call inside a user's jit is not slowed): a NaN anywhere would make every vertex NaN
    without a word, an empty batch fails deep inside XLA, and a complex pose would be
    cast to its real part."""
    for name, x in ((pose_name, pose), ("betas", betas), ("trans", trans)):
        if x is None:
            continue
        v = concrete(x)  # lists too; None when traced
        dtype = x.dtype if v is None else v.dtype
        if jnp.issubdtype(dtype, jnp.complexfloating):
            raise ValueError(f"{name} is complex ({dtype}); give real numbers (x.real if the imaginary part "
                             "is zero).")  # fmt: skip
        if v is not None and v.dtype.kind not in "biuf":
            raise ValueError(f"{name} must be a numeric array, got dtype {v.dtype}.")
        check_finite(name, v)
    v = concrete(pose)
    if v is not None and v.size == 0:
        raise ValueError(f"{pose_name} has shape {v.shape}: an empty batch (zero frames?); give at least one.")


def forward_rotations_unchecked(
    body: Body,
    local_rotations,
    betas=None,
    trans=None,
    skinning: str = "auto",
    joint_blend=None,
    blend_dtype=None,
    pose_blend: bool = True,
    pad_columns: bool = True,
) -> BodyOutput:
    """`forward_rotations` without its value checks and with its implementation choices
    open (for energies, tests and benchmarks): `skinning` as in `_skin`, `joint_blend`,
    `blend_dtype` and `pad_columns` as in `_blend_shapes`; `pose_blend=False` skips B_p
    (exact only for a body whose posedirs are zero: the caller checks that on the host,
    e.g. `methods.multiview`'s compact body)."""
    local, betas, trans = _check_inputs(body, local_rotations, betas, trans)
    dtype = local.dtype
    if body.dtype != dtype:
        body = body.astype(dtype)
    body = _unfolded(body)
    batch, nb = local.shape[:-3], betas.shape[-1]
    # Work on a flat batch of N samples: 2-D matrix products are what CPU and GPU BLAS
    # run fastest (a 3-D einsum against posedirs made XLA-CPU transpose it every call).
    local, betas, trans = local.reshape(-1, body.num_joints, 3, 3), betas.reshape(-1, nb), trans.reshape(-1, 3)

    pose_feature = (local[:, 1:] - jnp.eye(3, dtype=dtype)).reshape(len(local), -1) if pose_blend else None
    v_posed = _blend_shapes(body, betas, pose_feature, joint_blend, blend_dtype, pad_columns)

    rest = shaped_joints(body, betas)
    global_rot, global_pos = forward_kinematics(body.parents, local, rest)
    # Skinning transform A_j = G_j(θ) G_j(0)⁻¹ = [G_R | G_t - G_R J_j].
    offsets = global_pos - mat3_apply(global_rot, rest)
    transforms = jnp.concatenate([global_rot, offsets[..., None]], -1)  # (N, J, 3, 4)
    vertices = _skin(body, transforms, v_posed, skinning) + trans[:, None]
    unflat = lambda x: x.reshape(*batch, *x.shape[1:])  # noqa: E731
    return BodyOutput(
        vertices=unflat(vertices),
        joints=unflat(global_pos + trans[:, None]),
        joint_rotations=unflat(global_rot),
    )
