"""Many sequences at once: padding to a common length, `vmap`, per-sequence status.

Sequences of different lengths are padded to the longest (repeating their last frame,
so every padded value stays finite) and carry a (B, T) frame mask; padded frames drop
out of every term and keep their initial value. The whole batch runs in one `vmap`ped
`solve`: each element stops updating when it has converged, but the batch runs until
its slowest element is done (a `while_loop` under `vmap`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
from jax import Array

from .._checks import check_weight
from .solver import METHODS, Args, Solution, _check, _check_max_steps, _solve_core

__all__ = ["pad_sequences", "solve_batch", "with_weights"]


def pad_sequences(sequences: Sequence[Any], length: int | None = None) -> tuple[Any, Array]:
    """Stack pytrees whose leaves are (T_i, ...) into (B, T, ...) plus a (B, T) frame mask.

    Every leaf is treated as per-frame (frame axis first) and padded by repeating its
    last frame. Per-sequence constants that are not per-frame belong in the `Problem`
    (closed over by the term functions) or must be stacked by the caller.
    """
    lengths = []
    for seq in sequences:
        Ts = {jnp.shape(x)[0] for x in jax.tree_util.tree_leaves(seq)}
        if len(Ts) != 1:
            raise ValueError(f"every leaf of a sequence must share its frame axis; got lengths {sorted(Ts)}.")
        lengths.append(Ts.pop())
    T = max(lengths) if length is None else length
    if T < max(lengths):
        raise ValueError(f"length={length} is shorter than the longest sequence ({max(lengths)}).")

    def pad(x, Ti):
        x = jnp.asarray(x)
        return jnp.concatenate([x, jnp.repeat(x[-1:], T - Ti, axis=0)], 0) if T > Ti else x

    padded = [jax.tree_util.tree_map(lambda x, Ti=Ti: pad(x, Ti), seq) for seq, Ti in zip(sequences, lengths)]
    stacked = jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *padded)
    mask = jnp.arange(T)[None, :] < jnp.asarray(lengths)[:, None]
    return stacked, mask


def with_weights(problem, weights: dict | None):
    """`problem` with the named terms' weights replaced (arrays: traced, no recompilation)."""
    if not weights:
        return problem
    names = {t.name for t in problem.terms}
    unknown = sorted(set(weights) - names)
    if unknown:
        raise ValueError(f"weights for terms {unknown} that the problem lacks; its terms are {sorted(names)}.")
    terms = [eqx.tree_at(lambda t: t.weight, t, weights[t.name]) if t.name in weights else t for t in problem.terms]
    return eqx.tree_at(lambda p: p.terms, problem, tuple(terms))


def solve_batch(
    problem,
    params0: dict,
    data: Any,
    frame_mask: Array | None = None,
    *,
    weights: dict[str, Array] | None = None,
    method: str = "lm",
    rtol: float | Array = 1e-6,
    atol: float | Array = 1e-8,
    max_steps: int = 100,
    factor_dtype: Any = None,
    dtype: Any = None,
    damping: str = "levenberg",
) -> Solution:
    """`solve` over a leading batch axis of `params0`, `data` and `frame_mask`.

    Args are those of `solve`, each with a leading batch axis B (`rtol` and `atol` may be
    scalars or (B,) arrays: per-sequence tolerances). `weights` maps term names to (B,)
    weights, one per member: an ablation grid is a batch axis, one compilation.
    Returns a `Solution` whose every field has the batch axis first.
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}.")
    _check_max_steps(max_steps)
    for k, v in (weights or {}).items():
        check_weight(f"weights[{k!r}]", v)
    leaves = jax.tree_util.tree_leaves(params0)
    if not leaves:
        raise ValueError("params0 is empty; give a dict of batched (B, ...) initial parameters.")
    B = jnp.shape(leaves[0])[0]
    first = jax.tree_util.tree_map(lambda x: x[0], params0)
    layout, _, _, dtype = _check(problem, first, None, None if frame_mask is None else frame_mask[0], dtype)
    params0 = {k: jnp.asarray(params0[k], dtype) for k in layout.keys}
    if factor_dtype is None:
        factor_dtype = jnp.float64 if jax.config.jax_enable_x64 else dtype
    rtol = jnp.broadcast_to(jnp.asarray(rtol, dtype), (B,))
    atol = jnp.broadcast_to(jnp.asarray(atol, dtype), (B,))
    weights = {k: jnp.broadcast_to(jnp.asarray(v, dtype), (B,)) for k, v in (weights or {}).items()}
    with_weights(problem, weights and {k: v[0] for k, v in weights.items()})  # names checked here
    if frame_mask is not None:
        frame_mask = jnp.asarray(frame_mask, bool)
    max_steps = jnp.asarray(max_steps) if method == "lm" else int(max_steps)
    return _batch_jit(
        problem, layout, params0, data, frame_mask, weights, rtol, atol, max_steps, method=method,
        factor_dtype=jnp.dtype(factor_dtype), damping=damping,
    )  # fmt: skip


@eqx.filter_jit
def _batch_jit(problem, layout, params0, data, frame_mask, weights, rtol, atol, max_steps, **static):
    def one(p, d, m, w, rt, at):
        args = Args(with_weights(problem, w), d, m, layout)
        return _solve_core(args, p, rt, at, max_steps, solver=None, adjoint=None, **static)

    mask_axis = None if frame_mask is None else 0
    return jax.vmap(one, in_axes=(0, 0, mask_axis, 0, 0, 0))(params0, data, frame_mask, weights, rtol, atol)
