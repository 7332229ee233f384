"""Jacobian and Hessian blocks of a problem's structure by coloured forward-mode products.

Frames s ≡ c (mod 2b+1) never share a residual row, so one JVP with e_k on every frame
of colour c recovers column k of all frame blocks (Curtis-Powell-Reid); windows are
coloured mod K, the border takes one JVP per column. For the Hessian (the adjoint of a
solve) Hessian-vector products are coloured the same way, with 4b+1 frame and 2K-1
window colours.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..timeseries import shift_frames
from .assembly import TermBlocks, pin_padded
from .factorise import Normal
from .structure import Structure

__all__ = ["jacobian_blocks", "hessian_normal"]


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
    return pin_padded(Normal(FF, FW, WW, FG, WG, GG), st, frame_mask)
