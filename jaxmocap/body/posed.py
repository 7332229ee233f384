"""Posing a body with a whole motion: a batched, jitted forward pass in chunks.

Used wherever every frame's mesh is needed (mesh export, the physics report, metrics on
vertices); it lives with the body model, not with the pictures.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from .._progress import progress as show_progress
from .kinematics import forward
from .model import Body

__all__ = ["posed_vertices"]


@jax.jit
def _forward_chunk(body: Body, pose, betas, trans):
    out = forward(body, pose, betas, trans)
    return out.vertices, out.joints


def _chunk_size(n: int, max_chunk: int) -> int:
    """The smallest power of two >= n, capped at max_chunk: few distinct jit shapes."""
    size = 1
    while size < min(n, max_chunk):
        size *= 2
    return min(size, max_chunk)


def posed_vertices(
    body: Body,
    motion,
    frames: slice | Sequence[int] | np.ndarray | None = None,
    chunk: int = 256,
    progress: bool = False,
    betas=None,
) -> tuple[np.ndarray, np.ndarray]:
    """Pose `body` with every frame of `motion` (batched forward, jitted, chunked).

    Frames are processed `chunk` at a time (padded to a power of two, so a handful of
    shapes is ever compiled) to bound memory at about chunk·V·12 floats of skinning
    transforms.

    Args:
        body: the body model.
        motion: a `Motion` (poses (T, 24, 3), trans (T, 3), betas (B,)).
        frames: which frames (slice or index array); default all.
        chunk: frames per batched forward call.
        progress: show a tqdm progress bar.
        betas: shape coefficients to use instead of `motion.betas`. Either is cut to the
            body's first `body.num_betas` components (empty means the mean shape).
    Returns:
        (vertices (T', V, 3), joints (T', J, 3)) as NumPy arrays in the body's dtype.
    """
    if not hasattr(motion, "poses") or not hasattr(motion, "trans"):
        raise ValueError(f"motion must be a jaxmocap.motion.Motion, got {type(motion).__name__}; wrap arrays as "
                         "Motion(poses, trans, fps).")  # fmt: skip
    if isinstance(chunk, bool) or not isinstance(chunk, (int, np.integer)) or chunk < 1:
        raise ValueError(f"chunk must be an int >= 1 (frames per batched forward call), got {chunk!r}.")
    poses = np.asarray(motion.poses)
    trans = np.asarray(motion.trans)
    if frames is not None:
        poses, trans = poses[frames], trans[frames]
    if poses.ndim != 3 or poses.shape[1:] != (body.num_joints, 3):
        raise ValueError(f"motion poses have shape {poses.shape}; expected (T, {body.num_joints}, 3).")
    dtype = np.dtype(body.dtype)
    b = np.asarray(motion.betas if betas is None else betas, dtype).reshape(-1)[: body.num_betas]
    b = np.zeros(body.num_betas, dtype) if b.size == 0 else b
    T = poses.shape[0]
    if T == 0:
        raise ValueError(f"frames={frames!r} selects no frame of the motion's {len(motion.poses)}.")
    V, J = body.num_vertices, body.num_joints
    vertices = np.empty((T, V, 3), dtype)
    joints = np.empty((T, J, 3), dtype)
    size = _chunk_size(T, chunk)
    for start in show_progress(range(0, T, size), progress, f"posing {size} frames at a time", "batch"):
        stop = min(start + size, T)
        n = stop - start
        pose = np.zeros((size, J, 3), dtype)
        tr = np.zeros((size, 3), dtype)
        pose[:n], tr[:n] = poses[start:stop], trans[start:stop]
        v, j = _forward_chunk(body, jnp.asarray(pose), jnp.asarray(b), jnp.asarray(tr))
        vertices[start:stop] = np.asarray(v)[:n]
        joints[start:stop] = np.asarray(j)[:n]
    return vertices, joints
