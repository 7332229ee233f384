"""Triangulation of 2D detections from calibrated views, and choosing the subject across views.

Linear triangulation (Hartley & Zisserman §12.2; Hartley & Sturm's "Linear-LS"): each view
with pixel (u, v) and projection P gives two rows u P³ - P¹ and v P³ - P² of A (X, 1)ᵀ = 0,
whose residuals are the pixel errors times the point's depth in that view. Rows are
divided by the depth (from a first solve with unit rows, then once more from the
estimate), so the least-squares residuals are pixel errors, and multiplied by the
detection confidence; the 3x3 normal equations are solved in closed form for all points
at once (NumPy's batched SVD of the 2V x 4 systems alone takes twice as long: per-matrix
LAPACK calls).

`select_person` answers "which detection in each view is the subject" without trusting
OpenPose's person order (it changes from view to view and frame to frame; von Marcard
§4.3.2, Huang ch. 4): per frame, every pair of detections from two views seeds a 3D pose;
each seed collects, in every other view, the detection its projection explains best;
views that stay inconsistent are dropped; the hypothesis with the most supporting views,
then joints, then the lowest median reprojection error wins. From the second frame on,
the subject is followed rather than re-chosen: last frame's 3D pose, projected, picks one
detection per view as the first seed, and only if that hypothesis fails does the full
pairwise search run, preferring hypotheses within `max_jump` metres (median joint
distance) of last frame's pose. Work is in undistorted pixels (`undistort_pixels`),
where linear triangulation is exact.
"""

from __future__ import annotations

import numpy as np

from ..formats.calibration import CalibratedCamera
from ..formats.openpose import KeypointRecording, align_views
from .camera import undistort_pixels

__all__ = ["projection_matrices", "select_person", "triangulate", "undistort_recording"]


def projection_matrices(cameras) -> np.ndarray:
    """(V, 3, 4) projection matrices K [R | t] of calibrated cameras (undistorted pixels)."""
    cameras = list(cameras)
    if not cameras or not all(isinstance(c, CalibratedCamera) for c in cameras):
        raise ValueError("projection_matrices: give a non-empty sequence of CalibratedCamera.")
    return np.stack([c.K @ np.concatenate([c.R, c.t[:, None]], 1) for c in cameras])


def _reproject(P, X):
    """Pixels (V, ..., 2) and depths (V, ...) of points X (..., 3) under P (V, 3, 4)."""
    Xh = np.concatenate([X, np.ones(X.shape[:-1] + (1,))], -1)
    x = np.einsum("vab,...b->v...a", P, Xh)
    z = x[..., 2]
    safe = np.where(np.abs(z) < 1e-12, 1e-12, z)
    return x[..., :2] / safe[..., None], z


