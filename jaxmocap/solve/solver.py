"""`solve`: minimise a `Problem` through `optx.least_squares`, returning plain arrays.

One path for every backend: `solve` builds the residual function y ↦ r(y) of the stored
parameters (axis-angle rotations, (ω, t) rigid poses, angles, vectors) and calls
`optx.least_squares(fn, solver, params0, args, adjoint=optx.ImplicitAdjoint(...))`,
so `throw=False` result codes, step limits, implicit differentiation and any optimistix
least-squares solver come from optimistix. `args` carries the problem (terms with their
weights), the data and the frame mask, so gradients flow to all of them.

Solvers (`method=`, or any optimistix least-squares solver as `solver=`):

- ``"lm"`` (default) — `VonMarcardLM`, von Marcard's Levenberg-Marquardt (§2.3.2,
  §3.3.4) as an optimistix solver: δ = -(JᵀJ + λI)⁻¹ Jᵀr (eq. 2.52, `damping="levenberg"`)
  or -(JᵀJ + λ diag(JᵀJ))⁻¹ Jᵀr (eq. 2.54, `"marquardt"`), λ₀ = 10, ×10 on a rejected
  step, ×0.1 on an accepted one, manifold unknowns updated x ← x ⊕ δ and re-anchored
  after every accepted step (eq. 2.56-2.60). Jacobian blocks (a term's analytic
  `Term.jacobian`, else forward-mode AD by colouring over what the term `reads`) and H
  are built once per accepted iterate, at the top of the step that leaves it (so never
  for the last), and compiled once; a rejected step only refactorises with the new λ.
  Levenberg damping is the default: on the SIP problem Marquardt's diag(JᵀJ) scaling
  let joints seen only by the 0.003-weight prior take multi-radian steps.
- ``"optx_lm"`` / ``"optx_gn"`` — `optx.LevenbergMarquardt` / `optx.GaussNewton` with the
  structured factorisation as their linear solver (`StructuredCholesky`); they iterate
  additively on the stored parameters and rebuild the Jacobian on every step.
- ``"jaxopt"`` — `jaxopt.LevenbergMarquardt` with a dense Jacobian, for small problems.

Differentiation: `jax.grad` of anything computed from `Solution.value` flows through the
solve by the implicit function theorem (`optx.ImplicitAdjoint`): the adjoint system is the
Hessian of the cost, assembled by coloured Hessian-vector products in the same
banded-plus-border structure and solved with the same factorisation — never a dense matrix.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.tree_util as jtu
import numpy as np
import optimistix as optx
from jax import Array

from .._checks import check_max_steps
from .._progress import report
from .._compat import DIVERGENCE, MAX_STEPS, SUCCESSFUL, result_code
from .._compat import result_message as optx_message
from .assembly import half_squared_norm
from .linearisation import Args, linearise, residuals
from .residuals import Problem, sanitise
from .structure import full_precision
from .structured import StructuredCholesky
from .tridiagonal import TRIDIAGONAL_METHODS, default_tridiagonal_method
from .unknowns import from_manifold, retract, to_manifold

__all__ = [
    "Solution", "VonMarcardLM", "solve", "result_message", "METHODS", "linear_solver",
    "NO_OBSERVATIONS", "PROGRESS_FRAMES", "measure_bandwidths", "check_bandwidths",
]  # fmt: skip

METHODS = ("lm", "optx_lm", "optx_gn", "jaxopt")

#: `Solution.result` when every masked (observation) term masked out all of its rows: the
#: "solution" is the priors' alone. Beyond optimistix's codes, so `converged` is False.
NO_OBSERVATIONS = 100
#: Single solves of this many frames or more report each LM step (`solve(progress=None)`).
PROGRESS_FRAMES = 2000


class Solution(eqx.Module):
    """Outcome of `solve`; every field is an array (batched by `solve_batch`).

    Attributes:
        value: the parameters at the solution, same structure as `params0`.
        result: `optx.RESULTS` index: 0 successful, else see `result_message`.
        num_steps: iterations taken (for "lm": trial steps, accepted or not).
        cost: final total cost ½‖r‖².
        costs: final per-term costs ½ w Σ ρ(‖e‖²), keyed by term name.
        decrease: how far from converged: the relative cost decrease of the last accepted
            step, (cost before - cost after) / cost before ("lm" only; NaN for other
            methods, inf before any accepted step). A fit stopped at its step cap with a
            decrease well above its rtol was still improving: give it more steps.
    """

    value: Any
    result: Array
    num_steps: Array
    cost: Array
    costs: dict[str, Array]
    decrease: Array

    @property
    def converged(self) -> Array:
        return self.result == 0

    def status(self) -> str:
        """One line on how an (unbatched) solve ended, e.g. for a log.

        "converged in 23 steps", or for a capped fit how fast it was still improving:
        "stopped at the step cap (50 steps), the cost still falling 0.31 % per step".
        """
        if np.ndim(self.result) != 0:
            raise ValueError("status() describes one solve: index a batched Solution first (e.g. sol.result[i]).")
        steps, code = int(self.num_steps), int(self.result)
        if code == 0:
            return f"converged in {steps} steps"
        if code == int(MAX_STEPS):
            d = float(self.decrease)
            rate = "" if not np.isfinite(d) else f", the cost still falling {100 * d:.2g} % per step"
            return f"stopped at the step cap ({steps} steps){rate}"
        return f"{result_message(code)} (after {steps} steps)"


def result_message(result) -> str:
    """Human-readable meaning of a `Solution.result` index."""
    if int(result) == NO_OBSERVATIONS:
        return "no observations: every observation term was masked out (dropped or missing data)"
    return optx_message(result) or "successful"


def _observed(args: Args, value) -> Array | None:
    """Whether any masked term keeps a row at `value` (None if no term has a mask).

    The same rows as the residuals keep (`Term.kept`): the mask broadcast against the
    term's output shape, so a per-sensor mask is not read as per-frame when S == T.
    """
    masked = [t for t in args.problem.terms if t.mask is not None]
    if not masked:
        return None
    x = to_manifold(value, args.layout)
    clean = sanitise(args.data)
    views = args.problem.views(x)
    seen = []
    for t in masked:
        shape = jax.eval_shape(lambda t=t: t.raw(views[t.name], clean, args.data)).shape
        seen.append(jnp.any(t.kept(shape, args.data, args.frame_mask, args.layout.T)))
    return jnp.any(jnp.stack(seen))


def linear_solver(
    args: Args, factor_dtype=None, hessian: bool = False, tridiagonal: str | None = None
) -> StructuredCholesky:
    """The structured lineax solver for `args`' problem (optimistix solvers, adjoints)."""
    bw, cols = args.leaf_structure()
    return StructuredCholesky(args.layout, bw, cols, hessian, factor_dtype, args.frame_mask, tridiagonal=tridiagonal)


