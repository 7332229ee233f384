"""The coupled frames and the windows in super-blocks: a block-tridiagonal matrix.

The coupled frame unknowns (those a frame-coupling term reads, after per-frame
elimination) and the windows are grouped in super-blocks of G frames and r windows
(G = r·s, `Structure.blocking`), large enough that every coupling joins a block to
itself or the next. The resulting block-tridiagonal matrix is factorised by
`tridiagonal.py`, by a `lax.scan` along the sequence or by cyclic reduction in
⌈log₂ T⌉ parallel levels; `BandFactor` is that factor behind `CoupledFactor`.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jax import Array

from .structure import Structure
from .tridiagonal import CoupledFactor, CyclicFactor, ScanFactor, tridiagonal_factor

__all__ = ["BandFactor", "band_factor"]


class BandFactor(CoupledFactor):
    """The super-blocks' block-tridiagonal factor (`tridiagonal.py`'s scan or cyclic
    reduction); right-hand sides packed as (Kb, N, ...) super-block vectors."""

    tri: ScanFactor | CyclicFactor
    st: Structure = eqx.field(static=True)

    def pack(self, xF: Array | None, xW: Array | None) -> Array:
        """Coupled frame (T, nc, ...) and window (W, m, ...) parts -> super-block vectors (Kb, N, ...)."""
        st = self.st
        G, r, Kb = st.blocking()
        parts = []
        if st.nc and xF is not None:
            parts.append(_pad_to(xF, Kb * G).reshape((Kb, G * st.nc) + xF.shape[2:]))
        if r:
            parts.append(_pad_to(xW, Kb * r).reshape((Kb, r * st.m) + xW.shape[2:]))
        return jnp.concatenate(parts, 1)

    def unpack(self, x: Array):
        st = self.st
        G, r, Kb = st.blocking()
        xF = xW = None
        split = G * st.nc if st.nc else 0
        if st.nc:
            xF = x[:, :split].reshape((Kb * G, st.nc) + x.shape[2:])[: st.T]
        if r:
            xW = x[:, split:].reshape((Kb * r, st.m) + x.shape[2:])[: st.W]
        return xF, xW

    def solve(self, b: Array) -> Array:
        return self.tri.solve(b)


def band_factor(FF: list, FW: Array | None, WW: Array | None, st: Structure, method: str | None = None) -> BandFactor:
    """Factorise the coupled frames' band FF (`Normal.FF`, scaled and eliminated) with the
    windows' FW, WW in super-blocks; method as `tridiagonal_factor`'s."""
    return BandFactor(tridiagonal_factor(*_assemble(FF, FW, WW, st), method), st)


def _pad_to(x: Array, length: int, fill_eye: bool = False) -> Array:
    pad = length - x.shape[0]
    if pad <= 0:
        return x
    if fill_eye:
        filler = jnp.broadcast_to(jnp.eye(x.shape[-1], dtype=x.dtype), (pad,) + x.shape[1:])
    else:
        filler = jnp.zeros((pad,) + x.shape[1:], x.dtype)
    return jnp.concatenate([x, filler], 0)


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
        WWp = (
            jnp.concatenate([_pad_to(WW[:, :1], Kb * r, True), _pad_to(WW[:, 1:], Kb * r)], 1)
            if K > 1
            else _pad_to(WW, Kb * r, True)
        )
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
