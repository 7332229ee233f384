"""`solve`: minimise a `Problem` over a sequence, returning plain per-problem arrays.

Backends behind one call (`method=`):

- ``"lm"`` — von Marcard's Levenberg-Marquardt (§2.3.2, §3.3.4), written here on the
  structured solver: δ = -(JᵀJ + λI)⁻¹ Jᵀr (eq. 2.52, `damping="levenberg"`, default) or
  -(JᵀJ + λ diag(JᵀJ))⁻¹ Jᵀr (eq. 2.54, `damping="marquardt"`), λ₀ = 10, ×10 on a
  rejected step, ×0.1 on an accepted one; rotations re-anchored after every accepted
  step, ω ← log(exp(δ^) R(ω))^∨ (eq. 2.56-2.60). The Jacobian blocks (a term's own
  analytic `Term.jacobian`, else forward-mode AD by frame colouring over the columns
  the term `reads`) and JᵀJ are built once per accepted iterate; a rejected step only
  refactorises with the new λ (under `vmap` both branches run: each sequence of a
  batch relinearises on every step). It is
  the default: the seeds' algorithm, and the cheapest per iteration. Levenberg damping
  is the default because on the SIP-shaped problem (benchmarks/solver_scaling.py, T = 20)
  Marquardt's diag(JᵀJ) scaling let the weakly observed joints (seen by the 0.003-weight
  prior only) take multi-radian steps: cost 66.6 after 10 iterations against 0.54.
- ``"optx_lm"`` / ``"optx_gn"`` — `optx.LevenbergMarquardt` / `optx.GaussNewton` with the
  block-banded `BandedNormalCholesky` as their `linear_solver` (``linear_solver="dense"``
  gives optimistix's own dense default, QR / AutoLinearSolver, for small problems).
  optimistix's LM damps with λI and its own trust-region schedule, and rebuilds the
  Jacobian blocks on every step, rejected ones included: optimistix hands a linear
  solver nothing but the operator. Rotations use a fixed anchor, x = x₀ ⊕ δ (see
  `manifold.py`).
- ``"jaxopt"`` — `jaxopt.LevenbergMarquardt` on the flat δ with a materialised Jacobian,
  for small per-frame problems (n ≈ 75, T small) only; jaxopt is unmaintained.

All backends return a `Solution` of arrays only, so `solve` can be `vmap`ped (see
`batch.py`), and never raise on failure: `result` holds an `optx.RESULTS` index.
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
from jax import Array

from .manifold import FrameLayout, from_manifold, reproject, retract, to_manifold
from .residuals import Problem, _sanitise
from .structured import (
    BandedNormalCholesky,
    factor_banded,
    jacobian_blocks,
    jt_vector,
    normal_blocks,
    solve_banded,
)

__all__ = ["Solution", "solve", "result_message", "METHODS"]

METHODS = ("lm", "optx_lm", "optx_gn", "jaxopt")
_PADDING = "_padding"


class Solution(eqx.Module):
    """Outcome of `solve`; every field is an array (batched by `solve_batch`).

    Attributes:
        value: the parameters at the solution, same structure as `params0`.
        result: `optx.RESULTS` index: 0 successful, else see `result_message`.
        num_steps: iterations taken (for "lm": trial steps, accepted or not).
        cost: final total cost ½‖r‖².
        costs: final per-term costs ½ w Σ ρ(‖e‖²), keyed by term name.
    """

    value: Any
    result: Array
    num_steps: Array
    cost: Array
    costs: dict[str, Array]

    @property
    def converged(self) -> Array:
        return self.result == 0


def result_message(result) -> str:
    """Human-readable meaning of a `Solution.result` index."""
    return optx.RESULTS._index_to_message[int(result)] or "successful"


def _residual_fn(delta: Array, args, pad: bool = True) -> dict[str, Array]:
    """Weighted residuals at x₀ ⊕ δ; δ is (T, n). Padded frames are pinned to δ = 0."""
    problem, layout, anchor, data, frame_mask = args
    x = retract(anchor, layout.unravel(delta), problem.rotations)
    res = problem.residuals_on_manifold(x, data, frame_mask)
    if pad and frame_mask is not None:
        # Padded frames have no residual; pinning their δ keeps JᵀJ non-singular and
        # decoupled from the real frames, at zero cost.
        res[_PADDING] = jnp.where(frame_mask[:, None], jnp.zeros_like(delta), delta)
    return res


def _bandwidths(problem: Problem, with_padding: bool) -> tuple[int, ...]:
    bw = dict(problem.bandwidths)
    if with_padding:
        bw[_PADDING] = 0
    return tuple(bw[k] for k in sorted(bw))


def _check(problem, params0, data, frame_mask, dtype):
    if not isinstance(problem, Problem):
        raise ValueError(f"problem must be a jaxmocap.solve.Problem, got {type(problem).__name__}.")
    layout = FrameLayout.of(params0)
    for k in problem.rotations:
        if k not in params0:
            raise ValueError(f"rotation key {k!r} is not a parameter; parameters are {sorted(params0)}.")
    leaves = [jnp.asarray(params0[k]) for k in layout.keys]
    if dtype is None:
        dtype = jnp.result_type(*[x.dtype for x in leaves if jnp.issubdtype(x.dtype, jnp.floating)] or [jnp.float32])
    dtype = jnp.dtype(dtype)
    if dtype == jnp.float64 and not jax.config.jax_enable_x64:
        raise ValueError(
            "float64 requested but JAX runs in 32-bit mode; call "
            "jax.config.update('jax_enable_x64', True) first."
        )
    params0 = {k: jnp.asarray(params0[k], dtype) for k in layout.keys}
    T = leaves[0].shape[0]
    if frame_mask is not None:
        frame_mask = jnp.asarray(frame_mask, bool)
        if frame_mask.shape != (T,):
            raise ValueError(f"frame_mask has shape {frame_mask.shape}; expected (T,) = ({T},).")
    return layout, params0, frame_mask, dtype


def solve(
    problem: Problem,
    params0: dict,
    data: Any = None,
    *,
    frame_mask: Array | None = None,
    method: str = "lm",
    rtol: float | Array = 1e-6,
    atol: float | Array = 1e-8,
    max_steps: int = 100,
    linear_solver: str | lx.AbstractLinearSolver = "banded",
    factor_dtype: Any = None,
    dtype: Any = None,
    damping: str = "levenberg",
) -> Solution:
    """Minimise `problem` from `params0` given `data`; returns a `Solution` of arrays.

    Args:
        problem: the terms to balance.
        params0: dict of (T, ...) initial parameters (frame axis first).
        data: any pytree the term functions read (observations, constants).
        frame_mask: (T,) bool, False for padded frames (they keep their initial value).
        method: one of `METHODS` (see the module docstring).
        rtol, atol: stopping tolerances (arrays allowed, e.g. per sequence under vmap).
            "lm" stops when a step changes the cost by less than rtol·cost + atol or
            moves no unknown by more than rtol·|x| + atol; optimistix uses its Cauchy
            criterion with the same numbers; jaxopt stops when ‖Jᵀr‖₂ <= atol.
        max_steps: iteration cap (static); hitting it gives result max_steps_reached.
        linear_solver: "banded" (block-banded Cholesky), "dense" (optimistix's default,
            only for small T), or any lineax solver, for the optimistix methods.
        factor_dtype: dtype of JᵀJ and its factor (default: float64 when x64 is on,
            else the problem dtype).
        dtype: dtype of the solve (default: that of `params0`; float32 by default).
        damping: for method "lm": "levenberg", JᵀJ + λI (eq. 2.52), or "marquardt",
            JᵀJ + λ diag(JᵀJ) (eq. 2.54). Both use λ₀ = 10, ×10 / ×0.1.
    Returns:
        `Solution(value, result, num_steps, cost, costs)`.
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}.")
    if damping not in ("levenberg", "marquardt"):
        raise ValueError(f"damping must be 'levenberg' or 'marquardt', got {damping!r}.")
    layout, params0, frame_mask, dtype = _check(problem, params0, data, frame_mask, dtype)
    if factor_dtype is None:
        factor_dtype = jnp.float64 if jax.config.jax_enable_x64 else dtype
    if method == "lm":
        max_steps = jnp.asarray(max_steps)  # a loop bound only: no recompilation per value
    return _solve_jit(
        problem, layout, params0, data, frame_mask, jnp.asarray(rtol, dtype), jnp.asarray(atol, dtype),
        max_steps, method=method, linear_solver=linear_solver, factor_dtype=jnp.dtype(factor_dtype),
        damping=damping,
    )  # fmt: skip


