"""The watch: simulated wrist-IMU readings at 10 fps, and labels at its frames (package
docstring, step 1)."""

from __future__ import annotations

import numpy as np

from ..._checks import check_rate
from ...body.model import Body
from ...motion.sequence import Motion
from ._motion import body_or_default, posed_padded

__all__ = ["WATCH_RATE", "WATCH_SENSOR", "NUM_CHANNELS", "watch_readings", "resample_labels"]


#: Readings rate (fps) of §7.4.
WATCH_RATE = 10.0
#: The sip6 sensor that plays the watch.
WATCH_SENSOR = "left_forearm"
NUM_CHANNELS = 6  # a (3) and r (3)


def watch_readings(
    motion: Motion,
    body: Body | None = None,
    rng: np.random.Generator | None = None,
    error_model=None,
    rate: float = WATCH_RATE,
    sensor: str = WATCH_SENSOR,
) -> np.ndarray:
    """Simulated watch readings of `motion` at `rate` fps (module docstring, step 1).

    Args:
        motion: the motion; it must have at least `rate` fps (resample it up otherwise).
        body: the body (default `default_body("low")`); mean shape.
        rng: draws the sensor errors (default: seed 0).
        error_model: `IMUErrorModel` (default `IMUErrorModel.xsens()`).
        rate: output frame rate.
        sensor: a sensor of the "sip6" set ("left_forearm" is the watch).
    Returns:
        (N, 6) float32: specific force a (m/s²) and angular rate r (rad/s) in the sensor
        frame, N = floor(duration · rate) + 1 frames at t_k = k / rate.
    """
    from ...sensors.errors import IMUErrorModel, simulate_imu
    from ...sensors.imu import imu_placement

    if not isinstance(motion, Motion):
        raise ValueError(f"watch_readings needs a jaxmocap Motion, got {type(motion).__name__}.")
    check_rate("rate", rate)
    if motion.fps < rate:
        raise ValueError(
            f"the motion has {motion.fps:g} fps, fewer than the {rate:g} fps asked for; "
            f"resample it first (motion.resample({rate:g}) or more)."
        )
    if motion.num_frames < 4:
        raise ValueError(f"the motion has {motion.num_frames} frames; at least 4 are needed to differentiate twice.")
    body = body_or_default(body)
    rng = np.random.default_rng(0) if rng is None else rng
    error_model = IMUErrorModel.xsens() if error_model is None else error_model
    placement = imu_placement(body, "sip6").subset([sensor])
    poses, trans, output = posed_padded(body, motion)
    _, measured, _ = simulate_imu(body, placement, poses, None, trans, motion.fps, error_model, rng, output=output)
    T = motion.num_frames
    signal = np.concatenate([measured.acceleration[:T, 0], measured.angular_velocity[:T, 0]], -1)
    n = _watch_frames(T, motion.fps, rate)
    # Box average over [t_k - 0.5/rate, t_k + 0.5/rate): bin of each native sample.
    bins = np.floor(np.arange(T) / motion.fps * rate + 0.5).astype(int)
    keep = bins < n
    ok = np.isfinite(signal).all(1) & keep
    sums = np.zeros((n, NUM_CHANNELS))
    counts = np.zeros(n)
    np.add.at(sums, bins[ok], signal[ok])
    np.add.at(counts, bins[ok], 1.0)
    out = np.full((n, NUM_CHANNELS), np.nan)
    has = counts > 0
    out[has] = sums[has] / counts[has, None]
    # Bins with every sample dropped hold the previous bin (the next one at the start).
    if not has.all():
        if not has.any():
            raise ValueError("every watch sample was dropped; use a lower dropout rate.")
        idx = np.where(has, np.arange(n), -1)
        idx = np.maximum.accumulate(idx)
        idx[idx < 0] = np.flatnonzero(has)[0]
        out = out[idx]
    return out.astype(np.float32)


def resample_labels(labels, fps: float, rate: float = WATCH_RATE) -> np.ndarray:
    """Labels at the watch frames t_k = k / rate (k = 0 .. floor(duration · rate)): the
    label of the nearest frame of the `fps` sequence."""
    check_rate("fps", fps)
    check_rate("rate", rate)
    labels = np.asarray(labels)
    if labels.ndim != 1 or labels.size == 0:
        raise ValueError(f"labels has shape {labels.shape}; expected (T,) with T >= 1.")
    n = _watch_frames(labels.size, fps, rate)
    src = np.minimum(np.round(np.arange(n) / rate * fps).astype(int), labels.size - 1)
    return labels[src]


def _watch_frames(T: int, fps: float, rate: float) -> int:
    return int(np.floor((T - 1) / fps * rate + 1e-6)) + 1
