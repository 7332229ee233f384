"""Multi-view SMPLify (MuVS, Huang ch. 4): calibrated views, 2-D keypoints, silhouettes.

- **Stage 1, per frame** (§4.3.1): E_M = λ_θ E_θ + λ_β E_β + Σ_v E_J (eq. 4.1-4.4), every
  frame with its own pose, translation and shape, all frames solved as one batch; then
  E_1 = E_M + Σ_v E_S (eq. 4.5-4.6) from that result ("joints first, then silhouettes").
  The pose prior weight is annealed (`MuVSWeights.anneal`) during the joint fit, as in
  SMPLify, whose initialisation MuVS reuses; weights are traced, so every annealing step
  and ablation reuses one compiled solve.
- **Stage 2, temporal** (§4.3.2): β fixed to the median of the stage-1 shapes; poses and
  translations of all frames plus per-window DCT coefficients C (30-frame units, first
  10 components, §4.3.3) minimise E_2 = Σ_n E_M + λ_T Σ E_T (eq. 4.7-4.8); variant "+H"
  adds E_S here too.
- **Monocular** (Table 4.5): the same code with one view.

Left/right swaps (ours, opt-in): before stage 1, `resolve_left_right` can flip back the leg
labels of any view that disagrees with the others (2^V assignments triangulated per frame).

Initialisation (ours; MuVS reuses SMPLify's): per frame, the hips and shoulders are
triangulated from every view that sees them (confidence-weighted DLT) and give the root
position and orientation, the other joints start at the prior mean, β at 0; frames seen
by fewer than two views use one view's depth from the torso length (SMPLify's rule) and
a root facing the camera, turned round when the detected hips say the person faces away.

The problems are `jaxmocap.solve.Problem`s of the terms in `energies.camera`; nothing
here solves anything itself.
"""

from __future__ import annotations

import dataclasses
import functools
import warnings
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from ..body.kinematics import forward, shaped_joints
from ..body.model import Body
from ..energies.camera import (
    CameraData,
    Silhouettes,
    dct_coefficients,
    dct_window,
    keypoint_term,
    pose_prior_term,
    shape_term,
    silhouette_data,
    silhouette_terms,
    temporal_term,
)
from ..priors.pose_prior import PosePrior, default_pose_prior
from ..rotation import matrix_to_axis_angle
from ..sensors.keypoints import KEYPOINT_FORMATS, flip_pairs, keypoint_regressor
from ..sensors.triangulation import triangulate
from ..solve import Problem, frame, solve, solve_batch, with_weights

__all__ = ["MuVSWeights", "MuVSResult", "camera_data", "initialise", "resolve_left_right", "stage_one", "stage_two", "multiview_smplify", "mask_views", "stack"]


@dataclasses.dataclass(frozen=True)
class MuVSWeights:
    """Weights and constants of eq. 4.1-4.8 (our choices: Huang gives none; tuned on the
    CMU training clips, see experiments/muvs_tables.py). 0 switches a term off.

    keypoints: E_J weight; sigma: its Geman-McClure σ₁ (px).
    pose_prior, shape: λ_θ, λ_β; anneal: λ_θ multipliers of the stage-1 joint fit.
    silhouette_model, silhouette_mask: the two sums of E_S (eq. 4.5); silhouette_stride:
        every n-th vertex is a model point; silhouette_slack: px within which a mask
        point counts as covered by the model (`energies.camera.silhouette_terms`).
    temporal: λ_T; temporal_sigma: σ₂ (m); window, num_dct: DCT unit and basis size.
    """

    keypoints: float = 1.0
    sigma: float = 100.0
    pose_prior: float = 20.0
    shape: float = 50.0
    anneal: tuple[float, ...] = (20.0, 4.0, 1.0)
    silhouette_model: float = 0.1
    silhouette_mask: float = 0.1
    silhouette_stride: int = 2
    silhouette_slack: float = 2.0
    temporal: float = 2e5
    temporal_sigma: float = 0.05
    window: int = 30
    num_dct: int = 10
    num_betas: int = 10

    def replace(self, **changes) -> MuVSWeights:
        return dataclasses.replace(self, **changes)


@dataclasses.dataclass(frozen=True)
class MuVSResult:
    """Poses (T, 24, 3) axis-angle, trans (T, 3), betas (B,) of the final stage, the
    stage-1 outcome (`stage1`: poses, trans, per-frame betas (T, B)), and per-stage costs."""

    poses: np.ndarray
    trans: np.ndarray
    betas: np.ndarray
    stage1: dict
    costs: dict


