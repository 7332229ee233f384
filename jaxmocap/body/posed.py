"""Posing a body with a whole trajectory: a batched, jitted forward pass in chunks.

Used wherever every frame's mesh is needed (mesh export, the physics report, metrics on
vertices); it lives with the body model, not with the pictures.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from .._checks import check_finite
from .._progress import progress as show_progress
from .kinematics import forward
from .model import Body

__all__ = ["posed_arrays", "posed_vertices"]


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
    poses, trans = np.asarray(motion.poses), np.asarray(motion.trans)
    if frames is not None:
        poses, trans = poses[frames], trans[frames]
        if len(poses) == 0:
            raise ValueError(f"frames={frames!r} selects no frame of the motion's {len(motion.poses)}.")
    shape = np.reshape(motion.betas if betas is None else betas, -1)  # one shape for the whole motion
    return posed_arrays(body, poses, shape, trans, chunk=chunk, progress=progress)


def posed_arrays(
    body: Body, poses, betas=None, trans=None, chunk: int = 256, progress: bool = False, dtype=None
) -> tuple[np.ndarray, np.ndarray]:
    """Pose `body` with a trajectory given as arrays (batched forward, jitted, chunked).

    What `posed_vertices` does for a `Motion`, for fits that hold their result as arrays.

    Args:
        body: the body model.
        poses: (T, J, 3) axis-angle joint rotations.
        betas: (B,) shape coefficients shared by every frame, or (T, B) per frame; cut to
            the body's first `body.num_betas` (default or empty: the mean shape).
        trans: (T, 3) root translations (default: zeros).
        chunk: frames per batched forward call (padded to a power of two, so a handful of
            shapes is ever compiled; memory about chunk·V·12 floats of skinning transforms).
        progress: show a tqdm progress bar.
        dtype: the NumPy dtype of the result (default: the body's).
    Returns:
        (vertices (T, V, 3), joints (T, J, 3)) as NumPy arrays.
    """
    if isinstance(chunk, bool) or not isinstance(chunk, (int, np.integer)) or chunk < 1:
        raise ValueError(f"chunk must be an int >= 1 (frames per batched forward call), got {chunk!r}.")
    work = np.dtype(body.dtype)
    poses = np.asarray(poses, work)
    V, J = body.num_vertices, body.num_joints
    if poses.ndim != 3 or poses.shape[1:] != (J, 3):
        raise ValueError(f"poses have shape {poses.shape}; expected (T, {J}, 3) (one frame: poses[None]).")
    T = poses.shape[0]
    if T == 0:
        raise ValueError("poses have no frame (shape (0, ...)); give at least one.")
    trans = np.zeros((T, 3), work) if trans is None else np.asarray(trans, work)
    if trans.shape != (T, 3):
        raise ValueError(f"trans has shape {trans.shape}; expected ({T}, 3) for {T} frames of poses.")
    b = np.zeros(0, work) if betas is None else np.asarray(betas, work)
    if b.ndim not in (1, 2) or (b.ndim == 2 and len(b) != T):
        raise ValueError(f"betas has shape {b.shape}; expected (B,) for every frame or ({T}, B) per frame.")
    b = b[..., : body.num_betas]
    if b.shape[-1] == 0:
        b = np.zeros(body.num_betas, work)
    # Named here: inside the jit, forward's own value checks see tracers.
    for name, x in (("poses", poses), ("betas", b), ("trans", trans)):
        check_finite(name, x)
    # Shared betas go in per frame: one compiled program for either (same values bitwise).
    b = np.broadcast_to(b, (T, b.shape[-1]))
    out = np.dtype(dtype) if dtype is not None else work
    vertices = np.empty((T, V, 3), out)
    joints = np.empty((T, J, 3), out)
    size = _chunk_size(T, chunk)
    for start in show_progress(range(0, T, size), progress, f"posing {size} frames at a time", "batch"):
        stop = min(start + size, T)
        n = stop - start
        # Zero-padded to the chunk's size: a handful of compiled shapes however long the trajectory.
        pose, tr, bb = np.zeros((size, J, 3), work), np.zeros((size, 3), work), np.zeros((size, b.shape[1]), work)
        pose[:n], tr[:n], bb[:n] = poses[start:stop], trans[start:stop], b[start:stop]
        v, j = _forward_chunk(body, jnp.asarray(pose), jnp.asarray(bb), jnp.asarray(tr))
        vertices[start:stop] = np.asarray(v)[:n]
        joints[start:stop] = np.asarray(j)[:n]
    return vertices, joints
