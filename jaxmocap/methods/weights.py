"""One convention for the methods' weights, and one protocol for their results.

Weights: every method's weights (`SIPWeights`, `VIPWeights`, `MuVSWeights`, `InterCapWeights`)
is a frozen dataclass deriving from `Weights`. A field that weights a term carries the term's
name (`Term.name`), so `term_weights()` maps fields to the weights `solve` applies with no
table of renamings in between; where a method scales its fields (SIP and VIP divide the
sensor terms by the number of sensors, SIP's w_anthro multiplies both prior terms) its class
says so in its own `term_weights`. Fields named in `CONSTANTS` configure the terms (σ, point
counts, step budgets) and are not term weights. Every weight is checked on construction:
finite and >= 0 (0 switches its term off exactly; < 0 would reward the error).

Results: every method's result satisfies `FitResult`: `.solution` (the engine's `Solution`,
or one per stage), `.converged` and `.params` (the fitted unknowns by name).
"""

from __future__ import annotations

import dataclasses
import functools
import warnings
from typing import Any, ClassVar

import jax.numpy as jnp

from .._checks import check_weight
from ..solve import with_weights

__all__ = ["Weights", "renamed", "FitResult"]


class Weights:
    """Base of the methods' weights (derive with `@dataclasses.dataclass(frozen=True)`).

    Floats or arrays (traced: changing them does not recompile; differentiable). A field
    not in `CONSTANTS` is a weight: finite and >= 0, checked here (traced values are
    checked by their maker).
    """

    #: Fields that configure the terms (σ, point counts, step budgets), not term weights.
    CONSTANTS: ClassVar[tuple[str, ...]] = ()
    #: Old field name -> new, accepted for one release with a DeprecationWarning (`renamed`).
    RENAMED: ClassVar[dict[str, str]] = {}

    def __post_init__(self):
        for name in self.weight_names():
            check_weight(f"{type(self).__name__}.{name}", getattr(self, name))

    @classmethod
    def weight_names(cls) -> tuple[str, ...]:
        """The fields that are weights (every field not in `CONSTANTS`)."""
        return tuple(f.name for f in dataclasses.fields(cls) if f.name not in cls.CONSTANTS)

    def replace(self, **changes):
        return dataclasses.replace(self, **_new_names(type(self), changes))

    def to_dict(self) -> dict[str, Any]:
        """Every field (weights and constants) by name, e.g. for a results file."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}

    @classmethod
    def from_dict(cls, values: dict):
        """The weights of `values` ({field: value}, as `to_dict` writes them; fields left out
        keep their defaults, lists become tuples where the field's default is a tuple, e.g.
        from JSON). An unknown name is a ValueError naming the fields."""
        values = _new_names(cls, dict(values))
        fields = {f.name: f for f in dataclasses.fields(cls)}
        unknown = sorted(set(values) - set(fields))
        if unknown:
            raise ValueError(f"{cls.__name__} has no field {', '.join(map(repr, unknown))}; fields: {sorted(fields)}.")
        tuples = {n for n, f in fields.items() if isinstance(f.default, tuple)}
        return cls(**{k: tuple(v) if k in tuples and isinstance(v, list) else v for k, v in values.items()})

    def term_weights(self) -> dict[str, Any]:
        """{term name: weight} of the terms these weights set (`solve.with_weights`); a method
        whose terms do not read its fields one to one overrides this."""
        return {name: getattr(self, name) for name in self.weight_names()}

    def weigh(self, problem, dtype, **context):
        """`problem` with the weights of its terms (those `term_weights(**context)` names) as
        arrays of `dtype`: traced, so a new value does not recompile."""
        names = {t.name for t in problem.terms}
        w = self.term_weights(**context)
        return with_weights(problem, {k: jnp.asarray(v, dtype) for k, v in w.items() if k in names})

    def __getattr__(self, name: str):
        # Only called when normal lookup fails: an old field name reads the new field.
        new = type(self).RENAMED.get(name)
        if new is None:
            raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")
        _warn(type(self), name, new)
        return getattr(self, new)


def renamed(**old_to_new: str):
    """Class decorator (outside `dataclasses.dataclass`): keyword arguments and attributes of
    the old field names keep working for one release, with a DeprecationWarning."""

    def wrap(cls):
        cls.RENAMED = {**cls.RENAMED, **old_to_new}
        init = cls.__init__

        @functools.wraps(init)
        def __init__(self, *args, **kwargs):
            init(self, *args, **_new_names(cls, kwargs))

        cls.__init__ = __init__
        return cls

    return wrap


def _new_names(cls, values: dict) -> dict:
    out = {}
    for k, v in values.items():
        new = cls.RENAMED.get(k)
        if new is not None:
            _warn(cls, k, new)
            if new in values:
                raise ValueError(f"{cls.__name__}: pass {new!r} only ({k!r} is its old name).")
            k = new
        out[k] = v
    return out


def _warn(cls, old: str, new: str) -> None:
    warnings.warn(
        f"{cls.__name__}.{old} is now {cls.__name__}.{new} (named after its term); the old name goes in the "
        "next release.",
        DeprecationWarning,
        stacklevel=4,
    )


class FitResult:
    """What every method's result offers beside its own fields.

    solution: the engine's `Solution`, or for a method of several solves a dict of them by
    stage; converged: every solve ended with result code 0; and, defined by each result,
    params: the fitted unknowns, {name: array}.
    """

    @property
    def solutions(self) -> dict:
        """The `Solution` of each solve by stage name ({"fit": solution} for one solve)."""
        s = self.solution
        return dict(s) if isinstance(s, dict) else {"fit": s}

    @property
    def converged(self):
        """Every solve ended with result code 0: a bool array, () or per batch member."""
        codes = [jnp.asarray(s.result) == 0 for s in self.solutions.values()]
        if not codes:
            raise ValueError(f"this {type(self).__name__} records no solve, so whether it converged is unknown.")
        return functools.reduce(jnp.logical_and, codes)
