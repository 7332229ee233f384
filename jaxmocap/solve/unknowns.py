"""Unknowns: what a problem solves for, how they share frames, and how they move.

Every unknown of a `Problem` has a **kind**, saying which frames share it, and a
**manifold**, saying how a step updates it (von Marcard §2.2.4, §2.3.3):

| kind | array shape | example |
| --- | --- | --- |
| `frame()` | (T, ...) one value per frame | body pose, translation, camera pose per frame |
| `sequence()` | (...) one value for all frames | heading γ_s per sensor, initial pose x₀, shape β |
| `window(length, stride)` | (W, ...) one value per window | DCT coefficients of 30-frame windows |

| manifold | stored as | a term sees | step x ⊕ δ |
| --- | --- | --- | --- |
| `"vector"` | (..., d) | the same | x + δ |
| `"angle"` | (...) radians | the same | x + δ, stored wrapped to (-π, π] |
| `"so3"` | (..., 3) axis-angle ω | (..., 3, 3) R | exp(δ^) R (eq. 2.56) |
| `"se3"` | (..., 6) (ω, t) | (..., 4, 4) [R t; 0 1] | exp(ξ^) T, ξ = (φ, ρ): R ← exp(φ^) R, t ← exp(φ^) t + J_l(φ) ρ |

The tangent δ has the shape of the stored parameter (3 per rotation, 6 per rigid pose),
and rotations are perturbed on the left like von Marcard's eq. 2.56-2.58, so a residual's
Jacobian at δ = 0 is dR = δ^ R with no log/exp round trip to differentiate.

Windows: window w covers frames [w·stride, w·stride + length), the last one clipped to
the sequence; they must start inside the sequence and together cover all of it.
`Windows.frames` gathers a per-frame array into windows and `Windows.rows` turns
per-window residuals into rows per frame (slot j of frame t is window ⌊t/stride⌋ - j),
the layout the engine expects from a term that reads a per-window unknown.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..rotation import axis_angle_to_matrix, left_jacobian, matrix_to_axis_angle

__all__ = [
    "KINDS",
    "MANIFOLDS",
    "Unknown",
    "Windows",
    "frame",
    "sequence",
    "window",
    "Layout",
    "to_manifold",
    "from_manifold",
    "retract",
]

KINDS = ("frame", "sequence", "window")
MANIFOLDS = ("vector", "angle", "so3", "se3")
_ITEM = {"so3": 3, "se3": 6}  # trailing size a manifold needs (None: any)


class Windows(eqx.Module):
    """Windows of `length` frames every `stride` frames (static)."""

    length: int = eqx.field(static=True)
    stride: int = eqx.field(static=True)

    def __check_init__(self):
        if not (isinstance(self.length, int) and isinstance(self.stride, int) and 1 <= self.stride <= self.length):
            raise ValueError(
                f"windows need integers 1 <= stride <= length, got length={self.length!r}, "
                f"stride={self.stride!r} (a stride longer than the window leaves frames uncovered)."
            )

    @property
    def slots(self) -> int:
        """K, the most windows one frame belongs to: ⌈length / stride⌉."""
        return -(-self.length // self.stride)

    def count(self, T: int) -> int:
        """The number of windows that covers T frames."""
        return max(1, -(-(T - self.length) // self.stride) + 1)

    def check(self, T: int, W: int, key: str) -> None:
        if not ((W - 1) * self.stride < T <= (W - 1) * self.stride + self.length):
            raise ValueError(
                f"per-window unknown {key!r} has {W} windows of {self.length} frames every "
                f"{self.stride}, which do not cover the {T} frames exactly (every window must "
                f"start inside the sequence and together they must reach its end); use "
                f"{self.count(T)} windows for T = {T}."
            )

    def slot_windows(self, T: int, W: int) -> tuple[np.ndarray, np.ndarray]:
        """(window index (T, K), valid (T, K)): slot j of frame t is window ⌊t/stride⌋ - j."""
        t = np.arange(T)[:, None]
        w = t // self.stride - np.arange(self.slots)[None, :]
        valid = (w >= 0) & (w < W) & (t < w * self.stride + self.length)
        return np.where(valid, w, 0), valid

    def frames(self, x: Array) -> tuple[Array, Array]:
        """A per-frame array (T, ...) as windows (W, length, ...), plus (W, length) validity.

        Frames past the end of the sequence (in a clipped last window) repeat the last frame.
        """
        T = x.shape[0]
        W = self.count(T)
        idx = np.arange(W)[:, None] * self.stride + np.arange(self.length)[None, :]
        return x[np.minimum(idx, T - 1)], jnp.asarray(idx < T)

    def rows(self, per_window: Array, T: int) -> Array:
        """Per-window residuals (W, length, ...) as rows per frame (T, K, ...), 0 in empty slots."""
        W = per_window.shape[0]
        w, valid = self.slot_windows(T, W)
        offset = np.arange(T)[:, None] - w * self.stride
        rows = per_window[w, np.clip(offset, 0, self.length - 1)]
        mask = jnp.asarray(valid).reshape(valid.shape + (1,) * (rows.ndim - 2))
        return jnp.where(mask, rows, jnp.zeros_like(rows))


class Unknown(eqx.Module):
    """The kind and manifold of one unknown (static). Build with `frame`, `sequence`, `window`."""

    kind: str = eqx.field(static=True)
    manifold: str = eqx.field(static=True, default="vector")
    windows: Windows | None = eqx.field(static=True, default=None)

    def __check_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"unknown kind must be one of {KINDS}, got {self.kind!r}.")
        if self.manifold not in MANIFOLDS:
            raise ValueError(f"manifold must be one of {MANIFOLDS}, got {self.manifold!r}.")
        if (self.kind == "window") != (self.windows is not None):
            raise ValueError("a per-window unknown needs its Windows (use jaxmocap.solve.window(length, stride)).")


def frame(manifold: str = "vector") -> Unknown:
    """One value per frame, (T, ...)."""
    return Unknown("frame", manifold)


def sequence(manifold: str = "vector") -> Unknown:
    """One value shared by every frame of the sequence, (...)."""
    return Unknown("sequence", manifold)


def window(length: int, stride: int | None = None, manifold: str = "vector") -> Unknown:
    """One value per window of `length` frames every `stride` (default: non-overlapping), (W, ...)."""
    return Unknown("window", manifold, Windows(int(length), int(length if stride is None else stride)))


class Layout(eqx.Module):
    """How a parameter dict maps to the solver's tangent (F (T, n_F), W (W, n_W), G (n_G,)).

    Static metadata only (so it can sit in jit caches): keys sorted, per key its kind,
    manifold and per-item shape (frame: shape[1:], window: shape[1:], sequence: shape).
    """

    keys: tuple[str, ...] = eqx.field(static=True)
    kinds: tuple[str, ...] = eqx.field(static=True)
    manifolds: tuple[str, ...] = eqx.field(static=True)
    shapes: tuple[tuple[int, ...], ...] = eqx.field(static=True)
    T: int = eqx.field(static=True)
    num_windows: int = eqx.field(static=True)
    windows: Windows | None = eqx.field(static=True)

    @classmethod
    def of(cls, params: dict, unknowns: dict[str, Unknown]) -> Layout:
        """Layout of `params` given each key's `Unknown` (keys not in `unknowns`: per-frame vectors)."""
        if not isinstance(params, dict) or not params:
            raise ValueError(f"parameters must be a non-empty dict of arrays, got {type(params).__name__}.")
        extra = sorted(set(unknowns) - set(params))
        if extra:
            raise ValueError(f"the problem declares unknowns {extra} that params0 lacks; params0 has {sorted(params)}.")
        keys = tuple(sorted(params))
        spec = {k: unknowns.get(k, Unknown("frame")) for k in keys}
        shape = {k: tuple(jnp.shape(params[k])) for k in keys}
        framed = {k: shape[k][0] if shape[k] else None for k in keys if spec[k].kind == "frame"}
        if not framed:
            raise ValueError("a problem needs at least one per-frame unknown (it sets T, the number of frames).")
        if len(set(framed.values())) != 1 or None in framed.values():
            raise ValueError(
                f"every per-frame unknown must have the same leading frame axis T; got leading "
                f"axes {framed}. A value shared by all frames is a per-sequence unknown: declare "
                "it with unknowns={key: jaxmocap.solve.sequence()}."
            )
        T = next(iter(framed.values()))
        windows = {spec[k].windows for k in keys if spec[k].kind == "window"}
        if len(windows) > 1:
            raise ValueError(f"all per-window unknowns of a problem must share one window layout, got {windows}.")
        win = windows.pop() if windows else None
        W = 0
        for k in keys:
            u = spec[k]
            if u.kind == "window":
                if not shape[k]:
                    raise ValueError(f"per-window unknown {k!r} needs a leading window axis, got a scalar.")
                W = shape[k][0]
                u.windows.check(T, W, k)
            item = shape[k] if u.kind == "sequence" else shape[k][1:]
            need = _ITEM.get(u.manifold)
            if need and (not item or item[-1] != need):
                raise ValueError(
                    f"{u.manifold} unknown {k!r} must end in an axis of {need} "
                    f"({'axis-angle' if need == 3 else 'axis-angle then translation'}), got shape {shape[k]}."
                )
        items = tuple(shape[k] if spec[k].kind == "sequence" else shape[k][1:] for k in keys)
        return cls(keys, tuple(spec[k].kind for k in keys), tuple(spec[k].manifold for k in keys), items, T, W, win)

    def _keys(self, kind):
        return [i for i, c in enumerate(self.kinds) if c == kind]

    def size(self, kind: str = "frame") -> int:
        """Unknowns per frame (n_F), per window (n_W) or in the sequence (n_G)."""
        return sum(int(np.prod(self.shapes[i])) for i in self._keys(kind))

    @property
    def n(self) -> int:
        return self.size("frame")

    def columns(self, reads, kind: str = "frame") -> tuple[int, ...]:
        """Indices into the tangent of `kind` named by a `Term.reads`.

        `reads` pairs a key with indices along the first axis of its per-item shape (e.g.
        joints of a (24, 3) pose) or None for all of it; None reads every per-frame unknown
        and nothing else. Keys that are not parameters are skipped.
        """
        idx = self._keys(kind)
        sizes = [int(np.prod(self.shapes[i])) for i in idx]
        offsets = np.cumsum([0] + sizes)
        if reads is None:
            return tuple(range(int(offsets[-1]))) if kind == "frame" else ()
        cols = set()
        for key, index in reads:
            if key not in self.keys or self.keys.index(key) not in idx:
                continue
            pos = idx.index(self.keys.index(key))
            shape = self.shapes[idx[pos]]
            start = int(offsets[pos])
            if not shape:
                cols.add(start)
                continue
            per = int(np.prod(shape[1:]))
            rows = range(shape[0]) if index is None else index
            for r in rows:
                if not 0 <= r < shape[0]:
                    raise ValueError(f"reads index {r} out of range for parameter {key!r} of item shape {shape}.")
                cols.update(range(start + r * per, start + (r + 1) * per))
        return tuple(sorted(cols))

    def ravel(self, params: dict) -> tuple[Array, Array | None, Array | None]:
        """dict -> (F (T, n_F), W (W, n_W) or None, G (n_G,) or None)."""
        F = jnp.concatenate([params[self.keys[i]].reshape(self.T, -1) for i in self._keys("frame")], 1)
        wk, gk = self._keys("window"), self._keys("sequence")
        W = jnp.concatenate([params[self.keys[i]].reshape(self.num_windows, -1) for i in wk], 1) if wk else None
        G = jnp.concatenate([params[self.keys[i]].reshape(-1) for i in gk]) if gk else None
        return F, W, G

    def unravel(self, F: Array, W: Array | None = None, G: Array | None = None) -> dict:
        """(F, W, G) -> dict (inverse of `ravel`)."""
        out = {}
        for kind, flat, lead in (("frame", F, (self.T,)), ("window", W, (self.num_windows,)), ("sequence", G, ())):
            start = 0
            for i in self._keys(kind):
                size = int(np.prod(self.shapes[i]))
                out[self.keys[i]] = flat[..., start : start + size].reshape(lead + self.shapes[i])
                start += size
        return out

    def zeros(self, dtype) -> dict:
        """A zero tangent in dict form."""
        lead = {"frame": (self.T,), "window": (self.num_windows,), "sequence": ()}
        return {k: jnp.zeros(lead[c] + s, dtype) for k, c, s in zip(self.keys, self.kinds, self.shapes)}

    def manifold(self, key: str) -> str:
        return self.manifolds[self.keys.index(key)]