def _solve_core(
    problem, layout, params0, data, frame_mask, rtol, atol, max_steps, *, method, linear_solver, factor_dtype,
    damping="levenberg",
):  # fmt: skip
    """The unbatched, unjitted solve (vmapped by `solve_batch`)."""
    T, n = jax.tree_util.tree_leaves(params0)[0].shape[0], layout.size
    dtype = params0[layout.keys[0]].dtype
    x0 = to_manifold(params0, problem.rotations)
    args = (problem, layout, x0, data, frame_mask)
    delta0 = jnp.zeros((T, n), dtype)
    if method != "lm" and jax.config.jax_enable_x64:
        # optimistix 0.1 keeps its damping λ in float64 when x64 is on and then fails to
        # match a float32 iterate; jaxopt promotes likewise. Iterate in float64 there.
        delta0 = delta0.astype(jnp.float64)
    if method == "lm":
        value, result, steps = _marquardt(
            args, delta0, rtol, atol, max_steps, factor_dtype, damping == "marquardt"
        )
    elif method in ("optx_lm", "optx_gn"):
        if linear_solver == "banded":
            bw = _bandwidths(problem, frame_mask is not None)
            linear_solver = BandedNormalCholesky(bandwidths=bw, factor_dtype=factor_dtype)
        cls = optx.LevenbergMarquardt if method == "optx_lm" else optx.GaussNewton
        kwargs = {} if isinstance(linear_solver, str) and linear_solver == "dense" else {"linear_solver": linear_solver}
        solver = cls(rtol=rtol, atol=atol, **kwargs)
        sol = optx.least_squares(
            _residual_fn, solver, delta0, args, options={"jac": "fwd"}, max_steps=max_steps, throw=False
        )
        value = from_manifold(retract(x0, layout.unravel(sol.value), problem.rotations), problem.rotations)
        result, steps = sol.result._value, sol.stats["num_steps"]
    else:
        value, result, steps = _jaxopt(args, delta0, atol, max_steps)
    value = {k: v.astype(dtype) for k, v in value.items()}
    costs = problem.costs(value, data, frame_mask)
    cost = sum(jax.tree_util.tree_leaves(costs))
    # A non-finite end point is a divergence whatever the backend said.
    result = jnp.where(jnp.isfinite(cost), result, optx.RESULTS.nonlinear_divergence._value)
    return Solution(value, jnp.asarray(result, jnp.int32), jnp.asarray(steps, jnp.int32), cost, costs)


