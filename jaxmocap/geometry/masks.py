"""InterCap's temporal selection rule for object masks (Huang §5.2.2).

InterCap segments the object in every view with an instance segmenter that returns several
masks of plausible classes; the object's mask is the candidate with the largest overlap
ratio (IoU) with the reference mask, the previous frame's fit rendered into the view.
Simulated candidates come from `jaxmocap.sensors.segmentation.object_candidates`.
"""

from __future__ import annotations

import numpy as np

__all__ = ["select_candidate"]


def select_candidate(candidates: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """InterCap's rule (Huang §5.2.2): per view the candidate with the largest overlap ratio
    (IoU, |c ∩ r| / |c ∪ r|) with the reference, the previous frame's fit rendered into it.

    Args:
        candidates: (V, K, H, W) bool masks of one frame; reference: (V, H, W) bool.
    Returns:
        (V,) int candidate index per view; -1 where no candidate overlaps the reference
        (or the reference is empty).
    """
    candidates, reference = np.asarray(candidates), np.asarray(reference)
    if candidates.dtype != bool or candidates.ndim != 4:
        raise ValueError(f"candidates must be (V, K, H, W) bool masks, got {candidates.dtype} {candidates.shape}.")
    if reference.dtype != bool or reference.shape != (candidates.shape[0], *candidates.shape[2:]):
        raise ValueError(
            f"reference must be (V, H, W) = {(candidates.shape[0], *candidates.shape[2:])} bool masks, "
            f"got {reference.dtype} {reference.shape}."
        )
    ref = reference[:, None]
    inter = np.count_nonzero(candidates & ref, axis=(-1, -2))
    union = np.count_nonzero(candidates | ref, axis=(-1, -2))
    iou = inter / np.maximum(union, 1)
    best = np.argmax(iou, 1)
    return np.where(iou.max(1) > 0, best, -1) if iou.shape[1] else np.full(len(iou), -1)