#: `linearise` as a nested jit: init's shape query and step's call share one trace.
_linearise_once = eqx.filter_jit(linearise)


class _LMState(eqx.Module):
    normal: Any  # the linearisation at y when not `stale`
    grad: tuple
    cost: Array
    lam: Array
    step: Array
    done: Array
    result: Array
    stale: Array  # y moved since (or before) the last linearisation
    decrease: Array  # relative cost decrease of the last accepted step


def _report_step(step, max_steps, cost, accepted, done) -> None:
    """One stderr line per LM step of a long solve: step, cost, time per step, ETA."""
    report("LM step", step, max_steps, f"cost {float(cost):.6g} ({'accepted' if accepted else 'rejected'})", bool(done))


class VonMarcardLM(optx.AbstractLeastSquaresSolver):
    """Von Marcard's Levenberg-Marquardt on the structured normal equations (optimistix solver).

    λ₀ = 10, ×10 on a rejected step and ×0.1 on an accepted one (eq. 2.52, or eq. 2.54
    with `marquardt=True`); x ← x ⊕ δ on each unknown's manifold, re-anchored after every
    accepted step (eq. 2.56-2.60). Stops when an accepted step changes neither the cost
    (by more than rtol·cost + atol) nor any unknown (by more than rtol·|x| + atol), when a
    rejected step is already that small, or when λ exceeds 1e10 (no descent left at any
    damping); `max_steps` (an array: no recompilation per value) ends it otherwise.

    Its `args` must be the `Args` of a jaxmocap `Problem` (use `jaxmocap.solve.solve`).
    """

    rtol: float | Array = 1e-6
    atol: float | Array = 1e-8
    norm: Callable = optx.max_norm
    max_steps: int | Array = 100
    marquardt: bool = eqx.field(static=True, default=False)
    factor_dtype: Any = eqx.field(static=True, default=None)
    progress: bool = eqx.field(static=True, default=False)
    tridiagonal: str | None = eqx.field(static=True, default=None)

    def _setup(self, y, args):
        if not isinstance(args, Args):
            raise ValueError(
                "VonMarcardLM solves jaxmocap Problems: call jaxmocap.solve.solve(problem, "
                f"params0, data), or pass a jaxmocap.solve.Args as args (got {type(args).__name__})."
            )
        dtype = jtu.tree_leaves(y)[0].dtype
        return args.structure(), dtype, self.factor_dtype or dtype

    def init(self, fn, y, args, options, f_struct, aux_struct, tags):
        # The linearisation happens at the top of `step`, so that it is traced (and
        # compiled) once, not also here: init holds zeros of its shape, marked stale.
        st, dtype, fdtype = self._setup(y, args)
        res, _ = fn(y, args)
        cost = half_squared_norm(res, fdtype)
        shapes = eqx.filter_eval_shape(_linearise_once, y, args, st, dtype, fdtype, self.tridiagonal)[:2]
        normal, grad = jtu.tree_map(lambda s: jnp.zeros(s.shape, s.dtype), shapes)
        ok = jnp.isfinite(cost)
        return _LMState(
            normal, grad, cost, jnp.asarray(10.0, fdtype), jnp.asarray(0), ~ok,
            jnp.where(ok, SUCCESSFUL, DIVERGENCE), jnp.asarray(True), jnp.asarray(jnp.inf, fdtype),
        )  # fmt: skip

    def step(self, fn, y, args, options, state: _LMState, tags):
        st, dtype, fdtype = self._setup(y, args)
        layout = args.layout
        # Linearise at y after an accepted step (and at the start); not after the last.
        normal, grad = jax.lax.cond(
            state.stale,
            lambda: _linearise_once(y, args, st, dtype, fdtype, self.tridiagonal)[:2],
            lambda: (state.normal, state.grad),
        )  # fmt: skip
        # A `Normal` or, for a basis term, a `BasisNormal`: each factorises its own structure.
        dF, dW, dG = normal.factor(st, state.lam, self.marquardt, self.tridiagonal).solve(*grad)
        cast = lambda d: None if d is None else (-d).astype(dtype)  # noqa: E731
        delta = layout.unravel(cast(st.from_solver_order(dF)), cast(dW), cast(dG))
        y_new = from_manifold(retract(to_manifold(y, layout), delta, layout), layout)
        res_new, _ = fn(y_new, args)
        cost_new = half_squared_norm(res_new, fdtype)
        accept = jnp.isfinite(cost_new) & (cost_new < state.cost)
        # Cauchy-type test (as optimistix): an accepted step that changes neither the cost
        # nor the parameters noticeably, or a rejected step already negligible.
        small_step = jnp.all(
            jnp.asarray([jnp.all(jnp.abs(d) <= self.rtol * jnp.abs(v) + self.atol) for d, v in
                         zip(jtu.tree_leaves(delta), jtu.tree_leaves({k: y[k] for k in delta}))])
        )  # fmt: skip
        small_cost = (state.cost - cost_new) <= self.rtol * state.cost + self.atol
        converged = (accept & small_cost & small_step) | (~accept & small_step) | (state.lam > 1e10)

        cost = jnp.where(accept, cost_new, state.cost)
        y_next = jtu.tree_map(lambda a, b: jnp.where(accept, a, b), y_new, y)
        step = state.step + 1
        done = converged | (step >= self.max_steps)
        result = jnp.where(converged, SUCCESSFUL, MAX_STEPS)
        lam = jnp.where(accept, state.lam * 0.1, state.lam * 10.0)
        if self.progress:
            jax.debug.callback(_report_step, step, self.max_steps, cost, accept, done)
        decrease = jnp.where(
            accept, (state.cost - cost_new) / jnp.maximum(state.cost, jnp.finfo(fdtype).tiny), state.decrease
        )
        new = _LMState(normal, grad, cost, lam, step, done, jnp.where(done, result, state.result), accept, decrease)
        return y_next, new, None

    def terminate(self, fn, y, args, options, state: _LMState, tags):
        return state.done, optx.RESULTS.where(
            state.result == SUCCESSFUL,
            optx.RESULTS.successful,
            optx.RESULTS.where(
                state.result == DIVERGENCE,
                optx.RESULTS.nonlinear_divergence,
                optx.RESULTS.nonlinear_max_steps_reached,
            ),
        )

    def postprocess(self, fn, y, aux, args, options, state, tags, result):
        return y, aux, {}


