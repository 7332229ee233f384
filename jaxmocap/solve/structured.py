"""Structured normal equations: banded frames, windows and a sequence-wide border.

The unknowns of a sequence are per-frame (F: T frames of n), per-window (W windows of
m, window w covering frames [w·s, w·s + L)) and per-sequence (G: g shared by all
frames). With every residual row t depending on frames t-b .. t+b (`Term.bandwidth`),
on the windows containing t (terms that read windows have b = 0), and on any of G, the
Gauss-Newton matrix H = JᵀJ (and the Hessian of the cost, for implicit differentiation)
is "banded plus border" (an arrowhead):

    [ H_FF  H_FW  H_FG ]      H_FF: frame band of width 2b (von Marcard eq. 3.30-3.31)
    [ H_WF  H_WW  H_WG ]      H_FW: frame t × the ≤ K = ⌈L/s⌉ windows containing t
    [ H_GF  H_GW  H_GG ]      H_WW: window band of width K-1;  G: dense border

This module builds and solves it exactly, at a cost linear in T:

1. **Blocks by colouring.** Frames s ≡ c (mod 2b+1) never share a residual row, so one
   JVP with e_k on every frame of colour c recovers column k of all frame blocks
   (Curtis-Powell-Reid); windows are coloured mod K, the border takes one JVP per
   column. For the Hessian (the adjoint of a solve) Hessian-vector products are
   coloured the same way, with 4b+1 frame and 2K-1 window colours.
2. **Per-frame elimination.** Per-frame unknowns that no frame-coupling term reads
   ("local": SIP's hands and feet, every unknown of a per-frame problem) are eliminated
   frame by frame, S = H_cc - H_cl H_ll⁻¹ H_lc, batched over frames; their fill lands in
   the frame's coupled unknowns, the windows containing it and the border.
3. **Block-tridiagonal Cholesky.** The coupled frame unknowns and the windows are
   grouped in super-blocks (G frames and r windows, G = r·s, large enough that every
   coupling joins a block to itself or the next); the resulting block-tridiagonal
   matrix is factorised by a `lax.scan` along the sequence or by cyclic reduction in
   ⌈log₂ T⌉ parallel levels (accelerators), see `tridiagonal.py`. Without windows, and
   where the frame-coupling terms have fewer rows per frame than coupled unknowns, both
   instead keep those rows and factorise in their space (`rows.py`: the same pivots,
   the band's off-diagonal blocks never formed).
4. **Border.** The Schur complement on the sequence-wide unknowns,
   S = H_GG - H_GA H_AA⁻¹ H_AG, is formed by banded solves against the g border
   columns (O(T g) work), factorised densely, and the step is recovered by back
   substitution.

Everything is Jacobi-scaled (diag(H)^(-1/2)) and formed in `factor_dtype` (float64
when x64 is on: the 1/dt² of acceleration terms squares into H's condition number).
`StructuredCholesky` wraps this as a lineax solver for optimistix's own solvers (its
operator is J, or [J; √λ I] for Levenberg-Marquardt) and for `optx.ImplicitAdjoint`
(its operator is the Hessian of the cost).
"""

from __future__ import annotations

import functools
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.tree_util as jtu
import lineax as lx
import numpy as np
from jax import Array

from ..timeseries import shift_frames

from .rows import RowsCyclicFactor, RowsFactor, rows_cyclic_factor, rows_cyclic_solve, rows_factor, rows_solve, scale_rows
from .tridiagonal import (
    CyclicFactor,
    ScanFactor,
    default_tridiagonal_method,
    inverse_cholesky,
    tridiagonal_factor,
    tridiagonal_solve,
)
from .unknowns import Layout, Windows

__all__ = [
    "Structure",
    "TermBlocks",
    "Normal",
    "Factor",
    "StructuredCholesky",
    "jacobian_blocks",
    "normal_equations",
    "factor",
    "solve_factored",
]

_F32_SHIFT = 1e-5


def full_precision(fn):
    """`fn` traced with float32 products in full float32 (`Precision.HIGHEST`).

    GPUs' default float32 matmul is TF32 (10-bit mantissa). In the normal equations and
    their factors that is not rounding noise but a wrong step: SIP's 1000-frame solve on
    one H200 ended at cost 48.3 with the default and 19.1 with full float32 (as on the
    CPU), for 12 % more time (issue 20). Wrapping at trace time covers every product
    of a solve, the residuals' body model included, and of its implicit adjoint.
    """

    @functools.wraps(fn)
    def wrapped(*args, **kwargs):
        with jax.default_matmul_precision("highest"):
            return fn(*args, **kwargs)

    return wrapped


