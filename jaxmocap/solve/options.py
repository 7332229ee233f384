"""Which solver, with which options: the solver objects and the one check `solve` and `solve_batch` share.

A solve's options are of two kinds, as in optimistix. How to iterate (tolerances, damping,
the dtype and method of the factorisation) belongs to the solver and lives on a solver
object, made once and passed as `solver=`; what belongs to one call (the data, the frame
mask, the step cap, the working dtype, progress) is a keyword of `solve`. A solver object
is an immutable `eqx.Module`, so equal objects compile to one program; its tolerances
reach the compiled program as arrays (`resolve` takes them off the object), so changing
them does not recompile, and a (B,) array gives `solve_batch` one tolerance per sequence.

- `VonMarcardLM` (the default): von Marcard's LM on the structured normal equations.
- `OptxLevenbergMarquardt` / `OptxGaussNewton`: optimistix's solvers with the structured
  factorisation as their linear solver (built per problem, hence not optimistix objects
  themselves); they iterate additively on the stored parameters and rebuild the Jacobian
  on every step.
- `JaxoptLevenbergMarquardt`: jaxopt's LM on a dense Jacobian, for small problems.
- any optimistix least-squares solver or minimiser, used as it is.

`SOLVERS` maps the old `method=` names onto these classes. The loose keywords `solve`
took before (`method`, `rtol`, `atol`, `damping`, `factor_dtype`, `tridiagonal`) still
work for one release: `resolve` maps them onto a solver object with a DeprecationWarning
naming it.
"""

from __future__ import annotations

import dataclasses
import warnings
from typing import Any, ClassVar, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx
from jax import Array

from .._checks import check_max_steps
from .lm import VonMarcardLM, check_tridiagonal

__all__ = [
    "VonMarcardLM", "OptxLevenbergMarquardt", "OptxGaussNewton", "JaxoptLevenbergMarquardt", "SOLVERS",
    "DEPRECATED_KEYWORDS", "Resolved", "resolve", "structured_solver",
]  # fmt: skip


class OptxLevenbergMarquardt(eqx.Module):
    """`optx.LevenbergMarquardt` with the structured factorisation as its linear solver.

    Args: rtol, atol (optimistix's stopping tolerances), factor_dtype and tridiagonal
    (as `VonMarcardLM`'s).
    """

    rtol: float | Array = 1e-6
    atol: float | Array = 1e-8
    factor_dtype: Any = eqx.field(static=True, default=None)
    tridiagonal: str | None = eqx.field(static=True, default=None)
    optimistix: ClassVar[type] = optx.LevenbergMarquardt

    def __check_init__(self):
        if self.tridiagonal is not None:
            check_tridiagonal(self.tridiagonal)


class OptxGaussNewton(OptxLevenbergMarquardt):
    """`optx.GaussNewton` with the structured factorisation as its linear solver (no damping)."""

    optimistix: ClassVar[type] = optx.GaussNewton


class JaxoptLevenbergMarquardt(eqx.Module):
    """`jaxopt.LevenbergMarquardt` on a dense Jacobian (small problems only).

    jaxopt stops when ‖Jᵀr‖ ≤ atol; rtol is not used. No implicit differentiation.
    """

    rtol: float | Array = 1e-6
    atol: float | Array = 1e-8


#: The old `method=` names and the solver class each stands for.
SOLVERS = {
    "lm": VonMarcardLM,
    "optx_lm": OptxLevenbergMarquardt,
    "optx_gn": OptxGaussNewton,
    "jaxopt": JaxoptLevenbergMarquardt,
}
_OURS = tuple(SOLVERS.values())
#: `solve`'s loose keywords of the last release, now options of the solver object.
DEPRECATED_KEYWORDS = ("method", "rtol", "atol", "damping", "factor_dtype", "tridiagonal")


class Resolved(NamedTuple):
    """A solver split for the compiled program: `solver` is static (equal objects share a
    program), `rtol` and `atol` are traced arrays, `max_steps` an array for `VonMarcardLM`."""

    solver: Any
    rtol: Array
    atol: Array
    factor_dtype: Any
    tridiagonal: str
    max_steps: Any


