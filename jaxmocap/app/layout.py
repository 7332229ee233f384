"""Which keypoint layout the detections are in, told from the detections (BODY_25 vs BODY_25B).

Both OpenPose models write 25 points and the files do not say which; read under the wrong
one, "left elbow" is the right shoulder and "nose"-"right eye" spans the body. Rule:

1. the subject's points are triangulated once (confidence-weighted DLT, every view that
   sees them). The 3-D points and their reprojection errors are the same under every
   layout (only the names differ), so reprojection cannot choose; the skeleton can:
2. for each candidate layout, the lengths d_te of 22 segments named alike in every layout
   (upper and lower arms and legs, feet, shoulder and hip widths, torso sides,
   nose-eyes-ears) are compared with the body model's own l_e (rest pose, that layout's
   keypoint regressor): r_te = log(d_te / l_e) - s, with s the median over all (t, e)
   (one scale: the person's size);
3. score = median |r_te|: the typical relative error of a segment length, small only when
   the lengths stay put over time and have human proportions. The lowest score wins.

With one view there is no triangulation: 2-D lengths in pixels, one scale per frame
(foreshortening adds to every layout's score alike). Margins under noise, misses,
outliers and left/right swaps: `experiments/multiview_layout_margins.py` (the wrong
layout scores at least 2.6x the true one there; 3 px noise, 4 views: 0.04 against 0.39-0.58).
"""

from __future__ import annotations

import dataclasses

import numpy as np

__all__ = ["LayoutCheck", "SEGMENTS", "check_layout", "layout_scores"]

#: Pairs of keypoint names present in every layout with 25 points (and most in COCO-18).
SEGMENTS = tuple(
    [(f"{s}_{a}", f"{s}_{b}") for s in ("left", "right") for a, b in (
        ("shoulder", "elbow"), ("elbow", "wrist"), ("hip", "knee"), ("knee", "ankle"),
        ("ankle", "heel"), ("heel", "big_toe"), ("big_toe", "small_toe"), ("shoulder", "hip"),
        ("eye", "ear"),
    )]
    + [("left_shoulder", "right_shoulder"), ("left_hip", "right_hip"), ("nose", "left_eye"), ("nose", "right_eye")]
)  # fmt: skip
#: Fewer (frame, segment) lengths than this and the layout is not judged.
MIN_SAMPLES = 20
#: The named layout is refused when its score exceeds both of these: ABSURD_SCORE (a
#: typical segment 35 % off; the margins file: true layouts score at most 0.21, wrong ones
#: at least 0.32) and ABSURD_RATIO times the best layout's.
ABSURD_SCORE, ABSURD_RATIO = 0.3, 3.0
#: ... and warned about when its score exceeds the best's by this factor.
WARN_RATIO = 1.5


def _template(body, layout: str) -> np.ndarray:
    from ..geometry.keypoints import rest_keypoints

    return rest_keypoints(body, layout)


def layout_scores(subject, P, body, candidates) -> dict[str, float | None]:
    """Score (module docstring) of each candidate layout; None where too few lengths.

    Args:
        subject: (V, T, K, 3) the subject's (u, v, confidence) in undistorted pixels
            (`select_person`); P: (V, 3, 4) projection matrices of those pixels;
        body: the body model giving the segment lengths; candidates: layout names, all
            with K points.
    """
    from ..geometry.keypoints import KEYPOINT_FORMATS
    from ..geometry.triangulation import triangulate

    subject = np.asarray(subject, np.float64)
    V = subject.shape[0]
    conf = np.where(np.isfinite(subject[..., 2]), subject[..., 2], 0.0)
    uv = np.nan_to_num(subject[..., :2])
    if V >= 2:
        points, _ = triangulate(P, uv, conf)  # (T, K, 3), NaN with fewer than 2 views
        points = points[None]
    else:
        points = np.where(conf[..., None] > 0, uv, np.nan)  # (1, T, K, 2)
    scores: dict[str, float | None] = {}
    for layout in candidates:
        names = KEYPOINT_FORMATS[layout]
        pairs = [(names.index(a), names.index(b)) for a, b in SEGMENTS if a in names and b in names]
        i, j = np.array(pairs).T
        rest = _template(body, layout)
        length = np.linalg.norm(rest[i] - rest[j], axis=-1)  # (E,)
        d = np.linalg.norm(points[..., i, :] - points[..., j, :], axis=-1)  # (1, T, E)
        r = np.log(np.maximum(d, 1e-6) / length)
        if V == 1:  # one scale per frame: a body's distance changes its pixel size
            with np.errstate(all="ignore"):
                r = r - np.nanmedian(np.where(np.isfinite(r), r, np.nan), axis=-1, keepdims=True)
        r = r[np.isfinite(r)]
        scores[layout] = float(np.median(np.abs(r - np.median(r)))) if r.size >= MIN_SAMPLES else None
    return scores


