"""The normal equations from Jacobian blocks: H = JᵀJ and g = Jᵀr in the `Structure`'s blocks.

Each residual leaf is linearised as `TermBlocks` (its frame band, window and border
blocks, from `colouring.py` or a term's analytic Jacobian) or, for a per-frame term
with a factored analytic Jacobian, `FactoredBlocks`; `normal_equations` sums their
products into a `Normal` (`factorise.py`): the frame band H_{t,t+e}, or the coupling
terms' rows instead where `uses_rows`, the frame-window, window and border blocks.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import jax.tree_util as jtu
import numpy as np
from jax import Array

from ..timeseries import shift_frames
from .factorise import Normal
from .structure import Structure, group_sum
from .tridiagonal import default_tridiagonal_method

__all__ = [
    "TermBlocks",
    "FactoredBlocks",
    "jt_vector",
    "normal_equations",
    "pin_padded",
    "uses_rows",
    "half_squared_norm",
]


class TermBlocks(eqx.Module):
    """One residual leaf linearised: r (T, m_t); JF (T, 2b+1, m_t, n) (solver order);
    JW (T, K, m_t, m) per window slot or None; JG (T, m_t, g) or None."""

    r: Array
    JF: Array
    JW: Array | None = None
    JG: Array | None = None

    @property
    def bandwidth(self) -> int:
        return (self.JF.shape[1] - 1) // 2

    def add_jt(self, v: Array, st: Structure, dtype, gF: Array, gW: Array | None, gG: Array | None):
        """(gF, gW, gG) + this leaf's Jᵀv for its residual-shaped v; gF in solver order."""
        T, K = st.T, st.K
        v = v.reshape(T, -1).astype(dtype)
        b = self.bandwidth
        for d in range(-b, b + 1):
            gF = gF + shift_frames(jnp.einsum("tmi,tm->ti", self.JF[:, d + b].astype(dtype), v), d)
        if self.JW is not None:
            for j in range(K):
                gW = gW + group_sum("qura,qur->qa", self.JW[:, j].astype(dtype), v, j, st)
        if self.JG is not None:
            gG = gG + jnp.einsum("trk,tr->k", self.JG.astype(dtype), v)
        return gF, gW, gG