# --- the front door ------------------------------------------------------------------------


def check_tridiagonal(tridiagonal: str | None) -> str:
    """`tridiagonal` checked, None resolved to the backend's default (static under jit)."""
    if tridiagonal is None:
        return default_tridiagonal_method()
    if tridiagonal not in TRIDIAGONAL_METHODS:
        raise ValueError(f"tridiagonal must be one of {TRIDIAGONAL_METHODS} or None, got {tridiagonal!r}.")
    return tridiagonal


def check_inputs(problem, params0, data, frame_mask, dtype):
    """`solve`'s inputs checked (a clear ValueError for each mistake) and resolved:
    (layout, params0 cast to the working dtype, frame_mask as bool or None, dtype)."""
    if not isinstance(problem, Problem):
        raise ValueError(f"problem must be a jaxmocap.solve.Problem, got {type(problem).__name__}.")
    layout = problem.layout(params0)
    for t in problem.terms:
        # Layout.columns skips keys that are not unknowns, so a misspelt key would leave
        # the term undifferentiated and the solve "successful" with nothing moved.
        unknown = sorted((t.read_keys() or set()) - set(layout.keys))
        if unknown:
            raise ValueError(
                f"Term {t.name!r} reads {unknown}, which {'is' if len(unknown) == 1 else 'are'} not "
                f"among the unknowns {sorted(layout.keys)}: fix the reads (a typo?) or add the key to params0."
            )
    leaves = [jnp.asarray(params0[k]) for k in layout.keys]
    if dtype is None:
        dtype = jnp.result_type(*[x.dtype for x in leaves if jnp.issubdtype(x.dtype, jnp.floating)] or [jnp.float32])
    dtype = jnp.dtype(dtype)
    if dtype == jnp.float64 and not jax.config.jax_enable_x64:
        raise ValueError(
            "float64 requested but JAX runs in 32-bit mode; call jax.config.update('jax_enable_x64', True) first."
        )
    if layout.T == 0:
        raise ValueError("params0: the sequence has no frames (T = 0); give at least one frame.")
    params0 = {k: jnp.asarray(params0[k], dtype) for k in layout.keys}
    if frame_mask is not None:
        frame_mask = jnp.asarray(frame_mask, bool)
        if frame_mask.shape != (layout.T,):
            raise ValueError(f"frame_mask has shape {frame_mask.shape}; expected (T,) = ({layout.T},).")
    return layout, params0, frame_mask, dtype


