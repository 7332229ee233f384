"""Pinhole cameras: intrinsics, static or moving extrinsics, projection, lens distortion (von Marcard §4.2.2).

    [u, v, 1]ᵀ = π(K · M_g^c · p̄^g),   π(x, y, z) = (x/z, y/z, 1)      eq. 4.1-4.4

Camera frame: OpenCV convention (x right, y down, z forward). The world is y up
(jaxmocap's convention), so `look_at` builds x_c = forward × up, y_c = forward × x_c.
Extrinsics are the world-to-camera map p^c = R p^g + t (M_g^c in the thesis); moving
cameras carry a leading time axis on R and t.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jax import Array

__all__ = [
    "Camera",
    "intrinsics",
    "look_at",
    "project",
    "camera_centers",
    "ring_cameras",
    "distort_points",
    "undistort_pixels",
    "to_pixels",
    "project_points",
    "pinhole_camera",
]


class Camera(eqx.Module):
    """One pinhole camera (or a batch/time series of extrinsics for one intrinsic matrix).

    K: (3, 3) intrinsics [[f_u, 0, c_u], [0, f_v, c_v], [0, 0, 1]] (eq. 4.3).
    R: (..., 3, 3) world-to-camera rotation; t: (..., 3) translation (p^c = R p^g + t).
    width, height: image size in pixels (static).
    """

    K: Array
    R: Array
    t: Array
    width: int = eqx.field(static=True)
    height: int = eqx.field(static=True)


def intrinsics(width: int, height: int, fov_y_degrees: float = 60.0) -> np.ndarray:
    """K of a square-pixel camera with the principal point at the image centre."""
    if not (width > 0 and height > 0):
        raise ValueError(f"intrinsics: width and height must be > 0 pixels, got {width!r} x {height!r}.")
    if not 0 < fov_y_degrees < 180:
        raise ValueError(f"intrinsics: fov_y_degrees must lie in (0, 180), got {fov_y_degrees!r}.")
    f = 0.5 * height / np.tan(0.5 * np.radians(fov_y_degrees))
    return np.array([[f, 0.0, 0.5 * width], [0.0, f, 0.5 * height], [0.0, 0.0, 1.0]])


def look_at(eye, target, up=(0.0, 1.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """World-to-camera (R, t) of a camera at `eye` (..., 3) looking at `target` (..., 3)."""
    eye, target = np.asarray(eye, np.float64), np.asarray(target, np.float64)
    if not (np.isfinite(eye).all() and np.isfinite(target).all()):
        raise ValueError("look_at: eye and target must be finite (x, y, z) points.")
    forward = target - eye
    if np.any(np.linalg.norm(forward, axis=-1) < 1e-12):
        raise ValueError("look_at: eye and target are the same point; the camera has no viewing direction.")
    forward = forward / np.linalg.norm(forward, axis=-1, keepdims=True)
    right = np.cross(forward, np.broadcast_to(np.asarray(up, np.float64), forward.shape))
    norm = np.linalg.norm(right, axis=-1, keepdims=True)
    if np.any(norm < 1e-9):
        raise ValueError("look_at: the viewing direction is parallel to `up`; pick another up.")
    right = right / norm
    down = np.cross(forward, right)
    R = np.stack([right, down, forward], -2)
    t = -np.einsum("...ab,...b->...a", R, eye)
    return R, t


def project(K: Array, R: Array, t: Array, points: Array) -> tuple[Array, Array]:
    """Pixels and depths of world points (eq. 4.4).

    Args:
        K: (..., 3, 3); R: (..., 3, 3); t: (..., 3) world-to-camera; points: (..., N, 3);
        leading axes broadcast (e.g. K, R (V, 1, 3, 3) against points (T, N, 3)).
    Returns:
        uv (..., N, 2) pixel coordinates (pixel centres at integer + 0.5) and depth
        z^c (..., N); points behind the camera get z <= 0 and meaningless uv.
    """
    pc = jnp.einsum("...ab,...nb->...na", R, points) + t[..., None, :]
    z = pc[..., 2]
    safe = jnp.where(jnp.abs(z) < 1e-9, 1e-9, z)
    xy = pc[..., :2] / safe[..., None]
    uv = jnp.einsum("...ab,...nb->...na", K[..., :2, :2], xy) + K[..., None, :2, 2]
    return uv, z


def camera_centers(R, t) -> np.ndarray:
    """Camera centres -Rᵀ t in the world frame: (..., 3)."""
    return -np.einsum("...ba,...b->...a", np.asarray(R), np.asarray(t))


def ring_cameras(
    num_views: int, radius: float, height: float, target, start_angle: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Static views evenly spaced on a horizontal circle around `target`, looking at it.

    Returns (R (C, 3, 3), t (C, 3)); view 0 sits on +z (in front of a body facing +z).
    """
    target = np.asarray(target, np.float64)
    angles = start_angle + 2 * np.pi * np.arange(num_views) / num_views
    eyes = target + np.stack(
        [radius * np.sin(angles), np.full(num_views, height - target[1]), radius * np.cos(angles)], -1
    )
    return look_at(eyes, np.broadcast_to(target, eyes.shape))


# ------------------------------------------------------- lens distortion (host NumPy, OpenCV)
# Real calibrations (jaxmocap.formats) carry OpenCV's Brown-Conrady model on normalised
# coordinates x = (x_c / z_c, y_c / z_c), r² = x² + y²:
#   x_d = x (1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p1 x y + p2 (r² + 2 x²)
#   y_d = y (1 + k1 r² + k2 r⁴ + k3 r⁶) + p1 (r² + 2 y²) + 2 p2 x y
# Fitting works on undistorted pixels, so detections are undistorted once, up front.


