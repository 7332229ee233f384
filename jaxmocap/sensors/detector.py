"""A simulated 2D keypoint detector: detections of projected keypoints with OpenPose-like errors.

`DetectorErrorModel` and `detect`: per view and frame, every person's
keypoints get pixel noise, confidences that fall with the error, missed joints (and all
joints outside the image), uniform outliers inside the person's box, left/right swaps
over runs of frames (separately for arms, legs and face), missed people, and distractor
detections (human-shaped false positives). Output is padded per frame with the identity
of each detection (-1: distractor) kept for evaluating association (von Marcard §4.3.2).

The keypoint layouts and their regressors on the body are `jaxmocap.geometry.keypoints`.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .._checks import check_non_negative_fields
from ..geometry.keypoints import flip_pairs

__all__ = ["DetectorErrorModel", "Detections", "detect", "person_track"]


@dataclasses.dataclass(frozen=True)
class DetectorErrorModel:
    """Errors of a 2D keypoint detector (OpenPose-like); 0 switches an error off.

    pixel_noise: std of Gaussian pixel noise per coordinate (px).
    confidence_mean / confidence_std: confidence of a correct detection.
    miss_rate: probability that a keypoint is not detected (conf 0, uv 0).
    outlier_rate: probability that a keypoint lands anywhere in the person's box.
    swap_rate / swap_length: probability per frame that a left/right swap run starts
        (per person, view and group: arms, legs, face) and its mean length in frames.
    person_miss_rate: probability that a whole person is not detected in a frame.
    distractor_rate: mean number of distractor detections per frame (Poisson).
    max_distractors: cap per frame (fixes the padded detection count).
    """

    pixel_noise: float = 0.0
    confidence_mean: float = 0.9
    confidence_std: float = 0.0
    miss_rate: float = 0.0
    outlier_rate: float = 0.0
    swap_rate: float = 0.0
    swap_length: float = 10.0
    person_miss_rate: float = 0.0
    distractor_rate: float = 0.0
    max_distractors: int = 2

    def __post_init__(self):
        check_non_negative_fields(self)
        for name in ("confidence_mean", "miss_rate", "outlier_rate", "swap_rate", "person_miss_rate"):
            if getattr(self, name) > 1:
                raise ValueError(f"DetectorErrorModel.{name} is a probability in [0, 1], got {getattr(self, name)!r}.")
        if not isinstance(self.max_distractors, (int, np.integer)):
            raise ValueError(f"DetectorErrorModel.max_distractors must be an int >= 0, got {self.max_distractors!r}.")

    @classmethod
    def off(cls) -> DetectorErrorModel:
        return cls(confidence_mean=1.0, max_distractors=0)

    @classmethod
    def openpose(cls) -> DetectorErrorModel:
        """Plausible OpenPose-like errors at ~1000 px person height scaled to our images.

        Values chosen to give the failure modes von Marcard §4.2.5 / fig. 4.4 and Huang
        §4.3 describe (noise of a few px, occasional misses and outliers, left/right
        swaps over runs of frames, false positives), not measured statistics.
        """
        return cls(
            pixel_noise=1.5, confidence_mean=0.8, confidence_std=0.1, miss_rate=0.03,
            outlier_rate=0.01, swap_rate=0.01, swap_length=8.0, person_miss_rate=0.01,
            distractor_rate=0.3, max_distractors=2,
        )  # fmt: skip


@dataclasses.dataclass(frozen=True)
class Detections:
    """Detections of one view: (T, D, K, 3) rows (u, v, confidence), padded with zeros.

    person: (T, D) the true person index of each detection, -1 for distractors and -2
    for padding; swapped: (T, D, K) whether that keypoint is a left/right swap.
    """

    keypoints: np.ndarray
    person: np.ndarray
    swapped: np.ndarray


def _runs(rng, T, rate, length):
    on = np.zeros(T, bool)
    if rate <= 0:
        return on
    for t in np.flatnonzero(rng.random(T) < rate):
        on[t : t + rng.geometric(1.0 / length)] = True
    return on


def _groups(names):
    pairs = flip_pairs(names)
    group = {"arms": [], "legs": [], "face": []}
    for a, b in pairs:
        n = names[a]
        g = (
            "face"
            if ("eye" in n or "ear" in n)
            else "arms"
            if any(s in n for s in ("shoulder", "elbow", "wrist"))
            else "legs"
        )
        group[g].append((a, b))
    return group


def detect(
    keypoints_2d: np.ndarray,
    depth: np.ndarray,
    width: int,
    height: int,
    names: tuple[str, ...],
    model: DetectorErrorModel,
    rng: np.random.Generator,
) -> Detections:
    """Simulated detector output of one view.

    Args:
        keypoints_2d: (P, T, K, 2) true projections of P people.
        depth: (P, T, K) camera depths (keypoints with depth <= 0 are not seen).
        width, height: image size; names: keypoint names (for left/right pairs).
        model: the error model; rng: NumPy generator.
    Returns:
        Detections with D = P + model.max_distractors slots per frame.
    """
    P, T, K, _ = keypoints_2d.shape
    D = P + model.max_distractors
    out = np.zeros((T, D, K, 3))
    person = np.full((T, D), -2, int)
    swapped_out = np.zeros((T, D, K), bool)
    groups = _groups(names)
    dets, ids, swaps = [[] for _ in range(T)], [[] for _ in range(T)], [[] for _ in range(T)]
    for p in range(P):
        uv = keypoints_2d[p].copy()
        swapped = np.zeros((T, K), bool)
        for pairs in groups.values():
            on = _runs(rng, T, model.swap_rate, model.swap_length)
            for a, b in pairs:
                uv[on, a], uv[on, b] = keypoints_2d[p][on, b], keypoints_2d[p][on, a]
                swapped[on, a] = swapped[on, b] = True
        noise = rng.normal(scale=model.pixel_noise, size=uv.shape) if model.pixel_noise > 0 else 0.0
        uv = uv + noise
        conf = model.confidence_mean + (
            rng.normal(scale=model.confidence_std, size=(T, K)) if model.confidence_std > 0 else 0.0
        )
        lo, hi = keypoints_2d[p].min(1), keypoints_2d[p].max(1)  # (T, 2) person box
        outlier = rng.random((T, K)) < model.outlier_rate
        box = lo[:, None] + rng.random((T, K, 2)) * (hi - lo)[:, None]
        uv = np.where(outlier[..., None], box, uv)
        conf = np.where(outlier, rng.uniform(0.1, 0.6, (T, K)), conf)
        inside = (
            (depth[p] > 0)
            & (keypoints_2d[p][..., 0] >= 0) & (keypoints_2d[p][..., 0] < width)
            & (keypoints_2d[p][..., 1] >= 0) & (keypoints_2d[p][..., 1] < height)
        )  # fmt: skip
        missed = (rng.random((T, K)) < model.miss_rate) | ~inside
        conf = np.where(missed, 0.0, np.clip(conf, 0.05, 1.0))
        uv = np.where(missed[..., None], 0.0, uv)
        person_missed = (rng.random(T) < model.person_miss_rate) | (inside.sum(1) < 3)
        for t in np.flatnonzero(~person_missed):
            dets[t].append(np.concatenate([uv[t], conf[t][:, None]], -1))
            ids[t].append(p)
            swaps[t].append(swapped[t] & ~missed[t])
    if model.max_distractors > 0 and model.distractor_rate > 0:
        counts = np.minimum(rng.poisson(model.distractor_rate, T), model.max_distractors)
        for t in np.flatnonzero(counts):
            for _ in range(counts[t]):
                src = keypoints_2d[rng.integers(P), rng.integers(T)]
                centre = src.mean(0)
                scale = rng.uniform(0.4, 1.0)
                where = rng.uniform([0, 0], [width, height])
                uv = (src - centre) * scale + where
                conf = rng.uniform(0.05, 0.6, K) * (rng.random(K) > 0.3)
                uv = np.where(conf[:, None] > 0, uv, 0.0)
                dets[t].append(np.concatenate([uv, conf[:, None]], -1))
                ids[t].append(-1)
                swaps[t].append(np.zeros(K, bool))
    for t in range(T):
        order = rng.permutation(len(dets[t]))
        for slot, i in enumerate(order):
            out[t, slot], person[t, slot], swapped_out[t, slot] = dets[t][i], ids[t][i], swaps[t][i]
    return Detections(keypoints=out, person=person, swapped=swapped_out)


def person_track(keypoints: np.ndarray, person: np.ndarray, who: int = 0, extra: np.ndarray | None = None):
    """One simulated person's detections by the simulator's identity labels.

    keypoints: (V, T, D, K, 3) and person: (V, T, D) as in a scenario's `det_keypoints` /
    `det_person`. Returns (T, V, K, 3) (zeros where the person was not detected) and,
    if `extra` (V, T, D, ...) is given (e.g. `det_swapped`), its rows for that person too.
    """
    V, T = person.shape[:2]
    hit = person == who  # (V, T, D)
    slot = np.argmax(hit, -1)  # first matching slot (0 if none; masked below)
    found = hit.any(-1)

    def take(a):  # a[v, t, slot[v, t]], zero where the person was not detected
        tail = (1,) * (a.ndim - 3)
        rows = np.take_along_axis(a, slot.reshape(V, T, 1, *tail), 2)[:, :, 0]
        return np.where(found.reshape(V, T, *tail), rows, 0)

    out = np.swapaxes(take(keypoints), 0, 1)
    return out if extra is None else (out, np.swapaxes(take(extra), 0, 1))
