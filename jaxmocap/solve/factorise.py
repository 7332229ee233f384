"""Factorise the structured normal equations (`structure.py`) and solve with the factor.

1. **Scaling and damping.** Everything is Jacobi-scaled (diag(H)^(-1/2)) after adding
   λI (or λ diag(H), eq. 2.54), and formed in `factor_dtype` (float64 when x64 is on:
   the 1/dt² of acceleration terms squares into H's condition number).
2. **Per-frame elimination.** Per-frame unknowns that no frame-coupling term reads
   ("local": SIP's hands and feet, every unknown of a per-frame problem) are eliminated
   frame by frame, S = H_cc - H_cl H_ll⁻¹ H_lc, batched over frames; their fill lands in
   the frame's coupled unknowns, the windows containing it and the border.
3. **The coupled unknowns** (coupled frame unknowns and windows) are factorised behind
   `tridiagonal.CoupledFactor`: in super-blocks of frames and windows by `tridiagonal.py`'s
   scan or cyclic reduction (`superblocks.py`), or, without windows and where the
   frame-coupling terms have fewer rows per frame than coupled unknowns, in those rows'
   space (`rows.py`: the same pivots, the band's off-diagonal blocks never formed).
4. **Border.** The Schur complement on the sequence-wide unknowns,
   S = H_GG - H_GA H_AA⁻¹ H_AG, is formed by banded solves against the g border
   columns (O(T g) work), factorised densely, and the step is recovered by back
   substitution.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jax import Array

from ..timeseries import shift_frames
from .rows import rows_cyclic_factor, rows_factor, scale_rows
from .structure import Factorisation, NormalEquations, Structure, group_sum, window_of_slot
from .superblocks import band_factor
from .tridiagonal import CoupledFactor, default_tridiagonal_method, inverse_cholesky

__all__ = ["Normal", "Factor", "factor", "solve_factored"]

_F32_SHIFT = 1e-5


class Normal(NormalEquations):
    """The structured matrix (see `structure.py`).

    FF: [H_{t,t+e}] for e = 0..B2: FF[0] (T, n, n), FF[e>0] (T, nc, nc); or, with `C`,
    FF[0] only and the frame band as the coupling terms' rows C (T, B2+1, R, nc),
    H_{s,s'} = Σ_t C_tᵀ C_t for s ≠ s' (`rows.py`).
    FW (T, K, n, m); WW (W, K, m, m) with WW[w, e] = H_{w, w+e}; FG (T, n, g); WG (W, m, g); GG (g, g).
    """

    FF: list
    FW: Array | None
    WW: Array | None
    FG: Array | None
    WG: Array | None
    GG: Array | None
    C: Array | None = None

    def factor(self, st: Structure, damping, marquardt: bool = False, tridiagonal: str | None = None) -> Factor:
        return factor(self, st, damping, marquardt, tridiagonal)


class Factor(Factorisation):
    """A factorised `Normal` (+ damping): scales, per-frame elimination, the coupled
    unknowns' factor, and the border's Schur complement."""

    sF: Array
    sW: Array | None
    sG: Array | None
    L_local_inv: Array | None  # (T, n_l, n_l) inverse Cholesky factors of H_ll
    X: Array | None  # (T, n_l, nc + K m + g): L_ll⁻¹ [H_lc | H_lW | H_lG]
    tri: CoupledFactor | None  # the coupled frames (+ windows)
    Y: Array | None  # (Kb, N, g) or, with rows, (T, nc, g): A⁻¹ C
    S_inv: Array | None  # (g, g) inverse Cholesky factor of the border's Schur complement
    st: Structure = eqx.field(static=True)

    def solve(self, bF: Array, bW: Array | None = None, bG: Array | None = None):
        return solve_factored(self, bF, bW, bG)


def _damp_scale(H: Array, lam, marquardt: bool):
    """Add λI (or λ diag) to the diagonal blocks (..., k, k); return (H, diag^-1/2)."""
    k = H.shape[-1]
    eye = jnp.eye(k, dtype=H.dtype)
    d = jnp.diagonal(H, axis1=-2, axis2=-1)
    if marquardt:
        # Floor the diagonal so unknowns no residual touches stay factorisable.
        d = jnp.maximum(d, 1e-12 * jnp.maximum(jnp.max(d), 1.0))
        H = H + jnp.asarray(lam, H.dtype) * d[..., :, None] * eye
    else:
        H = H + jnp.asarray(lam, H.dtype) * eye
    diag = jnp.diagonal(H, axis1=-2, axis2=-1)
    scale = jnp.where(diag > 0, jax.lax.rsqrt(jnp.where(diag > 0, diag, 1.0)), 1.0)
    return H, scale


def _outer(a, b):
    return a[..., :, None] * b[..., None, :]


def factor(
    normal: Normal, st: Structure, damping: Array | float = 0.0, marquardt: bool = False, tridiagonal: str | None = None
) -> Factor:
    """Factorise H + λI (or H + λ diag(H), eq. 2.54) in its structure (the module docstring).

    tridiagonal: "scan", "cyclic", "rows" or None (the backend's default), see
    `tridiagonal.py`; a `normal` with coupling rows (`normal_equations` with "rows" or
    "cyclic") is factorised by `rows.py`, in frame order ("rows") or by cyclic reduction
    ("cyclic"); "rows" without them by "scan".
    """
    T, n, nc, K, m, g = st.T, st.n, st.nc, st.K, st.m, st.g
    FF = list(normal.FF)
    dtype = FF[0].dtype
    F0, sF = _damp_scale(FF[0], damping, marquardt)
    FF = [F0 * _outer(sF, sF)] + [f * _outer(sF[:, :nc], shift_frames(sF[:, :nc], -e)) for e, f in enumerate(FF[1:], 1)]
    FW = WW = FG = WG = GG = sW = sG = None
    if st.W:
        W0, sW = _damp_scale(normal.WW[:, 0], damping, marquardt)
        WW = normal.WW.at[:, 0].set(W0)
        WW = jnp.stack([WW[:, e] * _outer(sW, shift_frames(sW, -e)) for e in range(K)], 1)
        sW_slot = jnp.stack([window_of_slot(sW, j, st) for j in range(K)], 1)  # (T, K, m)
        FW = normal.FW * sF[:, None, :, None] * sW_slot[:, :, None, :]
    if g:
        GG, sG = _damp_scale(normal.GG, damping, marquardt)
        GG = GG * _outer(sG, sG)
        FG = normal.FG * _outer(sF, sG)
        WG = None if normal.WG is None else normal.WG * _outer(sW, sG)
    if jnp.finfo(dtype).bits < 64:
        # In float32 the scaled matrix (unit diagonal) loses definiteness to rounding when
        # H is ill-conditioned (measured: NaN factors on the SIP problem); a shift of a
        # few ulps of its unit diagonal restores it at the cost of a slightly damped step.
        FF[0] = FF[0] + _F32_SHIFT * jnp.eye(n, dtype=dtype)
        if st.W:
            WW = WW.at[:, 0].add(_F32_SHIFT * jnp.eye(m, dtype=dtype))
        if g:
            GG = GG + _F32_SHIFT * jnp.eye(g, dtype=dtype)
    L_local_inv = X = None
    if nc < n:
        H0 = FF[0]
        L_local_inv = inverse_cholesky(H0[:, nc:, nc:])
        right = [H0[:, nc:, :nc]]
        if st.W:
            right.append(jnp.swapaxes(FW[:, :, nc:, :], 1, 2).reshape(T, n - nc, K * m))
        if g:
            right.append(FG[:, nc:])
        X = L_local_inv @ jnp.concatenate(right, -1)
        Xc, Xw, Xg = _split_X(X, st)
        FF[0] = H0[:, :nc, :nc] - jnp.einsum("tla,tlb->tab", Xc, Xc)
        if st.W:
            FW = FW[:, :, :nc] - jnp.einsum("tla,tjlb->tjab", Xc, Xw)
            for j in range(K):
                for i in range(j + 1):
                    WW = WW.at[:, j - i].add(-group_sum("qula,qulb->qab", Xw[:, j], Xw[:, i], j, st))
        if g:
            FG = FG[:, :nc] - jnp.einsum("tla,tlk->tak", Xc, Xg)
            GG = GG - jnp.einsum("tla,tlk->ak", Xg, Xg)
            if st.W:
                for j in range(K):
                    WG = WG - group_sum("qula,qulk->qak", Xw[:, j], Xg, j, st)
    tri = Y = S_inv = None
    G, r, Kb = st.blocking()
    if normal.C is not None:
        method, C = tridiagonal or default_tridiagonal_method(), scale_rows(normal.C, sF[:, :nc])
        if method == "cyclic":
            tri = rows_cyclic_factor(FF[0], C)
        else:
            tri = rows_factor(FF[0], C)
    elif Kb:
        tri = band_factor(FF, FW, WW, st, tridiagonal)
    if g:
        if Kb:
            C = tri.pack(FG[:, :nc] if nc else None, WG)  # (Kb, N, g)
            Y = tri.solve(C)
            S = GG - jnp.einsum("kna,knb->ab", C, Y)
        else:
            S = GG
        S_inv = inverse_cholesky(S)
    return Factor(sF, sW, sG, L_local_inv, X, tri, Y, S_inv, st)


def _split_X(X: Array, st: Structure):
    nc, K, m, g = st.nc, st.K, st.m, st.g
    T, nl = X.shape[:2]
    Xc = X[..., :nc]
    Xw = jnp.swapaxes(X[..., nc : nc + K * m].reshape(T, nl, K, m), 1, 2) if st.W else None  # (T, K, n_l, m)
    Xg = X[..., nc + K * m :] if g else None
    return Xc, Xw, Xg


def solve_factored(f: Factor, bF: Array, bW: Array | None = None, bG: Array | None = None):
    """Solve (H + λI) x = b with a `Factor`; b and x as (F (T, n), W (W, m), G (g,)), solver order."""
    st = f.st
    nc, K, g = st.nc, st.K, st.g
    dtype = f.sF.dtype
    bF = bF.astype(dtype) * f.sF
    bW = None if bW is None else bW.astype(dtype) * f.sW
    bG = None if bG is None else bG.astype(dtype) * f.sG
    if f.X is not None:
        Xc, Xw, Xg = _split_X(f.X, st)
        z_local = jnp.einsum("tlk,tk->tl", f.L_local_inv, bF[:, nc:])
        cF = bF[:, :nc] - jnp.einsum("tla,tl->ta", Xc, z_local)
        if st.W:
            for j in range(K):
                bW = bW - group_sum("qula,qul->qa", Xw[:, j], z_local, j, st)
        if g:
            bG = bG - jnp.einsum("tlk,tl->k", Xg, z_local)
    else:
        cF = bF
    xF_c, xW, xG = cF, bW, None
    if f.tri is not None:
        b = f.tri.pack(cF, bW)
        z = f.tri.solve(b[..., None])[..., 0]
        if g:
            u = f.S_inv @ (bG - jnp.einsum("kna,kn->a", f.Y, b))
            xG = f.S_inv.T @ u
            z = z - jnp.einsum("kna,a->kn", f.Y, xG)
        xF_c, xW = f.tri.unpack(z)
    elif g:
        xG = f.S_inv.T @ (f.S_inv @ bG)
    if f.X is not None:
        rest = z_local
        if nc:
            rest = rest - jnp.einsum("tla,ta->tl", Xc, xF_c)
        if st.W:
            for j in range(K):
                rest = rest - jnp.einsum("tla,ta->tl", Xw[:, j], window_of_slot(xW, j, st))
        if g:
            rest = rest - jnp.einsum("tlk,k->tl", Xg, xG)
        x_local = jnp.einsum("tkl,tk->tl", f.L_local_inv, rest)
        xF = jnp.concatenate([xF_c, x_local], 1) if nc else x_local
    else:
        xF = xF_c
    xF = xF * f.sF
    xW = None if xW is None else xW * f.sW
    xG = None if xG is None else xG * f.sG
    return xF, xW, xG