class FactoredBlocks(eqx.Module):
    """A per-frame leaf linearised with a `BlockJacobian`: r (T, m) and J_t = s_t W blockdiag(D_t).

    s (T,) is the leaf's row scale (√w, 0 on padded frames); D (T, J, k, k); W (m, J k),
    (T, m, J k) or None; cols: the solver-order column of each of the J·k block columns.
    """

    r: Array
    s: Array
    D: Array
    W: Array | None
    cols: tuple[int, ...] = eqx.field(static=True)

    def _pos(self, n: int) -> np.ndarray:
        """(n,) each solver column's block column, or p (= none: a zero) outside the blocks."""
        p = len(self.cols)
        pos = np.full(n, p)
        pos[np.asarray(self.cols)] = np.arange(p)
        return pos

    def gram(self, n: int, dtype) -> Array:
        """This leaf's JᵀJ on the frame's diagonal block, (T, n, n): s² Dᵀ (WᵀW) D.

        With one W (or none) for all frames, each entry is Σ_ab E[u,a] G[(u,a),(v,b)] E[v,b]
        with E[t, u, a] = D[t, blk(u), a, off(u)]: k² elementwise products that XLA fuses
        into one pass over the output (the batched k × k products, or embedding a (p, p)
        result into the solver's columns, took 2-3 passes and 2-3× as long on the CPU).
        """
        T, J, k, _ = self.D.shape
        p, pos = J * k, self._pos(n)
        D = self.D.astype(dtype) * self.s.astype(dtype)[:, None, None, None]
        if self.W is not None and self.W.ndim == 3:  # per frame: (W D) of each frame, then its Gram
            WD = jnp.einsum("tmja,tjab->tmjb", self.W.astype(dtype).reshape(T, -1, J, k), D).reshape(T, -1, p)
            WD = jnp.pad(WD, ((0, 0), (0, 0), (0, 1)))[:, :, pos]
            return jnp.einsum("tmi,tmj->tij", WD, WD)
        E = jnp.pad(jnp.swapaxes(D, 2, 3).reshape(T, p, k), ((0, 0), (0, 1), (0, 0)))[:, pos]
        G = jnp.eye(p, dtype=dtype) if self.W is None else self.W.astype(dtype).T @ self.W.astype(dtype)
        rows = np.where(pos[:, None] < p, k * (pos[:, None] // k) + np.arange(k), p)  # (n, k) rows of G
        Gx = jnp.pad(G, ((0, 1), (0, 1)))[rows[:, :, None, None], rows[None, None]]  # (n, k, n, k)
        pairs = [(a, a) for a in range(k)] if self.W is None else [(a, b) for a in range(k) for b in range(k)]
        return sum(E[:, :, a, None] * Gx[None, :, a, :, b] * E[:, None, :, b] for a, b in pairs)

    def jt(self, v: Array, n: int, dtype) -> Array:
        """Jᵀv per frame, (T, n) solver order."""
        T, J, k, _ = self.D.shape
        v = v.reshape(T, -1).astype(dtype) * self.s.astype(dtype)[:, None]
        if self.W is not None:
            W = self.W.astype(dtype)
            v = v @ W if W.ndim == 2 else jnp.einsum("tm,tmp->tp", v, W)
        u = jnp.einsum("tjab,tja->tjb", self.D.astype(dtype), v.reshape(T, J, k))
        return jnp.pad(u.reshape(T, J * k), ((0, 0), (0, 1)))[:, self._pos(n)]

    def add_jt(self, v: Array, st: Structure, dtype, gF: Array, gW: Array | None, gG: Array | None):
        """(gF, gW, gG) + this leaf's Jᵀv (frame blocks only)."""
        return gF + self.jt(v, st.n, dtype), gW, gG


def _normal_blocks(blocks: list[Array], bandwidths, dtype, nc: int, n: int, diagonal_only: bool = False) -> list[Array]:
    """Upper frame band of JᵀJ: H[e][s] = H_{s, s+e}, e = 0 .. 2·max(b) (0 only: `diagonal_only`).

    H[e][s] = Σ_ℓ Σ_d J_ℓ[s-d, d]ᵀ J_ℓ[s-d, d+e]; the shifted factors of every leaf and
    offset are stacked along the contracted axis so each H[e] is one batched product
    (on XLA-CPU nearly as fast as one product per pair is slow). Frame-coupling leaves
    read only the first nc (coupled) unknowns.
    """
    B = max(bandwidths)
    H = []
    for e in range(1 if diagonal_only else 2 * B + 1):
        by_width = {}  # coupled-only leaves (nc columns) apart: no products of zeros
        for J, b in zip(blocks, bandwidths):
            if 2 * b < e:
                continue
            J = J.astype(dtype)
            if b > 0 and nc < n:
                J = J[..., :nc]
            left, right = by_width.setdefault(J.shape[-1], ([], []))
            for d in range(-b, b + 1 - e):
                # Row t = s - d couples frames s = t + d and s + e = t + d + e.
                left.append(shift_frames(J[:, d + b], d))
                right.append(shift_frames(J[:, d + e + b], d))
        out = None
        for width in sorted(by_width, reverse=True):
            left, right = by_width[width]
            p = jnp.einsum("tmi,tmj->tij", jnp.concatenate(left, 1), jnp.concatenate(right, 1))
            if out is None:  # H[0] is n wide even where only coupled leaves exist
                k = n if e == 0 else width
                out = jnp.pad(p, ((0, 0), (0, k - width), (0, k - width)))
            else:
                out = out.at[:, :width, :width].add(p)
        H.append(out)
    return H


def jt_vector(terms: list[TermBlocks | FactoredBlocks], st: Structure, vectors: list[Array], dtype):
    """Jᵀv from the blocks: (gF (T, n) solver order, gW (W, m) or None, gG (g,) or None)."""
    T = st.T
    gF = jnp.zeros((T, st.n), dtype)
    gW = jnp.zeros((st.W, st.m), dtype) if st.W else None
    gG = jnp.zeros((st.g,), dtype) if st.g else None
    for t, v in zip(terms, vectors):
        gF, gW, gG = t.add_jt(v, st, dtype, gF, gW, gG)
    return gF, gW, gG


def pin_padded(normal: Normal, st: Structure, frame_mask: Array | None) -> Normal:
    """Identity rows for padded frames and for windows without a real frame (their step is 0)."""
    if frame_mask is None:
        return normal
    dtype = normal.FF[0].dtype
    FF = [normal.FF[0] + (~frame_mask)[:, None, None] * jnp.eye(st.n, dtype=dtype)] + list(normal.FF[1:])
    WW = normal.WW
    if st.W:
        fm = frame_mask.astype(dtype)
        seen = sum(group_sum("qu,qu->q", fm, jnp.ones_like(fm), j, st) for j in range(st.K))
        WW = WW.at[:, 0].add((seen == 0)[:, None, None] * jnp.eye(st.m, dtype=dtype))
    return Normal(FF, normal.FW, WW, normal.FG, normal.WG, normal.GG, normal.C)


def uses_rows(st: Structure, rows: int, tridiagonal: str | None) -> bool:
    """Whether the frame band is factorised in its coupling rows' space (`rows.py`):
    "rows" (the CPU's default) or "cyclic" (accelerators') asked for, a band to
    factorise, no windows (their super-blocks need the band's), and fewer coupling rows
    per frame than coupled unknowns (otherwise the band is the smaller representation)."""
    method = tridiagonal or default_tridiagonal_method()
    return method in ("rows", "cyclic") and st.B2 > 0 and st.nc > 0 and not st.W and 0 < rows < st.nc


def _coupling_rows(JF: list[Array], bw, st: Structure) -> Array:
    """The frame-coupling leaves' blocks on the coupled unknowns, stacked: (T, B2+1, R, nc)."""
    B = st.B2 // 2
    parts = []
    for J, b in zip(JF, bw):
        if b:
            J = J[..., : st.nc].reshape(st.T, 2 * b + 1, -1, st.nc)
            parts.append(jnp.pad(J, ((0, 0), (B - b, B - b), (0, 0), (0, 0))))
    return jnp.concatenate(parts, 2)


def normal_equations(
    terms: list[TermBlocks | FactoredBlocks],
    st: Structure,
    dtype,
    frame_mask: Array | None = None,
    tridiagonal: str | None = None,
):
    """H = JᵀJ and g = Jᵀr of the linearised residual leaves: (`Normal`, (gF, gW, gG), cost).

    Padded frames (frame_mask False) and windows without a real frame get identity
    rows so that their step is exactly 0. `tridiagonal` ("rows", "cyclic" or None, see
    `uses_rows`) keeps the frame band as the coupling rows instead of forming it.
    """
    T, n, nc, K = st.T, st.n, st.nc, st.K
    rs = [t.r.reshape(T, -1).astype(dtype) for t in terms]
    grad = jt_vector(terms, st, rs, dtype)
    factored = [t for t in terms if isinstance(t, FactoredBlocks)]
    terms = [t for t in terms if not isinstance(t, FactoredBlocks)]
    bw = [t.bandwidth for t in terms]
    JF = [t.JF.astype(dtype) for t in terms]
    rows = sum(int(np.prod(t.JF.shape[2:-1])) for t in terms if t.bandwidth)
    C = _coupling_rows(JF, bw, st) if uses_rows(st, rows, tridiagonal) else None
    if JF:
        FF = _normal_blocks(JF, bw, dtype, nc, n, diagonal_only=C is not None)
    else:
        FF = [jnp.zeros((T, n, n), dtype)]
    for t in factored:
        FF[0] = FF[0] + t.gram(n, dtype)
    FW = WW = FG = WG = GG = None
    if st.W:
        m = st.m
        FW = jnp.zeros((T, K, n, m), dtype)
        WW = jnp.zeros((st.W, K, m, m), dtype)
        for t, J in zip(terms, JF):
            if t.JW is None:
                continue
            JW = t.JW.astype(dtype)
            FW = FW + jnp.einsum("tri,tjra->tjia", J[:, 0], JW)
            for j in range(K):
                for i in range(j + 1):
                    # Slots i <= j of one frame: windows w_j = w_i - (j - i), H_{w_j, w_i}.
                    WW = WW.at[:, j - i].add(group_sum("qura,qurb->qab", JW[:, j], JW[:, i], j, st))
    if st.g:
        g = st.g
        FG = jnp.zeros((T, n, g), dtype)
        WG = jnp.zeros((st.W, st.m, g), dtype) if st.W else None
        GG = jnp.zeros((g, g), dtype)
        for t, J, b in zip(terms, JF, bw):
            if t.JG is None:
                continue
            JG = t.JG.astype(dtype)
            for d in range(-b, b + 1):
                FG = FG + shift_frames(jnp.einsum("tri,trk->tik", J[:, d + b], JG), d)
            GG = GG + jnp.einsum("tri,trk->ik", JG, JG)
            if t.JW is not None:
                for j in range(K):
                    WG = WG + group_sum("qura,qurk->qak", t.JW[:, j].astype(dtype), JG, j, st)
    normal = pin_padded(Normal(FF, FW, WW, FG, WG, GG, C), st, frame_mask)
    return normal, grad, half_squared_norm(rs, dtype)


def half_squared_norm(residuals, dtype) -> Array:
    """½ Σ r² over the residual leaves, in `dtype` (the LM's and the linearisation's)."""
    return 0.5 * sum(jnp.sum(r.astype(dtype) ** 2) for r in jtu.tree_leaves(residuals))
