"""Simulated object segmentation candidates for InterCap (Huang §5.2.2).

InterCap segments the object in every view with an instance segmenter (PointRend) that
returns several masks of plausible classes; the object's mask is the candidate with the
largest overlap ratio with the rendering of the previous frame's fit (Huang §5.2.2).

`object_candidates` simulates that segmenter from a scenario's label images: per frame
and view K = 1 + num_distractors masks in random order,

  - the object's visible mask (labels == object_label) with mask errors: its boundary
    moved in or out by up to `error_px` pixels (erosion / dilation) and a few small holes.
    The boundary error shrinks for small masks so that the corrupted mask keeps IoU >= 0.7
    with the clean one (a segmenter that finds a 5-pixel object does not double it);
  - distractors: other objects, an ellipse or a copy of the object's shape of similar area,
    placed per view where the object never is (they are static scene objects, so they
    persist over frames with 1 px jitter and their own mask errors), re-placed in a frame
    where they would still overlap the object (IoU > 0.1);
  - with probability `miss_rate`, and wherever the object has no pixels, the object's
    candidate is an empty mask and its index is -1.

The selection rule that reads these candidates is `jaxmocap.geometry.masks.select_candidate`.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

# Lived here until the geometry split; the alias goes in the next release.
from ..geometry.masks import select_candidate as select_candidate

__all__ = ["object_candidates"]

_MIN_IOU = 0.7  # smallest IoU of a corrupted true mask with the clean one (before holes)
_MAX_DISTRACTOR_IOU = 0.1  # distractors overlap the object less than this
_PLACEMENT_TRIES = 32


def _int(name, value, low):
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        raise ValueError(f"{name} must be an int >= {low}, got {value!r}.")
    return int(value)


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    union = np.count_nonzero(a | b)
    return np.count_nonzero(a & b) / union if union else 0.0


def _bbox(mask: np.ndarray, pad: int = 0):
    """Row and column slices of the mask's bounding box grown by `pad` (clipped)."""
    rows, cols = np.flatnonzero(mask.any(1)), np.flatnonzero(mask.any(0))
    H, W = mask.shape
    return (slice(max(rows[0] - pad, 0), min(rows[-1] + 1 + pad, H)),
            slice(max(cols[0] - pad, 0), min(cols[-1] + 1 + pad, W)))  # fmt: skip


