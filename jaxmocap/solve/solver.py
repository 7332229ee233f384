"""`solve`: minimise a `Problem` through `optx.least_squares`, returning plain arrays.

One path for every backend: `solve` builds the residual function y ↦ r(y) of the stored
parameters (axis-angle rotations, (ω, t) rigid poses, angles, vectors) and calls
`optx.least_squares(fn, solver, params0, args, adjoint=optx.ImplicitAdjoint(...))`,
so `throw=False` result codes, step limits, implicit differentiation and any optimistix
least-squares solver come from optimistix. `args` carries the problem (terms with their
weights), the data and the frame mask, so gradients flow to all of them.

Solvers (`solver=`, an object carrying its own options; see `options` for the design):

- `VonMarcardLM(rtol, atol, damping, factor_dtype, tridiagonal)` (default) — von
  Marcard's Levenberg-Marquardt (§2.3.2, §3.3.4) as an optimistix solver (`lm.py`):
  Levenberg damping λI by default, manifold unknowns updated x ← x ⊕ δ and re-anchored
  after every accepted step (eq. 2.56-2.60), H built once per accepted iterate.
- `OptxLevenbergMarquardt` / `OptxGaussNewton` — optimistix's solvers with the structured
  factorisation as their linear solver (`StructuredCholesky`); they iterate additively on
  the stored parameters and rebuild the Jacobian on every step.
- `JaxoptLevenbergMarquardt` — jaxopt's LM with a dense Jacobian, for small problems.
- any optimistix least-squares solver, as it is.

What belongs to one call stays a keyword of `solve`: the frame mask, the step cap
`max_steps` (as in `optx.least_squares`), the working dtype, the adjoint, the bandwidth
check and progress.

Differentiation: `jax.grad` of anything computed from `Solution.value` flows through the
solve by the implicit function theorem (`optx.ImplicitAdjoint`): the adjoint system is the
Hessian of the cost, assembled by coloured Hessian-vector products in the same
banded-plus-border structure and solved with the same factorisation — never a dense matrix.
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.tree_util as jtu
import numpy as np
import optimistix as optx
from jax import Array

from .._compat import DIVERGENCE, MAX_STEPS, SUCCESSFUL, result_code
from .._compat import result_message as optx_message
from .linearisation import Args, residuals
from .lm import VonMarcardLM
from .options import SOLVERS, JaxoptLevenbergMarquardt, OptxLevenbergMarquardt, resolve, structured_solver
from .residuals import Problem, sanitise
from .structure import full_precision
from .structured import StructuredCholesky
from .unknowns import to_manifold

__all__ = [
    "Solution", "VonMarcardLM", "solve", "result_message", "METHODS", "linear_solver", "check_inputs", "prepare",
    "NO_OBSERVATIONS", "PROGRESS_FRAMES", "measure_bandwidths", "check_bandwidths",
]  # fmt: skip

#: The old `method=` names (`options.SOLVERS`), kept for one release.
METHODS = tuple(SOLVERS)

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
        num_steps: iterations taken (for `VonMarcardLM`: trial steps, accepted or not).
        cost: final total cost ½‖r‖².
        costs: final per-term costs ½ w Σ ρ(‖e‖²), keyed by term name.
        decrease: how far from converged: the relative cost decrease of the last accepted
            step, (cost before - cost after) / cost before (`VonMarcardLM` only; NaN for
            other solvers, inf before any accepted step). A fit stopped at its step cap with a
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
        raw = lambda t=t: t.raw(views[t.name], clean, args.data, args.problem.posed_of(x, clean, [t]))  # noqa: E731
        shape = jax.eval_shape(raw).shape
        seen.append(jnp.any(t.kept(shape, args.data, args.frame_mask, args.layout.T)))
    return jnp.any(jnp.stack(seen))


def linear_solver(
    args: Args, factor_dtype=None, hessian: bool = False, tridiagonal: str | None = None
) -> StructuredCholesky:
    """The structured lineax solver for `args`' problem (optimistix solvers, adjoints)."""
    bw, cols = args.leaf_structure()
    return StructuredCholesky(args.layout, bw, cols, hessian, factor_dtype, args.frame_mask, tridiagonal=tridiagonal)


# --- the front door ------------------------------------------------------------------------


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


def prepare(problem, params0, data, frame_mask, dtype, solver, deprecated: dict, max_steps, check_bandwidth, where):
    """Everything `solve` and `solve_batch` check, in one place (`solve_batch` passes its
    first member): the inputs (`check_inputs`), the solver and its options (`options.resolve`,
    the deprecated loose keywords included), the step cap, and the measured bandwidths if
    asked. Returns (layout, params0, frame_mask, dtype, `options.Resolved`)."""
    layout, params0, frame_mask, dtype = check_inputs(problem, params0, data, frame_mask, dtype)
    how = resolve(solver, deprecated, dtype, max_steps, where)
    if check_bandwidth:
        check_bandwidths(problem, params0, data, frame_mask)
    return layout, params0, frame_mask, dtype, how


