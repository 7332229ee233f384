"""Points on the body's rest mesh: the rest joints and the skin vertex straight out from a point.

Shared by the keypoint regressors (`keypoints`) and the virtual IMU placements
(`jaxmocap.sensors.imu`), which pick face, foot and sensor vertices with `ray_vertex`.
"""

from __future__ import annotations

import numpy as np

from ..body.model import Body

__all__ = ["ray_vertex", "rest_joints"]


def ray_vertex(body: Body, point, direction, bone: int) -> int:
    """The rest-mesh vertex skinned mostly to `bone` nearest to the ray point + s·direction, s > 0.

    Candidates: skinning weight ≥ 0.5 for `bone`; fallbacks: argmax weight = bone, then
    any weight > 0. Deterministic (ties resolve to the lowest index).
    """
    v = np.asarray(body.v_template, np.float64)
    w = np.asarray(body.weights, np.float64)
    d = np.asarray(direction, np.float64)
    d = d / np.linalg.norm(d)
    rel = v - np.asarray(point, np.float64)
    along = rel @ d
    dist = np.linalg.norm(rel - along[:, None] * d, axis=1)
    for candidates in (w[:, bone] >= 0.5, w.argmax(1) == bone, w[:, bone] > 0.0):
        ok = candidates & (along > 0)
        if ok.any():
            return int(np.flatnonzero(ok)[np.argmin(dist[ok])])
    raise ValueError(f"No vertex of this body is skinned to joint {bone}.")


def rest_joints(body: Body) -> np.ndarray:
    """Rest joints 𝒥 T̄ of the mean shape, (J, 3) NumPy float64."""
    return np.asarray(body.J_regressor, np.float64) @ np.asarray(body.v_template, np.float64)
