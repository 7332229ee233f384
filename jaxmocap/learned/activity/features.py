"""Input features of the MLP from watch readings: the thesis's raw windows, window
statistics, and per-channel standardisation (package docstring, step 2)."""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..._checks import check_finite
from .readings import NUM_CHANNELS

__all__ = [
    "WINDOW",
    "window_features",
    "SUMMARY_WINDOWS",
    "summary_feature_names",
    "summary_features",
    "Standardiser",
    "fit_standardiser",
]

#: Window length of §7.4 (frames, the current one included: 6 s at 10 fps).
WINDOW = 60


def _check_readings(name: str, readings) -> Array:
    shape = np.shape(readings)
    if len(shape) != 2 or shape[1] != NUM_CHANNELS:
        raise ValueError(
            f"{name} has shape {shape}; expected (N, 6) watch frames (acceleration x, y, z, "
            "angular rate x, y, z), as `watch_readings` returns."
        )
    if shape[0] < 1:
        raise ValueError(f"{name} has 0 frames; at least one is needed.")
    check_finite(name, readings)
    return jnp.asarray(readings, jnp.float32)


def window_features(readings, window: int = WINDOW) -> Array:
    """Input vectors x_t = vec(a_{t-M+1..t}, r_{t-M+1..t}) of every frame (§7.3, M = `window`).

    Args:
        readings: (N, 6) watch frames [a, r] (standardised or not).
        window: frames per window, the current one included.
    Returns:
        (N, 6 · window): per frame, the window's accelerations (frame-major, 3 axes each)
        then its angular rates. Frames before the first repeat the first frame.
    """
    x = _check_readings("readings", readings)
    if not (isinstance(window, int) and window >= 1):
        raise ValueError(f"window must be a whole number of frames >= 1, got {window!r}.")
    padded = jnp.concatenate([jnp.repeat(x[:1], window - 1, 0), x], 0)
    idx = jnp.arange(x.shape[0])[:, None] + jnp.arange(window)[None, :]  # (N, M)
    w = padded[idx]  # (N, M, 6)
    return jnp.concatenate([w[..., :3].reshape(x.shape[0], -1), w[..., 3:].reshape(x.shape[0], -1)], -1)


#: Window lengths (watch frames: 1 s, 3 s, 6 s) of `summary_features`.
SUMMARY_WINDOWS: tuple[int, ...] = (10, 30, 60)
#: Values per window of `summary_features` (names in `summary_feature_names`).
_SUMMARY_NAMES = (
    "up_x", "up_y", "up_z", "acc_mean_norm", "acc_dynamic", "acc_std_x", "acc_std_y", "acc_std_z",
    "acc_norm_std", "gyro_mean_x", "gyro_mean_y", "gyro_mean_z", "gyro_std_x", "gyro_std_y",
    "gyro_std_z", "gyro_rms", "yaw_rate", "yaw_rate_abs", "acc_norm_crossings",
)  # fmt: skip


def summary_feature_names(windows: Sequence[int] = SUMMARY_WINDOWS) -> list[str]:
    """Names of the columns of `summary_features`, window by window."""
    return [f"{n}@{w}" for w in windows for n in _SUMMARY_NAMES]


def _moving_mean(x: np.ndarray, length: int, centred: bool) -> np.ndarray:
    """Mean over a window of `length` frames ending at (or centred on) each frame; the
    sequence is continued by its first / last frame."""
    before = length // 2 if centred else length - 1
    after = length - 1 - before
    pad = [(before, after)] + [(0, 0)] * (x.ndim - 1)
    xp = np.pad(x, pad, mode="edge")
    cs = np.concatenate([np.zeros((1, *x.shape[1:])), np.cumsum(xp, 0)], 0)
    return (cs[length:] - cs[:-length]) / length


