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
3. **Per-frame elimination.** Unknowns that only per-frame terms read ("local", e.g.
   the hands and feet in SIP, which only the prior sees) are ordered last and
   eliminated frame by frame, S = H_cc - H_cl H_ll⁻¹ H_lc, batched over frames; the
   band shrinks to the n_c coupled unknowns (51 of 75 in SIP).
4. **Block-tridiagonal Cholesky.** Grouping g = 2b consecutive frames into one
   super-block makes S block-tridiagonal; `lax.scan` factorises it
   (S_k = D_k - W_{k-1}ᵀW_{k-1}, L_k = chol(S_k), W_k = L_k⁻¹U_k, keeping L_k⁻¹) and
   solves by forward and backward substitution (products with L_k⁻¹). Cost
   O(T (g n_c)³ + T n_l³), memory O(T g n²).

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
import numpy as np
from jax import Array

__all__ = [
    "BandedNormalCholesky",
    "jacobian_blocks",
    "normal_blocks",
    "factor_banded",
    "solve_banded",
    "jt_vector",
    "shift_frames",
]


def shift_frames(x: Array, d: int) -> Array:
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


def jacobian_blocks(mv, T: int, n: int, dtype, bandwidths, columns=None) -> list[Array]:
    """Every non-zero Jacobian block of a frame-banded linear map, by colouring.

    Leaves are grouped by bandwidth b and each group gets its own (2b+1)·k JVPs, k the
    number of per-frame columns its leaves read (`columns`, default all n), with the
    other leaves' outputs dead code that XLA removes: per-frame terms cost k JVPs, not
    (2·max b + 1)·n.

    Args:
        mv: linear map (T, n) -> pytree of leaves (T, ...), leaf ℓ's row t depending on
            input frames t - b_ℓ .. t + b_ℓ only.
        T, n: frames and unknowns per frame.
        dtype: dtype of the input.
        bandwidths: b_ℓ per output leaf (in `jtu.tree_leaves` order).
        columns: per leaf, the per-frame columns it depends on (None: all); the blocks
            of the other columns are returned as zeros without being computed.
    Returns:
        One array per leaf, (T, 2b_ℓ+1, m_ℓ, n): block [t, d] = ∂r_t/∂x_{t+d},
        d = -b_ℓ .. b_ℓ (zero where t+d is outside the sequence).
    """
    eye = jnp.eye(n, dtype=dtype)
    t = jnp.arange(T)
    columns = [None] * len(bandwidths) if columns is None else list(columns)
    blocks = [None] * len(bandwidths)
    for b in sorted(set(bandwidths)):
        members = [i for i, bi in enumerate(bandwidths) if bi == b]
        cols = sorted(set().union(*[range(n) if columns[i] is None else columns[i] for i in members]))
        C = 2 * b + 1
        colour = t % C
        unit = eye[np.asarray(cols)]  # (k, n)

        def per_colour(c, members=members, colour=colour, unit=unit):
            # Tangents (k, T, n): e_j on every frame of colour c, for each read column j.
            tangents = (colour == c)[None, :, None].astype(dtype) * unit[:, None, :]
            leaves = jtu.tree_leaves(jax.vmap(mv)(tangents))
            return [leaves[i].reshape(len(cols), T, -1) for i in members]

        # lax.map over colours bounds live memory to one colour's JVP outputs at a time.
        outs = jax.lax.map(per_colour, jnp.arange(C))  # (C, k, T, m) per member
        for i, leaf in zip(members, outs):
            per_frame = jnp.transpose(leaf, (2, 0, 3, 1))  # (T, C, m, k)
            if len(cols) < n:
                # Embed the k computed columns among n (the others are zero).
                pos = np.full(n, len(cols))
                pos[np.asarray(cols)] = np.arange(len(cols))
                zero = jnp.zeros(per_frame.shape[:-1] + (1,), per_frame.dtype)
                per_frame = jnp.concatenate([per_frame, zero], -1)[..., pos]
            blocks[i] = jnp.stack([per_frame[t, (t + d) % C] for d in range(-b, b + 1)], axis=1)
    return blocks


