"""The true motion posed on the body, padded to a few compiled lengths (shared by the
labelling rule and the simulated watch)."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jax import Array

from ...body.model import Body
from ...motion.sequence import Motion


def _extended(motion: Motion, frames: int) -> tuple[np.ndarray, np.ndarray]:
    """Poses and trans continued by `frames` frames past the end, by point reflection about
    the last frame (trans: 2 x_{T-1} - x_{T-1-k}; each joint: R_{T-1} R_{T-1-k}ᵀ R_{T-1}),
    so velocities carry on smoothly and the finite differences at the real last frame see no
    jump. Used to pad sequences to a few compiled lengths."""
    from ...rotation import host_compose

    T = motion.num_frames
    if frames <= 0:
        return motion.poses, motion.trans
    k = np.minimum(np.arange(1, frames + 1), T - 1)
    src = T - 1 - k
    trans = 2 * motion.trans[-1] - motion.trans[src]
    last = motion.poses[-1]  # (24, 3)
    poses = np.empty((frames, 24, 3))
    for i, s in enumerate(src):
        poses[i] = host_compose(last, -motion.poses[s], last)  # exp(-ω) = exp(ω)ᵀ
    return np.concatenate([motion.poses, poses]), np.concatenate([motion.trans, trans])


_BUCKET = 256


def _padded_length(T: int) -> int:
    return max(_BUCKET, -(-T // _BUCKET) * _BUCKET)


@eqx.filter_jit
def _forward(body: Body, poses: Array, trans: Array):
    from ...body.kinematics import forward

    return forward(body, poses, None, trans)


def posed_padded(body: Body, motion: Motion):
    """(padded poses, padded trans, forward output) with T padded to a multiple of 256
    frames (a handful of compiled shapes instead of one per clip length)."""
    T = motion.num_frames
    poses, trans = _extended(motion, _padded_length(T) - T)
    dtype = body.dtype
    poses, trans = jnp.asarray(poses, dtype), jnp.asarray(trans, dtype)
    return poses, trans, _forward(body, poses, trans)


def body_or_default(body):
    """`body`, or the low-resolution default body for None."""
    if body is None:
        from ...body.io import default_body

        return default_body("low")
    return body