@dataclasses.dataclass(frozen=True)
class LayoutCheck:
    """The outcome of `check_layout`. layout: the one to fit with; scores: per candidate
    (None: not judged); verdict: "detected" (none named), "confirmed", "warned"
    (named kept, though another fits clearly better), "unchecked" (one candidate or too
    little data); message: one line for the console."""

    layout: str
    scores: dict
    verdict: str
    message: str


def check_layout(subject, P, body, count: int, named: str | None = None, named_by: str = "layout") -> LayoutCheck:
    """The layout to fit `subject` with: `named` checked against the data, or the best one.

    Args:
        subject, P, body: as `layout_scores`; count: points per detection;
        named: the layout the user or the project's Config.toml gave (None: detect);
        named_by: where `named` came from, for messages ("--layout", "Config.toml").
    Raises:
        ValueError when `named` has another point count, when it fits absurdly worse
        than another layout (thresholds above), or when nothing is named and the data
        cannot decide between layouts of `count` points.
    """
    from ..formats.openpose import KEYPOINT_COUNTS

    candidates = [n for n, k in KEYPOINT_COUNTS.items() if k == count]
    if not candidates:
        raise ValueError(f"no layout has {count} keypoints (known: {KEYPOINT_COUNTS}).")
    if named is not None and named not in candidates:
        raise ValueError(
            f"{named_by} names {named!r} ({KEYPOINT_COUNTS.get(named, '?')} points), but the detections have "
            f"{count} points per person: {' or '.join(candidates)}; fix {named_by}."
        )
    if len(candidates) == 1:
        return LayoutCheck(candidates[0], {}, "unchecked", f"layout   {candidates[0]} (the only {count}-point layout)")
    scores = layout_scores(subject, P, body, candidates)
    judged = {n: s for n, s in scores.items() if s is not None}
    shown = ", ".join(f"{n} {s:.3f}" for n, s in judged.items())
    if len(judged) < len(candidates):
        if named is None:
            raise ValueError(
                f"too few detections to tell {' from '.join(candidates)} apart (the files have {count} points "
                "either way); name the OpenPose model with --layout (or pose_model in Config.toml)."
            )
        return LayoutCheck(
            named, scores, "unchecked", f"layout   {named} (from {named_by}; too few detections to check it)"
        )
    best = min(judged, key=judged.get)
    if named is None:
        return LayoutCheck(best, scores, "detected",
                           f"layout   {best}, detected from the skeleton (segment-length error {shown})")  # fmt: skip
    if named == best:
        return LayoutCheck(named, scores, "confirmed",
                           f"layout   {named} (from {named_by}; confirmed by the skeleton: {shown})")  # fmt: skip
    s_named, s_best = judged[named], judged[best]
    fix = f"pass --layout {best}" + ("" if named_by.startswith("--") else f" or correct {named_by}")
    if s_named > ABSURD_SCORE and s_named > ABSURD_RATIO * s_best:
        raise ValueError(
            f"{named_by} says the keypoints are {named}, but read so the skeleton is absurd (typical segment "
            f"length {100 * (np.exp(s_named) - 1):.0f} % off, against {100 * (np.exp(s_best) - 1):.0f} % as "
            f"{best}; scores {shown}); the detections are {best}: {fix}."
        )
    if s_named > WARN_RATIO * s_best:
        return LayoutCheck(named, scores, "warned",
                           f"warning: {named_by} says {named}, but {best} fits the skeleton clearly better ({shown}); "
                           f"fitting as {named}; check the OpenPose model ({fix}).")  # fmt: skip
    return LayoutCheck(named, scores, "confirmed", f"layout   {named} (from {named_by}; {shown})")