def triangulate(P, uv, conf, min_views: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Confidence-weighted linear triangulation of V views (module docstring).

    Args:
        P: (V, 3, 4) projection matrices (`projection_matrices`); uv: (V, ..., 2) undistorted
        pixels; conf: (V, ...) confidences (0 = not seen); min_views: views needed per point.
    Returns:
        points (..., 3), NaN where fewer than `min_views` views have conf > 0 (or the rays
        are degenerate); and the reprojection error (V, ...) in pixels of every view (also
        those with conf 0: how well that view's pixel would fit), inf where the point is
        behind that camera, NaN where the point is NaN.
    """
    P = np.asarray(P, np.float64)
    uv = np.asarray(uv, np.float64)
    conf = np.asarray(conf, np.float64)
    V = P.shape[0]
    if P.shape[1:] != (3, 4) or uv.shape[0] != V or uv.shape[-1] != 2 or conf.shape != uv.shape[:-1]:
        raise ValueError(
            f"triangulate: need P (V, 3, 4), uv (V, ..., 2), conf (V, ...); got {P.shape}, {uv.shape}, {conf.shape}."
        )
    batch = uv.shape[1:-1]
    Pb = P.reshape((V,) + (1,) * len(batch) + (3, 4))
    w = np.where(np.isfinite(uv).all(-1) & (conf > 0), conf, 0.0)
    u, v = np.nan_to_num(uv[..., 0]), np.nan_to_num(uv[..., 1])
    raw = np.stack([u[..., None] * Pb[..., 2, :] - Pb[..., 0, :], v[..., None] * Pb[..., 2, :] - Pb[..., 1, :]])
    # (2, V, ..., 4) rows; a first solve with unit rows gives the depths for the second
    unit = raw / np.maximum(np.linalg.norm(raw[..., :3], axis=-1, keepdims=True), 1e-300)
    X = _solve_rows(unit * w[..., None])
    # second pass: rows / depth of the estimate have pixel-error residuals
    depth = np.einsum("v...a,...a->v...", Pb[..., 2, :3], np.nan_to_num(X)) + Pb[..., 2, 3]
    good = np.isfinite(X).all(-1) & (depth > 1e-9)
    rows = np.where(good[..., None], raw / np.where(good, depth, 1.0)[..., None], unit)
    X = np.where(np.isfinite(X), _solve_rows(rows * w[..., None]), X)
    enough = (w > 0).sum(0) >= min_views
    X = np.where(enough[..., None], X, np.nan)
    proj, z = _reproject(P, np.nan_to_num(X))
    err = np.linalg.norm(proj - uv, axis=-1)
    err = np.where(z > 0, err, np.inf)
    err = np.where(np.isfinite(X).all(-1), err, np.nan)
    return X, err


def _solve_rows(rows):
    """Least-squares X of rows (..., 4) · (X, 1) = 0 over the two leading axes (2, V, ...)."""
    a, b = rows[..., :3], rows[..., 3]
    M = np.einsum("nv...i,nv...j->...ij", a, a)
    c = -np.einsum("nv...i,nv...->...i", a, b)
    # closed-form 3x3 solve via the adjugate (vectorised; M is symmetric)
    adj = np.stack([
        np.cross(M[..., 1, :], M[..., 2, :]),
        np.cross(M[..., 2, :], M[..., 0, :]),
        np.cross(M[..., 0, :], M[..., 1, :]),
    ], -1)  # fmt: skip
    det = np.einsum("...i,...i->...", M[..., 0, :], adj[..., :, 0])
    trace = np.einsum("...ii->...", M)
    ok = np.abs(det) > 1e-12 * np.maximum(trace, 1e-300) ** 3
    X = np.einsum("...ij,...j->...i", adj, c) / np.where(ok, det, 1.0)[..., None]
    return np.where(ok[..., None], X, np.nan)


def _masked_median(x, mask, axis=-1):
    """Median of x where mask along `axis` (inf where nothing is masked in); warning-free."""
    x = np.where(mask, x, np.inf)
    xs = np.sort(x, axis=axis)
    n = mask.sum(axis=axis, keepdims=True)
    lo = np.take_along_axis(xs, np.maximum((n - 1) // 2, 0), axis=axis)
    hi = np.take_along_axis(xs, np.maximum(n // 2, 0), axis=axis)
    med = np.squeeze(0.5 * (lo + hi), axis=axis)
    return np.where(np.squeeze(n, axis=axis) > 0, med, np.inf)


def undistort_recording(recording: KeypointRecording, cameras) -> list[np.ndarray]:
    """Per view (T, P, K, 3) detections in undistorted pixels (cameras aligned to the views).

    Keypoints with confidence 0, or that the lens model cannot map back, get (0, 0, 0).
    """
    out = []
    for kp, cam in zip(recording.keypoints, align_views(recording, cameras)):
        uv = undistort_pixels(kp[..., :2], cam.K, cam.dist)
        ok = (kp[..., 2] > 0) & np.isfinite(uv).all(-1)
        out.append(np.where(ok[..., None], np.concatenate([uv, kp[..., 2:]], -1), 0.0))
    return out


def select_person(
    recording: KeypointRecording,
    cameras,
    min_views: int = 2,
    *,
    max_error: float = 0.02,
    max_jump: float = 0.5,
    min_joints: int = 3,
) -> np.ndarray:
    """One person per view and frame, chosen by cross-view consistency (module docstring).

    Args:
        recording: `read_openpose` output; cameras: its calibration (any order; matched to
            `recording.views` by `align_views`).
        min_views: views that must agree for a frame to have a subject.
        max_error: reprojection error, as a fraction of each view's focal length, below which
            a detection (median over its joints) or a joint supports a 3D pose (0.02 ≈ 1.1°:
            30 px at f = 1500 px).
        max_jump: metres the median joint may move per frame and still count as the
            same person as the previous frame's subject.
        min_joints: confident joints two detections must share to be compared.
    Returns:
        (V, T, K, 3) the subject's (u, v, confidence) in UNDISTORTED pixels, views in
        `recording.views` order; confidence 0 in a view (and frame) whose detections are
        all inconsistent with the chosen 3D pose, and in frames where fewer than
        `min_views` views agree. With one view, the subject is followed in 2D instead:
        the most confident detection first, then the one nearest the previous choice.
    """
    cams = align_views(recording, cameras)
    dets = undistort_recording(recording, cams)
    V, T = len(cams), recording.num_frames
    K = dets[0].shape[2]
    out = np.zeros((V, T, K, 3))
    if V == 1:
        return _follow_2d(dets[0])[None]
    if not 2 <= min_views <= V:
        raise ValueError(f"select_person: min_views must be in 2..{V} with {V} views (got {min_views}).")
    P = projection_matrices(cams)
    tau = max_error * np.array([0.5 * (c.K[0, 0] + c.K[1, 1]) for c in cams])  # (V,) px
    previous, gap = None, 1
    for t in range(T):
        frame = [d[t] for d in dets]  # per view (P_v, K, 3)
        real = [np.flatnonzero((f[..., 2] > 0).sum(-1) >= min_joints) for f in frame]
        best = None
        if previous is not None:
            # Follow first: the detections near last frame's pose (with room for motion) seed
            # one hypothesis; the full search runs only when it does not hold up.
            seed = _grow(P, frame, real, 3 * tau, min_joints, previous[None])
            if (seed >= 0).sum() >= 2:
                best = _pick(
                    *_evaluate(P, frame, real, tau, min_views, min_joints, seed),
                    previous,
                    max_jump * gap,
                    True,
                )
        if best is None:
            seeds = [(a, i, b, j) for a in range(V) for b in range(a + 1, V) for i in real[a] for j in real[b]]
            if seeds:
                choice = np.full((len(seeds), V), -1)
                for s, (a, i, b, j) in enumerate(seeds):
                    choice[s, a], choice[s, b] = i, j
                evaluated = _evaluate(P, frame, real, tau, min_views, min_joints, choice)
                best = _pick(*evaluated, previous, max_jump * gap, False)
        if best is None:
            gap += 1
            continue
        choice, X = best
        for v, p in enumerate(choice):
            if p >= 0:
                out[v, t] = frame[v][p]
        previous, gap = X, 1
    return out


def _grow(P, frame, real, tau, min_joints, X):
    """Per pose X (S, K, 3), each view's detection that its projection explains best: (S, V).

    A view takes the detection with the lowest median joint error if it is below tau[v]
    and over at least `min_joints` shared joints, else none (-1).
    """
    S, V = X.shape[0], len(frame)
    proj, z = _reproject(P, np.nan_to_num(X))  # (V, S, K, 2), (V, S, K)
    known = np.isfinite(X).all(-1)  # (S, K)
    choice = np.full((S, V), -1)
    for v in range(V):
        if len(real[v]) == 0:
            continue
        cand = frame[v][real[v]]  # (C, K, 3)
        e = np.linalg.norm(proj[v][:, None] - cand[None, ..., :2], axis=-1)  # (S, C, K)
        e = np.where(z[v][:, None] > 0, e, np.inf)
        mask = known[:, None] & (cand[None, ..., 2] > 0)
        med = np.where(mask.sum(-1) >= min_joints, _masked_median(e, mask), np.inf)
        c = np.argmin(med, axis=1)
        choice[:, v] = np.where(med[np.arange(S), c] < tau[v], real[v][c], -1)
    return choice


def _evaluate(P, frame, real, tau, min_views, min_joints, choice):
    """Grow seed choices (S, V) into hypotheses and score them.

    Returns choice (S, V), X (S, K, 3), supporting views (S,), supporting joints (S,),
    median reprojection error (S,) and whether each is a valid hypothesis (S,).
    """
    S = choice.shape[0]
    X, _ = _triangulate_choice(P, frame, choice)
    # every view (the seed's own too) takes what the seed's pose explains best, so a seed
    # from a wrong pair can still grow into the right person
    choice = _grow(P, frame, real, tau, min_joints, X)
    for _ in range(2):  # re-triangulate with every view, drop views that remain inconsistent
        X, err = _triangulate_choice(P, frame, choice)
        seen = _chosen_conf(frame, choice) > 0  # (V, S, K)
        med = _masked_median(err, seen & np.isfinite(err))  # (V, S)
        choice = np.where((med.T < tau) & (choice >= 0), choice, -1)
    X, err = _triangulate_choice(P, frame, choice)
    seen = (_chosen_conf(frame, choice) > 0) & np.isfinite(err)
    views = (choice >= 0).sum(1)
    joints = (seen & (err < tau[:, None, None])).sum((0, 2))
    median = _masked_median(np.moveaxis(err, 0, 1).reshape(S, -1), np.moveaxis(seen, 0, 1).reshape(S, -1))
    ok = (views >= min_views) & (np.isfinite(X).all(-1).sum(-1) >= min_joints)
    return choice, X, views, joints, median, ok


def _pick(choice, X, views, joints, median, ok, previous, gate, near_only):
    """The best valid hypothesis: within `gate` m of `previous` if any (or if `near_only`),
    then most views, most joints, lowest median error. None if there is none."""
    if previous is not None:
        both = np.isfinite(X).all(-1) & np.isfinite(previous).all(-1)
        dist = _masked_median(np.linalg.norm(np.nan_to_num(X) - np.nan_to_num(previous), axis=-1), both)
        near = ok & (dist < gate)
        if near.any() or near_only:
            ok = near
    if not ok.any():
        return None
    order = np.lexsort((median, -joints, -views))  # the last key is the primary one
    s = next(s for s in order if ok[s])
    return choice[s], X[s]


def _chosen_conf(frame, choice):
    """(V, S, K) confidences of the chosen detections (0 where a view chose none)."""
    return np.stack([
        np.where(choice[:, v, None] >= 0, frame[v][np.maximum(choice[:, v], 0), :, 2], 0.0)
        for v in range(len(frame))
    ])  # fmt: skip


def _triangulate_choice(P, frame, choice):
    uv = np.stack([frame[v][np.maximum(choice[:, v], 0), :, :2] for v in range(len(frame))])  # (V, S, K, 2)
    return triangulate(P, uv, _chosen_conf(frame, choice))


def _follow_2d(det):
    """One view: (T, P, K, 3) -> (T, K, 3), following the most confident person in 2D."""
    T, _, K, _ = det.shape
    out = np.zeros((T, K, 3))
    last = None
    for t in range(T):
        seen = det[t, ..., 2] > 0
        if not seen.any():
            continue
        p = int(np.argmax(det[t, ..., 2].sum(-1)))
        if last is not None:
            both = seen & (last[:, 2] > 0)
            dist = _masked_median(np.linalg.norm(det[t, ..., :2] - last[:, :2], axis=-1), both)
            lo, hi = last[last[:, 2] > 0, :2].min(0), last[last[:, 2] > 0, :2].max(0)
            if np.min(dist) < 0.5 * np.linalg.norm(hi - lo) + 1.0:  # within half the box diagonal
                p = int(np.argmin(dist))
        out[t] = det[t, p]
        last = out[t]
    return out