def _from_keywords(solver, keywords: dict, where: str):
    """The solver object the deprecated loose `keywords` stand for (with their warning)."""
    unknown = sorted(set(keywords) - set(DEPRECATED_KEYWORDS))
    if unknown:
        raise TypeError(f"{where}() got unexpected keyword argument(s) {unknown}.")
    given = [k for k in DEPRECATED_KEYWORDS if k in keywords]
    if solver is not None:
        hint = "e.g. solver=VonMarcardLM(rtol=..., atol=...)"
        if not isinstance(solver, _OURS):  # the loose factor options reached only its adjoint
            hint = "for an optimistix solver, give adjoint=optx.ImplicitAdjoint(linear_solver=...) for the adjoint"
        raise ValueError(
            f"{where}() got solver= and also {', '.join(k + '=' for k in given)}, which are options of the "
            f"solver: set them on it instead ({hint}), not both."
        )
    options = dict(keywords)
    method = options.pop("method", "lm")
    if method not in SOLVERS:
        raise ValueError(f"method must be one of {tuple(SOLVERS)}, got {method!r}.")
    cls = SOLVERS[method]
    if "damping" in options and cls is not VonMarcardLM:
        raise ValueError(f"damping is an option of method 'lm' (VonMarcardLM), not of {method!r}.")
    if cls is JaxoptLevenbergMarquardt:  # jaxopt never read these
        options = {k: v for k, v in options.items() if k in ("rtol", "atol")}
    new = cls(**options)
    warnings.warn(
        f"{where}({', '.join(k + '=' for k in given)}) is deprecated and goes in the next release: pass "
        f"solver={cls.__name__}({', '.join(k + '=...' for k in options)}) instead "
        f"(from jaxmocap.solve{'' if cls is VonMarcardLM else '.options'} import {cls.__name__}).",
        DeprecationWarning,
        stacklevel=5,  # the caller of solve / solve_batch (through prepare and resolve)
    )
    return new


def resolve(solver, keywords: dict, dtype, max_steps, where: str) -> Resolved:
    """`solver` (default `VonMarcardLM()`) checked, the deprecated `keywords` mapped onto it,
    and split for the compiled program; `max_steps` checked. Shared by `solve` and `solve_batch`.

    Tolerances are cast to `dtype`; a foreign optimistix solver keeps its own (its
    structured adjoint uses the default factor dtype and band method).
    """
    if keywords:
        solver = _from_keywords(solver, keywords, where)
    elif solver is None:
        solver = VonMarcardLM()
    check_max_steps(max_steps)
    if isinstance(solver, str):
        raise ValueError(
            f"solver must be a solver object, got the name {solver!r}: pass e.g. "
            f"jaxmocap.solve.options.SOLVERS[{solver!r}]() (names: {tuple(SOLVERS)})."
        )
    if not isinstance(solver, (*_OURS, optx.AbstractLeastSquaresSolver, optx.AbstractMinimiser)):
        raise ValueError(
            f"solver must be a VonMarcardLM, another solver of jaxmocap.solve.options or an optimistix "
            f"least-squares solver, got {type(solver).__name__}."
        )
    factor_dtype = getattr(solver, "factor_dtype", None) if isinstance(solver, _OURS) else None
    factor_dtype = jnp.dtype(factor_dtype or (jnp.float64 if jax.config.jax_enable_x64 else dtype))
    tridiagonal = check_tridiagonal(getattr(solver, "tridiagonal", None) if isinstance(solver, _OURS) else None)
    if isinstance(solver, _OURS):
        rtol, atol = jnp.asarray(solver.rtol, dtype), jnp.asarray(solver.atol, dtype)
        # Static from here on: the options that are not arrays, with placeholders for the
        # tolerances, which travel as traced arrays (a new value does not recompile), and
        # for what travels beside it (factor dtype, band method) or is set per call.
        blank = dict(rtol=0.0, atol=0.0)
        if isinstance(solver, (VonMarcardLM, OptxLevenbergMarquardt)):
            blank.update(factor_dtype=None, tridiagonal=None)
        if isinstance(solver, VonMarcardLM):
            blank.update(max_steps=100, progress=False)
        solver = dataclasses.replace(solver, **blank)
    else:
        rtol, atol = jnp.asarray(1e-6, dtype), jnp.asarray(1e-8, dtype)
    # VonMarcardLM takes the cap as a traced loop bound: no recompilation per value.
    max_steps = jnp.asarray(max_steps) if isinstance(solver, VonMarcardLM) else int(max_steps)
    return Resolved(solver, rtol, atol, factor_dtype, tridiagonal, max_steps)


def structured_solver(solver, rtol, atol, max_steps, factor_dtype, tridiagonal, progress, linear_solver):
    """The optimistix solver a `resolve`d jaxmocap solver stands for, with its tolerances
    (traced) and options back in place; `linear_solver()` builds the structured factorisation.
    A foreign optimistix solver is returned as it is."""
    if isinstance(solver, VonMarcardLM):
        return VonMarcardLM(
            rtol, atol, solver.norm, damping=solver.damping, factor_dtype=factor_dtype, tridiagonal=tridiagonal,
            max_steps=max_steps, progress=progress,
        )  # fmt: skip
    if isinstance(solver, OptxLevenbergMarquardt):
        return solver.optimistix(rtol=rtol, atol=atol, linear_solver=linear_solver())
    return solver
