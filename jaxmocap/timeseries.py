"""Shifting and differencing along the frame axis, shared by energies and the solver."""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array

__all__ = ["shift_frames"]


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
