"""Shifting and differencing along the frame axis, shared by energies and the solver."""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array

__all__ = ["second_difference", "shift_frames"]


def shift_frames(x: Array, d: int) -> Array:
    """y[s] = x[s - d] along axis 0, zero where s - d is out of range."""
    if d == 0:
        return x
    T = x.shape[0]
    if abs(d) >= T:
        return jnp.zeros_like(x)
    zeros = jnp.zeros((abs(d),) + x.shape[1:], x.dtype)
    if d > 0:
        return jnp.concatenate([zeros, x[: T - d]], 0)
    return jnp.concatenate([x[-d:], zeros], 0)


def second_difference(x: Array) -> Array:
    """x[t-1] - 2 x[t] + x[t+1] along axis 0, edge rows from edge padding.  (T, ...) -> (T, ...).

    The numerator of the central finite-difference acceleration (von Marcard eq. 3.10);
    divide by dt². Rows 0 and T-1 are placeholders that a bandwidth-1 `Term` drops.
    """
    padded = jnp.concatenate([x[:1], x, x[-1:]], axis=0)
    return padded[:-2] - 2.0 * padded[1:-1] + padded[2:]