def solve(
    problem: Problem,
    params0: dict,
    data: Any = None,
    *,
    solver: Any = None,
    frame_mask: Array | None = None,
    max_steps: int = 100,
    dtype: Any = None,
    adjoint: optx.AbstractAdjoint | None = None,
    check_bandwidth: bool = False,
    progress: bool | None = None,
    **deprecated,
) -> Solution:
    """Minimise `problem` from `params0` given `data`; returns a `Solution` of arrays.

    Args:
        problem: the terms to balance and the kinds of the unknowns.
        params0: dict of initial parameters (per-frame (T, ...), per-sequence (...),
            per-window (W, ...), as the problem declares).
        data: any pytree the term functions read (observations, constants).
        solver: how to iterate, with its options: `VonMarcardLM(rtol=1e-6, atol=1e-8,
            damping="levenberg", factor_dtype=None, tridiagonal=None)` by default; another
            solver of `jaxmocap.solve.options` or any optimistix least-squares solver
            (e.g. `optx.Dogleg(..., linear_solver=...)`, see the module docstring).
        frame_mask: (T,) bool, False for padded frames (they keep their initial value).
        max_steps: iteration cap; for `VonMarcardLM` a traced bound (no recompilation per value).
        dtype: dtype of the solve (default: that of `params0`; float32 by default).
        adjoint: how gradients flow through the solve (default: implicit
            differentiation with the structured Hessian factorisation).
        check_bandwidth: first measure each term's true frame coupling at params0
            (`check_bandwidths`; one Jacobian-vector product per term, best on a short
            sequence) and raise if a term reads further than its declared `bandwidth`,
            which would otherwise give a wrong answer reported as successful.
        progress: print each LM step (cost, time per step, ETA) on stderr (`VonMarcardLM`
            only). Default: on for sequences of `PROGRESS_FRAMES` frames or more, whose
            solves take seconds to minutes; off inside `solve_batch`.
        **deprecated: the loose solver options of the last release (`method`, `rtol`,
            `atol`, `damping`, `factor_dtype`, `tridiagonal`), mapped onto the solver with a
            DeprecationWarning; with `solver=` as well they are an error.
    Returns:
        `Solution(value, result, num_steps, cost, costs, decrease)`; `result` is `NO_OBSERVATIONS`
        when every masked term masked out all of its rows.
    """
    layout, params0, frame_mask, dtype, how = prepare(
        problem, params0, data, frame_mask, dtype, solver, deprecated, max_steps, check_bandwidth, "solve"
    )
    args = Args(problem, data, frame_mask, layout)
    if progress is None:
        progress = layout.T >= PROGRESS_FRAMES
    return _solve_jit(
        args, params0, how.rtol, how.atol, how.max_steps, solver=how.solver, factor_dtype=how.factor_dtype,
        tridiagonal=how.tridiagonal, adjoint=adjoint, progress=bool(progress) and isinstance(how.solver, VonMarcardLM),
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
def solve_unjitted(args: Args, params0, rtol, atol, max_steps, *, solver, factor_dtype, tridiagonal, adjoint,
                   progress=False):  # fmt: skip
    """The unbatched, unjitted solve (vmapped by `solve_batch`); `solver` as `options.resolve` leaves it."""
    dtype = jtu.tree_leaves(params0)[0].dtype
    decrease = jnp.asarray(jnp.nan, dtype)
    if isinstance(solver, JaxoptLevenbergMarquardt):
        value, result, steps = _jaxopt(args, params0, atol, max_steps)
    else:
        y0 = params0
        if jax.config.jax_enable_x64 and isinstance(solver, OptxLevenbergMarquardt):  # or its OptxGaussNewton
            # optimistix 0.1 keeps its damping λ in float64 when x64 is on and then fails
            # to match a float32 iterate: iterate in float64 there.
            y0 = jtu.tree_map(lambda v: v.astype(jnp.float64), y0)
        solver = structured_solver(
            solver, rtol, atol, max_steps, factor_dtype, tridiagonal, progress,
            lambda: linear_solver(args, factor_dtype, tridiagonal=tridiagonal),
        )  # fmt: skip
        if adjoint is None:
            adjoint = optx.ImplicitAdjoint(linear_solver=linear_solver(args, factor_dtype, True, tridiagonal))
        steps_cap = None if isinstance(solver, VonMarcardLM) else int(max_steps)
        sol = optx.least_squares(residuals, solver, y0, args, max_steps=steps_cap, adjoint=adjoint, throw=False)
        value, result, steps = sol.value, result_code(sol.result), sol.stats["num_steps"]
        if isinstance(solver, VonMarcardLM):
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