def camera_data(
    body: Body,
    K,
    R,
    t,
    keypoints,
    layout: str = "body25",
    masks=None,
    prior: PosePrior | None = None,
    joint_weights=None,
    silhouette_points: int = 256,
    dtype=jnp.float32,
) -> CameraData:
    """`CameraData` from NumPy inputs: K, R (V, 3, 3), t (V, 3); keypoints (T, V, K, 3)
    rows (u, v, confidence) in undistorted pixels; masks (T, V, H, W) booleans or None."""
    keypoints = np.asarray(keypoints, np.float64)
    K, R, t = (np.asarray(a, np.float64) for a in (K, R, t))
    if layout not in KEYPOINT_FORMATS:
        raise ValueError(f"unknown keypoint layout {layout!r}; choose from {sorted(KEYPOINT_FORMATS)}.")
    names = KEYPOINT_FORMATS[layout]
    if keypoints.ndim != 4 or keypoints.shape[-1] != 3 or keypoints.shape[2] != len(names):
        raise ValueError(
            f"keypoints must be (T, V, {len(names)}, 3) rows (u, v, confidence) of the {layout!r} "
            f"layout; got shape {keypoints.shape}."
        )
    T, V = keypoints.shape[:2]
    if T == 0:
        raise ValueError("keypoints have no frames (T = 0).")
    if K.shape != (V, 3, 3) or R.shape != (V, 3, 3) or t.shape != (V, 3):
        raise ValueError(
            f"cameras must be K (V, 3, 3), R (V, 3, 3), t (V, 3) for the V = {V} views of the "
            f"keypoints; got {K.shape}, {R.shape}, {t.shape}."
        )
    conf = np.where(np.isfinite(keypoints).all(-1), keypoints[..., 2], 0.0).clip(0.0, None)
    uv = np.nan_to_num(keypoints[..., :2])
    sil = None
    if masks is not None:
        masks = np.asarray(masks, bool)
        if masks.shape[:2] != (T, V):
            raise ValueError(f"masks must be (T={T}, V={V}, H, W); got shape {masks.shape}.")
        sil = silhouette_data(masks, silhouette_points)
    w = np.ones(len(names)) if joint_weights is None else np.asarray(joint_weights, np.float64)
    a = lambda x: jnp.asarray(x, dtype)  # noqa: E731
    return CameraData(
        body=body.astype(dtype), prior=prior if prior is not None else default_pose_prior(dtype),
        regressor=a(keypoint_regressor(body, layout)), K=a(K), R=a(R), t=a(t), keypoints=a(uv),
        confidence=a(conf), joint_weights=a(w), betas=None, silhouettes=sil, layout=layout,
    )  # fmt: skip


def _root_frames(left, right, up_from, up_to):
    """Root rotations (T, 3, 3) with body +x towards `left`-`right`, +y along up_to-up_from."""
    x = left - right
    x = x / np.linalg.norm(x, axis=-1, keepdims=True)
    y = up_to - up_from
    y = y - np.sum(y * x, -1, keepdims=True) * x
    y = y / np.linalg.norm(y, axis=-1, keepdims=True)
    return np.stack([x, y, np.cross(x, y)], -1)


