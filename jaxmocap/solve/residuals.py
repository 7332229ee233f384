"""Energies as weighted residual terms: masks, robust losses, frame coupling.

Every method in jaxmocap minimises E(x) = Σ_terms w_k Σ_i ρ_k(‖e_k,i(x)‖²), a sum of
(robust) squared residuals (von Marcard eq. 2.41-2.43, eq. 3.5; Huang eq. 4.1). A `Term`
is one named energy: a residual function of (parameters, data) with one row per frame,
a weight, an optional robust loss and an optional observation mask. A `Problem` is a set
of terms over a dict of unknowns, each per frame, per sequence or per window
(`unknowns.py`), the rows of every term still one per frame.

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
import numpy as np
from jax import Array

from .._checks import check_weight
from .unknowns import Layout, Unknown, to_manifold

__all__ = [
    "RobustLoss",
    "GemanMcClure",
    "Huber",
    "Cauchy",
    "Term",
    "BlockJacobian",
    "Params",
    "Problem",
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


def nan_mask(observation: Array, axis: int | tuple[int, ...] = -1) -> Array:
    """True where an observation is present: no NaN along `axis` (reduced away)."""
    return jnp.all(jnp.isfinite(observation), axis=axis)


class BlockJacobian(eqx.Module):
    """One key's Jacobian of a per-frame term in factored form, W · blockdiag(D_1 .. D_J).

    For residuals e_t = W x_t (or e_t = f(x_t) elementwise, W None) of k-vectors x_{t,j}
    each depending on one item δ_{t, index[j]} of the key alone: a pose prior on joint
    angles, δ a joint's rotation tangent. The solver then forms the term's share of JᵀJ
    as Dᵀ (WᵀW) D and never builds the dense m × n block; with one W for all frames that
    takes about m/(2k) times fewer products (SIP's Mahalanobis prior: 69 rows, 3 × 3
    blocks, 11×).

    Attributes:
        D: (T, J, k, k), D[t, j] = ∂x_{t,j}/∂δ_{t, index[j]}.
        W: (m, J·k) for every frame, (T, m, J·k) per frame, or None (identity, m = J·k).
        index: the J items (along the key's first per-frame axis, each k wide) read.
    """

    D: Array
    W: Array | None
    index: tuple[int, ...] = eqx.field(static=True)

    def dense(self, e_shape: tuple[int, ...], key_shape: tuple[int, ...]) -> Array:
        """The plain form of a `Term.jacobian` value: (T, 1, *e_shape, *key_shape)."""
        T, J, k, _ = self.D.shape
        if len(key_shape) != 2 or key_shape[1] != k or max(self.index) >= key_shape[0]:
            raise ValueError(
                f"BlockJacobian with {J} blocks of {k} x {k} cannot index a key of per-frame shape {key_shape}."
            )
        onehot = jnp.asarray(np.eye(key_shape[0])[np.asarray(self.index)], self.D.dtype)  # (J, N)
        if self.W is None:
            blocks = jnp.einsum("tjab,jn->tjanb", self.D, onehot).reshape(T, J * k, key_shape[0], k)
        else:
            W = jnp.broadcast_to(self.W, (T,) + self.W.shape[-2:]).reshape(T, -1, J, k).astype(self.D.dtype)
            WD = jnp.einsum("tmja,tjab->tmjb", W, self.D)
            blocks = jnp.einsum("tmjb,jn->tmnb", WD, onehot)
        return blocks.reshape((T, 1) + tuple(e_shape) + tuple(key_shape))


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
        reads: the unknowns `fn` depends on, as (parameter key, indices along the
            first axis of the key's per-item shape, or None for all of it) pairs, e.g.
            (("pose", (1, 2)), ("heading", None)); None: every per-frame unknown.
            Per-sequence and per-window unknowns reach `fn` only if declared here (an
            undeclared one raises a ValueError naming it). The solver differentiates
            only what a term reads, and per-frame unknowns that no frame-coupling term
            reads are eliminated frame by frame before the banded factorisation (e.g.
            the hands and feet in SIP, seen by the prior only). A term that reads a
            per-window unknown must have bandwidth 0 and return, for its rows at frame
            t, one block per window slot (see `jaxmocap.solve.Windows.rows`).
        jacobian: optional analytic Jacobian, `jacobian(params, data)` -> {key: array
            (T, 2b+1, *e.shape[1:], *per-frame shape of key)}: ∂e_t/∂δ_{t+d}, d = -b..b,
            of `fn`'s raw output e (before weight, loss and mask; zero where t+d leaves
            the sequence), w.r.t. the tangent δ of each parameter (for rotation keys the
            left perturbation R ← exp(δ^) R). Keys left out are zero. A per-frame term
            (bandwidth 0) may give a key's Jacobian as a `BlockJacobian` instead. Without
            it the solver takes the blocks by forward-mode AD.
        basis: a `basis.WindowBasis` when the term is a per-window basis term (built by
            `basis_term`, whose `fn` is then `basis.residual`): the LM solves its problem
            with the Kronecker elimination of `jaxmocap.solve.basis`.
        posed: None, or the posed body the term reads, `posed(params, data)` (static: an
            equinox module of static configuration, e.g. `energies.posed.PosedBody()`):
            then `fn` (and `jacobian`) take it as a third argument, `fn(params, data,
            posed)`, computed once per evaluation for all the terms of the problem that
            read it (`Problem.posed`).
    """

    name: str = eqx.field(static=True)
    fn: Callable[[Any, Any], Array] = eqx.field(static=True)
    weight: float | Array = 1.0
    bandwidth: int = eqx.field(static=True, default=0)
    loss: RobustLoss | None = None
    mask: Callable[[Any], Array] | None = eqx.field(static=True, default=None)
    reads: tuple[tuple[str, tuple[int, ...] | None], ...] | None = eqx.field(static=True, default=None)
    jacobian: Callable[[Any, Any], dict[str, Array]] | None = eqx.field(static=True, default=None)
    basis: Any = eqx.field(static=True, default=None)
    posed: Callable[[Any, Any], Any] | None = eqx.field(static=True, default=None)

    def __check_init__(self):
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"Term name must be a non-empty str, got {self.name!r}.")
        if not callable(self.fn):
            raise ValueError(f"Term {self.name!r}: fn must be callable, got {type(self.fn).__name__}.")
        # A negative weight rewards the error and the solve diverges without a word.
        check_weight(f"Term {self.name!r} weight", self.weight)
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

    def _call(self, f, params, data, raw_data, posed):
        if self.posed is None:
            return f(params, self._input(data, raw_data))
        if posed is None:
            raise ValueError(f"Term {self.name!r} reads the posed body: evaluate it through its Problem.")
        return f(params, self._input(data, raw_data), posed)

    def raw(self, params, data, raw_data, posed=None) -> Array:
        """`fn`'s output e (`data`: NaN-free, `raw_data`: as given, `posed`: the posed
        body when the term reads it)."""
        return self._call(self.fn, params, data, raw_data, posed)

    def raw_jacobian(self, params, data, raw_data, posed=None) -> dict[str, Array]:
        """The analytic Jacobian of `raw` (see `jacobian`)."""
        return self._call(self.jacobian, params, data, raw_data, posed)

    def residual(self, params, data, raw_data, frame_mask: Array | None, T: int, posed=None) -> Array:
        """Weighted, masked (square-root robust) residual, flattened to (T, m)."""
        return self.finish(self.raw(params, data, raw_data, posed), raw_data, frame_mask, T)

    def read_keys(self) -> set[str] | None:
        """Keys named in `reads` (None: undeclared, every per-frame unknown)."""
        return None if self.reads is None else {k for k, _ in self.reads}

    def kept(self, shape, raw_data, frame_mask: Array | None, T: int) -> Array | None:
        """Which entries of a raw residual of `shape` count (None: all), before the last axis.

        The mask broadcasts against `shape[:-1]` by NumPy's rules (trailing axes first),
        so a (S,) mask is per sensor even when S == T; the frame mask and the window
        validity act on the leading (frame) axis.
        """
        keep = _window_valid(T, self.bandwidth, frame_mask)  # (T,) or None
        if self.mask is None:
            return keep
        m = jnp.asarray(self.mask(raw_data), dtype=bool)
        try:
            m = jnp.broadcast_to(m, tuple(shape[:-1]))
        except ValueError:
            raise ValueError(
                f"Term {self.name!r}: mask shape {m.shape} does not broadcast to the "
                f"residual shape without its last axis, {tuple(shape[:-1])}."
            ) from None
        return m if keep is None else m & keep.reshape((T,) + (1,) * (len(shape) - 2))

    def finish(self, e: Array, raw_data, frame_mask: Array | None, T: int) -> Array:
        """e -> √w · mask · robust(e), flattened to (T, m); row t depends on e_t only."""
        if e.ndim < 2 or e.shape[0] != T:
            raise ValueError(
                f"Term {self.name!r} returned shape {e.shape}; expected (T={T}, ..., d): "
                "one row per frame, the last axis one observation. Add a trailing axis "
                "(e[..., None]) for scalar residuals."
            )
        keep = self.kept(e.shape, raw_data, frame_mask, T)
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


