"""Plausibility statistics: penetration, floating, foot contact, skating, contact heat maps.

Per-frame quantities come from two sources and are reported side by side:
- capsules through MJX (`checker.check`): ground, object and foot distances per bone;
- the skinned mesh itself: the exact signed distance of every vertex to the plane.

Per sequence, following Huang §5.4 (GRAB's protocol): "contact frames" are frames with at
least minimal contact (lowest point within 4.5 mm of the surface, or below it); report the
fraction of contact frames whose penetration exceeds 5, 7, 10 and 20 mm, and the mean
penetration over contact frames. Contact heat maps threshold per-vertex distances at
4.5 mm and average the binary maps over frames.
"""

from __future__ import annotations

import numpy as np

from ..body.model import SMPL_FEET
from .checker import Scene
from .mjcf import Ground

__all__ = [
    "CONTACT_THRESHOLD",
    "PENETRATION_THRESHOLDS",
    "bone_min_distance",
    "foot_contact",
    "foot_skating",
    "penetration_summary",
    "contact_heatmap",
]

#: Distance (m) below which a vertex or geom counts as in contact (Huang §5.4: 4.5 mm).
CONTACT_THRESHOLD = 0.0045
#: Penetration depths (m) whose exceedance fractions are reported (Huang §5.4).
PENETRATION_THRESHOLDS = (0.005, 0.007, 0.010, 0.020)
#: Foot points whose skating is measured: heels (ankle bones) and toes (foot bones).


def bone_min_distance(scene: Scene, distances, bones=SMPL_FEET) -> np.ndarray:
    """Minimum over each bone's capsules of per-capsule distances (..., K) -> (..., len(bones))."""
    distances = np.asarray(distances)
    out = []
    for name in bones:
        ks = scene.capsules_of(name)
        if not ks:
            raise ValueError(f"bone {name!r} has no collision capsule in this scene.")
        out.append(distances[..., ks].min(-1))
    return np.stack(out, -1)


def foot_contact(foot_heights, height: float = 0.02) -> np.ndarray:
    """Feet in contact: (..., F) foot heights above the ground (m) -> (..., F) bool.

    A foot point is in contact when its lowest capsule is within `height` of the floor
    (or below it). 2 cm by default: mocap feet hover a few mm to 1 cm over the floor
    during stance (soft soles, marker offsets); the 4.5 mm of the mesh heat maps would
    call most stance frames airborne.
    """
    return np.asarray(foot_heights) < height


def foot_skating(foot_positions, contact, ground: Ground, fps: float) -> np.ndarray:
    """Horizontal foot speed (m/s) between frames where the foot is in contact at both.

    Args:
        foot_positions: (T, F, 3) foot points (heel/toe joints) in the world.
        contact: (T, F) bool, from `foot_contact`.
        ground: the plane; speeds are measured in it.
        fps: frame rate.
    Returns:
        (T-1, F) speeds; NaN where the foot is not in contact at t and t+1.
    """
    p = np.asarray(foot_positions, np.float64)
    n = np.asarray(ground.normal, np.float64)
    step = np.diff(p, axis=0)
    horizontal = step - (step @ n)[..., None] * n
    speed = np.linalg.norm(horizontal, axis=-1) * fps
    both = np.asarray(contact[1:]) & np.asarray(contact[:-1])
    return np.where(both, speed, np.nan)


def penetration_summary(lowest, threshold: float = CONTACT_THRESHOLD, thresholds=PENETRATION_THRESHOLDS) -> dict:
    """Sequence statistics of a per-frame lowest signed distance (T,) (m, < 0 = inside).

    Returns a dict (lengths in mm, fractions in [0, 1]): penetration mean/max over all
    frames, lowest-point height mean/min/max, the number of contact frames (lowest <
    `threshold`), the mean penetration over contact frames, and the fraction of
    contact frames with penetration above each of `thresholds` (`frac_above_5mm`, ...).
    """
    lowest = np.asarray(lowest, np.float64)
    pen = np.maximum(-lowest, 0.0)
    contact = lowest < threshold
    out = {
        "penetration_mean_mm": 1e3 * float(pen.mean()),
        "penetration_max_mm": 1e3 * float(pen.max()),
        "lowest_mean_mm": 1e3 * float(lowest.mean()),
        "lowest_min_mm": 1e3 * float(lowest.min()),
        "lowest_max_mm": 1e3 * float(lowest.max()),
        "contact_frames": int(contact.sum()),
        "penetration_in_contact_mean_mm": 1e3 * float(pen[contact].mean()) if contact.any() else 0.0,
    }
    for t in thresholds:
        out[f"frac_above_{1e3 * t:g}mm"] = float((pen[contact] > t).mean()) if contact.any() else 0.0
    return out


def contact_heatmap(signed_distances, threshold: float = CONTACT_THRESHOLD) -> np.ndarray:
    """Per-vertex contact frequency: (T, V) signed distances -> (V,) fraction of frames
    with distance below `threshold` (binary contact maps integrated over time, Huang §5.4)."""
    return (np.asarray(signed_distances) < threshold).mean(0)