def normal_blocks(blocks: list[Array], bandwidths, dtype, coupled: int | None = None) -> list[Array]:
    """Upper block band of JᵀJ: H[e][s] = H_{s, s+e}, e = 0 .. 2·max(b).

    H[0] is (T, n, n). With `coupled` = n_c, the unknowns are ordered coupled first and
    every frame-coupling leaf (b > 0) reads the first n_c only, so H[e >= 1] is
    (T, n_c, n_c) and those leaves add to H[0]'s top-left corner only.

    H[e][s] = Σ_ℓ Σ_d J_ℓ[s-d, d]ᵀ J_ℓ[s-d, d+e]: the shifted factors of every leaf and
    offset are stacked along the contracted axis so that each H[e] is one batched
    product (on XLA-CPU the cost of a batched product is nearly independent of its
    contracted length, so this is several times faster than one product per pair).
    """
    B = max(bandwidths)
    n = blocks[0].shape[-1]
    nc = n if coupled is None else coupled
    H = []
    for e in range(2 * B + 1):
        left, right = [], []
        for J, b in zip(blocks, bandwidths):
            if 2 * b < e:
                continue
            J = J.astype(dtype)
            if b > 0 and nc < n:
                J = J[..., :nc]
                if e == 0:
                    J = jnp.pad(J, [(0, 0)] * (J.ndim - 1) + [(0, n - nc)])
            for d in range(-b, b + 1 - e):
                # Row t = s - d couples frames s = t + d and s + e = t + d + e.
                left.append(shift_frames(J[:, d + b], d))
                right.append(shift_frames(J[:, d + e + b], d))
        H.append(jnp.einsum("tmi,tmj->tij", jnp.concatenate(left, 1), jnp.concatenate(right, 1)))
    return H


def jt_vector(blocks: list[Array], bandwidths, residuals: list[Array], dtype) -> Array:
    """Jᵀ r from the blocks: g[s] = Σ_d J_{s-d, s}ᵀ r_{s-d}.  -> (T, n)."""
    T, n = blocks[0].shape[0], blocks[0].shape[-1]
    g = jnp.zeros((T, n), dtype)
    for J, b, r in zip(blocks, bandwidths, residuals):
        r = r.reshape(T, -1).astype(dtype)
        for d in range(-b, b + 1):
            g = g + shift_frames(jnp.einsum("tmi,tm->ti", J[:, d + b].astype(dtype), r), d)
    return g


_F32_SHIFT = 1e-5


class BandedFactor(eqx.Module):
    """Factor of JᵀJ + λI: local unknowns eliminated per frame, then a block-tridiagonal
    (super-block) Cholesky of the coupled ones' Schur complement, plus the Jacobi scale."""

    L: Array  # (K, N, N) inverses of the lower Cholesky factors of the Schur complements
    W: Array  # (K, N, N) L_k⁻¹ U_k (last one unused)
    scale: Array  # (T, n) diag(H)^(-1/2)
    L_local: Array | None  # (T, n_l, n_l) Cholesky factor of H_ll per frame
    X: Array | None  # (T, n_l, n_c) L_ll⁻¹ H_lc
    group: int = eqx.field(static=True)


