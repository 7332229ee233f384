"""Block-banded normal equations: Jacobian blocks by frame colouring, banded Cholesky.

A whole-sequence problem has n unknowns per frame (75 for pose + translation) and T
frames. With every residual row t depending on frames t-b .. t+b only (`Term.bandwidth`),
the Jacobian is block-banded and JᵀJ has block bandwidth 2b (von Marcard eq. 3.27,
3.30-3.31). This module exploits that, at a cost linear in T:

1. **Compressed Jacobian.** Frames s ≡ c (mod 2b+1) never share a residual row, so one
   JVP with the unit vector e_k placed on every frame of colour c recovers column k of
   all blocks J_{t,s} with s ≡ c at once: (2b+1)·n JVPs give every block, independent
   of T (Curtis-Powell-Reid colouring).
2. **Normal equations.** H = JᵀJ + λ I, assembled as per-frame n×n blocks H_{s,s+e},
   e = 0..2b, in `factor_dtype` (float64 when the problem is float32 and x64 is on:
   the 1/dt² of the acceleration term squares into H's condition number), after a
   symmetric Jacobi scaling diag(H)^(-1/2) that removes the bad scaling between terms.
3. **Block-tridiagonal Cholesky.** Grouping g = 2b consecutive frames into one
   super-block makes H block-tridiagonal; `lax.scan` factorises it
   (S_k = D_k - W_{k-1}ᵀW_{k-1}, L_k = chol(S_k), W_k = L_k⁻¹U_k) and solves by forward
   and backward substitution. Cost O(T (gn)³), memory O(T g n²).

`BandedNormalCholesky` wraps this as a lineax solver, so it plugs into
`optx.LevenbergMarquardt(linear_solver=...)` / `optx.GaussNewton(linear_solver=...)`.
It solves the least-squares problem min ‖A x - v‖ through the normal equations, where A
is either a residual Jacobian J (Gauss-Newton) or optimistix's damped operator [J; √λ I]
(Levenberg-Marquardt), which it recognises and turns into JᵀJ + λ I without any JVP of
the damping rows.
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
import jax.tree_util as jtu
import lineax as lx
from jax import Array

__all__ = [
    "BandedNormalCholesky",
    "jacobian_blocks",
    "normal_blocks",
    "factor_banded",
    "solve_banded",
    "jt_vector",
]


def _shift(x: Array, d: int) -> Array:
    """y[s] = x[s - d] along axis 0, zero where s - d is out of range."""
    if d == 0:
        return x
    T = x.shape[0]
    if abs(d) >= T:
        return jnp.zeros_like(x)
    zeros = jnp.zeros((abs(d),) + x.shape[1:], x.dtype)
    if d > 0:
        return jnp.concatenate([zeros, x[: T - d]], 0)
    return jnp.concatenate([x[-d:], zeros], 0)


def jacobian_blocks(mv, T: int, n: int, dtype, bandwidths) -> list[Array]:
    """Every non-zero Jacobian block of a frame-banded linear map, by colouring.

    Leaves are grouped by bandwidth b and each group gets its own (2b+1)·n JVPs, with
    the other leaves' outputs dead code that XLA removes: per-frame terms cost n JVPs,
    not (2·max b + 1)·n.

    Args:
        mv: linear map (T, n) -> pytree of leaves (T, ...), leaf ℓ's row t depending on
            input frames t - b_ℓ .. t + b_ℓ only.
        T, n: frames and unknowns per frame.
        dtype: dtype of the input.
        bandwidths: b_ℓ per output leaf (in `jtu.tree_leaves` order).
    Returns:
        One array per leaf, (T, 2b_ℓ+1, m_ℓ, n): block [t, d] = ∂r_t/∂x_{t+d},
        d = -b_ℓ .. b_ℓ (zero where t+d is outside the sequence).
    """
    eye = jnp.eye(n, dtype=dtype)
    t = jnp.arange(T)
    blocks = [None] * len(bandwidths)
    for b in sorted(set(bandwidths)):
        members = [i for i, bi in enumerate(bandwidths) if bi == b]
        C = 2 * b + 1
        colour = t % C

        def per_colour(c, members=members, colour=colour):
            # Tangents (n, T, n): e_k on every frame of colour c.
            tangents = (colour == c)[None, :, None].astype(dtype) * eye[:, None, :]
            leaves = jtu.tree_leaves(jax.vmap(mv)(tangents))
            return [leaves[i].reshape(n, T, -1) for i in members]

        # lax.map over colours bounds live memory to one colour's JVP outputs at a time.
        outs = jax.lax.map(per_colour, jnp.arange(C))  # (C, n, T, m) per member
        for i, leaf in zip(members, outs):
            per_frame = jnp.transpose(leaf, (2, 0, 3, 1))  # (T, C, m, n)
            blocks[i] = jnp.stack([per_frame[t, (t + d) % C] for d in range(-b, b + 1)], axis=1)
    return blocks


def normal_blocks(blocks: list[Array], bandwidths, dtype) -> list[Array]:
    """Upper block band of JᵀJ: H[e][s] = H_{s, s+e}, e = 0 .. 2·max(b), each (T, n, n)."""
    B = max(bandwidths)
    T, n = blocks[0].shape[0], blocks[0].shape[-1]
    H = [jnp.zeros((T, n, n), dtype) for _ in range(2 * B + 1)]
    for J, b in zip(blocks, bandwidths):
        J = J.astype(dtype)
        for e in range(2 * b + 1):
            for d in range(-b, b + 1 - e):
                # Row t = s - d couples frames s = t + d and s + e = t + d + e.
                Q = jnp.einsum("tmi,tmj->tij", J[:, d + b], J[:, d + e + b])
                H[e] = H[e] + _shift(Q, d)
    return H


def jt_vector(blocks: list[Array], bandwidths, residuals: list[Array], dtype) -> Array:
    """Jᵀ r from the blocks: g[s] = Σ_d J_{s-d, s}ᵀ r_{s-d}.  -> (T, n)."""
    T, n = blocks[0].shape[0], blocks[0].shape[-1]
    g = jnp.zeros((T, n), dtype)
    for J, b, r in zip(blocks, bandwidths, residuals):
        r = r.reshape(T, -1).astype(dtype)
        for d in range(-b, b + 1):
            g = g + _shift(jnp.einsum("tmi,tm->ti", J[:, d + b].astype(dtype), r), d)
    return g


_F32_SHIFT = 1e-5


class BandedFactor(eqx.Module):
    """Cholesky factor of a block-tridiagonal (super-block) matrix, plus Jacobi scale."""

    L: Array  # (K, N, N) lower factors of the Schur complements
    W: Array  # (K, N, N) L_k⁻¹ U_k (last one unused)
    scale: Array  # (T, n) diag(H)^(-1/2)
    group: int = eqx.field(static=True)


def factor_banded(H: list[Array], damping: Array | float = 0.0, marquardt: bool = False) -> BandedFactor:
    """Factorise JᵀJ + λ I (or JᵀJ + λ diag(JᵀJ), `marquardt`, eq. 2.54) from its band.

    Frames are grouped in super-blocks of g = max(1, 2b) so the band becomes
    block-tridiagonal; the tail is padded with identity frames.
    """
    Hd = H[0]
    T, n, _ = Hd.shape
    dtype = Hd.dtype
    eye = jnp.eye(n, dtype=dtype)
    if marquardt:
        d = jnp.diagonal(Hd, axis1=-2, axis2=-1)
        # Floor the diagonal so unknowns no residual touches stay factorisable.
        d = jnp.maximum(d, 1e-12 * jnp.maximum(jnp.max(d), 1.0))
        Hd = Hd + jnp.asarray(damping, dtype) * d[:, :, None] * eye
    else:
        Hd = Hd + jnp.asarray(damping, dtype) * eye
    # Jacobi scaling s_i = diag(H)^(-1/2) (1 for empty columns) conditions the factor.
    diag = jnp.diagonal(Hd, axis1=-2, axis2=-1)
    scale = jnp.where(diag > 0, jax.lax.rsqrt(jnp.where(diag > 0, diag, 1.0)), 1.0)
    Hs = [Hd * scale[:, :, None] * scale[:, None, :]]
    if jnp.finfo(dtype).bits < 64:
        # In float32 the scaled matrix (unit diagonal) loses definiteness to rounding when
        # JᵀJ is ill-conditioned (measured: NaN factors on the SIP problem); a shift of
        # a few ulps of its unit diagonal restores it at the cost of a slightly damped step.
        Hs[0] = Hs[0] + _F32_SHIFT * eye
    for e in range(1, len(H)):
        Hs.append(H[e] * scale[:, :, None] * _shift(scale, -e)[:, None, :])
    g = max(1, len(H) - 1)
    K = -(-T // g)
    pad = K * g - T
    if pad:
        Hs[0] = jnp.concatenate([Hs[0], jnp.broadcast_to(eye, (pad, n, n))], 0)
        Hs[1:] = [jnp.concatenate([h, jnp.zeros((pad, n, n), dtype)], 0) for h in Hs[1:]]
    Hs = [h.reshape(K, g, n, n) for h in Hs]
    zero = jnp.zeros((K, n, n), dtype)
    # Super-block D_k[i, j] = H_{kg+i, kg+j}; U_k[i, j] = H_{kg+i, (k+1)g+j}.
    D_rows, U_rows = [], []
    for i in range(g):
        D_row, U_row = [], []
        for j in range(g):
            e = j - i
            if e >= 0:
                D_row.append(Hs[e][:, i])
            else:
                D_row.append(jnp.swapaxes(Hs[-e][:, j], -1, -2))
            e = g + j - i
            U_row.append(Hs[e][:, i] if e < len(Hs) else zero)
        D_rows.append(jnp.concatenate(D_row, -1))
        U_rows.append(jnp.concatenate(U_row, -1))
    D = jnp.concatenate(D_rows, -2)  # (K, N, N)
    U = jnp.concatenate(U_rows, -2)
    if g == 1 and len(H) == 1:
        L = jnp.linalg.cholesky(D)
        return BandedFactor(L, jnp.zeros_like(L), scale, g)

    def step(W_prev, DU):
        Dk, Uk = DU
        S = Dk - W_prev.T @ W_prev
        Lk = jnp.linalg.cholesky(S)
        Wk = jsl.solve_triangular(Lk, Uk, lower=True)
        return Wk, (Lk, Wk)

    _, (L, W) = jax.lax.scan(step, jnp.zeros_like(D[0]), (D, U))
    return BandedFactor(L, W, scale, g)


def solve_banded(factor: BandedFactor, rhs: Array) -> Array:
    """Solve (JᵀJ + λI) x = rhs with a `BandedFactor`.  rhs (T, n) -> (T, n)."""
    T, n = rhs.shape
    K, N, _ = factor.L.shape
    b = (rhs.astype(factor.L.dtype) * factor.scale).reshape(-1)
    b = jnp.concatenate([b, jnp.zeros((K * N - T * n,), b.dtype)]).reshape(K, N)
    def forward(z_prev, LWb):
        Lk, Wk_prev, bk = LWb
        z = jsl.solve_triangular(Lk, bk - Wk_prev.T @ z_prev, lower=True)
        return z, z

    W_prev = jnp.concatenate([jnp.zeros_like(factor.W[:1]), factor.W[:-1]], 0)
    _, z = jax.lax.scan(forward, jnp.zeros((N,), b.dtype), (factor.L, W_prev, b))

    def backward(x_next, LWz):
        Lk, Wk, zk = LWz
        x = jsl.solve_triangular(Lk.T, zk - Wk @ x_next, lower=False)
        return x, x

    _, x = jax.lax.scan(backward, jnp.zeros((N,), b.dtype), (factor.L, factor.W, z), reverse=True)
    x = x.reshape(-1)[: T * n].reshape(T, n)
    return (x * factor.scale).astype(rhs.dtype)


def _damped_parts(operator: lx.AbstractLinearOperator, damped: bool | None):
    """(J.mv, λ) for optimistix's LM operator y ↦ (J y, √λ y); (A.mv, None) otherwise.

    optimistix 0.1 closure-converts the damped map into an opaque jaxpr, so it is
    recognised by structure (a 2-tuple output whose second part is shaped like the
    input) unless `damped` says so explicitly; √λ is read off one probe product.
    """
    out, struct = operator.out_structure(), operator.in_structure()
    if damped is None:
        damped = isinstance(out, tuple) and len(out) == 2 and eqx.tree_equal(out[1], struct) is True
    if not damped:
        return operator.mv, None
    probe = jnp.zeros(struct.shape, struct.dtype).at[0, 0].set(1.0)
    sqrt_lambda = operator.mv(probe)[1][0, 0]
    return (lambda y: operator.mv(y)[0]), sqrt_lambda**2


class BandedNormalCholesky(lx.AbstractLinearSolver):
    """Least-squares solve through block-banded normal equations (a lineax solver).

    For an operator A: (T, n) -> residual pytree whose leaf ℓ has frame bandwidth b_ℓ,
    returns x = (AᵀA)⁻¹ Aᵀ v. When A is optimistix's Levenberg-Marquardt operator
    [J; √λ I] this is the damped step (JᵀJ + λ I)⁻¹ Jᵀ r, von Marcard eq. 2.52.

    Attributes:
        bandwidths: b per residual leaf of J, in `jtu.tree_leaves` order (for a dict of
            terms: sorted by name). A single int applies to every leaf.
        factor_dtype: dtype in which JᵀJ is formed and factorised (None: the operator's).
        damped: whether the operator is optimistix's damped [J; √λ I] (None: detect it
            from the output structure, a 2-tuple whose second part is shaped like y).
    """

    bandwidths: tuple[int, ...] | int = eqx.field(static=True, default=0)
    factor_dtype: Any = eqx.field(static=True, default=None)
    damped: bool | None = eqx.field(static=True, default=None)

    def _leaf_bandwidths(self, out_structure) -> tuple[int, ...]:
        leaves = jtu.tree_leaves(out_structure)
        if isinstance(self.bandwidths, int):
            return (self.bandwidths,) * len(leaves)
        if len(self.bandwidths) != len(leaves):
            raise ValueError(
                f"BandedNormalCholesky has {len(self.bandwidths)} bandwidths but the "
                f"operator has {len(leaves)} output leaves; give one per residual leaf."
            )
        return tuple(self.bandwidths)

    def init(self, operator, options):
        del options
        jac_mv, damping = _damped_parts(operator, self.damped)
        struct = operator.in_structure()
        out_structure = operator.out_structure()
        if damping is not None:
            out_structure = out_structure[0]
        if not (hasattr(struct, "shape") and len(struct.shape) == 2):
            raise ValueError(
                f"BandedNormalCholesky needs a (T, n) array of unknowns, got {struct}; "
                "ravel the per-frame parameters first (FrameLayout.ravel)."
            )
        T, n = struct.shape
        for leaf in jtu.tree_leaves(out_structure):
            if leaf.shape[:1] != (T,):
                raise ValueError(
                    f"every residual leaf must have the frame axis first (T={T}), got {leaf.shape}."
                )
        bw = self._leaf_bandwidths(out_structure)
        dtype = self.factor_dtype or struct.dtype
        blocks = jacobian_blocks(jac_mv, T, n, struct.dtype, bw)
        H = normal_blocks(blocks, bw, dtype)
        factor = factor_banded(H, 0.0 if damping is None else damping)
        return factor, blocks, damping

    def compute(self, state, vector, options):
        del options
        factor, blocks, damping = state
        bw = tuple((b.shape[1] - 1) // 2 for b in blocks)
        r = vector if damping is None else vector[0]
        g = jt_vector(blocks, bw, jtu.tree_leaves(r), factor.L.dtype)
        if damping is not None:
            # Aᵀv = Jᵀ v_r + √λ v_y (v_y = 0 in optimistix's LM, honoured anyway).
            g = g + jnp.sqrt(damping).astype(g.dtype) * vector[1].astype(g.dtype)
        x = solve_banded(factor, g.astype(factor.L.dtype)).astype(blocks[0].dtype)
        return x, lx.RESULTS.successful, {}

    def transpose(self, state, options):
        raise NotImplementedError(
            "BandedNormalCholesky solves a least-squares problem; differentiate through "
            "optimistix with optx.ImplicitAdjoint(linear_solver=lx.AutoLinearSolver(...))."
        )

    def conj(self, state, options):
        return state, options

    def assume_full_rank(self):
        return True