def _dist5(dist) -> np.ndarray:
    d = np.asarray(dist, np.float64).reshape(-1)
    if d.size not in (0, 4, 5):
        raise ValueError(f"dist must hold 4 or 5 OpenCV coefficients (k1, k2, p1, p2[, k3]); got {d.size}.")
    return np.concatenate([d, np.zeros(5 - d.size)])


def distort_points(xy, dist) -> np.ndarray:
    """Normalised image coordinates (..., 2) -> distorted normalised coordinates (OpenCV model)."""
    xy = np.asarray(xy, np.float64)
    k1, k2, p1, p2, k3 = _dist5(dist)
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    x_d = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    y_d = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([x_d, y_d], -1)


def _distort_jacobian(x, y, d) -> np.ndarray:
    """∂(x_d, y_d)/∂(x, y): (..., 2, 2)."""
    k1, k2, p1, p2, k3 = d
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    dradial = k1 + r2 * (2 * k2 + 3 * k3 * r2)  # d radial / d r²
    dxdx = radial + 2 * x * x * dradial + 2 * p1 * y + 6 * p2 * x
    dxdy = 2 * x * y * dradial + 2 * p1 * x + 2 * p2 * y
    dydx = 2 * x * y * dradial + 2 * p1 * x + 2 * p2 * y
    dydy = radial + 2 * y * y * dradial + 6 * p1 * y + 2 * p2 * x
    return np.stack([np.stack([dxdx, dxdy], -1), np.stack([dydx, dydy], -1)], -2)


def undistort_pixels(uv, K, dist, iterations: int = 20) -> np.ndarray:
    """Distorted pixels (..., 2) -> ideal pinhole pixels under the same K.

    The inverse of `distort_points` between K's pixels, like ``cv2.undistortPoints(uv, K,
    dist, P=K)`` but solved by Newton's method (OpenCV's fixed-point loop stops at ~1e-3 px
    on strong lenses): converges to ~1e-10 px inside the image. Pixels the lens model
    cannot map back (beyond the fold of a strongly distorting model) come out NaN.
    """
    uv = np.asarray(uv, np.float64)
    K = np.asarray(K, np.float64)
    d = _dist5(dist)
    if not np.any(d):
        return uv.copy()
    # normalised distorted coordinates: solve K [x, y, 1]ᵀ = [u, v, 1]ᵀ (K upper triangular)
    yd = (uv[..., 1] - K[1, 2]) / K[1, 1]
    xd = (uv[..., 0] - K[0, 2] - K[0, 1] * yd) / K[0, 0]
    target = np.stack([xd, yd], -1)
    xy = target.copy()
    for _ in range(iterations):
        residual = distort_points(xy, d) - target
        J = _distort_jacobian(xy[..., 0], xy[..., 1], d)
        det = J[..., 0, 0] * J[..., 1, 1] - J[..., 0, 1] * J[..., 1, 0]
        det = np.where(np.abs(det) < 1e-12, 1e-12, det)
        step = np.stack(
            [J[..., 1, 1] * residual[..., 0] - J[..., 0, 1] * residual[..., 1],
             -J[..., 1, 0] * residual[..., 0] + J[..., 0, 0] * residual[..., 1]], -1
        ) / det[..., None]  # fmt: skip
        xy = xy - step
        if np.all(np.abs(step) < 1e-15):
            break
    ok = np.all(np.abs(distort_points(xy, d) - target) < 1e-9, -1)
    xy = np.where(ok[..., None], xy, np.nan)
    return to_pixels(K, xy)


def to_pixels(K, xy):
    """K applied to normalised coordinates (..., 2) -> pixels (..., 2)."""
    u = K[0, 0] * xy[..., 0] + K[0, 1] * xy[..., 1] + K[0, 2]
    return np.stack([u, K[1, 1] * xy[..., 1] + K[1, 2]], -1)


def project_points(K, dist, R, t, points) -> tuple[np.ndarray, np.ndarray]:
    """Distorted pixels and depths of world points (..., 3) in a calibrated camera (NumPy).

    K (3, 3), dist (5,) OpenCV, R (3, 3), t (3,) world-to-camera. Returns uv (..., 2) and
    z (...); points with z <= 0 are behind the camera and their uv is meaningless.
    """
    points = np.asarray(points, np.float64)
    pc = points @ np.asarray(R, np.float64).T + np.asarray(t, np.float64)
    z = pc[..., 2]
    safe = np.where(np.abs(z) < 1e-12, 1e-12, z)
    xy = distort_points(pc[..., :2] / safe[..., None], dist)
    K = np.asarray(K, np.float64)
    return to_pixels(K, xy), z


def pinhole_camera(calibrated) -> Camera:
    """jaxmocap's `Camera` of a real calibration (`jaxmocap.formats.CalibratedCamera`).

    Pixel conventions differ by half a pixel: OpenCV, OpenPose and the calibration files
    put pixel centres at integers, jaxmocap's `project` and rasteriser at integer + 0.5.
    The principal point is shifted by +0.5 so that projecting with this camera lands on
    the detection's pixel + 0.5; compare it with `uv + 0.5` of undistorted detections
    (`jaxmocap.geometry.triangulation.select_person`). The lens distortion is not part of
    `Camera`: work with undistorted pixels.
    """
    if calibrated.width <= 0:
        raise ValueError(
            f"camera {calibrated.name!r}: the calibration gives no image size; "
            "set it with dataclasses.replace(camera, width=..., height=...)."
        )
    K = np.array(calibrated.K, np.float64)
    K[:2, 2] += 0.5
    R, t = jnp.asarray(calibrated.R), jnp.asarray(calibrated.t)
    return Camera(K=jnp.asarray(K), R=R, t=t, width=calibrated.width, height=calibrated.height)