_solve_jit = eqx.filter_jit(_solve_core)


def _jaxopt(args, delta0, tol, max_steps):
    import jaxopt

    problem, layout, x0, data, frame_mask = args
    T, n = delta0.shape

    def flat_residual(d, a):
        res = _residual_fn(d.reshape(T, n), a)
        return jnp.concatenate([r.reshape(-1) for r in jax.tree_util.tree_leaves(res)])

    lm = jaxopt.LevenbergMarquardt(
        residual_fun=flat_residual, maxiter=max_steps, tol=tol, solver="cholesky",
        materialize_jac=True, implicit_diff=False,
    )  # fmt: skip
    d, state = lm.run(delta0.reshape(-1), args)
    value = from_manifold(retract(x0, layout.unravel(d.reshape(T, n)), problem.rotations), problem.rotations)
    result = jnp.where(
        state.error <= tol, optx.RESULTS.successful._value, optx.RESULTS.nonlinear_max_steps_reached._value
    )
    return value, result, state.iter_num


class _LMState(eqx.Module):
    anchor: Any  # accepted parameters x (rotations as matrices)
    cost: Array
    H: list
    g: Array
    lam: Array
    step: Array
    done: Array
    result: Array


class _Structure(eqx.Module):
    """Static bookkeeping of a linearisation: terms in residual order, bandwidths, the
    columns each term reads, and the per-frame order "coupled unknowns first"."""

    names: tuple[str, ...] = eqx.field(static=True)
    bandwidths: tuple[int, ...] = eqx.field(static=True)
    columns: tuple[tuple[int, ...], ...] = eqx.field(static=True)
    perm: tuple[int, ...] | None = eqx.field(static=True)  # None: identity order
    coupled: int = eqx.field(static=True)

    @classmethod
    def of(cls, problem: Problem, layout, with_padding: bool) -> "_Structure":
        terms = {t.name: t for t in problem.terms}
        names = tuple(sorted(list(terms) + ([_PADDING] if with_padding else [])))
        bw = tuple(terms[k].bandwidth if k in terms else 0 for k in names)
        cols = tuple(layout.columns(terms[k].reads if k in terms else None) for k in names)
        coupled = sorted(set().union(*[c for c, b in zip(cols, bw) if b > 0]))
        n = layout.size
        if not coupled or len(coupled) == n:
            return cls(names, bw, cols, None, n)
        # Unknowns that no frame-coupling term reads are eliminated frame by frame.
        perm = tuple(coupled) + tuple(sorted(set(range(n)) - set(coupled)))
        return cls(names, bw, cols, perm, len(coupled))

    def to_solver_order(self, x: Array) -> Array:
        return x if self.perm is None else x[..., np.asarray(self.perm)]

    def from_solver_order(self, x: Array) -> Array:
        return x if self.perm is None else x[..., np.argsort(self.perm)]


