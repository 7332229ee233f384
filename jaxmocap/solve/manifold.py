"""Per-frame parameter layout and the update x ⊕ δ on SO(3) (von Marcard §2.2.4, §2.3.3).

Rotations are perturbed left-multiplicatively, R(ω ⊕ δ) = exp(δ^) R(ω) (eq. 2.34,
2.56), every other parameter additively. Users hold rotations as axis-angle ω; inside a
solve they are rotation matrices (`to_manifold`), so that residuals at x ⊕ δ cost one
Rodrigues formula and one product per rotation, and their Jacobian at δ = 0 is
dR = δ^ R (eq. 2.58) with no log/exp round trip to differentiate. Term functions
therefore receive the rotation keys as (..., 3, 3) matrices.

The unknowns of a solve are a per-frame tangent δ, a (T, n) array (n = 3 per rotation
plus the other parameters' sizes; `FrameLayout` of the axis-angle parameters):

- `solve(..., method="lm")` (von Marcard's LM, written here) re-anchors after every
  accepted step, x ← x ⊕ δ, δ ← 0, storing ω ← log(exp(δ^) R(ω))^∨ (eq. 2.60,
  `reproject`): exactly eq. 2.56-2.60, the Jacobian always taken at δ = 0.
- The optimistix and jaxopt backends add increments to their iterate, so there δ is
  accumulated on a fixed anchor, x = x₀ ⊕ δ. At the first step this is the same
  linearisation as eq. 2.58; later the Jacobian carries the SO(3) left Jacobian of δ,
  regular for ‖δ‖ < 2π, so the iterate stays on SO(3) exactly (a product of
  rotations), never crosses the θ = π seam of ω, and converges like the re-anchored
  form as long as the solution lies within ‖δ‖ < π of the start (tests compare both).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..rotation import axis_angle_to_matrix, matrix_to_axis_angle

__all__ = ["FrameLayout", "retract", "to_manifold", "from_manifold", "reproject"]


class FrameLayout(eqx.Module):
    """How a parameter dict maps to a (T, n) array of per-frame unknowns.

    Static metadata only (keys sorted, per-frame shapes), so it can sit in jit caches.
    """

    keys: tuple[str, ...] = eqx.field(static=True)
    shapes: tuple[tuple[int, ...], ...] = eqx.field(static=True)

    @classmethod
    def of(cls, params: dict) -> "FrameLayout":
        """Layout of `params`, a dict of arrays with a common leading frame axis."""
        if not isinstance(params, dict) or not params:
            raise ValueError(
                f"parameters must be a non-empty dict of arrays with the frame axis first, "
                f"got {type(params).__name__}."
            )
        keys = tuple(sorted(params))
        T = {k: jnp.shape(params[k])[0] if jnp.ndim(params[k]) else None for k in keys}
        if len(set(T.values())) != 1 or None in T.values():
            raise ValueError(
                f"every parameter must have the same leading frame axis T; got leading "
                f"axes {T}. Per-sequence (global) unknowns are not supported by the "
                "banded solver yet: repeat them per frame with a smoothness term."
            )
        return cls(keys, tuple(tuple(jnp.shape(params[k])[1:]) for k in keys))

    @property
    def sizes(self) -> tuple[int, ...]:
        return tuple(int(np.prod(s)) for s in self.shapes)

    @property
    def size(self) -> int:
        """n, unknowns per frame."""
        return sum(self.sizes)

    def columns(self, reads) -> tuple[int, ...]:
        """Per-frame indices into the (T, n) unknowns named by a `Term.reads` (None: all).

        `reads` pairs a parameter key with indices along its first per-frame axis (e.g.
        joints of a (24, 3) pose) or None for the whole key; unknown keys are skipped.
        """
        if reads is None:
            return tuple(range(self.size))
        offsets = np.cumsum((0,) + self.sizes)
        cols = set()
        for key, index in reads:
            if key not in self.keys:
                continue
            i = self.keys.index(key)
            shape = self.shapes[i]
            if not shape:
                cols.add(int(offsets[i]))
                continue
            per = int(np.prod(shape[1:]))
            rows = range(shape[0]) if index is None else index
            for r in rows:
                if not 0 <= r < shape[0]:
                    raise ValueError(f"reads index {r} out of range for parameter {key!r} of per-frame shape {shape}.")
                cols.update(range(int(offsets[i]) + r * per, int(offsets[i]) + (r + 1) * per))
        return tuple(sorted(cols))

    def ravel(self, params: dict) -> Array:
        """dict of (T, ...) -> (T, n)."""
        return jnp.concatenate([params[k].reshape(params[k].shape[0], -1) for k in self.keys], axis=1)

    def unravel(self, flat: Array) -> dict:
        """(T, n) -> dict of (T, ...)."""
        out, start = {}, 0
        for k, shape, size in zip(self.keys, self.shapes, self.sizes):
            out[k] = flat[:, start : start + size].reshape(flat.shape[0], *shape)
            start += size
        return out


def to_manifold(params: dict, rotations: tuple[str, ...]) -> dict:
    """Axis-angle (..., 3) -> matrices (..., 3, 3) for the keys in `rotations`."""
    for k in rotations:
        if params[k].shape[-1] != 3:
            raise ValueError(f"rotation parameter {k!r} has shape {params[k].shape}; expected (..., 3) axis-angle.")
    return {k: axis_angle_to_matrix(x) if k in rotations else x for k, x in params.items()}


def from_manifold(x: dict, rotations: tuple[str, ...]) -> dict:
    """Matrices -> axis-angle, ω = log(R)^∨ with θ in [0, π], for keys in `rotations`."""
    return {k: matrix_to_axis_angle(v) if k in rotations else v for k, v in x.items()}


def retract(x: dict, delta: dict, rotations: tuple[str, ...]) -> dict:
    """x ⊕ δ on matrices: R ← exp(δ^) R for keys in `rotations` (eq. 2.56), x + δ otherwise.

    `x` holds rotation matrices (..., 3, 3) for the rotation keys (see `to_manifold`);
    δ holds one 3-vector per rotation. At δ = 0 the derivative is dR = δ^ R, the
    left-trivialised Jacobian of eq. 2.58, with no log/exp round trip to differentiate.
    """
    return {
        k: axis_angle_to_matrix(delta[k]) @ v if k in rotations else v + delta[k]
        for k, v in x.items()
    }


def reproject(x: dict, rotations: tuple[str, ...]) -> dict:
    """Store rotations as ω ← log(R)^∨ and back (eq. 2.60), removing rounding drift off SO(3)."""
    return to_manifold(from_manifold(x, rotations), rotations)