def initialise(data: CameraData, num_betas: int = 10) -> dict:
    """Starting values {pose (T, 24, 3), trans (T, 3), betas (T, B)} (module docstring);
    batched data gives a leading batch axis."""
    if _batched(data):
        each = [initialise(_member(data, i), num_betas) for i in range(data.keypoints.shape[0])]
        return {k: np.stack([e[k] for e in each]) for k in each[0]}
    body = data.body
    names = KEYPOINT_FORMATS[data.layout]
    idx = [names.index(n) for n in ("left_hip", "right_hip", "left_shoulder", "right_shoulder")]
    K, R, t = (np.asarray(a, np.float64) for a in (data.K, data.R, data.t))
    uv = np.asarray(data.keypoints, np.float64)[:, :, idx]  # (T, V, 4, 2)
    conf = np.asarray(data.confidence, np.float64)[:, :, idx]
    T, V = uv.shape[:2]
    P = K @ np.concatenate([R, t[..., None]], -1)
    X = _robust_triangulation(P, np.moveaxis(uv, 1, 0), np.moveaxis(conf, 1, 0), 0.05 * float(np.mean(K[:, 0, 0])))
    lh, rh, ls, rs = (X[:, i] for i in range(4))
    root = _root_frames(lh, rh, 0.5 * (lh + rh), 0.5 * (ls + rs))
    mid_hip = 0.5 * (lh + rh)
    valid = np.all(np.isfinite(root.reshape(T, -1)), -1) & np.all(np.isfinite(mid_hip), -1)
    if valid.sum() >= 3:  # a frame far from its neighbours' median is a bad triangulation
        with warnings.catch_warnings():  # windows without a valid frame give NaN, then False
            warnings.simplefilter("ignore", RuntimeWarning)
            med = np.stack([np.nanmedian(np.where(valid[:, None], mid_hip, np.nan)[max(0, i - 4) : i + 5], 0)
                            for i in range(T)])  # fmt: skip
        valid &= np.linalg.norm(mid_hip - med, axis=-1) < 0.3
    if valid.any():  # fill the others from the nearest good frames
        good = np.flatnonzero(valid)
        near = good[np.abs(np.arange(T)[:, None] - good[None]).argmin(1)]
        root = root[near]
        mid_hip = np.stack([np.interp(np.arange(T), good, mid_hip[good, k]) for k in range(3)], -1)
    else:
        root, mid_hip = _monocular_root(data, uv, conf)
    rest = np.asarray(shaped_joints(body, jnp.zeros((1, num_betas), body.dtype)))[0].astype(np.float64)
    lj, rj = body.joint_index("left_hip"), body.joint_index("right_hip")
    rest_mid = 0.5 * (rest[lj] + rest[rj])
    trans = mid_hip - rest[0] - np.einsum("tab,b->ta", root, rest_mid - rest[0])
    pose = np.zeros((T, body.num_joints, 3))
    pose[:, 1:] = np.asarray(data.prior.mean, np.float64).reshape(23, 3)
    pose[:, 0] = np.asarray(matrix_to_axis_angle(jnp.asarray(root)))
    return {"pose": pose, "trans": trans, "betas": np.zeros((T, num_betas))}