def factor_banded(H: list[Array], damping: Array | float = 0.0, marquardt: bool = False) -> BandedFactor:
    """Factorise JᵀJ + λ I (or JᵀJ + λ diag(JᵀJ), `marquardt`, eq. 2.54) from its band.

    H as from `normal_blocks`: H[0] (T, n, n); H[e >= 1] (T, n_c, n_c) couple only the
    first n_c unknowns of each frame. The other n_l = n - n_c ("local") unknowns are
    eliminated frame by frame (batched, exact: S = H_cc - H_cl H_ll⁻¹ H_lc), then frames
    are grouped in super-blocks of g = max(1, 2b) so the band of S becomes
    block-tridiagonal; the tail is padded with identity frames.
    """
    Hd = H[0]
    T, n, _ = Hd.shape
    nc = H[1].shape[-1] if len(H) > 1 else n
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
    Hd = Hd * scale[:, :, None] * scale[:, None, :]
    if jnp.finfo(dtype).bits < 64:
        # In float32 the scaled matrix (unit diagonal) loses definiteness to rounding when
        # JᵀJ is ill-conditioned (measured: NaN factors on the SIP problem); a shift of
        # a few ulps of its unit diagonal restores it at the cost of a slightly damped step.
        Hd = Hd + _F32_SHIFT * eye
    L_local = X = None
    if nc < n:
        L_local = jnp.linalg.cholesky(Hd[:, nc:, nc:])
        X = jsl.solve_triangular(L_local, Hd[:, nc:, :nc], lower=True)  # (T, n_l, n_c)
        Hd = Hd[:, :nc, :nc] - jnp.einsum("tlc,tld->tcd", X, X)
    sc = scale[:, :nc]
    Hs = [Hd] + [H[e] * sc[:, :, None] * shift_frames(sc, -e)[:, None, :] for e in range(1, len(H))]
    n = nc
    eye = jnp.eye(n, dtype=dtype)
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
        L_inv = jsl.solve_triangular(jnp.linalg.cholesky(D), jnp.broadcast_to(jnp.eye(D.shape[-1], dtype=dtype), D.shape), lower=True)
        return BandedFactor(L_inv, jnp.zeros_like(L_inv), scale, L_local, X, g)

    def step(W_prev, DU):
        Dk, Uk = DU
        S = Dk - W_prev.T @ W_prev
        # The inverse factor turns both substitutions of `solve_banded` into products,
        # which XLA-CPU runs several times faster than triangular solves in a scan.
        Lk_inv = jsl.solve_triangular(jnp.linalg.cholesky(S), eye_N, lower=True)
        Wk = Lk_inv @ Uk
        return Wk, (Lk_inv, Wk)

    eye_N = jnp.eye(D.shape[-1], dtype=dtype)
    _, (L, W) = jax.lax.scan(step, jnp.zeros_like(D[0]), (D, U))
    return BandedFactor(L, W, scale, L_local, X, g)


def solve_banded(factor: BandedFactor, rhs: Array) -> Array:
    """Solve (JᵀJ + λI) x = rhs with a `BandedFactor`.  rhs (T, n) -> (T, n)."""
    T, n = rhs.shape
    K, N, _ = factor.L.shape
    b = rhs.astype(factor.L.dtype) * factor.scale
    if factor.X is not None:
        nc = factor.X.shape[-1]
        z_local = jsl.solve_triangular(factor.L_local, b[:, nc:, None], lower=True)[..., 0]
        b = b[:, :nc] - jnp.einsum("tlc,tl->tc", factor.X, z_local)
    nc = b.shape[1]
    b = b.reshape(-1)
    b = jnp.concatenate([b, jnp.zeros((K * N - T * nc,), b.dtype)]).reshape(K, N)

    def forward(z_prev, LWb):
        Lk_inv, Wk_prev, bk = LWb
        z = Lk_inv @ (bk - Wk_prev.T @ z_prev)
        return z, z

    W_prev = jnp.concatenate([jnp.zeros_like(factor.W[:1]), factor.W[:-1]], 0)
    _, z = jax.lax.scan(forward, jnp.zeros((N,), b.dtype), (factor.L, W_prev, b))

    def backward(x_next, LWz):
        Lk_inv, Wk, zk = LWz
        x = Lk_inv.T @ (zk - Wk @ x_next)
        return x, x

    _, x = jax.lax.scan(backward, jnp.zeros((N,), b.dtype), (factor.L, factor.W, z), reverse=True)
    x = x.reshape(-1)[: T * nc].reshape(T, nc)
    if factor.X is not None:
        rest = z_local - jnp.einsum("tlc,tc->tl", factor.X, x)
        x_local = jsl.solve_triangular(jnp.swapaxes(factor.L_local, -1, -2), rest[..., None], lower=False)[..., 0]
        x = jnp.concatenate([x, x_local], 1)
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
