"""Depth cameras: per-view point clouds with visibility and noise (InterCap-style RGB-D).

From a rasterised depth image (`geometry.raster.rasterize`) every covered pixel back-projects
to p^c = z K⁻¹ (u, v, 1)ᵀ and to the world by p^g = Rᵀ (p^c - t). Noise follows the
usual time-of-flight / structured-light model: axial std σ_z = σ₀ + σ₂ z² along the
pixel ray, lateral std `lateral` (m) and a fraction of missing pixels. A fixed number of
points per view and frame is sampled (without replacement, deterministic from the rng),
padded with a mask when fewer pixels are covered.

`visible_vertices` (the vertices the z-buffer sees) is `jaxmocap.geometry.raster`.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .._checks import check_non_negative_fields
from ..geometry.raster import BACKGROUND, FLOOR

# Lived here until the geometry split; the alias goes in the next release.
from ..geometry.raster import visible_vertices as visible_vertices

__all__ = ["DepthNoiseModel", "depth_point_cloud"]


@dataclasses.dataclass(frozen=True)
class DepthNoiseModel:
    """σ_z = axial_base + axial_quadratic · z² (m), lateral std (m), missing-pixel rate.

    Defaults are Kinect-class values (≈ 2 mm at 1 m, 1.3 cm at 3 m).
    """

    axial_base: float = 0.0015
    axial_quadratic: float = 0.0013
    lateral: float = 0.002
    missing_rate: float = 0.02

    def __post_init__(self):
        check_non_negative_fields(self, " (metres or a rate)")
        if self.missing_rate > 1:
            raise ValueError(f"DepthNoiseModel.missing_rate is a probability in [0, 1], got {self.missing_rate!r}.")

    @classmethod
    def off(cls) -> DepthNoiseModel:
        return cls(0.0, 0.0, 0.0, 0.0)


def depth_point_cloud(
    K,
    R,
    t,
    depth: np.ndarray,
    label: np.ndarray,
    num_points: int,
    rng: np.random.Generator,
    noise: DepthNoiseModel = DepthNoiseModel(),
    keep_floor: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Noisy world-frame points of one view and frame.

    Args:
        K (3, 3), R (3, 3), t (3,): camera; depth (H, W) and label (H, W) from `rasterize`.
        num_points: points returned (padded); rng: NumPy generator; noise: the model.
        keep_floor: also return floor pixels (label -2).
    Returns:
        points (num_points, 3) world frame, labels (num_points,) int (-3 for padding),
        valid (num_points,) bool.
    """
    K, R, t = (np.asarray(x, np.float64) for x in (K, R, t))
    depth, label = np.asarray(depth), np.asarray(label)
    keep = np.isfinite(depth) & (label != BACKGROUND)
    if not keep_floor:
        keep &= label != FLOOR
    if noise.missing_rate > 0:
        keep &= rng.random(depth.shape) >= noise.missing_rate
    rows, cols = np.nonzero(keep)
    n = min(len(rows), num_points)
    pick = np.sort(rng.choice(len(rows), n, replace=False)) if n else np.zeros(0, int)
    rows, cols = rows[pick], cols[pick]
    z = depth[rows, cols].astype(np.float64)
    ray = np.stack([cols + 0.5, rows + 0.5, np.ones(n)], -1) @ np.linalg.inv(K).T
    if noise.axial_base > 0 or noise.axial_quadratic > 0:
        z = z + rng.normal(size=n) * (noise.axial_base + noise.axial_quadratic * z**2)
    pc = ray * z[:, None]
    if noise.lateral > 0:
        pc[:, :2] += rng.normal(scale=noise.lateral, size=(n, 2))
    points = np.zeros((num_points, 3))
    labels = np.full(num_points, -3, int)
    valid = np.zeros(num_points, bool)
    points[:n] = (pc - t) @ R  # Rᵀ (p^c - t) for row vectors
    labels[:n] = label[rows, cols]
    valid[:n] = True
    return points, labels, valid