def resolve_left_right(data: CameraData, truncation: float = 0.05, margin: float = 0.005, max_views: int = 6) -> CameraData:
    """`data` with each view's leg keypoints swapped back where that view swapped left and right.

    Detectors confuse the legs of a person seen from the side or the back, one view at a
    time. Per frame, every assignment of the views' leg labels (as detected or swapped,
    2^V hypotheses; hips, knees, ankles and feet swap together) is triangulated and scored
    by its reprojection error, truncated at `truncation` × the mean focal length so that
    one bad point cannot dominate; the best one is kept if it beats the detections as they
    are by more than `margin` × the mean focal length of RMS error per leg point (legs
    close together reproject alike either way: no flip then).
    Our addition (MuVS leaves swaps to the robust ρ and the temporal term of stage 2):
    with two or more views a swapped view disagrees with the others, so it is cheap to
    find before any fit. Views beyond `max_views` are left as they are.
    """
    if _batched(data):
        return stack([resolve_left_right(_member(data, i), truncation, margin, max_views) for i in range(data.keypoints.shape[0])])
    names = KEYPOINT_FORMATS[data.layout]
    pairs = [(a, b) for a, b in flip_pairs(names) if not any(k in names[a] for k in ("eye", "ear", "shoulder", "elbow", "wrist"))]
    conf = np.asarray(data.confidence, np.float64)  # (T, V, K)
    seen = np.flatnonzero((conf > 0).any((0, 2)))[:max_views]
    if len(seen) < 2 or not pairs:
        return data
    K, R, t = (np.asarray(a, np.float64) for a in (data.K, data.R, data.t))
    P = (K @ np.concatenate([R, t[..., None]], -1))[seen]
    uv = np.asarray(data.keypoints, np.float64)[:, seen]  # (T, V', K, 2)
    cf = conf[:, seen]
    left, right = (np.array(x) for x in zip(*pairs))
    legs = np.concatenate([left, right])
    flips = np.array(np.meshgrid(*[[0, 1]] * len(seen), indexing="ij")).reshape(len(seen), -1).T  # (H, V')
    # uv of the leg points under every hypothesis: (V', H, T, 2L, 2)
    swapped = np.concatenate([right, left])
    u = np.stack([np.where(f[None, :, None, None] > 0, uv[:, :, swapped], uv[:, :, legs]).swapaxes(0, 1) for f in flips], 1)
    c = np.stack([np.where(f[None, :, None] > 0, cf[:, :, swapped], cf[:, :, legs]).swapaxes(0, 1) for f in flips], 1)
    X, err = triangulate(P, u, c)  # (H, T, 2L, 3), (V', H, T, 2L)
    tau = truncation * float(np.mean(K[:, 0, 0]))
    cost = np.where(c > 0, np.minimum(np.nan_to_num(err, nan=tau), tau) ** 2 * c, 0.0).sum((0, 3))  # (H, T)
    # A hypothesis and its complement (every view flipped) reproject alike: that global
    # choice of which 3-D leg is "left" is the body fit's. Between such near-ties the
    # hips on the shoulders' side decide, then fewer flips; neither can make a flip win
    # against the detections as they are by itself (both stay below the margin).
    threshold = (margin * float(np.mean(K[:, 0, 0]))) ** 2 * np.maximum((c[:, 0] > 0).sum((0, 2)), 1)  # (T,)
    sh = [names.index(n) for n in ("left_shoulder", "right_shoulder")]
    hips = [list(legs).index(names.index(n)) for n in ("left_hip", "right_hip")] if "left_hip" in names else None
    if hips is not None:
        S, _ = triangulate(P, np.moveaxis(uv[:, :, sh], 1, 0), np.moveaxis(cf[:, :, sh], 1, 0))  # (T, 2, 3)
        across = np.einsum("htk,tk->ht", X[:, :, hips[0]] - X[:, :, hips[1]], S[:, 0] - S[:, 1])
        cost = cost + 0.4 * threshold * (np.nan_to_num(across, nan=1.0) < 0)
    cost = cost + 0.1 * threshold * flips.sum(1)[:, None] / len(seen)
    choice = np.argmin(cost, 0)
    gain = cost[0] - cost[choice, np.arange(cost.shape[1])]  # hypothesis 0: no flip
    choice = np.where(gain > threshold, choice, 0)
    best = flips[choice]  # (T, V')
    kp, cn = np.asarray(data.keypoints), np.asarray(data.confidence)
    out, out_c = kp.copy(), cn.copy()
    for j, v in enumerate(seen):
        ti = np.flatnonzero(best[:, j])[:, None]
        out[ti, v, legs[None]] = kp[ti, v, swapped[None]]
        out_c[ti, v, legs[None]] = cn[ti, v, swapped[None]]
    return dataclasses_replace(data, keypoints=jnp.asarray(out, data.keypoints.dtype), confidence=jnp.asarray(out_c, data.confidence.dtype))


def _robust_triangulation(P, uv, conf, max_error: float) -> np.ndarray:
    """`triangulate`, dropping the worst view of a point while its reprojection error
    exceeds `max_error` px (a swapped or outlying detection) and two views remain."""
    conf = conf.copy()
    for _ in range(len(P) - 2):
        X, err = triangulate(P, uv, conf)
        err = np.where(conf > 0, np.nan_to_num(err, nan=np.inf), -1.0)
        worst = err.max(0)
        bad = (worst > max_error) & ((conf > 0).sum(0) > 2)
        if not bad.any():
            break
        drop = (err == worst[None]) & bad[None]
        conf = np.where(drop, 0.0, conf)
    X, _ = triangulate(P, uv, conf)
    return X


def _monocular_root(data, uv, conf, torso: float = 0.5):
    """Root rotation and mid-hip position from the most confident single view per frame
    (SMPLify's depth from the torso length; facing the camera unless the hips say not)."""
    K, R, t = (np.asarray(a, np.float64) for a in (data.K, data.R, data.t))
    n = len(uv)
    best = np.argmax(conf.sum(-1), 1)  # (n,)
    rots, mids = np.zeros((n, 3, 3)), np.zeros((n, 3))
    for i, v in enumerate(best):
        p = uv[i, v]
        hip, sho = 0.5 * (p[0] + p[1]), 0.5 * (p[2] + p[3])
        length = max(float(np.linalg.norm(sho - hip)), 1.0)
        # A foreshortened torso (bending towards the camera) would put the body kilometres
        # away: depths are kept to 1-10 m.
        depth = np.clip(K[v, 0, 0] * torso / length, 1.0, 10.0) if conf[i, v].min() > 0 else 4.0
        ray = np.linalg.solve(K[v], np.array([hip[0], hip[1], 1.0]))
        mids[i] = R[v].T @ (ray * depth - t[v])
        up = R[v].T @ np.array([0.0, -1.0, 0.0])
        forward = -R[v].T @ np.array([0.0, 0.0, 1.0])  # towards the camera
        left = np.cross(up, forward)
        rot = np.stack([left, up, forward], -1)
        if p[0, 0] < p[1, 0] and conf[i, v, :2].min() > 0:  # left hip left of right: back view
            rot = rot @ np.diag([-1.0, 1.0, -1.0])
        rots[i] = rot
    return rots, mids