def _term_blocks(term, x, clean, data, frame_mask, layout, T, dtype):
    """Residual (T, m) and blocks (T, 2b+1, m, n) of a term with an analytic Jacobian.

    The term supplies ∂e/∂δ of its raw output; weight, robust loss and masks (which act
    row by row) are applied by pushing each column through their linearisation.
    """
    e = term.raw(x, clean, data)
    jac = term.raw_jacobian(x, clean, data)
    C = 2 * term.bandwidth + 1
    parts = []
    for key, size in zip(layout.keys, layout.sizes):
        if key in jac:
            parts.append(jnp.asarray(jac[key], dtype).reshape((T, C) + e.shape[1:] + (size,)))
        else:
            parts.append(jnp.zeros((T, C) + e.shape[1:] + (size,), dtype))
    J = jnp.concatenate(parts, -1)  # (T, C, *e, n)
    e = e.astype(dtype)
    if term.loss is None:
        # finish is then linear, r = √w · keep · e: its Jacobian is r's of a unit e.
        r = term.finish(e, data, frame_mask, T)
        row_scale = term.finish(jnp.ones_like(e), data, frame_mask, T)  # (T, m)
        return r, row_scale[:, None, :, None] * J.reshape(T, C, -1, J.shape[-1])
    r, lin = jax.linearize(lambda e_: term.finish(e_, data, frame_mask, T), e)
    tangents = jnp.moveaxis(jnp.moveaxis(J, -1, 0), 2, 1)  # (n, C, T, *e)
    cols = jax.vmap(jax.vmap(lin))(tangents)  # (n, C, T, m)
    return r, jnp.transpose(cols, (2, 1, 3, 0))


def _linearise(args, st: _Structure, T, n, dtype, factor_dtype):
    """Residuals at δ = 0 and their Jacobian blocks, JᵀJ band and Jᵀr (eq. 2.58).

    Terms with an analytic `jacobian` supply their blocks directly; the others (and the
    padding pins) are differentiated by frame colouring over the columns they read.
    Blocks, JᵀJ and Jᵀr are in the solver's order (coupled unknowns first).
    """
    problem, layout, anchor, data, frame_mask = args
    terms = {t.name: t for t in problem.terms}
    clean = _sanitise(data)
    r, blocks = {}, {}
    for name in st.names:
        t = terms.get(name)
        if t is not None and t.jacobian is not None:
            r[name], blocks[name] = _term_blocks(t, anchor, clean, data, frame_mask, layout, T, dtype)
        elif name == _PADDING:
            free = ~frame_mask
            r[name] = jnp.zeros((T, n), dtype)
            blocks[name] = (free[:, None, None, None] * jnp.eye(n, dtype=dtype)).astype(dtype)
    auto = [k for k in st.names if k not in blocks]
    if auto:
        sub = Problem([terms[k] for k in auto], problem.rotations)
        sub_args = (sub, layout, anchor, data, frame_mask)
        res, lin = jax.linearize(lambda d: _residual_fn(d, sub_args, pad=False), jnp.zeros((T, n), dtype))
        idx = [st.names.index(k) for k in auto]
        auto_blocks = jacobian_blocks(
            lin, T, n, dtype, tuple(st.bandwidths[i] for i in idx), [st.columns[i] for i in idx]
        )
        for k, J in zip(auto, auto_blocks):
            r[k], blocks[k] = res[k], J
    leaves = [r[k] for k in st.names]
    J = [st.to_solver_order(blocks[k]) for k in st.names]
    H = normal_blocks(J, st.bandwidths, factor_dtype, coupled=None if st.perm is None else st.coupled)
    g = jt_vector(J, st.bandwidths, leaves, factor_dtype)
    cost = 0.5 * sum(jnp.sum(x.astype(factor_dtype) ** 2) for x in leaves)
    return cost, H, g