def sanitise(data):
    """`data` with NaN/inf replaced by 0 in every floating leaf: what the terms read (their
    masks see the raw data), so a masked-out NaN sample never reaches a residual (0·NaN = NaN)."""

    def clean(x):
        if eqx.is_array(x) and jnp.issubdtype(x.dtype, jnp.inexact):
            return jnp.where(jnp.isfinite(x), x, jnp.zeros_like(x))
        return x

    return jtu.tree_map(clean, data)


class Params(dict):
    """The unknowns as a term function sees them (rotations as matrices), one evaluation.

    A dict of the per-frame unknowns and the per-sequence / per-window unknowns the
    term declares in `reads`; reading an undeclared one raises a ValueError naming it.
    """

    def __init__(self, values, hidden=(), term=""):
        super().__init__(values)
        self._hidden = dict(hidden)
        self._term = term

    def __missing__(self, key):
        if key in self._hidden:
            raise ValueError(
                f"Term {self._term!r} reads the {self._hidden[key]} unknown {key!r} without "
                f"declaring it: add ({key!r}, None) to the term's reads."
            )
        raise KeyError(key)


class Problem(eqx.Module):
    """A least-squares problem: named terms over a dict of unknowns.

    Each unknown has a kind (per frame (T, ...), per sequence (...), per window
    (W, ...)) and a manifold (vector, angle, SO(3), SE(3)); see `jaxmocap.solve.unknowns`.
    Keys not declared in `unknowns` are per-frame vectors. Term functions receive
    rotations as (..., 3, 3) matrices and rigid poses as (..., 4, 4) matrices.

        Problem(terms, unknowns={"pose": frame("so3"), "heading": sequence("angle")})

    Attributes:
        terms: the energy terms; names must be unique.
        unknowns: {key: Unknown}; `rotations=("pose",)` is short for {"pose": frame("so3")}.
        posed: the posed body `posed(params, data)` shared by the terms that read one
            (`Term.posed`), computed once per evaluation and passed to each as
            `fn(params, data, posed)`. Default: the terms' own, which must then agree;
            give it to choose one for terms that differ (e.g. a physics term's
            `PosedBody()` in a camera problem posed by `PosedInViews()`).
    """

    terms: tuple[Term, ...]
    unknowns: tuple[tuple[str, Unknown], ...] = eqx.field(static=True, default=())
    posed: Callable[[Any, Any], Any] | None = eqx.field(static=True, default=None)

    def __init__(self, terms, unknowns=None, rotations=(), posed=None):
        self.terms = tuple(terms)
        spec = {k: Unknown("frame", "so3") for k in rotations}
        spec.update(unknowns or {})
        self.unknowns = tuple(sorted(spec.items()))
        if posed is None:
            own = list(dict.fromkeys(t.posed for t in self.terms if t.posed is not None))
            if len(own) > 1:
                readers = {t.name: t.posed for t in self.terms if t.posed is not None}
                raise ValueError(
                    f"the terms read different posed bodies {readers}: give the Problem the one "
                    f"to compute for all of them, Problem(..., posed=...)."
                )
            posed = own[0] if own else None
        self.posed = posed

    def __check_init__(self):
        names = [t.name for t in self.terms]
        if len(set(names)) != len(names) or not names:
            raise ValueError(f"Problem needs at least one term and unique term names, got {names}.")
        if any(n.startswith("_") for n in names):
            raise ValueError(f"Term names starting with '_' are reserved, got {names}.")
        if self.posed is not None and not callable(self.posed):
            raise ValueError(f"Problem posed must be callable, posed(params, data), got {self.posed!r}.")
        spec = dict(self.unknowns)
        for key, u in spec.items():
            if not isinstance(u, Unknown):
                raise ValueError(f"unknowns[{key!r}] must be frame(), sequence() or window(...), got {u!r}.")
            if u.kind == "frame":
                continue
            readers = [t for t in self.terms if t.reads is not None and key in t.read_keys()]
            if not readers:
                raise ValueError(
                    f"no term reads the {u.kind} unknown {key!r}, so nothing determines it (a "
                    f"singular border): declare it in the reads of the terms that use it, "
                    f"e.g. reads=(({key!r}, None), ...), or remove it."
                )
            if u.kind == "window":
                for t in readers:
                    if t.bandwidth != 0:
                        raise ValueError(
                            f"Term {t.name!r} reads the per-window unknown {key!r} and has bandwidth "
                            f"{t.bandwidth}; a term that reads windows must be per-frame (bandwidth 0). "
                            "Split it into a window term and a frame-coupling term."
                        )

    @property
    def spec(self) -> dict[str, Unknown]:
        return dict(self.unknowns)

    @property
    def rotations(self) -> tuple[str, ...]:
        """Keys stored as axis-angle rotations (SO(3))."""
        return tuple(k for k, u in self.unknowns if u.manifold == "so3")

    @property
    def bandwidth(self) -> int:
        """Largest frame coupling over the terms."""
        return max(t.bandwidth for t in self.terms)

    @property
    def bandwidths(self) -> dict[str, int]:
        return {t.name: t.bandwidth for t in self.terms}

    def layout(self, params: dict):
        """The `Layout` of `params` under this problem's unknowns."""
        return Layout.of(params, self.spec)

    def _view(self, x: dict, declared: set[str], name: str) -> Params:
        spec = self.spec
        kinds = {k: spec[k].kind if k in spec else "frame" for k in x}
        visible = {k: v for k, v in x.items() if kinds[k] == "frame" or k in declared}
        hidden = {k: "per-" + kinds[k] for k in x if k not in visible}
        return Params(visible, hidden, name)

    def views(self, x: dict) -> dict[str, Params]:
        """Per term, the unknowns it may read."""
        return {t.name: self._view(x, t.read_keys() or set(), t.name) for t in self.terms}

    def posed_of(self, x: dict, data, terms=None):
        """`posed(params, data)` at `x` (manifold form) for those of `terms` (default: all)
        that read it, None if none does. It sees the unknowns that any of them may read;
        `data` is the NaN-free data (`sanitise`)."""
        readers = [t for t in (self.terms if terms is None else terms) if t.posed is not None]
        if not readers:
            return None
        declared = set().union(*(t.read_keys() or set() for t in readers))
        return self.posed(self._view(x, declared, "posed"), data)

    def residuals(self, params, data, frame_mask: Array | None = None) -> dict[str, Array]:
        """Weighted residuals per term at stored `params`, each flattened to (T, m_term)."""
        layout = self.layout(params)
        return self.residuals_on_manifold(to_manifold(params, layout), data, frame_mask, layout.T)

    def residuals_on_manifold(self, x, data, frame_mask: Array | None = None, T: int | None = None,
                              names=None) -> dict[str, Array]:  # fmt: skip
        """As `residuals`, with `x` already in manifold form (rotations as matrices);
        `names`: only these terms' (default: all). The posed body is computed once, and
        only when one of these terms reads it."""
        if T is None:
            spec = self.spec
            T = next(jnp.shape(v)[0] for k, v in x.items() if k not in spec or spec[k].kind == "frame")
        clean = sanitise(data)
        views = self.views(x)
        terms = self.terms if names is None else [t for t in self.terms if t.name in names]
        posed = self.posed_of(x, clean, terms)
        return {t.name: t.residual(views[t.name], clean, data, frame_mask, T, posed) for t in terms}

    def costs(self, params, data, frame_mask: Array | None = None) -> dict[str, Array]:
        """Per-term costs ½ w Σ ρ(‖e‖²), the balance the solver struck."""
        return {k: 0.5 * jnp.sum(r * r) for k, r in self.residuals(params, data, frame_mask).items()}

    def cost(self, params, data, frame_mask: Array | None = None) -> Array:
        """Total cost ½‖r‖², the objective the solvers minimise."""
        return sum(jax.tree_util.tree_leaves(self.costs(params, data, frame_mask)))
