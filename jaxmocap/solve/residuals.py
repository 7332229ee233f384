"""Energies as weighted residual terms: masks, robust losses, frame coupling.

Every method in jaxmocap minimises E(x) = Σ_terms w_k Σ_i ρ_k(‖e_k,i(x)‖²), a sum of
(robust) squared residuals (von Marcard eq. 2.41-2.43, eq. 3.5; Huang eq. 4.1). A `Term`
is one named energy: a residual function of (parameters, data) with one row per frame,
a weight, an optional robust loss and an optional observation mask. A `Problem` is a set
of terms over a parameter pytree whose leaves all carry the frame axis first.

Conventions (the contract the structured solver relies on):

- A term's residual has shape (T, ..., d): row t is "the residual at frame t", the last
  axis d is one observation (a 3-vector orientation error, a 2-D keypoint, ...).
- Row t may depend on the parameters of frames t-b .. t+b only, b = `Term.bandwidth`
  (0: per-frame terms such as E_ori, 1: central differences such as E_acc, eq. 3.10).
  Rows whose window leaves the sequence, or touches a padded frame, are dropped
  automatically, so a term may compute its edge rows with any (finite) padding.
- Cost convention: the reported cost of a term is ½ w Σ_i ρ(‖e_i‖²), the same ½‖r‖²
  that optimistix minimises, so the per-term costs add up to the solver's loss.

Robust losses use the *square-root* form r̃ = √(ρ(s)/s)·e, s = ‖e‖², so that ‖r̃‖² = ρ(s)
exactly. Gauss-Newton/LM then minimise the robust cost itself (the LM acceptance test and
the reported costs are those of the robust energy), with no outer reweighting loop. The
alternative, iteratively reweighted least squares, converges to the same stationary
points but its inner objective is not the robust cost, so LM's "never accept an increase"
guarantee would be about the wrong function. The price of the square-root form is that
its Gauss-Newton matrix neglects ρ'' (as IRLS does too); `tests/test_solve.py` checks the
minimiser against a direct minimisation of the robust cost.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.tree_util as jtu
from jax import Array

__all__ = [
    "RobustLoss",
    "GemanMcClure",
    "Huber",
    "Cauchy",
    "Term",
    "Problem",
    "second_difference",
    "nan_mask",
]


class RobustLoss(eqx.Module):
    """A robust penalty ρ(s) of a squared residual norm s = ‖e‖², with ρ(s) ≈ s near 0."""

    def rho(self, s: Array) -> Array:
        """ρ(s) for s = ‖e‖² >= 0, elementwise."""
        raise NotImplementedError

    def sqrt_scale(self, s: Array) -> Array:
        """√(ρ(s)/s), the factor that turns e into the square-root residual r̃.

        Finite with finite gradients at s = 0 (where it equals 1) for every subclass.
        """
        raise NotImplementedError

    def __call__(self, residual: Array) -> Array:
        """Square-root residual r̃ = √(ρ(‖e‖²)/‖e‖²)·e over the last axis, same shape."""
        s = jnp.sum(residual * residual, axis=-1, keepdims=True)
        return self.sqrt_scale(s) * residual


class GemanMcClure(RobustLoss):
    """ρ(s) = σ² s / (σ² + s): quadratic for ‖e‖ ≪ σ, saturating at σ² for outliers.

    Huang eq. 4.3 writes ρ_σ(e) = e²/(σ² + e²); that is this ρ divided by σ², i.e. the
    same minimiser with a weight of 1/σ². The form here keeps ρ(s) ≈ s near zero so that
    weights mean the same with and without the robust loss.
    """

    sigma: float | Array

    def rho(self, s):
        s2 = self.sigma**2
        return s2 * s / (s2 + s)

    def sqrt_scale(self, s):
        s2 = self.sigma**2
        return jnp.sqrt(s2 / (s2 + s))


class Cauchy(RobustLoss):
    """ρ(s) = σ² log(1 + s/σ²) (Cauchy / Lorentzian)."""

    sigma: float | Array

    def rho(self, s):
        s2 = self.sigma**2
        return s2 * jnp.log1p(s / s2)

    def sqrt_scale(self, s):
        s2 = self.sigma**2
        u = s / s2
        small = u < 1e-4
        safe_u = jnp.where(small, 1.0, u)
        # log1p(u)/u = 1 - u/2 + u²/3 - ... behind a double where (finite gradients at 0).
        ratio = jnp.where(small, 1.0 - u / 2.0 + u * u / 3.0, jnp.log1p(safe_u) / safe_u)
        return jnp.sqrt(ratio)


class Huber(RobustLoss):
    """ρ(s) = s for ‖e‖ <= δ, 2δ‖e‖ - δ² beyond (quadratic core, linear tails)."""

    delta: float | Array

    def rho(self, s):
        inner = s <= self.delta**2
        safe = jnp.where(inner, self.delta**2, s)
        return jnp.where(inner, s, 2.0 * self.delta * jnp.sqrt(safe) - self.delta**2)

    def sqrt_scale(self, s):
        inner = s <= self.delta**2
        safe = jnp.where(inner, self.delta**2, s)
        outer = 2.0 * self.delta / jnp.sqrt(safe) - self.delta**2 / safe
        return jnp.sqrt(jnp.where(inner, 1.0, outer))


def second_difference(x: Array) -> Array:
    """x[t-1] - 2 x[t] + x[t+1] along axis 0, edge rows from edge padding.  (T, ...) -> (T, ...).

    The numerator of the central finite-difference acceleration (von Marcard eq. 3.10);
    divide by dt². Rows 0 and T-1 are placeholders that a bandwidth-1 `Term` drops.
    """
    padded = jnp.concatenate([x[:1], x, x[-1:]], axis=0)
    return padded[:-2] - 2.0 * padded[1:-1] + padded[2:]


def nan_mask(observation: Array, axis: int | tuple[int, ...] = -1) -> Array:
    """True where an observation is present: no NaN along `axis` (reduced away)."""
    return jnp.all(jnp.isfinite(observation), axis=axis)


class Term(eqx.Module):
    """One named, weighted energy term: residual rows per frame, optional loss and mask.

    Attributes:
        name: unique name; per-term costs are reported under it.
        fn: residual function `fn(params, data) -> (T, ..., d)`, row t at frame t,
            depending on frames t-bandwidth .. t+bandwidth only. For a term with a
            `mask`, `data` reaches it with every NaN replaced by 0 (so dropped samples
            cannot poison values or gradients) and the mask sees the raw data; without
            a mask a NaN observation gives a NaN cost, reported as a failed solve.
        weight: w >= 0; the residual is scaled by √w, the cost by w (eq. 3.5).
        bandwidth: frame coupling b (0 per-frame, 1 for t-1, t, t+1, ...).
        loss: robust loss applied per observation (last axis), or None for ρ(s) = s.
        mask: `mask(data) -> bool` broadcastable to the residual's shape without its
            last axis (e.g. (T, N_s) for (T, N_s, 3) residuals); False rows are dropped.
        reads: the per-frame unknowns `fn` depends on, as (parameter key, indices along
            the key's first per-frame axis, or None for all of it) pairs; None: every
            unknown. The solver differentiates only these, and unknowns that no
            frame-coupling term reads are eliminated frame by frame before the banded
            factorisation (e.g. the hands and feet in SIP, seen by the prior only).
        jacobian: optional analytic Jacobian, `jacobian(params, data)` -> {key: array
            (T, 2b+1, *e.shape[1:], *per-frame shape of key)}: ∂e_t/∂δ_{t+d}, d = -b..b,
            of `fn`'s raw output e (before weight, loss and mask; zero where t+d leaves
            the sequence), w.r.t. the tangent δ of each parameter (for rotation keys the
            left perturbation R ← exp(δ^) R). Keys left out are zero. Without it the
            solver takes the blocks by forward-mode AD.
    """

    name: str = eqx.field(static=True)
    fn: Callable[[Any, Any], Array] = eqx.field(static=True)
    weight: float | Array = 1.0
    bandwidth: int = eqx.field(static=True, default=0)
    loss: RobustLoss | None = None
    mask: Callable[[Any], Array] | None = eqx.field(static=True, default=None)
    reads: tuple[tuple[str, tuple[int, ...] | None], ...] | None = eqx.field(static=True, default=None)
    jacobian: Callable[[Any, Any], dict[str, Array]] | None = eqx.field(static=True, default=None)

    def __check_init__(self):
        if not isinstance(self.bandwidth, int) or self.bandwidth < 0:
            raise ValueError(f"Term {self.name!r}: bandwidth must be an int >= 0, got {self.bandwidth!r}.")
        if self.reads is not None and not all(
            isinstance(r, tuple) and len(r) == 2 and isinstance(r[0], str) for r in self.reads
        ):
            raise ValueError(f"Term {self.name!r}: reads must be (key, indices or None) pairs, got {self.reads!r}.")

    def _input(self, data, raw_data):
        # Only a masked term gets NaN-free data: an unmasked NaN must surface as a NaN
        # cost (a failed solve) rather than be silently read as 0.
        return data if self.mask is not None else raw_data

    def raw(self, params, data, raw_data) -> Array:
        """`fn`'s output e (`data`: NaN-free, `raw_data`: as given)."""
        return self.fn(params, self._input(data, raw_data))

    def raw_jacobian(self, params, data, raw_data) -> dict[str, Array]:
        """The analytic Jacobian of `raw` (see `jacobian`)."""
        return self.jacobian(params, self._input(data, raw_data))

    def residual(self, params, data, raw_data, frame_mask: Array | None) -> Array:
        """Weighted, masked (square-root robust) residual, flattened to (T, m)."""
        T = jtu.tree_leaves(params)[0].shape[0]
        return self.finish(self.raw(params, data, raw_data), raw_data, frame_mask, T)

    def finish(self, e: Array, raw_data, frame_mask: Array | None, T: int) -> Array:
        """e -> √w · mask · robust(e), flattened to (T, m); row t depends on e_t only."""
        if e.ndim < 2 or e.shape[0] != T:
            raise ValueError(
                f"Term {self.name!r} returned shape {e.shape}; expected (T={T}, ..., d): "
                "one row per frame, the last axis one observation. Add a trailing axis "
                "(e[..., None]) for scalar residuals."
            )
        keep = _window_valid(T, self.bandwidth, frame_mask)  # (T,) or None
        if self.mask is not None:
            m = jnp.asarray(self.mask(raw_data), dtype=bool)
            try:
                m = jnp.broadcast_to(m, e.shape[:-1])
            except ValueError:
                raise ValueError(
                    f"Term {self.name!r}: mask shape {m.shape} does not broadcast to the "
                    f"residual shape without its last axis, {e.shape[:-1]}."
                ) from None
            keep = m if keep is None else m & keep.reshape((T,) + (1,) * (e.ndim - 2))
        if self.loss is not None:
            e = self.loss(e)
        if keep is not None:
            keep = jnp.broadcast_to(keep.reshape(keep.shape + (1,) * (e.ndim - keep.ndim)), e.shape)
            # Forward-mode safe: the tangent of a dropped row is exactly 0 too.
            e = jnp.where(keep, e, jnp.zeros_like(e))
        w = jnp.asarray(self.weight, e.dtype)
        return (jnp.sqrt(w) * e).reshape(T, -1)