def summary_features(readings, windows: Sequence[int] = SUMMARY_WINDOWS, centred: bool = True) -> np.ndarray:
    """Window statistics of the raw watch readings, per frame (an alternative to the
    thesis's raw windows, `window_features`; compact enough for a few subjects of data).

    For every window length L in `windows` (frames), centred on the frame (or ending at it
    with `centred=False`), 19 values:

        up (3)            the mean specific force, normalised: the direction of "up" in
                          the watch frame, i.e. how the forearm is held
        acc_mean_norm     |mean specific force| (≈ g unless the wrist accelerates steadily)
        acc_dynamic       sqrt(mean |a - mean a|²): how much the wrist shakes
        acc_std (3), acc_norm_std   per-axis and magnitude standard deviations
        gyro_mean (3), gyro_std (3), gyro_rms   the angular rate's mean, spread, energy
        yaw_rate, |yaw_rate|   the angular rate about the vertical (r_t · up_t, up_t from a
                          1 s mean of a): turning of the whole body, signed (+ = left,
                          counter-clockwise seen from above)
        acc_norm_crossings   the rate of |a| crossing its window mean (per frame): the
                          step or swing frequency

    Args:
        readings: (N, 6) raw watch frames (a m/s², r rad/s), as `watch_readings` returns.
    Returns:
        (N, 19 · len(windows)) float32, columns named by `summary_feature_names`.
    """
    x = np.asarray(_check_readings("readings", readings), np.float64)
    if not windows or not all(isinstance(w, int) and w >= 2 for w in windows):
        raise ValueError(f"windows must be whole numbers of frames >= 2, got {windows!r}.")
    a, r = x[:, :3], x[:, 3:]
    up_local = _moving_mean(a, 10, centred)
    up_local /= np.maximum(np.linalg.norm(up_local, axis=1, keepdims=True), 1e-9)
    yaw = np.sum(r * up_local, 1, keepdims=True)
    anorm = np.linalg.norm(a, axis=1, keepdims=True)
    out = []
    for L in windows:
        ma = _moving_mean(a, L, centred)
        ma_norm = np.linalg.norm(ma, axis=1, keepdims=True)
        up = ma / np.maximum(ma_norm, 1e-9)
        a2 = _moving_mean(a**2, L, centred)
        a_var = np.maximum(a2 - ma**2, 0.0)
        dyn = np.sqrt(a_var.sum(1, keepdims=True))
        mn = _moving_mean(anorm, L, centred)
        n_std = np.sqrt(np.maximum(_moving_mean(anorm**2, L, centred) - mn**2, 0.0))
        mr = _moving_mean(r, L, centred)
        r2 = _moving_mean(r**2, L, centred)
        r_std = np.sqrt(np.maximum(r2 - mr**2, 0.0))
        r_rms = np.sqrt(r2.sum(1, keepdims=True))
        yaw_mean = _moving_mean(yaw, L, centred)
        yaw_abs = _moving_mean(np.abs(yaw), L, centred)
        above = (anorm > mn).astype(np.float64)
        crossings = _moving_mean(np.abs(np.diff(above, axis=0, prepend=above[:1])), L, centred)
        out += [up, ma_norm, dyn, np.sqrt(a_var), n_std, mr, r_std, r_rms, yaw_mean, yaw_abs, crossings]
    return np.concatenate(out, 1).astype(np.float32)


class Standardiser(eqx.Module):
    """Per-channel standardisation (x - mean) / std of the 6 watch channels."""

    mean: Array  # (6,)
    std: Array  # (6,)

    def __call__(self, readings) -> Array:
        x = _check_readings("readings", readings)
        return (x - self.mean) / self.std


def fit_standardiser(readings: Sequence) -> Standardiser:
    """Mean and standard deviation of each channel over a list of (N_i, 6) readings."""
    if len(readings) == 0:
        raise ValueError("fit_standardiser needs at least one (N, 6) readings array.")
    x = np.concatenate([np.asarray(_check_readings(f"readings[{i}]", r)) for i, r in enumerate(readings)])
    std = x.std(0)
    return Standardiser(jnp.asarray(x.mean(0), jnp.float32), jnp.asarray(np.maximum(std, 1e-6), jnp.float32))