# --- problems: one compiled solve each, weights traced ------------------------------------


@functools.lru_cache(maxsize=None)
def _stage_one_problem(sigma: float, stride: int, slack: float, silhouettes: bool) -> Problem:
    # Cached: a term's function is static, so a new closure would mean a new compile.
    terms = [keypoint_term(sigma), pose_prior_term(), shape_term()]
    if silhouettes:
        terms += silhouette_terms(stride=stride, slack=slack)
    return Problem(terms, {"pose": frame("so3"), "trans": frame(), "betas": frame()})


@functools.lru_cache(maxsize=None)
def _stage_two_problem(sigma: float, stride: int, slack: float, silhouettes: bool, length: int, num_dct: int,
                       temporal_sigma: float) -> Problem:
    windows = dct_window(length)
    terms = [keypoint_term(sigma), pose_prior_term(), temporal_term(windows.windows, num_dct, temporal_sigma)]
    if silhouettes:
        terms += silhouette_terms(stride=stride, slack=slack)
    return Problem(terms, {"pose": frame("so3"), "trans": frame(), "coef": windows})


def _weighted(problem: Problem, w: MuVSWeights, dtype, prior_factor: float = 1.0) -> Problem:
    """`problem` with the weights of `w` as traced arrays (no recompilation per value)."""
    values = {
        "keypoints": w.keypoints, "pose_prior": w.pose_prior * prior_factor, "shape": w.shape * prior_factor,
        "silhouette_model": w.silhouette_model, "silhouette_mask": w.silhouette_mask, "temporal": w.temporal,
    }  # fmt: skip
    names = {t.name for t in problem.terms}
    return with_weights(problem, {k: jnp.asarray(v, dtype) for k, v in values.items() if k in names})


def _batched(data: CameraData) -> bool:
    return data.keypoints.ndim == 5


def _member(data: CameraData, i: int) -> CameraData:
    return jax.tree_util.tree_map(lambda x: x[i], data)


def stack(datas: Sequence[CameraData]) -> CameraData:
    """Sequences of equal T and V as one batched `CameraData` (leading axis B) for the
    stage functions, which then solve all members at once (`solve_batch`)."""
    return jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *datas)


def _solve(problem: Problem, params: dict, data: CameraData, max_steps: int):
    run = solve_batch if _batched(data) else solve
    return run(problem, params, data, max_steps=max_steps)


def stage_one(data: CameraData, params0: dict, weights: MuVSWeights = MuVSWeights(), silhouettes: bool = True,
              max_steps: int = 50) -> tuple[dict, dict]:
    """Per-frame fit (eq. 4.1-4.6): joints with an annealed prior, then + silhouettes.

    Returns ({pose, trans, betas (T, B)}, {stage: cost}).
    """
    dtype = data.K.dtype
    p = {k: jnp.asarray(v, dtype) for k, v in params0.items()}
    costs = {}
    joints_only = _stage_one_problem(weights.sigma, weights.silhouette_stride, weights.silhouette_slack, False)
    for i, factor in enumerate(weights.anneal):
        prob = _weighted(joints_only, weights, dtype, factor)
        sol = _solve(prob, p, data, max_steps)
        p = sol.value
        costs[f"joints_{i}"] = np.asarray(sol.cost).tolist()
        costs[f"joints_{i}_steps"] = np.asarray(sol.num_steps).tolist()
    if silhouettes and data.silhouettes is not None:
        prob = _weighted(_stage_one_problem(weights.sigma, weights.silhouette_stride, weights.silhouette_slack, True), weights, dtype)
        sol = _solve(prob, p, data, max_steps)
        p = sol.value
        costs["silhouettes"] = np.asarray(sol.cost).tolist()
        costs["silhouettes_steps"] = np.asarray(sol.num_steps).tolist()
    return {k: np.asarray(v) for k, v in p.items()}, costs