def _se3_matrix(x: Array) -> Array:
    R = axis_angle_to_matrix(x[..., :3])
    top = jnp.concatenate([R, x[..., 3:, None]], -1)
    bottom = jnp.broadcast_to(jnp.asarray([0.0, 0.0, 0.0, 1.0], x.dtype), top.shape[:-2] + (1, 4))
    return jnp.concatenate([top, bottom], -2)


def to_manifold(params: dict, layout: Layout) -> dict:
    """Stored parameters -> what terms see: rotations as (..., 3, 3), rigid poses as (..., 4, 4)."""
    out = {}
    for k, v in params.items():
        m = layout.manifold(k)
        out[k] = axis_angle_to_matrix(v) if m == "so3" else _se3_matrix(v) if m == "se3" else v
    return out


def from_manifold(x: dict, layout: Layout) -> dict:
    """Inverse of `to_manifold`: ω = log(R)^∨ with θ in [0, π]; angles wrapped to (-π, π]."""
    out = {}
    for k, v in x.items():
        m = layout.manifold(k)
        if m == "so3":
            out[k] = matrix_to_axis_angle(v)
        elif m == "se3":
            out[k] = jnp.concatenate([matrix_to_axis_angle(v[..., :3, :3]), v[..., :3, 3]], -1)
        elif m == "angle":
            out[k] = v - 2 * math.pi * jnp.floor((v + math.pi) / (2 * math.pi))
        else:
            out[k] = v
    return out


def retract(x: dict, delta: dict, layout: Layout) -> dict:
    """x ⊕ δ on the manifold form `x` (see the module table)."""
    out = {}
    for k, v in x.items():
        m, d = layout.manifold(k), delta[k]
        if m == "so3":
            out[k] = axis_angle_to_matrix(d) @ v
        elif m == "se3":
            phi, rho = d[..., :3], d[..., 3:]
            R = axis_angle_to_matrix(phi)
            rot = R @ v[..., :3, :3]
            t = jnp.einsum("...ab,...b->...a", R, v[..., :3, 3]) + jnp.einsum(
                "...ab,...b->...a", left_jacobian(phi), rho
            )
            out[k] = jnp.concatenate([jnp.concatenate([rot, t[..., None]], -1), v[..., 3:, :]], -2)
        else:
            out[k] = v + d
    return out