def solve(
    problem: Problem,
    params0: dict,
    data: Any = None,
    *,
    frame_mask: Array | None = None,
    method: str = "lm",
    solver: optx.AbstractLeastSquaresSolver | None = None,
    rtol: float | Array = 1e-6,
    atol: float | Array = 1e-8,
    max_steps: int = 100,
    factor_dtype: Any = None,
    dtype: Any = None,
    damping: str = "levenberg",
    adjoint: optx.AbstractAdjoint | None = None,
    check_bandwidth: bool = False,
    progress: bool | None = None,
    tridiagonal: str | None = None,
) -> Solution:
    """Minimise `problem` from `params0` given `data`; returns a `Solution` of arrays.

    Args:
        problem: the terms to balance and the kinds of the unknowns.
        params0: dict of initial parameters (per-frame (T, ...), per-sequence (...),
            per-window (W, ...), as the problem declares).
        data: any pytree the term functions read (observations, constants).
        frame_mask: (T,) bool, False for padded frames (they keep their initial value).
        method: one of `METHODS` (see the module docstring); ignored if `solver` is given.
        solver: any optimistix least-squares solver (e.g. `optx.Dogleg(...,
            linear_solver=jaxmocap.solve.linear_solver(...))`).
        rtol, atol: stopping tolerances (arrays allowed, e.g. per sequence under vmap).
        max_steps: iteration cap; for "lm" a traced bound (no recompilation per value).
        factor_dtype: dtype of H and its factor (default: float64 when x64 is on, else
            the problem dtype).
        dtype: dtype of the solve (default: that of `params0`; float32 by default).
        damping: for "lm": "levenberg", JᵀJ + λI (eq. 2.52), or "marquardt" (eq. 2.54).
        adjoint: how gradients flow through the solve (default: implicit
            differentiation with the structured Hessian factorisation).
        check_bandwidth: first measure each term's true frame coupling at params0
            (`check_bandwidths`; one Jacobian-vector product per term, best on a short
            sequence) and raise if a term reads further than its declared `bandwidth`,
            which would otherwise give a wrong answer reported as successful.
        progress: print each LM step (cost, time per step, ETA) on stderr ("lm" only).
            Default: on for sequences of `PROGRESS_FRAMES` frames or more, whose solves
            take seconds to minutes; off inside `solve_batch`.
        tridiagonal: how the frame band is factorised: "rows" (sequential, the fill kept
            in the coupling terms' rows, fewest flops where they have fewer rows per frame
            than coupled unknowns and there are no windows; "scan" otherwise), "scan"
            (sequential block Cholesky of the band) or
            "cyclic" (cyclic reduction, ⌈log₂ T⌉ parallel levels); default: "rows" on
            the CPU, "cyclic" on accelerators. Speed only: all are exact.
    Returns:
        `Solution(value, result, num_steps, cost, costs, decrease)`; `result` is `NO_OBSERVATIONS`
        when every masked term masked out all of its rows.
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}.")
    if damping not in ("levenberg", "marquardt"):
        raise ValueError(f"damping must be 'levenberg' or 'marquardt', got {damping!r}.")
    layout, params0, frame_mask, dtype = check_inputs(problem, params0, data, frame_mask, dtype)
    check_max_steps(max_steps)
    if check_bandwidth:
        check_bandwidths(problem, params0, data, frame_mask)
    if factor_dtype is None:
        factor_dtype = jnp.float64 if jax.config.jax_enable_x64 else dtype
    args = Args(problem, data, frame_mask, layout)
    if progress is None:
        progress = layout.T >= PROGRESS_FRAMES
    # "lm" takes max_steps as a traced loop bound: no recompilation per value.
    max_steps = jnp.asarray(max_steps) if method == "lm" and solver is None else int(max_steps)
    return _solve_jit(
        args, params0, jnp.asarray(rtol, dtype), jnp.asarray(atol, dtype), max_steps,
        method=method, solver=solver, factor_dtype=jnp.dtype(factor_dtype), damping=damping, adjoint=adjoint,
        progress=bool(progress) and method == "lm" and solver is None,
        tridiagonal=check_tridiagonal(tridiagonal),
    )  # fmt: skip


def measure_bandwidths(
    problem: Problem, params0: dict, data: Any = None, frame_mask=None, frame=None
) -> dict[str, int]:
    """The frame coupling each term really has at `params0`: {term name: b}.

    Perturbs every per-frame unknown at one frame t₀ (default T // 2) in random
    directions (one Jacobian-vector product) and returns, per term, the largest |t - t₀|
    over the residual rows t that change. Rows masked out at params0 do not count, nor
    do rows whose derivative happens to vanish there (x² at x = 0): measure at a generic
    point where the data are present; a short sequence (T ≥ 2b + 1) is enough.
    """
    layout = problem.layout(params0)
    T = layout.T
    t0 = T // 2 if frame is None else int(frame)
    if not 0 <= t0 < T:
        raise ValueError(f"frame={frame} is outside the {T} frames.")
    spec = problem.spec
    keys = [k for k in params0 if k not in spec or spec[k].kind == "frame"]
    rng = np.random.default_rng(0)
    primals = {k: jnp.asarray(v) for k, v in params0.items()}
    tangents = {}
    for k, v in primals.items():
        t = np.zeros(v.shape, np.float64)
        if k in keys:
            t[t0] = rng.normal(size=v.shape[1:])
        tangents[k] = jnp.asarray(t, v.dtype)
    _, dr = jax.jvp(lambda p: problem.residuals(p, data, frame_mask), (primals,), (tangents,))
    out = {}
    for name, d in dr.items():
        rows = np.flatnonzero(np.any(np.abs(np.asarray(d)) > 0, axis=1))
        out[name] = int(np.max(np.abs(rows - t0))) if rows.size else 0
    return out


def check_bandwidths(problem: Problem, params0: dict, data: Any = None, frame_mask=None, frame=None) -> dict[str, int]:
    """`measure_bandwidths`, raising a ValueError naming every term that reads further
    than its declared `bandwidth` (the solver would drop that coupling); returns the
    measured bandwidths otherwise."""
    measured = measure_bandwidths(problem, params0, data, frame_mask, frame)
    declared = problem.bandwidths
    wrong = {k: (declared[k], b) for k, b in measured.items() if b > declared[k]}
    if wrong:
        text = ", ".join(
            f"Term {k!r} declares bandwidth={d} but reads {b} frame(s) away" for k, (d, b) in wrong.items()
        )
        raise ValueError(f"{text}: set bandwidth to at least the measured value.")
    return measured


@full_precision
def solve_unjitted(
    args: Args,
    params0,
    rtol,
    atol,
    max_steps,
    *,
    method,
    solver,
    factor_dtype,
    damping,
    adjoint,
    progress=False,
    tridiagonal="scan",
):
    """The unbatched, unjitted solve (vmapped by `solve_batch`)."""
    dtype = jtu.tree_leaves(params0)[0].dtype
    decrease = jnp.asarray(jnp.nan, dtype)
    if method == "jaxopt" and solver is None:
        value, result, steps = _jaxopt(args, params0, atol, max_steps)
    else:
        y0 = params0
        if solver is None:
            if method == "lm":
                solver = VonMarcardLM(
                    rtol, atol, max_steps=max_steps, marquardt=damping == "marquardt", factor_dtype=factor_dtype,
                    progress=progress, tridiagonal=tridiagonal,
                )  # fmt: skip
            else:
                if jax.config.jax_enable_x64:
                    # optimistix 0.1 keeps its damping λ in float64 when x64 is on and then
                    # fails to match a float32 iterate: iterate in float64 there.
                    y0 = jtu.tree_map(lambda v: v.astype(jnp.float64), y0)
                cls = optx.LevenbergMarquardt if method == "optx_lm" else optx.GaussNewton
                solver = cls(
                    rtol=rtol, atol=atol, linear_solver=linear_solver(args, factor_dtype, tridiagonal=tridiagonal)
                )
        if adjoint is None:
            adjoint = optx.ImplicitAdjoint(linear_solver=linear_solver(args, factor_dtype, True, tridiagonal))
        steps_cap = None if isinstance(solver, VonMarcardLM) else int(max_steps)
        sol = optx.least_squares(residuals, solver, y0, args, max_steps=steps_cap, adjoint=adjoint, throw=False)
        value, result, steps = sol.value, result_code(sol.result), sol.stats["num_steps"]
        if isinstance(sol.state, _LMState):
            decrease = sol.state.decrease.astype(dtype)
    value = {k: v.astype(dtype) for k, v in value.items()}
    res = residuals(value, args)
    costs = {k: 0.5 * jnp.sum(r * r) for k, r in res.items()}
    cost = sum(jtu.tree_leaves(costs))
    # A non-finite end point is a divergence whatever the backend said.
    result = jnp.where(jnp.isfinite(cost), result, DIVERGENCE)
    observed = _observed(args, value)
    if observed is not None:
        result = jnp.where(observed, result, NO_OBSERVATIONS)
    return Solution(value, jnp.asarray(result, jnp.int32), jnp.asarray(steps, jnp.int32), cost, costs, decrease)


_solve_jit = eqx.filter_jit(solve_unjitted)


def _jaxopt(args: Args, params0, tol, max_steps):
    import jaxopt

    layout = args.layout

    def flat(y):
        F, W, G = layout.ravel(y)
        return jnp.concatenate([p.reshape(-1) for p in (F, W, G) if p is not None])

    F0, W0, G0 = layout.ravel(params0)

    def unflat(v):
        parts, start = [], 0
        for p in (F0, W0, G0):
            if p is None:
                parts.append(None)
                continue
            parts.append(v[start : start + p.size].reshape(p.shape))
            start += p.size
        return layout.unravel(*parts)

    def flat_residual(v, a):
        return jnp.concatenate([r.reshape(-1) for r in jtu.tree_leaves(residuals(unflat(v), a))])

    lm = jaxopt.LevenbergMarquardt(
        residual_fun=flat_residual, maxiter=max_steps, tol=tol, solver="cholesky",
        materialize_jac=True, implicit_diff=False,
    )  # fmt: skip
    v, state = lm.run(flat(params0), args)
    result = jnp.where(state.error <= tol, SUCCESSFUL, MAX_STEPS)
    return unflat(v), result, state.iter_num