def _mask_error(mask: np.ndarray, rng: np.random.Generator, error_px: int) -> np.ndarray:
    """The mask with its boundary moved by up to `error_px` pixels and a few 5-pixel holes."""
    area = np.count_nonzero(mask)
    if area == 0:
        return mask.copy()
    radius = int(rng.integers(0, error_px + 1))
    grow = rng.random() < 0.5
    box = _bbox(mask, error_px + 1)
    crop = mask[box]
    out = crop
    for r in range(radius, 0, -1):  # the largest error that keeps IoU >= _MIN_IOU
        op = ndimage.binary_dilation if grow else ndimage.binary_erosion
        cand = op(crop, iterations=r)
        n = np.count_nonzero(cand)
        if min(n, area) >= _MIN_IOU * max(n, area):
            out = cand
            break
    out = out.copy()
    # Holes (3 x 3 crosses, 5 px) take at most 5 % of the area: speckle, not a cut-out.
    holes = min(int(rng.integers(0, 4)), int(0.05 * area) // 5)
    if holes:
        rows, cols = np.nonzero(out)
        for i in rng.choice(len(rows), holes, replace=False):
            r, c = rows[i], cols[i]
            out[r, max(c - 1, 0) : c + 2] = False
            out[max(r - 1, 0) : r + 2, c] = False
    full = np.zeros_like(mask)
    full[box] = out
    return full


def _ellipse(rng: np.random.Generator, area: float) -> np.ndarray:
    """A filled ellipse of about `area` pixels, random aspect and orientation (its crop)."""
    aspect = rng.uniform(0.4, 1.0)
    a = np.sqrt(max(area, 4.0) / (np.pi * aspect))
    b, phi = a * aspect, rng.uniform(0, np.pi)
    n = int(np.ceil(a)) + 1
    y, x = np.mgrid[-n : n + 1, -n : n + 1] + 0.0
    u, v = x * np.cos(phi) + y * np.sin(phi), -x * np.sin(phi) + y * np.cos(phi)
    shape = (u / a) ** 2 + (v / b) ** 2 <= 1.0
    return shape[_bbox(shape)]


def _stamp(shape: np.ndarray, top: int, left: int, H: int, W: int) -> np.ndarray:
    """An (H, W) mask with `shape` at (top, left), clipped at the image border."""
    out = np.zeros((H, W), bool)
    h, w = shape.shape
    r0, c0 = max(top, 0), max(left, 0)
    r1, c1 = min(top + h, H), min(left + w, W)
    if r0 < r1 and c0 < c1:
        out[r0:r1, c0:c1] = shape[r0 - top : r1 - top, c0 - left : c1 - left]
    return out


def _place(rng, shape, avoid, H, W):
    """(top, left) of `shape` inside the image overlapping `avoid` least (random tries)."""
    h, w = shape.shape
    best, best_overlap = (0, 0), np.inf
    for _ in range(_PLACEMENT_TRIES):
        top = int(rng.integers(0, max(H - h, 0) + 1))
        left = int(rng.integers(0, max(W - w, 0) + 1))
        overlap = np.count_nonzero(shape[: H - top, : W - left] & avoid[top : top + h, left : left + w])
        if overlap < best_overlap:
            best, best_overlap = (top, left), overlap
            if overlap == 0:
                break
    return best


def object_candidates(
    labels: np.ndarray,
    object_label: int,
    rng: np.random.Generator,
    num_distractors: int = 2,
    error_px: int = 2,
    miss_rate: float = 0.05,
) -> tuple[np.ndarray, np.ndarray]:
    """Simulated instance-segmenter masks of one sequence (see the module docstring).

    Args:
        labels: (V, T, H, W) label images of one sequence, as in a scenario's
            `sequence(i)["labels"]` (views first).
        object_label: the object's label (the number of people P in a scenario).
        rng: NumPy generator (or a seed); the only source of randomness.
        num_distractors: distractor masks per frame and view.
        error_px: largest boundary error of a mask (pixels).
        miss_rate: probability that the segmenter misses the object in a frame and view.
    Returns:
        candidates (T, V, K, H, W) bool with K = 1 + num_distractors, and true_index
        (T, V) int: the slot of the object's mask, -1 where it is missed or not visible.
    """
    labels = np.asarray(labels)
    if labels.ndim != 4 or not np.issubdtype(labels.dtype, np.integer):
        raise ValueError(f"labels must be (V, T, H, W) integer label images, got {labels.dtype} {labels.shape}.")
    if isinstance(object_label, bool) or not isinstance(object_label, (int, np.integer)) or object_label < 0:
        raise ValueError(f"object_label must be an int >= 0 (the number of people), got {object_label!r}.")
    num_distractors = _int("num_distractors", num_distractors, 0)
    error_px = _int("error_px", error_px, 0)
    if not (np.isscalar(miss_rate) and 0.0 <= float(miss_rate) <= 1.0):
        raise ValueError(f"miss_rate must be a probability in [0, 1], got {miss_rate!r}.")
    if rng is None:
        raise ValueError("rng must be a numpy Generator or a seed (None would not be reproducible).")
    rng = np.random.default_rng(rng)
    V, T, H, W = labels.shape
    K = 1 + num_distractors
    clean = labels == object_label
    areas = clean.sum((-1, -2))  # (V, T)
    typical = float(np.median(areas[areas > 0])) if np.any(areas > 0) else 0.01 * H * W
    candidates = np.zeros((T, V, K, H, W), bool)
    true_index = np.full((T, V), -1, int)
    for v in range(V):
        seen = np.flatnonzero(areas[v] > 0)
        swept = clean[v].any(0)  # everywhere the object is in this view
        shapes, anchors = [], []
        for _ in range(num_distractors):
            if len(seen) and rng.random() < 0.5:  # another object of the same kind
                frame = clean[v, seen[rng.integers(len(seen))]]
                shape = frame[_bbox(frame)]
            else:
                shape = _ellipse(rng, typical * rng.uniform(0.5, 1.5))
            shapes.append(shape)
            anchors.append(_place(rng, shape, swept, H, W))
        for t in range(T):
            masks = [np.zeros((H, W), bool)]
            if areas[v, t] > 0 and rng.random() >= miss_rate:
                masks[0] = _mask_error(clean[v, t], rng, error_px)
            found = masks[0].any()
            for shape, (top, left) in zip(shapes, anchors):
                top, left = top + int(rng.integers(-1, 2)), left + int(rng.integers(-1, 2))
                mask = _stamp(shape, top, left, H, W)
                if _iou(mask, clean[v, t]) > _MAX_DISTRACTOR_IOU:  # the object moved onto it
                    mask = _stamp(shape, *_place(rng, shape, clean[v, t], H, W), H, W)
                masks.append(_mask_error(mask, rng, error_px))
            order = rng.permutation(K)  # slot k holds masks[order[k]]
            candidates[t, v] = np.stack(masks)[order]
            if found:
                true_index[t, v] = int(np.flatnonzero(order == 0)[0])
    return candidates, true_index
