"""Moving cameras, simulated: a hand-held operator's path and an IMU fixed to a camera.

The pinhole geometry itself (`look_at`, `project`, intrinsics) is `jaxmocap.geometry.camera`.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from scipy.ndimage import gaussian_filter1d

from ..geometry.camera import look_at
from ..rotation import host_exp
from .imu import IMUReadings, imu_from_trajectory

__all__ = ["handheld_trajectory", "camera_imu"]


def _smooth_noise(rng, shape, std, sigma_frames):
    """Gaussian-filtered white noise with standard deviation `std` (hand tremor, sway)."""
    if std <= 0:
        return np.zeros(shape)
    x = gaussian_filter1d(rng.normal(size=shape), sigma_frames, axis=0, mode="nearest")
    return x * (std / max(x.std(), 1e-12))


def handheld_trajectory(
    targets: np.ndarray,
    fps: float,
    rng: np.random.Generator,
    distance: float = 3.5,
    height: float = 1.5,
    orbit_degrees_per_second: float = 8.0,
    start_angle: float | None = None,
    position_shake: float = 0.02,
    rotation_shake_degrees: float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """A hand-held camera following `targets` (T, 3): slow orbit, sway and tremor.

    The operator walks around the subjects at `distance` with the camera at `height` m,
    aiming at a smoothed version of the target path (1 s Gaussian); position sway
    (`position_shake` m, ~0.5 s correlation) and rotational tremor (~0.1 s) are smooth
    random processes. Returns world-to-camera (R (T, 3, 3), t (T, 3)).
    """
    targets = np.asarray(targets, np.float64)
    T = len(targets)
    aim = gaussian_filter1d(targets, fps, axis=0, mode="nearest") if T > 1 else targets
    theta0 = rng.uniform(-np.pi / 4, np.pi / 4) if start_angle is None else start_angle
    theta = theta0 + np.radians(orbit_degrees_per_second) * np.arange(T) / fps
    eyes = aim + np.stack([distance * np.sin(theta), height - aim[:, 1], distance * np.cos(theta)], -1)
    eyes = eyes + _smooth_noise(rng, (T, 3), position_shake, 0.5 * fps)
    R, t = look_at(eyes, aim)
    tremor = _smooth_noise(rng, (T, 3), np.radians(rotation_shake_degrees), 0.1 * fps)
    R = host_exp(tremor) @ R  # about the camera's own axes
    t = -np.einsum("tab,tb->ta", R, eyes)
    return R, t


def camera_imu(R, t, fps: float) -> IMUReadings:
    """Readings of an IMU rigidly fixed to a moving camera, axes = camera axes.

    The sensor frame is the camera frame: orientation R_c^g = Rᵀ, position the camera
    centre. R (T, 3, 3), t (T, 3) world-to-camera; returns (T, 1, ...) readings.
    """
    R = jnp.asarray(R)
    Rcg = jnp.swapaxes(R, -1, -2)
    center = -jnp.einsum("tba,tb->ta", R, jnp.asarray(t))
    return imu_from_trajectory(Rcg[:, None], center[:, None], fps)
