"""The structure of a problem's normal equations: banded frames, windows and a border.

The unknowns of a sequence are per-frame (F: T frames of n), per-window (W windows of
m, window w covering frames [w·s, w·s + L)) and per-sequence (G: g shared by all
frames). With every residual row t depending on frames t-b .. t+b (`Term.bandwidth`),
on the windows containing t (terms that read windows have b = 0), and on any of G, the
Gauss-Newton matrix H = JᵀJ (and the Hessian of the cost, for implicit differentiation)
is "banded plus border" (an arrowhead):

    [ H_FF  H_FW  H_FG ]      H_FF: frame band of width 2b (von Marcard eq. 3.30-3.31)
    [ H_WF  H_WW  H_WG ]      H_FW: frame t × the ≤ K = ⌈L/s⌉ windows containing t
    [ H_GF  H_GW  H_GG ]      H_WW: window band of width K-1;  G: dense border

The engine builds and solves it exactly, at a cost linear in T, one concern per module:

- here: the static `Structure` (sizes, the solver's column order, the super-blocking),
  the stride groups that map frames to the windows containing them, and the interface
  every linearised system offers the LM (`NormalEquations.factor` -> `Factorisation.solve`);
- `colouring.py`: the Jacobian (or Hessian) blocks by coloured forward-mode products;
- `assembly.py`: the blocks of H = JᵀJ and g = Jᵀr from them (`Normal`'s fields);
- `factorise.py`: Jacobi scaling and damping, per-frame elimination, the coupled band
  (behind `tridiagonal.CoupledFactor`: `superblocks.py` over `tridiagonal.py`'s scan or
  cyclic reduction, or `rows.py`'s factorisations in the coupling rows' space) and the
  border's Schur complement;
- `structured.py`: all of it as a lineax solver for optimistix (`StructuredCholesky`).
"""

from __future__ import annotations

import abc
import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..timeseries import shift_frames
from .unknowns import Layout, Windows

__all__ = ["Structure", "NormalEquations", "Factorisation", "full_precision", "group_sum", "window_of_slot"]


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


class NormalEquations(eqx.Module):
    """Linearised normal equations (H, in some structure) as the LM sees them: `Normal`
    (`factorise.py`) for the banded-plus-border structure, `BasisNormal` (`basis.py`)
    for a basis term's Kronecker structure."""

    @abc.abstractmethod
    def factor(self, st: Structure, damping, marquardt: bool = False, tridiagonal: str | None = None) -> Factorisation:
        """H + λI (or H + λ diag(H), eq. 2.54) factorised; `st` and `tridiagonal` as `factorise.factor`'s."""


class Factorisation(eqx.Module):
    """A factorised `NormalEquations`: x = (H + λI)⁻¹ b with b and x as
    (F (T, n), W (W, ·) or None, G (g,) or None)."""

    @abc.abstractmethod
    def solve(self, bF: Array, bW: Array | None = None, bG: Array | None = None):
        """(xF, xW, xG) for the right-hand side (bF, bW, bG)."""


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


def group_sum(spec: str, a: Array, b: Array, j: int, st: Structure) -> Array:
    """Σ over the frames of each stride group of einsum(spec) for slot j, as per-window (W, ...)."""
    mask = jnp.asarray(_slot_mask(st, j), a.dtype)
    per = jnp.einsum(spec, _groups(a, st) * mask.reshape(mask.shape + (1,) * (a.ndim - 1)), _groups(b, st))
    return _to_windows(per, j, st)


def window_of_slot(x: Array, j: int, st: Structure) -> Array:
    """Per-window x (W, ...) read at slot j of every frame: (T, ...), 0 where invalid."""
    s = st.windows.stride
    Q = -(-st.T // s)
    w = np.arange(Q) - j
    vals = x[np.clip(w, 0, st.W - 1)]  # (Q, ...)
    vals = jnp.broadcast_to(vals[:, None], (Q, s) + x.shape[1:])
    mask = jnp.asarray(_slot_mask(st, j)).reshape((Q, s) + (1,) * (x.ndim - 1))
    return jnp.where(mask, vals, 0.0).reshape((Q * s,) + x.shape[1:])[: st.T]