def stage_two(data: CameraData, params1: dict, weights: MuVSWeights = MuVSWeights(), silhouettes: bool = False,
              max_steps: int = 30) -> tuple[dict, dict]:
    """Temporal fit (eq. 4.7-4.8) with β = median of the stage-1 shapes.

    Returns ({pose, trans, betas (B,), coef}, {"temporal": cost}).
    """
    dtype = data.K.dtype
    betas = np.median(np.asarray(params1["betas"]), -2)  # over frames: (B,) or (batch, B)
    data2 = dataclasses_replace(data, betas=jnp.asarray(betas, dtype))
    # A sequence shorter than a window gets a window of its length and the same bandwidth
    # (10 of 30 frames): the first frames of a 30-frame DCT basis are so ill-conditioned
    # that E_T would pull towards huge float32 coefficients instead of smoothing.
    length = min(weights.window, data.keypoints.shape[-4])
    num_dct = max(1, min(weights.num_dct, round(weights.num_dct * length / weights.window)))
    windows = dct_window(length).windows
    body = _member(data, 0).body if _batched(data) else data.body
    posed = forward(body, jnp.asarray(params1["pose"], dtype), data2.betas[..., None, :],
                    jnp.asarray(params1["trans"], dtype))  # fmt: skip
    joints = np.asarray(posed.joints)
    if _batched(data):
        coef = np.stack([dct_coefficients(j, windows, num_dct) for j in joints])
    else:
        coef = dct_coefficients(joints, windows, num_dct)
    p = {"pose": jnp.asarray(params1["pose"], dtype), "trans": jnp.asarray(params1["trans"], dtype),
         "coef": jnp.asarray(coef, dtype)}  # fmt: skip
    use_sil = silhouettes and data.silhouettes is not None
    w = weights
    prob = _stage_two_problem(w.sigma, w.silhouette_stride, w.silhouette_slack, use_sil, length, num_dct,
                              w.temporal_sigma)
    prob = _weighted(prob, w, dtype)
    sol = _solve(prob, p, data2, max_steps)
    out = {k: np.asarray(v) for k, v in sol.value.items()}
    out["betas"] = betas
    return out, {"temporal": np.asarray(sol.cost).tolist(), "temporal_steps": np.asarray(sol.num_steps).tolist()}


def dataclasses_replace(data: CameraData, **changes) -> CameraData:
    """`data` with fields replaced (an equinox Module is immutable)."""
    import equinox as eqx

    keys = list(changes)
    return eqx.tree_at(lambda d: [getattr(d, k) for k in keys], data, [changes[k] for k in keys],
                       is_leaf=lambda x: x is None)


def multiview_smplify(
    data: CameraData,
    weights: MuVSWeights = MuVSWeights(),
    silhouettes: bool = True,
    temporal: bool = True,
    temporal_silhouettes: bool = False,
    params0: dict | None = None,
    resolve_swaps: bool = False,
) -> MuVSResult:
    """MuVS on one sequence: stage 1 (+S if masks are given), then stage 2 (+T, +H).

    With `resolve_swaps`, views that swapped the legs are flipped back first
    (`resolve_left_right`; our addition, off by default until its effect on the fit is
    measured: it flips back most swapped views, but also some unswapped ones)."""
    data = resolve_left_right(data) if resolve_swaps else data
    p0 = initialise(data, weights.num_betas) if params0 is None else params0
    p1, costs = stage_one(data, p0, weights, silhouettes)
    stage1 = {"poses": p1["pose"], "trans": p1["trans"], "betas": p1["betas"]}
    if not temporal:
        return MuVSResult(p1["pose"], p1["trans"], np.median(p1["betas"], -2), stage1, costs)
    p2, c2 = stage_two(data, p1, weights, temporal_silhouettes)
    return MuVSResult(p2["pose"], p2["trans"], p2["betas"], stage1, {**costs, **c2})


def mask_views(data: CameraData, keep: Sequence[int]) -> CameraData:
    """`data` with only the views `keep` observed (the others get confidence 0 and no
    mask): 1, 2, 3 of 4 views share one compiled solve with the full set."""
    V = data.K.shape[0] if data.K.ndim == 3 else data.K.shape[1]
    on = np.zeros(V, bool)
    on[list(keep)] = True
    on = jnp.asarray(on)
    sil = data.silhouettes
    if sil is not None:
        sil = Silhouettes(sil.distance, sil.points, sil.valid & on[:, None], sil.area)
    return dataclasses_replace(data, confidence=data.confidence * on[:, None], silhouettes=sil)
