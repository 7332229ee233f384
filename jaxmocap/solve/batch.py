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

from .solver import METHODS, Solution, _check, _solve_core

__all__ = ["pad_sequences", "solve_batch"]


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


def solve_batch(
    problem,
    params0: dict,
    data: Any,
    frame_mask: Array | None = None,
    *,
    method: str = "lm",
    rtol: float | Array = 1e-6,
    atol: float | Array = 1e-8,
    max_steps: int = 100,
    linear_solver="banded",
    factor_dtype: Any = None,
    dtype: Any = None,
    damping: str = "levenberg",
) -> Solution:
    """`solve` over a leading batch axis of `params0`, `data` and `frame_mask`.

    Args are those of `solve`, each with a leading batch axis B (`rtol` and `atol` may be
    scalars or (B,) arrays: per-sequence tolerances). Returns a `Solution` whose every
    field has the batch axis first: per-sequence value, result, num_steps, cost, costs.
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}.")
    leaves = jax.tree_util.tree_leaves(params0)
    B = jnp.shape(leaves[0])[0]
    first = jax.tree_util.tree_map(lambda x: x[0], params0)
    layout, _, _, dtype = _check(problem, first, None, None if frame_mask is None else frame_mask[0], dtype)
    params0 = {k: jnp.asarray(params0[k], dtype) for k in layout.keys}
    if factor_dtype is None:
        factor_dtype = jnp.float64 if jax.config.jax_enable_x64 else dtype
    rtol = jnp.broadcast_to(jnp.asarray(rtol, dtype), (B,))
    atol = jnp.broadcast_to(jnp.asarray(atol, dtype), (B,))
    if frame_mask is not None:
        frame_mask = jnp.asarray(frame_mask, bool)
    if method == "lm":
        max_steps = jnp.asarray(max_steps)
    return _batch_jit(
        problem, layout, params0, data, frame_mask, rtol, atol, max_steps, method=method,
        linear_solver=linear_solver, factor_dtype=jnp.dtype(factor_dtype), damping=damping,
    )  # fmt: skip


@eqx.filter_jit
def _batch_jit(problem, layout, params0, data, frame_mask, rtol, atol, max_steps, **static):
    def one(p, d, m, rt, at):
        return _solve_core(problem, layout, p, d, m, rt, at, max_steps, **static)

    mask_axis = None if frame_mask is None else 0
    return jax.vmap(one, in_axes=(0, 0, mask_axis, 0, 0))(params0, data, frame_mask, rtol, atol)