def _marquardt(args, delta0, rtol, atol, max_steps, factor_dtype, marquardt):
    """Von Marcard's LM (λ₀ = 10, ×10 / ×0.1, eq. 2.52 or 2.54) with re-anchoring (eq. 2.60)."""
    problem, layout, x0, data, frame_mask = args
    T, n = delta0.shape
    dtype = delta0.dtype
    lam_max = 1e10
    st = _Structure.of(problem, layout, frame_mask is not None)
    R = optx.RESULTS

    def with_anchor(x):
        return (problem, layout, x, data, frame_mask)

    cost0, H0, g0 = _linearise(args, st, T, n, dtype, factor_dtype)
    init = _LMState(
        x0, cost0, H0, g0, jnp.asarray(10.0, factor_dtype), jnp.asarray(0),
        ~jnp.isfinite(cost0), jnp.where(jnp.isfinite(cost0), R.successful._value, R.nonlinear_divergence._value),
    )  # fmt: skip

    def body(s: _LMState) -> _LMState:
        factor = factor_banded(s.H, s.lam, marquardt=marquardt)
        delta = -st.from_solver_order(solve_banded(factor, s.g)).astype(dtype)
        x_new = reproject(retract(s.anchor, layout.unravel(delta), problem.rotations), problem.rotations)
        res_new = jax.tree_util.tree_leaves(_residual_fn(jnp.zeros_like(delta), with_anchor(x_new)))
        cost_new = 0.5 * sum(jnp.sum(x.astype(factor_dtype) ** 2) for x in res_new)
        accept = jnp.isfinite(cost_new) & (cost_new < s.cost)
        # Small steps: Cauchy-type test on the accepted change of cost and of parameters.
        x_flat, d_flat = layout.ravel(from_manifold(s.anchor, problem.rotations)), delta
        small_step = jnp.all(jnp.abs(d_flat) <= rtol * jnp.abs(x_flat) + atol)
        small_cost = (s.cost - cost_new) <= rtol * s.cost + atol
        # Cauchy-type test (as optimistix): an accepted step that changes neither the cost
        # nor the parameters noticeably, or a rejected step already negligible.
        converged = (accept & small_cost & small_step) | (~accept & small_step)
        converged = converged | (s.lam > lam_max)  # no descent left at any damping

        def relinearise(_):
            return _linearise(with_anchor(x_new), st, T, n, dtype, factor_dtype)

        def keep(_):
            return s.cost, s.H, s.g

        cost, H, g = jax.lax.cond(accept, relinearise, keep, None)
        anchor = jax.tree_util.tree_map(lambda a, b: jnp.where(accept, a, b), x_new, s.anchor)
        lam = jnp.where(accept, s.lam * 0.1, s.lam * 10.0)
        step = s.step + 1
        done = converged | (step >= max_steps)
        result = jnp.where(converged, R.successful._value, R.nonlinear_max_steps_reached._value)
        return _LMState(anchor, cost, H, g, lam, step, done, jnp.where(done, result, s.result))

    final = jax.lax.while_loop(lambda s: ~s.done, body, init)
    return from_manifold(final.anchor, problem.rotations), final.result, final.step
