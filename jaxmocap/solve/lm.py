"""`VonMarcardLM`: von Marcard's Levenberg-Marquardt (§2.3.2, §3.3.4) as an optimistix solver.

δ = -(JᵀJ + λI)⁻¹ Jᵀr (eq. 2.52) or -(JᵀJ + λ diag(JᵀJ))⁻¹ Jᵀr (eq. 2.54) on the
structured normal equations. Jacobian blocks (a term's analytic `Term.jacobian`, else
forward-mode AD by colouring over what the term `reads`) and H are built once per accepted
iterate, at the top of the step that leaves it (so never for the last), and compiled once;
a rejected step only refactorises with the new λ.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.tree_util as jtu
import optimistix as optx
from jax import Array

from .._compat import DIVERGENCE, MAX_STEPS, SUCCESSFUL
from .._progress import report
from .assembly import half_squared_norm
from .linearisation import Args, linearise
from .tridiagonal import TRIDIAGONAL_METHODS, default_tridiagonal_method
from .unknowns import from_manifold, retract, to_manifold

__all__ = ["VonMarcardLM", "DAMPINGS", "check_tridiagonal"]

#: `VonMarcardLM(damping=...)`: the λ term of eq. 2.52 (λI) or eq. 2.54 (λ diag(JᵀJ)).
DAMPINGS = ("levenberg", "marquardt")


def check_tridiagonal(tridiagonal: str | None) -> str:
    """`tridiagonal` checked, None resolved to the backend's default (static under jit)."""
    if tridiagonal is None:
        return default_tridiagonal_method()
    if tridiagonal not in TRIDIAGONAL_METHODS:
        raise ValueError(f"tridiagonal must be one of {TRIDIAGONAL_METHODS} or None, got {tridiagonal!r}.")
    return tridiagonal


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

    λ₀ = 10, ×10 on a rejected step and ×0.1 on an accepted one; x ← x ⊕ δ on each
    unknown's manifold, re-anchored after every accepted step (eq. 2.56-2.60). Stops when
    an accepted step changes neither the cost (by more than rtol·cost + atol) nor any
    unknown (by more than rtol·|x| + atol), when a rejected step is already that small,
    or when λ exceeds 1e10 (no descent left at any damping); `max_steps` ends it otherwise.

    Args:
        rtol, atol: stopping tolerances (arrays allowed: `solve` passes them traced, so a
            new value does not recompile; (B,) arrays give `solve_batch` per-sequence ones).
        damping: "levenberg", JᵀJ + λI (eq. 2.52, the default), or "marquardt",
            JᵀJ + λ diag(JᵀJ) (eq. 2.54). On the SIP problem Marquardt's scaling let joints
            seen only by the 0.003-weight prior take multi-radian steps.
        factor_dtype: dtype of H and its factor (default: float64 when x64 is on, else the
            problem dtype).
        tridiagonal: how the frame band is factorised: "rows" (sequential, the fill kept
            in the coupling terms' rows, fewest flops where they have fewer rows per frame
            than coupled unknowns and there are no windows; "scan" otherwise), "scan"
            (sequential block Cholesky of the band) or "cyclic" (cyclic reduction, ⌈log₂ T⌉
            parallel levels); default (None): "rows" on the CPU, "cyclic" on accelerators.
            Speed only: all are exact.
        max_steps, progress: set by `solve` from its call options (the step cap is a
            traced loop bound there: no recompilation per value).

    Its `args` must be the `Args` of a jaxmocap `Problem`: pass it to
    `jaxmocap.solve.solve(..., solver=VonMarcardLM(...))`.
    """

    rtol: float | Array = 1e-6
    atol: float | Array = 1e-8
    norm: Callable = optx.max_norm
    damping: str = eqx.field(static=True, default="levenberg")
    factor_dtype: Any = eqx.field(static=True, default=None)
    tridiagonal: str | None = eqx.field(static=True, default=None)
    max_steps: int | Array = 100
    progress: bool = eqx.field(static=True, default=False)

    def __check_init__(self):
        if self.damping not in DAMPINGS:
            raise ValueError(f"damping must be one of {DAMPINGS}, got {self.damping!r}.")
        if self.tridiagonal is not None:
            check_tridiagonal(self.tridiagonal)

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
        dF, dW, dG = normal.factor(st, state.lam, self.damping == "marquardt", self.tridiagonal).solve(*grad)
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
