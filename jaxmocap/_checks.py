"""Argument checks for the public entry points, run once on the host or at trace time.

Each check names the argument and says what was expected. Values that are traced (inside
`jit`, `vmap`, `grad`) cannot be inspected; the checks skip them, so they never add work
to a compiled kernel: validation happens where the user hands over concrete arrays.
"""

from __future__ import annotations

import math

import jax
import numpy as np

__all__ = [
    "concrete",
    "check_rate",
    "check_weight",
    "check_frames",
    "check_rotations",
    "check_finite",
    "output_folder",
    "output_npz",
]


def concrete(x) -> np.ndarray | None:
    """`x` as a NumPy array, or None when it is a tracer (no value to check)."""
    if isinstance(x, jax.core.Tracer):
        return None
    try:
        return np.asarray(x)
    except (jax.errors.TracerArrayConversionError, jax.errors.ConcretizationTypeError):
        return None


def check_max_steps(max_steps) -> None:
    """An LM step cap: an int >= 1 (or an integer array; traced values pass unchecked).

    0 or a negative cap would still take one step (optimistix checks after stepping).
    """
    steps = concrete(max_steps)
    if steps is not None and (steps.ndim != 0 or not np.issubdtype(steps.dtype, np.integer) or steps < 1):
        raise ValueError(f"max_steps must be an int >= 1, got {max_steps!r}.")


def check_rate(name: str, value, what: str = "frames per second") -> None:
    """A rate such as fps: a finite number > 0 (a sign flip or zero would be silently wrong)."""
    v = concrete(value)
    if v is None:
        return
    if v.ndim != 0 or not np.issubdtype(v.dtype, np.number):
        raise ValueError(f"{name} must be one positive number ({what}), got {value!r}.")
    if not (math.isfinite(float(v)) and float(v) > 0):
        raise ValueError(f"{name} must be a finite number > 0 ({what}), got {float(v)}.")


def check_weight(name: str, value) -> None:
    """A term weight: finite and >= 0 (0 switches a term off; < 0 would reward the error)."""
    v = concrete(value)
    if v is None:
        return
    if not np.issubdtype(v.dtype, np.number) or v.dtype == np.bool_:
        raise ValueError(f"{name} must be a finite number >= 0, got {value!r}.")
    if not (np.all(np.isfinite(v)) and np.all(v >= 0)):
        raise ValueError(f"{name} must be finite and >= 0 (0 switches the term off), got {v.tolist()}.")


def check_non_negative_fields(obj, unit: str = "") -> None:
    """Every field of the dataclass `obj` a finite real number >= 0 (not a bool): a negative
    std or rate would otherwise fail deep inside NumPy, or not at all."""
    import dataclasses

    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        if (
            isinstance(v, bool)
            or not isinstance(v, (int, float, np.integer, np.floating))
            or not (np.isfinite(v) and v >= 0)
        ):
            raise ValueError(f"{type(obj).__name__}.{f.name} must be a finite number >= 0{unit}, got {v!r}.")


def check_frames(name: str, T: int, at_least: int = 1) -> None:
    """A frame count T >= `at_least`."""
    if T < at_least:
        raise ValueError(f"{name} has {T} frames; at least {at_least} needed (an empty slice or a T = 0 array?).")


def check_finite(name: str, x) -> None:
    """Every entry finite (skipped for traced values)."""
    v = concrete(x)
    if v is None or not np.issubdtype(v.dtype, np.inexact):
        return
    if not np.isfinite(v).all():
        bad = np.argwhere(~np.isfinite(v))[0]
        raise ValueError(f"{name} contains NaN or inf (first at index {tuple(int(i) for i in bad)}).")


def check_rotations(name: str, R, atol: float = 1e-3, allow_nan: bool = False) -> None:
    """(..., 3, 3) rotation matrices: RᵀR = I and det R = +1 within `atol`.

    With `allow_nan`, matrices holding a NaN (dropped samples) are skipped.
    """
    v = concrete(R)
    if v is None:
        return
    if v.ndim < 2 or v.shape[-2:] != (3, 3):
        raise ValueError(f"{name} has shape {v.shape}; expected (..., 3, 3) rotation matrices.")
    v = v.reshape(-1, 3, 3).astype(np.float64)
    present = np.isfinite(v).all(axis=(1, 2))
    if not allow_nan and not present.all():
        raise ValueError(f"{name} contains NaN or inf (matrix {int(np.argmin(present))}).")
    index = np.flatnonzero(present)
    v = v[present]
    if v.size == 0:
        return
    ortho = np.abs(np.swapaxes(v, 1, 2) @ v - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(v)
    bad = (ortho > atol) | (np.abs(det - 1.0) > atol)
    if bad.any():
        i = int(np.argmax(bad))
        raise ValueError(
            f"{name} holds matrices that are not rotations (RᵀR = I, det = +1): matrix "
            f"{int(index[i])} (flattened) has |RᵀR - I| = {ortho[i]:.3g}, det = {det[i]:.3g}."
        )


def output_folder(path, name: str = "out_dir (--out)", create: bool = True):
    """`path` created (or found) and writable, as a Path: called before minutes of work,
    so that a file given as the folder, or a folder that cannot be made, fails at once.
    With `create=False` nothing is written: its nearest existing folder must be writable."""
    import os
    from pathlib import Path

    path = Path(path)
    if path.exists() and not path.is_dir():
        raise ValueError(f"{name} {str(path)!r} is a file, not a folder; give a folder to write into.")
    if not create:
        base = path
        while not base.exists():
            base = base.parent
        if not base.is_dir():
            raise ValueError(f"{name} {str(path)!r} cannot be created ({str(base)!r} is a file); give another folder.")
        if not os.access(base, os.W_OK | os.X_OK):
            raise ValueError(f"{name} {str(path)!r} cannot be created ({str(base)!r} is not writable).")
        return path
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ValueError(
            f"{name} {str(path)!r} cannot be created ({e.strerror}); give a folder you can write to."
        ) from None
    if not os.access(path, os.W_OK | os.X_OK):
        raise ValueError(f"{name} {str(path)!r} is not writable; give a folder you can write to.")
    return path


def output_npz(path, who: str = "save_motion", example: str = "motion.npz"):
    """The `.npz` file that `np.savez(path)` writes (it appends `.npz` to other names),
    refused with a ValueError when that is an existing folder or its folder is missing."""
    from pathlib import Path

    path = Path(path)
    target = path if path.suffix == ".npz" else path.with_name(path.name + ".npz")
    # np.savez would quietly write "<folder>.npz" beside a folder the user named.
    if path.is_dir():
        raise ValueError(f"{who}: path {str(path)!r} is a folder; give a file name, e.g. {str(path / example)!r}.")
    if target.is_dir():
        raise ValueError(f"{who}: path {str(path)!r} would be written as {str(target)!r}, which is a folder; "
                         "give another file name.")  # fmt: skip
    if not target.parent.is_dir():
        raise ValueError(
            f"{who}: the folder {str(target.parent)!r} of path {str(path)!r} does not exist; create it first."
        )
    return target