def _window_valid(T: int, bandwidth: int, frame_mask: Array | None) -> Array | None:
    """valid[t] = frames t-b .. t+b all exist and are unpadded; None if all valid."""
    if bandwidth == 0:
        return None if frame_mask is None else frame_mask
    valid = jnp.ones((T,), bool) if frame_mask is None else frame_mask
    padded = jnp.concatenate([jnp.zeros((bandwidth,), bool), valid, jnp.zeros((bandwidth,), bool)])
    out = valid
    for d in range(-bandwidth, bandwidth + 1):
        out = out & padded[bandwidth + d : bandwidth + d + T]
    return out


def _sanitise(data):
    """Replace NaN/inf by 0 in every floating leaf (masks see the raw data)."""

    def clean(x):
        if eqx.is_array(x) and jnp.issubdtype(x.dtype, jnp.inexact):
            return jnp.where(jnp.isfinite(x), x, jnp.zeros_like(x))
        return x

    return jtu.tree_map(clean, data)


class Problem(eqx.Module):
    """A least-squares problem: named terms over a per-frame parameter pytree.

    Parameters are a dict of arrays, each (T, ...) with the frame axis first, e.g.
    {"pose": (T, 24, 3), "trans": (T, 3)}. Keys listed in `rotations` hold axis-angle
    vectors (..., 3) that the solvers update on SO(3) (see `manifold.py`); the term
    functions receive them as rotation matrices (T, ..., 3, 3).

    Attributes:
        terms: the energy terms; names must be unique.
        rotations: parameter keys holding axis-angle rotations.
    """

    terms: tuple[Term, ...]
    rotations: tuple[str, ...] = eqx.field(static=True, default=())

    def __init__(self, terms, rotations=()):
        self.terms = tuple(terms)
        self.rotations = tuple(rotations)

    def __check_init__(self):
        names = [t.name for t in self.terms]
        if len(set(names)) != len(names) or not names:
            raise ValueError(f"Problem needs at least one term and unique term names, got {names}.")
        if any(n.startswith("_") for n in names):
            raise ValueError(f"Term names starting with '_' are reserved, got {names}.")

    @property
    def bandwidth(self) -> int:
        """Largest frame coupling over the terms."""
        return max(t.bandwidth for t in self.terms)

    @property
    def bandwidths(self) -> dict[str, int]:
        return {t.name: t.bandwidth for t in self.terms}

    def residuals(self, params, data, frame_mask: Array | None = None) -> dict[str, Array]:
        """Weighted residuals per term at axis-angle `params`, each flattened to (T, m_term)."""
        from .manifold import to_manifold

        return self.residuals_on_manifold(to_manifold(params, self.rotations), data, frame_mask)

    def residuals_on_manifold(self, x, data, frame_mask: Array | None = None) -> dict[str, Array]:
        """As `residuals`, with the rotation keys of `x` already rotation matrices."""
        params = x
        clean = _sanitise(data)
        return {t.name: t.residual(params, clean, data, frame_mask) for t in self.terms}

    def costs(self, params, data, frame_mask: Array | None = None) -> dict[str, Array]:
        """Per-term costs ½ w Σ ρ(‖e‖²), the balance the solver struck."""
        return {k: 0.5 * jnp.sum(r * r) for k, r in self.residuals(params, data, frame_mask).items()}

    def cost(self, params, data, frame_mask: Array | None = None) -> Array:
        """Total cost ½‖r‖², the objective the solvers minimise."""
        return sum(jax.tree_util.tree_leaves(self.costs(params, data, frame_mask)))