class Structure(eqx.Module):
    """Static shape of one problem's normal equations.

    T frames of n unknowns (solver order: the nc coupled ones first, `perm` maps from
    the layout's order), band half-width B2 = 2·max(b) of H, W windows of m unknowns,
    g border unknowns.
    """

    T: int = eqx.field(static=True)
    n: int = eqx.field(static=True)
    nc: int = eqx.field(static=True)
    perm: tuple[int, ...] | None = eqx.field(static=True)
    B2: int = eqx.field(static=True)
    windows: Windows | None = eqx.field(static=True)
    W: int = eqx.field(static=True)
    m: int = eqx.field(static=True)
    g: int = eqx.field(static=True)

    @classmethod
    def of(cls, layout: Layout, bandwidths, frame_columns) -> Structure:
        """From the layout and, per residual leaf, its bandwidth and per-frame columns."""
        n = layout.n
        B = max(bandwidths) if bandwidths else 0
        coupled = sorted(set().union(*[set(c) for c, b in zip(frame_columns, bandwidths) if b > 0]))
        perm = tuple(coupled) + tuple(sorted(set(range(n)) - set(coupled)))
        perm = None if perm == tuple(range(n)) else perm
        return cls(
            layout.T, n, len(coupled), perm, 2 * B, layout.windows, layout.num_windows,
            layout.size("window"), layout.size("sequence"),
        )  # fmt: skip

    @property
    def K(self) -> int:
        return self.windows.slots if self.W else 0

    def to_solver_order(self, x: Array) -> Array:
        return x if self.perm is None else x[..., np.asarray(self.perm)]

    def from_solver_order(self, x: Array) -> Array:
        return x if self.perm is None else x[..., np.argsort(self.perm)]

    def rows_to_solver_order(self, x: Array) -> Array:
        """The second-to-last axis (per-frame rows of a block) in solver order."""
        return x if self.perm is None else x[..., np.asarray(self.perm), :]

    def slot_windows(self):
        return self.windows.slot_windows(self.T, self.W)

    def blocking(self) -> tuple[int, int, int]:
        """(G frames, r windows, Kb super-blocks) of the block-tridiagonal stage."""
        if not self.W:
            G = max(1, self.B2)
            return G, 0, (-(-self.T // G) if self.nc else 0)
        s, K = self.windows.stride, self.K
        r = max(1, K - 1, -(-self.B2 // s) if self.nc else 1)
        G = r * s
        return G, r, max(-(-self.T // G) if self.nc else 0, -(-self.W // r))


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


class Normal(eqx.Module):
    """The structured matrix (see the module docstring) and a right-hand side.

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


# --- stride groups: frames t = q·s + u share the windows q, q-1, ..., q-K+1 --------------


def _groups(x: Array, st: Structure) -> Array:
    """(T, ...) -> (Q, s, ...), zero-padded at the end."""
    s = st.windows.stride
    Q = -(-st.T // s)
    pad = Q * s - st.T
    if pad:
        x = jnp.concatenate([x, jnp.zeros((pad,) + x.shape[1:], x.dtype)], 0)
    return x.reshape((Q, s) + x.shape[1:])


def _slot_mask(st: Structure, j: int) -> np.ndarray:
    """(Q, s) validity of slot j: window q - j exists and contains frame q·s + u."""
    s, L = st.windows.stride, st.windows.length
    Q = -(-st.T // s)
    q, u = np.arange(Q)[:, None], np.arange(s)[None, :]
    return (q - j >= 0) & (q - j < st.W) & (u + j * s < L) & (q * s + u < st.T)


def _to_windows(per_group: Array, j: int, st: Structure) -> Array:
    """Per-group sums (Q, ...) of slot j -> per-window (W, ...): window w = q - j."""
    Q = per_group.shape[0]
    out = shift_frames(per_group, -j)[: st.W] if j else per_group[: st.W]
    if Q < st.W:
        out = jnp.concatenate([out, jnp.zeros((st.W - Q,) + out.shape[1:], out.dtype)], 0)
    return out


def _group_sum(spec: str, a: Array, b: Array, j: int, st: Structure) -> Array:
    """Σ over the frames of each stride group of einsum(spec) for slot j, as per-window (W, ...)."""
    mask = jnp.asarray(_slot_mask(st, j), a.dtype)
    per = jnp.einsum(spec, _groups(a, st) * mask.reshape(mask.shape + (1,) * (a.ndim - 1)), _groups(b, st))
    return _to_windows(per, j, st)


def _window_of_slot(x: Array, j: int, st: Structure) -> Array:
    """Per-window x (W, ...) read at slot j of every frame: (T, ...), 0 where invalid."""
    s = st.windows.stride
    Q = -(-st.T // s)
    w = np.arange(Q) - j
    vals = x[np.clip(w, 0, st.W - 1)]  # (Q, ...)
    vals = jnp.broadcast_to(vals[:, None], (Q, s) + x.shape[1:])
    mask = jnp.asarray(_slot_mask(st, j)).reshape((Q, s) + (1,) * (x.ndim - 1))
    return jnp.where(mask, vals, 0.0).reshape((Q * s,) + x.shape[1:])[: st.T]


# --- normal equations from Jacobian blocks ---------------------------------------------


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
    T, K = st.T, st.K
    gF = jnp.zeros((T, st.n), dtype)
    gW = jnp.zeros((st.W, st.m), dtype) if st.W else None
    gG = jnp.zeros((st.g,), dtype) if st.g else None
    for t, v in zip(terms, vectors):
        if isinstance(t, FactoredBlocks):
            gF = gF + t.jt(v, st.n, dtype)
            continue
        v = v.reshape(T, -1).astype(dtype)
        b = t.bandwidth
        for d in range(-b, b + 1):
            gF = gF + shift_frames(jnp.einsum("tmi,tm->ti", t.JF[:, d + b].astype(dtype), v), d)
        if t.JW is not None:
            for j in range(K):
                gW = gW + _group_sum("qura,qur->qa", t.JW[:, j].astype(dtype), v, j, st)
        if t.JG is not None:
            gG = gG + jnp.einsum("trk,tr->k", t.JG.astype(dtype), v)
    return gF, gW, gG


def _pin(normal: Normal, st: Structure, frame_mask: Array | None) -> Normal:
    """Identity rows for padded frames and for windows without a real frame (their step is 0)."""
    if frame_mask is None:
        return normal
    dtype = normal.FF[0].dtype
    FF = [normal.FF[0] + (~frame_mask)[:, None, None] * jnp.eye(st.n, dtype=dtype)] + list(normal.FF[1:])
    WW = normal.WW
    if st.W:
        fm = frame_mask.astype(dtype)
        seen = sum(_group_sum("qu,qu->q", fm, jnp.ones_like(fm), j, st) for j in range(st.K))
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
    terms: list[TermBlocks | FactoredBlocks], st: Structure, dtype, frame_mask: Array | None = None, tridiagonal: str | None = None
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
                    WW = WW.at[:, j - i].add(_group_sum("qura,qurb->qab", JW[:, j], JW[:, i], j, st))
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
                    WG = WG + _group_sum("qura,qurk->qak", t.JW[:, j].astype(dtype), JG, j, st)
    normal = _pin(Normal(FF, FW, WW, FG, WG, GG, C), st, frame_mask)
    return normal, grad, half_squared_norm(rs, dtype)


def half_squared_norm(residuals, dtype) -> Array:
    """½ Σ r² over the residual leaves, in `dtype` (the LM's and the linearisation's)."""
    return 0.5 * sum(jnp.sum(r.astype(dtype) ** 2) for r in jtu.tree_leaves(residuals))


# --- blocks by colouring -----------------------------------------------------------------


def jacobian_blocks(mv, st: Structure, dtype, bandwidths, columns, out_shapes=None) -> list[TermBlocks]:
    """Every non-zero Jacobian block of a linear map with the problem's structure.

    Args:
        mv: linear map (tF (T, n), tW (W, m) or None, tG (g,) or None) -> list of
            residual leaves (T, ...), tangents in the layout's order (not solver order).
        bandwidths: per leaf; columns: per leaf, the (frame, window, sequence) column
            tuples it reads (the other blocks are zeros, not computed).
        out_shapes: the shapes of mv's leaves where the caller knows them (else traced).
    Returns:
        One `TermBlocks` per leaf, residual r = 0 (the caller fills it in).
    """
    T, n = st.T, st.n
    zF = jnp.zeros((T, n), dtype)
    zW = jnp.zeros((st.W, st.m), dtype) if st.W else None
    zG = jnp.zeros((st.g,), dtype) if st.g else None
    if out_shapes is None:
        out_shapes = [s.shape for s in jax.eval_shape(mv, zF, zW, zG)]
    rows = [int(np.prod(shape[1:])) for shape in out_shapes]
    found = [dict() for _ in bandwidths]
    t = np.arange(T)

    def run(tangents, members):
        leaves = jax.vmap(mv)(*tangents)
        return [leaves[i].reshape(leaves[i].shape[0], T, -1) for i in members]

    def embed(x, cols, size):  # (..., k) computed columns -> (..., size)
        if len(cols) == size:
            return x
        pos = np.full(size, len(cols))
        pos[np.asarray(cols)] = np.arange(len(cols))
        return jnp.concatenate([x, jnp.zeros(x.shape[:-1] + (1,), x.dtype)], -1)[..., pos]

    for b in sorted(set(bandwidths)):
        members = [i for i, bi in enumerate(bandwidths) if bi == b and columns[i][0]]
        if not members:
            continue
        cols = sorted(set().union(*[columns[i][0] for i in members]))
        C = 2 * b + 1
        unit = jnp.asarray(np.eye(n)[np.asarray(cols)], dtype)  # (k, n)

        def per_colour(c, unit=unit, C=C, members=members):
            tF = (jnp.asarray(t % C) == c)[None, :, None].astype(dtype) * unit[:, None, :]
            k = tF.shape[0]
            return run((tF, _bcast(zW, k), _bcast(zG, k)), members)

        # lax.map over colours bounds live memory to one colour's JVP outputs at a time.
        res = jax.lax.map(per_colour, jnp.arange(C))  # per member (C, k, T, m)
        for leaf, i in zip(res, members):
            per_frame = embed(jnp.transpose(leaf, (2, 0, 3, 1)), cols, n)  # (T, C, m, n)
            blocks = jnp.stack([per_frame[t, (t + d) % C] for d in range(-b, b + 1)], axis=1)
            found[i]["JF"] = st.to_solver_order(blocks)
    members = [i for i in range(len(bandwidths)) if columns[i][1]]
    if members:
        K, m = st.K, st.m
        cols = sorted(set().union(*[columns[i][1] for i in members]))
        unit = jnp.asarray(np.eye(m)[np.asarray(cols)], dtype)
        colour = np.arange(st.W) % K  # the K windows containing a frame differ mod K

        def per_wcolour(c):
            tW = (jnp.asarray(colour) == c)[None, :, None].astype(dtype) * unit[:, None, :]
            k = tW.shape[0]
            return run((_bcast(zF, k), tW, _bcast(zG, k)), members)

        res = jax.lax.map(per_wcolour, jnp.arange(K))  # per member (K, k, T, m_t)
        wid, valid = st.slot_windows()
        for leaf, i in zip(res, members):
            per = embed(jnp.transpose(leaf, (2, 0, 3, 1)), cols, m)  # (T, K colours, m_t, m)
            JW = per[t[:, None], wid % K]  # (T, K slots, m_t, m)
            found[i]["JW"] = jnp.where(jnp.asarray(valid)[:, :, None, None], JW, 0.0)
    members = [i for i in range(len(bandwidths)) if columns[i][2]]
    if members:
        cols = sorted(set().union(*[columns[i][2] for i in members]))
        unit = jnp.asarray(np.eye(st.g)[np.asarray(cols)], dtype)
        k = unit.shape[0]
        for leaf, i in zip(run((_bcast(zF, k), _bcast(zW, k), unit), members), members):
            found[i]["JG"] = embed(jnp.moveaxis(leaf, 0, -1), cols, st.g)  # (T, m_t, g)
    out = []
    for i, b in enumerate(bandwidths):
        JF = found[i].get("JF")
        if JF is None:
            JF = jnp.zeros((T, 2 * b + 1, rows[i], n), dtype)
        out.append(TermBlocks(jnp.zeros((T, rows[i]), dtype), JF, found[i].get("JW"), found[i].get("JG")))
    return out


def _bcast(x, k):
    return None if x is None else jnp.broadcast_to(x, (k,) + x.shape)


def hessian_normal(hvp, st: Structure, dtype, frame_mask: Array | None = None) -> Normal:
    """The Hessian in `Normal` form from Hessian-vector products, by colouring.

    H couples frames within B2 = 2b, so 2·B2 + 1 frame colours separate them; windows
    overlap their K-1 neighbours, so 2K - 1 window colours; the border takes g products.
    `hvp(tF, tW, tG) -> (HF (T, n), HW (W, m) or None, HG (g,) or None)`, layout order.
    """
    T, n, nc, K = st.T, st.n, st.nc, st.K
    t = np.arange(T)
    zF = jnp.zeros((T, n), dtype)
    zW = jnp.zeros((st.W, st.m), dtype) if st.W else None
    zG = jnp.zeros((st.g,), dtype) if st.g else None
    C = 2 * st.B2 + 1
    eye = jnp.eye(n, dtype=dtype)
    # hvp's linear part, traced once: each colour then skips hvp's primal (gradient) pass.
    _, hvp = jax.linearize(hvp, zF, zW, zG)

    def per_colour(c):
        tF = (jnp.asarray(t % C) == c)[None, :, None].astype(dtype) * eye[:, None, :]
        return jax.vmap(hvp)(tF, _bcast(zW, n), _bcast(zG, n))[0]  # (n, T, n)

    res = jax.lax.map(per_colour, jnp.arange(C))  # (C, k, T, n)
    cols = jnp.transpose(res, (2, 0, 3, 1))  # (T, C, n_out, k)
    cols = st.to_solver_order(st.rows_to_solver_order(cols))
    FF = [cols[t, (t + e) % C] for e in range(st.B2 + 1)]
    FF = [FF[0]] + [f[:, :nc, :nc] for f in FF[1:]]
    FF = [jnp.where(shift_frames(jnp.ones((T,), bool), -e)[:, None, None], f, 0.0) for e, f in enumerate(FF)]
    FW = WW = FG = WG = GG = None
    if st.W:
        m = st.m
        Cw = 2 * K - 1
        wcol = np.arange(st.W) % Cw
        eyem = jnp.eye(m, dtype=dtype)

        def per_wcolour(c):
            tW = (jnp.asarray(wcol) == c)[None, :, None].astype(dtype) * eyem[:, None, :]
            HF, HW, _ = jax.vmap(hvp)(_bcast(zF, m), tW, _bcast(zG, m))
            return HF, HW

        HFw, HWw = jax.lax.map(per_wcolour, jnp.arange(Cw))  # (Cw, m, T, n), (Cw, m, W, m)
        wid, valid = st.slot_windows()
        perF = jnp.transpose(HFw, (2, 0, 3, 1))  # (T, Cw, n, m)
        FW = st.rows_to_solver_order(perF[t[:, None], wid % Cw])
        FW = jnp.where(jnp.asarray(valid)[:, :, None, None], FW, 0.0)
        perW = jnp.transpose(HWw, (2, 0, 3, 1))  # (W, Cw, m, m)
        w = np.arange(st.W)
        WW = jnp.stack([perW[w, (w + e) % Cw] * jnp.asarray(w + e < st.W)[:, None, None] for e in range(K)], 1)
    if st.g:
        eyeg = jnp.eye(st.g, dtype=dtype)
        HF, HW, HG = jax.vmap(hvp)(_bcast(zF, st.g), _bcast(zW, st.g), eyeg)
        FG = st.rows_to_solver_order(jnp.moveaxis(HF, 0, -1))  # (T, n, g)
        WG = None if HW is None else jnp.moveaxis(HW, 0, -1)
        GG = HG
    return _pin(Normal(FF, FW, WW, FG, WG, GG), st, frame_mask)


# --- factorisation -----------------------------------------------------------------------


class Factor(eqx.Module):
    """A factorised `Normal` (+ damping): scales, per-frame elimination, block-tridiagonal
    inverse factors, and the border's Schur complement."""

    sF: Array
    sW: Array | None
    sG: Array | None
    L_local_inv: Array | None  # (T, n_l, n_l) inverse Cholesky factors of H_ll
    X: Array | None  # (T, n_l, nc + K m + g): L_ll⁻¹ [H_lc | H_lW | H_lG]
    tri: ScanFactor | CyclicFactor | RowsFactor | RowsCyclicFactor | None  # the coupled frames (+ windows)
    Y: Array | None  # (Kb, N, g) or, with rows, (T, nc, g): A⁻¹ C
    S_inv: Array | None  # (g, g) inverse Cholesky factor of the border's Schur complement
    st: Structure = eqx.field(static=True)


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


def _pad_to(x: Array, length: int, fill_eye: bool = False) -> Array:
    pad = length - x.shape[0]
    if pad <= 0:
        return x
    if fill_eye:
        filler = jnp.broadcast_to(jnp.eye(x.shape[-1], dtype=x.dtype), (pad,) + x.shape[1:])
    else:
        filler = jnp.zeros((pad,) + x.shape[1:], x.dtype)
    return jnp.concatenate([x, filler], 0)


#: The factorisations in the coupling rows' space: frames as they are, no super-blocks.
_ROWS_FACTORS = (RowsFactor, RowsCyclicFactor)


def _to_blocks(xF: Array | None, xW: Array | None, st: Structure, tri=None) -> Array:
    """Coupled frame (T, nc, ...) and window (W, m, ...) parts -> super-block vectors (Kb, N, ...)
    (frames as they are for the coupling rows' factors, which have no windows)."""
    if isinstance(tri, _ROWS_FACTORS):
        return xF
    G, r, Kb = st.blocking()
    parts = []
    if st.nc and xF is not None:
        parts.append(_pad_to(xF, Kb * G).reshape((Kb, G * st.nc) + xF.shape[2:]))
    if r:
        parts.append(_pad_to(xW, Kb * r).reshape((Kb, r * st.m) + xW.shape[2:]))
    return jnp.concatenate(parts, 1)


def _from_blocks(x: Array, st: Structure, tri=None):
    if isinstance(tri, _ROWS_FACTORS):
        return x, None
    G, r, Kb = st.blocking()
    xF = xW = None
    split = G * st.nc if st.nc else 0
    if st.nc:
        xF = x[:, :split].reshape((Kb * G, st.nc) + x.shape[2:])[: st.T]
    if r:
        xW = x[:, split:].reshape((Kb * r, st.m) + x.shape[2:])[: st.W]
    return xF, xW


def _assemble(FF: list, FW: Array | None, WW: Array | None, st: Structure):
    """Super-blocks D_k (diagonal) and U_k (to block k+1) of the coupled frames + windows."""
    G, r, Kb = st.blocking()
    nc, m, K = st.nc, st.m, st.K
    dtype = FF[0].dtype
    FFb = FWb = FWn = WWb = None
    if nc:
        FFp = [_pad_to(FF[0], Kb * G, True)] + [_pad_to(f, Kb * G) for f in FF[1:]]
        FFb = [f.reshape((Kb, G) + f.shape[1:]) for f in FFp]
    if r:
        WWp = jnp.concatenate([_pad_to(WW[:, :1], Kb * r, True), _pad_to(WW[:, 1:], Kb * r)], 1) if K > 1 else _pad_to(WW, Kb * r, True)
        WWb = WWp.reshape((Kb, r) + WWp.shape[1:])
        if nc:
            FWp = _pad_to(FW, Kb * G)
            FWb = FWp.reshape((Kb, G) + FWp.shape[1:])
            FWn = jnp.concatenate([FWb[1:], jnp.zeros_like(FWb[:1])], 0)
    s = st.windows.stride if r else 1
    zero = lambda a, b: jnp.zeros((Kb, a, b), dtype)  # noqa: E731
    B2 = len(FF) - 1
    D_rows, U_rows = [], []
    for i in range(G if nc else 0):
        D_row, U_row = [], []
        for i2 in range(G):
            e = i2 - i
            if 0 <= e <= B2:
                D_row.append(FFb[e][:, i])
            elif -B2 <= e < 0:
                D_row.append(jnp.swapaxes(FFb[-e][:, i2], -1, -2))
            else:
                D_row.append(zero(nc, nc))
            e = G + i2 - i
            U_row.append(FFb[e][:, i] if e <= B2 else zero(nc, nc))
        for p in range(r):
            j = i // s - p
            D_row.append(FWb[:, i, j, :nc] if 0 <= j < K else zero(nc, m))
            U_row.append(zero(nc, m))
        D_rows.append(jnp.concatenate(D_row, -1))
        U_rows.append(jnp.concatenate(U_row, -1))
    for p in range(r):
        D_row, U_row = [], []
        for i2 in range(G if nc else 0):
            j = i2 // s - p
            D_row.append(jnp.swapaxes(FWb[:, i2, j, :nc], -1, -2) if 0 <= j < K else zero(m, nc))
            j = r + i2 // s - p
            U_row.append(jnp.swapaxes(FWn[:, i2, j, :nc], -1, -2) if 0 <= j < K else zero(m, nc))
        for q in range(r):
            e = q - p
            if 0 <= e < K:
                D_row.append(WWb[:, p, e])
            elif -K < e < 0:
                D_row.append(jnp.swapaxes(WWb[:, q, -e], -1, -2))
            else:
                D_row.append(zero(m, m))
            e = r + q - p
            U_row.append(WWb[:, p, e] if e < K else zero(m, m))
        D_rows.append(jnp.concatenate(D_row, -1))
        U_rows.append(jnp.concatenate(U_row, -1))
    return jnp.concatenate(D_rows, -2), jnp.concatenate(U_rows, -2)


def factor(
    normal: Normal, st: Structure, damping: Array | float = 0.0, marquardt: bool = False, tridiagonal: str | None = None
) -> Factor:
    """Factorise H + λI (or H + λ diag(H), eq. 2.54) in its structure (module docstring).

    tridiagonal: "scan", "cyclic", "rows" or None (the backend's default), see
    `tridiagonal.py`; a `normal` with coupling rows (`normal_equations` with "rows" or
    "cyclic") is factorised by `rows.py`, in frame order ("rows") or by cyclic reduction
    ("cyclic"); "rows" without them by "scan".
    """
    T, n, nc, K, m, g = st.T, st.n, st.nc, st.K, st.m, st.g
    FF = list(normal.FF)
    dtype = FF[0].dtype
    F0, sF = _damp_scale(FF[0], damping, marquardt)
    FF = [F0 * _outer(sF, sF)] + [
        f * _outer(sF[:, :nc], shift_frames(sF[:, :nc], -e)) for e, f in enumerate(FF[1:], 1)
    ]
    FW = WW = FG = WG = GG = sW = sG = None
    if st.W:
        W0, sW = _damp_scale(normal.WW[:, 0], damping, marquardt)
        WW = normal.WW.at[:, 0].set(W0)
        WW = jnp.stack([WW[:, e] * _outer(sW, shift_frames(sW, -e)) for e in range(K)], 1)
        sW_slot = jnp.stack([_window_of_slot(sW, j, st) for j in range(K)], 1)  # (T, K, m)
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
                    WW = WW.at[:, j - i].add(-_group_sum("qula,qulb->qab", Xw[:, j], Xw[:, i], j, st))
        if g:
            FG = FG[:, :nc] - jnp.einsum("tla,tlk->tak", Xc, Xg)
            GG = GG - jnp.einsum("tla,tlk->ak", Xg, Xg)
            if st.W:
                for j in range(K):
                    WG = WG - _group_sum("qula,qulk->qak", Xw[:, j], Xg, j, st)
    tri = Y = S_inv = None
    G, r, Kb = st.blocking()
    if normal.C is not None:
        method, C = tridiagonal or default_tridiagonal_method(), scale_rows(normal.C, sF[:, :nc])
        if method == "cyclic":
            tri = rows_cyclic_factor(FF[0], C)
        else:
            tri = rows_factor(FF[0], C)
    elif Kb:
        tri = tridiagonal_factor(*_assemble(FF, FW, WW, st), tridiagonal)
    if g:
        if Kb:
            C = _to_blocks(FG[:, :nc] if nc else None, WG, st, tri)  # (Kb, N, g)
            Y = _coupled_solve(tri, C)
            S = GG - jnp.einsum("kna,knb->ab", C, Y)
        else:
            S = GG
        S_inv = inverse_cholesky(S)
    return Factor(sF, sW, sG, L_local_inv, X, tri, Y, S_inv, st)


def _coupled_solve(tri, b: Array) -> Array:
    if isinstance(tri, RowsFactor):
        return rows_solve(tri, b)
    if isinstance(tri, RowsCyclicFactor):
        return rows_cyclic_solve(tri, b)
    return tridiagonal_solve(tri, b)


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
                bW = bW - _group_sum("qula,qul->qa", Xw[:, j], z_local, j, st)
        if g:
            bG = bG - jnp.einsum("tlk,tl->k", Xg, z_local)
    else:
        cF = bF
    xF_c, xW, xG = cF, bW, None
    if f.tri is not None:
        b = _to_blocks(cF, bW, st, f.tri)
        z = _coupled_solve(f.tri, b[..., None])[..., 0]
        if g:
            u = f.S_inv @ (bG - jnp.einsum("kna,kn->a", f.Y, b))
            xG = f.S_inv.T @ u
            z = z - jnp.einsum("kna,a->kn", f.Y, xG)
        xF_c, xW = _from_blocks(z, st, f.tri)
    elif g:
        xG = f.S_inv.T @ (f.S_inv @ bG)
    if f.X is not None:
        rest = z_local
        if nc:
            rest = rest - jnp.einsum("tla,ta->tl", Xc, xF_c)
        if st.W:
            for j in range(K):
                rest = rest - jnp.einsum("tla,ta->tl", Xw[:, j], _window_of_slot(xW, j, st))
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


# --- as a lineax solver ----------------------------------------------------------------------


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
    leaves, tree = jtu.tree_flatten(struct)
    probe = [jnp.zeros(s.shape, s.dtype) for s in leaves]
    probe[0] = probe[0].reshape(-1).at[0].set(1.0).reshape(leaves[0].shape)
    sqrt_lambda = jtu.tree_leaves(operator.mv(jtu.tree_unflatten(tree, probe))[1])[0].reshape(-1)[0]
    return (lambda y: operator.mv(y)[0]), sqrt_lambda**2


class StructuredCholesky(lx.AbstractLinearSolver):
    """The structured factorisation as a lineax solver (for optimistix).

    With `hessian=False` the operator is a residual Jacobian J (Gauss-Newton) or
    optimistix's damped [J; √λ I] (Levenberg-Marquardt, recognised and turned into
    JᵀJ + λI without any product of the damping rows), and the solve is the
    least-squares x = (JᵀJ + λI)⁻¹ Jᵀ v. With `hessian=True` the operator is the
    (symmetric) Hessian of the cost, as in `optx.ImplicitAdjoint`, and x = H⁻¹ v (with a
    relative ridge of ~1e-10 in float64 so that gauge freedoms stay solvable).
    The operator's input is the problem's parameter dict.

    Attributes:
        layout: the parameters' `Layout`.
        bandwidths: per residual leaf (in `jtu.tree_leaves` order), its frame coupling.
        columns: per residual leaf, the (frame, window, sequence) columns it reads.
        hessian: whether the operator is the Hessian (see above).
        refinements: rounds of iterative refinement of a Hessian solve against the ridge.
        factor_dtype: dtype in which H is formed and factorised (None: the operator's).
        tridiagonal: "rows", "scan", "cyclic" or None (the backend's default), see `solve`.
        frame_mask: (T,) False for padded frames (pinned to a zero step), or None.
    """

    layout: Layout = eqx.field(static=True)
    bandwidths: tuple[int, ...] = eqx.field(static=True)
    columns: tuple = eqx.field(static=True)
    hessian: bool = eqx.field(static=True, default=False)
    factor_dtype: Any = eqx.field(static=True, default=None)
    frame_mask: Array | None = None
    damped: bool | None = eqx.field(static=True, default=None)
    refinements: int = eqx.field(static=True, default=3)
    tridiagonal: str | None = eqx.field(static=True, default=None)

    @property
    def structure(self) -> Structure:
        return Structure.of(self.layout, self.bandwidths, [c[0] for c in self.columns])

    def _tangent(self, tF, tW, tG):
        return self.layout.unravel(tF, tW, tG)

    @full_precision
    def init(self, operator, options):
        del options
        st, layout = self.structure, self.layout
        struct = operator.in_structure()
        if not isinstance(struct, dict) or set(struct) != set(layout.keys):
            raise ValueError(
                f"StructuredCholesky needs an operator on the parameter dict {list(layout.keys)}, got {struct}."
            )
        in_dtype = jtu.tree_leaves(struct)[0].dtype
        dtype = self.factor_dtype or in_dtype
        if self.hessian:

            def hvp(tF, tW, tG):
                return layout.ravel(operator.mv(self._tangent(tF, tW, tG)))

            normal = hessian_normal(hvp, st, in_dtype, self.frame_mask)
            normal = jtu.tree_map(lambda x: x.astype(dtype), normal)
            # A relative ridge ε·diag(H), ε ≈ 1e-2 √(machine ε), keeps a gauge freedom of the
            # cost (SIP's translation drift, seen by accelerations only: H singular)
            # factorisable; `compute` refines against H itself, so the ridge costs no accuracy.
            ridge = 1e-2 * float(np.sqrt(np.finfo(dtype).eps))
            return factor(normal, st, ridge, True, self.tridiagonal), None, None, operator
        jac_mv, damping = _damped_parts(operator, self.damped)
        out = jtu.tree_leaves(operator.out_structure()[0] if damping is not None else operator.out_structure())
        if len(out) != len(self.bandwidths):
            raise ValueError(
                f"StructuredCholesky has {len(self.bandwidths)} bandwidths but the operator has "
                f"{len(out)} output leaves; give one per residual leaf."
            )
        for leaf in out:
            if leaf.shape[:1] != (st.T,):
                raise ValueError(f"every residual leaf must have the frame axis first (T={st.T}), got {leaf.shape}.")

        def mv(tF, tW, tG):
            return jtu.tree_leaves(jac_mv(self._tangent(tF, tW, tG)))

        blocks = jacobian_blocks(mv, st, in_dtype, self.bandwidths, self.columns, [leaf.shape for leaf in out])
        normal, _, _ = normal_equations(blocks, st, dtype, self.frame_mask, self.tridiagonal)
        return factor(normal, st, 0.0 if damping is None else damping, False, self.tridiagonal), blocks, damping, None

    @full_precision
    def compute(self, state, vector, options):
        del options
        f, blocks, damping, operator = state
        st, layout = f.st, self.layout
        dtype = jtu.tree_leaves(vector)[0].dtype
        cast = lambda x: None if x is None else x.astype(dtype)  # noqa: E731

        def solve(bF, bW, bG):  # solver-order right-hand side -> parameter dict
            xF, xW, xG = solve_factored(f, bF, bW, bG)
            return layout.unravel(cast(st.from_solver_order(xF)), cast(xW), cast(xG))

        def solve_dict(v):
            bF, bW, bG = layout.ravel(v)
            return solve(st.to_solver_order(bF), bW, bG)

        if blocks is None:
            # x = (H + εD)⁻¹ b, then iterative refinement x ← x + (H + εD)⁻¹ (b - H x): each
            # round shrinks the ridge's error by ~ε·cond(H); a gauge (null) component of x
            # stays bounded and does not reach gauge-invariant outputs.
            def refine(_, x):  # a loop, not unrolled: H and the solve traced once
                r = jtu.tree_map(lambda b, hx: b - hx, vector, operator.mv(x))
                return jtu.tree_map(jnp.add, x, solve_dict(r))

            x = jax.lax.fori_loop(0, self.refinements, refine, solve_dict(vector))
            return x, lx.RESULTS.successful, {}
        r = vector if damping is None else vector[0]
        bF, bW, bG = jt_vector(blocks, st, jtu.tree_leaves(r), f.sF.dtype)
        if damping is not None:
            # Aᵀv = Jᵀ v_r + √λ v_y (v_y = 0 in optimistix's LM, honoured anyway).
            yF, yW, yG = layout.ravel(vector[1])
            c = jnp.sqrt(damping).astype(bF.dtype)
            bF = bF + c * st.to_solver_order(yF).astype(bF.dtype)
            bW = None if bW is None else bW + c * yW.astype(bF.dtype)
            bG = None if bG is None else bG + c * yG.astype(bF.dtype)
        return solve(bF, bW, bG), lx.RESULTS.successful, {}

    def transpose(self, state, options):
        if not self.hessian:
            raise NotImplementedError(
                "StructuredCholesky(hessian=False) solves a least-squares problem; differentiate "
                "a solve through optx.ImplicitAdjoint(linear_solver=StructuredCholesky(..., hessian=True))."
            )
        return state, options  # the Hessian is symmetric

    def conj(self, state, options):
        return state, options

    def assume_full_rank(self):
        return True
