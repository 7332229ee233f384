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
- **Monocular** (Table 4.5): the same code with one view. The result says so
  (`MuVSResult.monocular`) with the depth along the camera's line of sight and its 1σ
  (`monocular_depth`: the body's size, the frames' depth scatter, and where the feet meet
  a known floor, `place_monocular`). Where the floor is known, both stages also hold the
  lowest foot on it (ours: InterCap's ground and contact terms, eq. 5.6-5.7, with the floor
  as the surface touched, `energies.interaction.floor_contact_term`): one view's keypoint
  term alone pulls the body towards the camera (below). On 3 clips of the evaluated
  subjects (one view of 4, 40 frames, `experiments/results/muvs_monocular.md`) it lowers
  the unaligned MPJPE after stage 2 (+H) from 407 to 206 mm (aligned 84 -> 75 mm: ratio
  4.9 -> 2.7, per clip 2.3-3.2) and puts the median depth within 0.96-0.99 of the truth.

Left/right swaps (ours, on by default in `multiview_smplify` and the CLI): before stage 1,
`resolve_left_right` flips back the leg labels of any view that disagrees with the others
(2^V assignments triangulated per frame) or with its own past (labels that jump between
frames). On 10 unseen CMU clips (experiments/muvs_tables.py) it lowers MPJPE at every
stage with 2-4 views (3 views after stage 2: 93.7 -> 80.7 mm) and raises the swaps
repaired after stage 2 from 65 % to 95 % (1-4 views pooled; 2-4 views 70 -> 98 %).
`resolve_swaps=False` is MuVS as written.

Initialisation (ours; MuVS reuses SMPLify's): per frame, the hips and shoulders are
triangulated from every view that sees them (confidence-weighted DLT) and give the root
position and orientation, the other joints start at the prior mean, β at 0; frames seen
by fewer than two views use one view's depth from the torso length (SMPLify's rule) and
a root facing the camera, turned round when the detected hips say the person faces away.

The problems are `jaxmocap.solve.Problem`s of the terms in `energies.camera`. Speed (ours,
same energies): the terms run on a `compact` body (the keypoints as rigidly skinned points
per joint, a fixed subsample of model points for E_S, no pose blend shapes when the body
has none); E_T is a basis term, whose DCT coefficients the engine eliminates by their
Kronecker structure (`jaxmocap.solve.basis`, 10x faster per step than the generic window
elimination); every solve takes at most `MuVSWeights.steps` LM steps.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from scipy.ndimage import median_filter

from ..body.compact import compact_body
from ..body.kinematics import forward, shaped_joints
from ..body.model import Body
from ..energies.interaction import floor_contact_term
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
from ..geometry.camera import intrinsics
from ..geometry.keypoints import KEYPOINT_FORMATS, flip_pairs, keypoint_regressor, regress_keypoints
from ..geometry.surface import rest_joints
from ..geometry.triangulation import triangulate
from ..priors.pose_prior import PosePrior, default_pose_prior
from ..rotation import matrix_to_axis_angle
from ..solve import Problem, frame, solve, solve_batch
from .weights import FitResult, Weights

__all__ = [
    "MuVSWeights",
    "PRESETS",
    "preset",
    "MuVSResult",
    "camera_data",
    "compact",
    "initialise",
    "resolve_left_right",
    "stage_one",
    "stage_two",
    "multiview_smplify",
    "mask_views",
    "stack",
    "monocular_view",
    "monocular_depth",
    "place_monocular",
    "final_depth",
    "rescale_about_camera",
    "STATURE_CV",
    "reprojection_px",
]


#: Focal length (px) of the cameras MuVSWeights were tuned with: 256 x 192 px, 55° vertical.
REFERENCE_FOCAL = float(intrinsics(256, 192, 55.0)[1, 1])


@dataclasses.dataclass(frozen=True)
class MuVSWeights(Weights):
    """Weights and constants of eq. 4.1-4.8 (our choices: Huang gives none). The defaults
    are the "validated" preset (`PRESETS`, the default of `multiview_smplify`, the stages
    and `jaxmocap multiview`): λ_θ, λ_β and the silhouette setting as
    experiments/muvs_tuning.py chose them on the development subjects 02 and 131
    (experiments/results/muvs_tuning.json), the rest as this implementation started. 0
    switches a term off. The weights carry their terms' names (`term_weights`); the other
    fields (`CONSTANTS`) configure the terms and the stages.

    keypoints: E_J weight; sigma: its Geman-McClure σ₁ (px) with two or more views;
        sigma_monocular: σ₁ when only one view sees the person (`_sigma`). A detection
        further than σ₁ from the model is an outlier: a leg swap in one view (20-60 px
        on our 256 x 192 images) is then outvoted by the others, which σ₁ = 100 px
        (SMPLify's) never did; with one view nothing outvotes it, and a small σ₁ only
        lets the depth drift (3 CMU clips: MPJPE 1.1 m at 100 px, 290 m at 10 px).
    pose_prior, shape: λ_θ, λ_β; anneal: λ_θ multipliers of the stage-1 joint fit. On
        keypoints alone λ_β = 50 keeps β short of the truth: a synthetic walk with
        β₀ = 1 (3 views, 2 px noise, λ_θ = 1) fitted β₀ = 0.51 and limbs 2-4 % short of
        the true ones; λ_β = 10: 0.89, 1-2 %; λ_β = 2: 1.06, within 1 % (triangulating
        the same detections made them 0-8 % long: noise lengthens them). On the
        development clips (4 views, 3 px noise, outliers and leg swaps, stage 1 on
        joints) λ_β = 50 still fitted best: MPJPE 53.4 mm against 54.7 at 10 and 55.6 at
        2 (λ_θ = 1), shape error 21.8 against 23.2 and 30.5 mm; λ_θ = 1 against 20:
        53.4 against 72.7 mm (muvs_tuning.json).
    silhouette_model, silhouette_mask: the two sums of E_S (eq. 4.5); silhouette_points:
        model points of E_S, a fixed subsample of the mesh (`compact`; None: every
        silhouette_stride-th vertex); silhouette_slack: px within which a mask point
        counts as covered by the model (`energies.camera.silhouette_terms`).
    steps: LM steps per solve of each stage (joints per annealing step, silhouettes,
        temporal; ours: the solver's own stopping test rarely fires in float32, so this
        is the working limit). Stage 1 settles within 10 (60 frames: E_1 within 0.1 %
        of 20 steps); E_2 falls slowly (10 / 20 / 40 steps: 86k / 73k / 42k on 02_01),
        and 10 steps of stage 2 left its MPJPE above stage 1's.
    temporal: λ_T; temporal_sigma: σ₂ (m); window, num_dct: DCT unit and basis size.
    temporal_noise: px (at `reference_focal`) of stage 1's median reprojection error at
        and above which λ_T applies in full; below it λ_T × (error / temporal_noise)²
        (`_temporal_weight`, ours); None: always in full, as written. E_J's fixed weight
        stands for detections good to about a pixel and λ_T = 2e5 trusts the DCT span to
        1.6 mm, while 10 vectors of 30 frames at 30 fps leave a synthetic walk's joints
        4.5 mm from the span: on noise-free keypoints (stage 1 at 0.074 px, λ_θ = 1)
        stage 2 pulled the fit off by that, to 0.169 px and MPJPE 4.8 -> 7.3 mm, however
        many steps (it converged in 19). Noise makes E_J's residuals, not the span, the
        larger error; weighting E_T by the residual variance is then what a posterior
        would do (2 px noise: stage 1 at 2.07 px, λ_T in full; with 15-frame windows
        instead, stage 2 smoothed half as much: MPJPE 21.5 -> 28.7 mm).
    reference_focal: the focal length (px) the pixel quantities above are given for: σ₁,
        the silhouette slack, and the px² scales of E_J and E_S. Each recording converts
        them by s = its mean focal length / reference_focal (`_in_pixels`), so the same
        scene filmed at 4x the resolution is fitted alike (without it, 3 CMU clips at
        1024 x 768 instead of 256 x 192, noise in proportion: MPJPE 84 -> 168 mm).
        Default: the 256 x 192, 55° cameras the weights were tuned with. None: raw
        pixels (InterCap, whose weights were tuned on its own cameras).
    floor, floor_sigma: λ (per m²) and Geman-McClure σ (m; None: quadratic) of the floor
        contact term (`energies.interaction.floor_contact_term`, eq. 5.6-5.7 with the floor
        as the surface: the lowest foot point on a known floor), used only where the
        stages are given a floor; `multiview_smplify` gives it with one view only
        (`_floor_for`). λ = 1e4 makes 1 cm of floating cost 1 px² of E_J; σ = 0.1 m lets
        a jump's frames go (feet 0.3 m up: 1/100 of a quadratic's gradient). Chosen on the
        development clips 02_04, 02_07, 131_01 (one view of 4, 40 frames): stage 1's
        unaligned / aligned MPJPE ratio per clip 2.5-4.8 without the term; with σ = 0.1 and
        λ = 1e3 2.1-4.1, 1e4 1.8-2.6, 1e5 1.7-2.4 (σ 0.05, 0.2 or quadratic no better); the
        whole pipeline (muvs_monocular.py --development, S,T,H) 316 / 139 mm without the
        term, 199 / 136 mm with λ = 1e4, 196 / 131 mm with 1e5.
    """

    keypoints: float = 1.0
    sigma: float = 10.0
    sigma_monocular: float = 100.0
    pose_prior: float = 1.0  # λ_θ, eq. 4.1: "validated" (muvs_tuning.json best_pose_prior; "thesis" 20)
    shape: float = 50.0  # λ_β, eq. 4.1: "validated" = "thesis" (muvs_tuning.json best_shape)
    anneal: tuple[float, ...] = (20.0, 4.0, 1.0)
    silhouette_model: float = 0.1
    silhouette_mask: float = 0.1
    silhouette_points: int | None = 256
    silhouette_stride: int = 2
    silhouette_slack: float = 2.0
    steps: tuple[int, int, int] = (10, 10, 40)
    temporal: float = 2e5
    temporal_sigma: float = 0.05
    window: int = 30
    num_dct: int = 10
    temporal_noise: float | None = 2.0
    num_betas: int = 10
    reference_focal: float | None = REFERENCE_FOCAL
    floor: float = 1e4
    floor_sigma: float | None = 0.1

    CONSTANTS = ("sigma", "sigma_monocular", "anneal", "silhouette_points", "silhouette_stride", "silhouette_slack",
                 "steps", "temporal_sigma", "window", "num_dct", "temporal_noise", "num_betas", "reference_focal",
                 "floor_sigma")  # fmt: skip

    def term_weights(self, prior_factor: float = 1.0) -> dict:
        """{term: weight}; `prior_factor` scales λ_θ and λ_β (a step of `anneal`)."""
        w = super().term_weights()
        return {**w, "pose_prior": self.pose_prior * prior_factor, "shape": self.shape * prior_factor}


#: The named settings, as the inertial posers' (`methods.inertial.PRESETS`).
#: "validated" (the default, = `MuVSWeights()`): what experiments/muvs_tuning.py chose on the
#: development subjects 02 and 131 only (experiments/results/muvs_tuning.json; tests/test_presets.py
#: fails when they disagree). "thesis": the values this implementation started with, exact
#: (Huang gives no weights; λ_θ = 20, λ_β = 50, everything else as "validated").
PRESETS = {
    "validated": MuVSWeights(),
    "thesis": MuVSWeights(pose_prior=20.0, shape=50.0),
}


def preset(weights: MuVSWeights | str = "validated") -> MuVSWeights:
    """The `MuVSWeights` a `weights` argument means: a preset name or the weights themselves."""
    if isinstance(weights, str):
        if weights not in PRESETS:
            raise ValueError(f"weights={weights!r}: pass a preset name {sorted(PRESETS)} or MuVSWeights(...).")
        return PRESETS[weights]
    if not isinstance(weights, MuVSWeights):
        raise ValueError(
            f"weights must be MuVSWeights or a preset name {sorted(PRESETS)}, got {type(weights).__name__}."
        )
    return weights


@dataclasses.dataclass(frozen=True)
class MuVSResult(FitResult):
    """Poses (T, 24, 3) axis-angle, trans (T, 3), betas (B,) of the final stage, the
    stage-1 outcome (`stage1`: poses, trans, per-frame betas (T, B)), and per-stage costs.
    monocular: one view saw the person, so depth along its line of sight was not measured;
    depth: then `monocular_depth`'s record (depth, its 1σ uncertainty, what it came from).
    solution: the engine's `Solution` of each solve by stage ("joints_0", ...,
    "silhouettes", "temporal"; `FitResult`)."""

    poses: np.ndarray
    trans: np.ndarray
    betas: np.ndarray
    stage1: dict
    costs: dict
    monocular: bool = False
    depth: dict | None = None
    solution: dict = dataclasses.field(default_factory=dict)

    @property
    def params(self) -> dict:
        return {"pose": self.poses, "trans": self.trans, "betas": self.betas}


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


def _farthest_points(points: np.ndarray, count: int) -> np.ndarray:
    """Indices of `count` of the points (N, 3) spread by farthest-point sampling (sorted)."""
    if count >= len(points):
        return np.arange(len(points))
    if count <= 0:
        return np.zeros(0, int)
    chosen = [int(np.argmin(points[:, 1]))]  # start at the lowest vertex: deterministic
    dist = np.linalg.norm(points - points[chosen[0]], axis=-1)
    for _ in range(count - 1):
        chosen.append(int(np.argmax(dist)))
        dist = np.minimum(dist, np.linalg.norm(points - points[chosen[-1]], axis=-1))
    return np.sort(np.asarray(chosen))


def compact(data: CameraData, silhouette_points: int | None = 256, stride: int = 2) -> CameraData:
    """`data` on a body cut down to the points the MuVS terms read (ours, for speed).

    Same energies, a fraction of the forward pass (`body.compact_body`, exact). The
    compact body has, in this order: `silhouette_points` model points of E_S (a fixed
    farthest-point subsample of the rest mesh; None: every `stride`-th vertex, as on a
    full body; 0: none, for the joint fits), those keypoint points, and one point per
    joint at J(β) = 𝒥(T̄ + B_s β) (so the joints, and with them the skinning transforms,
    are the full body's). Pose blend shapes are skipped when the body has none
    (`CameraData.pose_blend`). Default body (1229 vertices): 256 + 75 + 24 points.
    """
    if _batched(data):
        return stack([compact(_member(data, i), silhouette_points, stride) for i in range(data.keypoints.shape[0])])
    if data.model_points is not None:
        raise ValueError("compact: data are already compact; call it on the CameraData of camera_data.")
    key = (id(data.body), id(data.regressor), silhouette_points, stride)
    hit = _COMPACT.get(key)
    if hit is None or hit[0] is not data.body or hit[1] is not data.regressor:
        hit = (data.body, data.regressor, *_compact_body(data.body, data.regressor, silhouette_points, stride))
        _COMPACT.clear()  # one entry per (body, regressor, points): holds no stale arrays
        _COMPACT[key] = hit
    small, regressor, n, pose_blend = hit[2:]
    return dataclasses.replace(data, body=small, regressor=regressor, model_points=jnp.arange(n, dtype=jnp.int32),
                               pose_blend=pose_blend)  # fmt: skip


_COMPACT: dict = {}


def _compact_body(body: Body, reg, silhouette_points, stride):
    """(compact body, its keypoint regressor, number of model points, pose_blend) of `compact`."""
    V = body.num_vertices
    v_template = np.asarray(body.v_template, np.float64)
    sil = np.arange(0, V, stride) if silhouette_points is None else _farthest_points(v_template, silhouette_points)
    small, regressor, pose_blend = compact_body(body, reg, keep=sil)
    return small, regressor, len(sil), pose_blend


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


def resolve_left_right(
    data: CameraData, truncation: float = 0.05, margin: float = 0.005, max_views: int = 6, temporal: float = 1.0
) -> CameraData:
    """`data` with each view's leg keypoints swapped back where that view swapped left and right.

    Detectors confuse the legs of a person seen from the side or the back, one view at a
    time. Per frame, every assignment of the views' leg labels (as detected or swapped,
    2^V hypotheses; hips, knees, ankles and feet swap together) is triangulated and scored
    by its reprojection error, truncated at `truncation` × the mean focal length so that
    one bad point cannot dominate; the best one is kept if it beats the detections as they
    are by more than `margin` × the mean focal length of RMS error per leg point (legs
    close together reproject alike either way: no flip then).
    With `temporal` > 0 (default) the labels must also persist over time: the hypotheses
    of all frames are chosen together (Viterbi) by their reprojection error, a price of
    the margin on every flipped frame, and `temporal` × how far each view's labelled leg
    points move from one frame to the next (truncated as above), so a swap shows where its
    labels jump in and out. That settles what no single frame can: two views that
    disagree, and a single view. temporal = 1 was chosen on 9 clips of
    ../shared/data/cmu (4 ring views, muvs_tables' detector): swapped views flipped back
    per-frame / temporal: 43 / 92 % with 2 views, 85 / 99 % with 3, 91 / 99 % with 4,
    0 / 71 % with one; unswapped views flipped by mistake 4-5 % / 1-2 % (one view 5 %).
    Our addition (MuVS leaves swaps to the robust ρ and the temporal term of stage 2):
    a swapped view disagrees with the others and with its own past, so it is cheap to find
    before any fit. Views beyond `max_views` are left as they are.
    """
    if _batched(data):
        return stack([resolve_left_right(_member(data, i), truncation, margin, max_views, temporal)
                      for i in range(data.keypoints.shape[0])])  # fmt: skip
    names = KEYPOINT_FORMATS[data.layout]
    pairs = [
        (a, b)
        for a, b in flip_pairs(names)
        if not any(k in names[a] for k in ("eye", "ear", "shoulder", "elbow", "wrist"))
    ]
    conf = np.asarray(data.confidence, np.float64)  # (T, V, K)
    seen = np.flatnonzero((conf > 0).any((0, 2)))[:max_views]
    if not pairs or len(seen) == 0 or (len(seen) < 2 and temporal <= 0):
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
    u = np.stack(
        [np.where(f[None, :, None, None] > 0, uv[:, :, swapped], uv[:, :, legs]).swapaxes(0, 1) for f in flips], 1
    )
    c = np.stack([np.where(f[None, :, None] > 0, cf[:, :, swapped], cf[:, :, legs]).swapaxes(0, 1) for f in flips], 1)
    tau = truncation * float(np.mean(K[:, 0, 0]))
    threshold = (margin * float(np.mean(K[:, 0, 0]))) ** 2 * np.maximum((c[:, 0] > 0).sum((0, 2)), 1)  # (T,)
    if len(seen) >= 2:
        cost = _reprojection_costs(P, u, c, uv, cf, names, legs, tau, threshold)  # (H, T)
    else:  # one view: nothing to triangulate, only the motion can tell
        cost = np.zeros((len(flips), len(uv)))
    cost = cost + 0.1 * threshold * flips.sum(1)[:, None] / len(seen)
    if temporal > 0:
        # Labels persist from frame to frame: the cost of a pair of consecutive hypotheses is
        # how far each view's labelled leg points move between them (truncated like the
        # reprojection error); the margin becomes a price on every flipped frame.
        unary = cost + threshold * (np.arange(len(flips)) > 0)[:, None]  # (H, T)
        one = [0, len(flips) - 1]  # a view's two labellings: as detected, swapped
        ul, cl = u[:, one], c[:, one]  # (V', 2, T, 2L, 2), (V', 2, T, 2L)
        moved = np.minimum(np.sum((ul[:, :, None, 1:] - ul[:, None, :, :-1]) ** 2, -1), tau**2)  # (V', 2, 2, T-1, 2L)
        both = (cl[:, :, None, 1:] > 0) & (cl[:, None, :, :-1] > 0)
        per_view = np.where(both, moved, 0.0).sum(-1)  # (V', label now, label before, T-1)
        pair = temporal * sum(per_view[j][flips[:, j][:, None], flips[:, j][None, :]] for j in range(len(seen)))
        choice = _viterbi(unary, pair)  # pair: (H now, H before, T-1)
    else:
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
    return dataclasses_replace(
        data, keypoints=jnp.asarray(out, data.keypoints.dtype), confidence=jnp.asarray(out_c, data.confidence.dtype)
    )


def _reprojection_costs(P, u, c, uv, cf, names, legs, tau, threshold) -> np.ndarray:
    """(H, T) truncated reprojection error of the leg points triangulated under every
    hypothesis (`resolve_left_right`), plus the hips-on-the-shoulders'-side rule."""
    X, err = triangulate(P, u, c)  # (H, T, 2L, 3), (V', H, T, 2L)
    cost = np.where(c > 0, np.minimum(np.nan_to_num(err, nan=tau), tau) ** 2 * c, 0.0).sum((0, 3))  # (H, T)
    # A hypothesis and its complement (every view flipped) reproject alike: that global
    # choice of which 3-D leg is "left" is the body fit's. Between such near-ties the
    # hips on the shoulders' side decide, then fewer flips; neither can make a flip win
    # against the detections as they are by itself (both stay below the margin).
    sh = [names.index(n) for n in ("left_shoulder", "right_shoulder")]
    hips = [list(legs).index(names.index(n)) for n in ("left_hip", "right_hip")] if "left_hip" in names else None
    if hips is not None:
        S, _ = triangulate(P, np.moveaxis(uv[:, :, sh], 1, 0), np.moveaxis(cf[:, :, sh], 1, 0))  # (T, 2, 3)
        across = np.einsum("htk,tk->ht", X[:, :, hips[0]] - X[:, :, hips[1]], S[:, 0] - S[:, 1])
        cost = cost + 0.4 * threshold * (np.nan_to_num(across, nan=1.0) < 0)
    return cost


def _viterbi(unary: np.ndarray, pair: np.ndarray) -> np.ndarray:
    """The state sequence (T,) minimising Σ_t unary[s_t, t] + Σ_t pair[s_t, s_{t-1}, t-1]
    for unary (S, T) and pair (S, S, T-1)."""
    S, T = unary.shape
    total, back = unary[:, 0].copy(), np.zeros((T, S), int)
    for t in range(1, T):
        step = total[None, :] + pair[:, :, t - 1]  # (now, before)
        back[t] = np.argmin(step, 1)
        total = step[np.arange(S), back[t]] + unary[:, t]
    states = np.zeros(T, int)
    states[-1] = int(np.argmin(total))
    for t in range(T - 1, 0, -1):
        states[t - 1] = back[t, states[t]]
    return states


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
# Terms are equinox modules with static configuration: problems built twice with the same
# settings are equal, so `solve`'s jit reuses one program without caching the problems.


def _stage_one_problem(
    sigma: float, stride: int, slack: float, silhouettes: bool, huber: float = 1.0, floor: tuple | None = None
) -> Problem:
    terms = [keypoint_term(sigma), pose_prior_term(), shape_term()] + _silhouettes(silhouettes, stride, slack, huber)
    return Problem(terms + _floor_terms(floor), {"pose": frame("so3"), "trans": frame(), "betas": frame()})


def _stage_two_problem(
    sigma: float,
    stride: int,
    slack: float,
    silhouettes: bool,
    length: int,
    num_dct: int,
    temporal_sigma: float,
    huber: float = 1.0,
    floor: tuple | None = None,
) -> Problem:
    terms = [keypoint_term(sigma), pose_prior_term(), temporal_term(length, num_dct, temporal_sigma)]
    terms += _silhouettes(silhouettes, stride, slack, huber) + _floor_terms(floor)
    return Problem(terms, {"pose": frame("so3"), "trans": frame(), "coef": dct_window(length)})


def _floor_terms(spec: tuple | None) -> list:
    """The floor contact term of `_floor_spec`'s (up, height, points, offsets, σ), or none."""
    return [] if spec is None else [floor_contact_term(*spec)]


#: Keypoints that stand for the soles in the floor contact term, by name; layouts without
#: feet (COCO) use the ankles.
_FOOT_KEYPOINTS = ("toe", "heel", "foot_index")


def _floor_spec(data: CameraData, floor, sigma: float | None) -> tuple | None:
    """Hashable (up, height, points, offsets, σ) of the floor contact term for `floor` =
    (up (3,), height), or None without a floor: the foot keypoints of `data.layout` and
    each one's height above the sole of the rest mesh (β = 0: within millimetres of any
    body's, the feet are flat in the rest pose)."""
    if floor is None:
        return None
    up, height = np.asarray(floor[0], np.float64), float(floor[1])
    if up.shape != (3,) or not np.linalg.norm(up) > 0 or not np.isfinite(height):
        raise ValueError(f"floor must be (up (3,) non-zero, height); got {floor!r}.")
    up = up / np.linalg.norm(up)
    names = KEYPOINT_FORMATS[data.layout]
    points = [i for i, n in enumerate(names) if any(k in n for k in _FOOT_KEYPOINTS)]
    points = points or [names.index(n) for n in ("left_ankle", "right_ankle") if n in names]
    if not points:
        raise ValueError(f"floor: the {data.layout!r} layout has no foot or ankle keypoints to stand on the floor.")
    one = _member(data, 0) if _batched(data) else data
    if one.model_points is not None:
        raise ValueError("floor: pass the CameraData of camera_data, not a compact one.")
    rest = np.asarray(one.body.v_template, np.float64)
    feet = regress_keypoints(np.asarray(one.regressor, np.float64)[points], rest, rest_joints(one.body))
    offsets = feet @ up - float((rest @ up).min())
    return (tuple(up.tolist()), height, tuple(points), tuple(offsets.tolist()), sigma)


def _silhouettes(on: bool, stride: int, slack: float, huber: float) -> list:
    """E_S's two terms when `on`, else none."""
    return silhouette_terms(stride=stride, slack=slack, huber=huber) if on else []


def _weighted(problem: Problem, w: MuVSWeights, dtype, prior_factor: float = 1.0) -> Problem:
    """`problem` with the weights of `w` as traced arrays (no recompilation per value)."""
    return w.weigh(problem, dtype, prior_factor=prior_factor)


def _batched(data: CameraData) -> bool:
    return data.keypoints.ndim == 5


def _member(data: CameraData, i: int) -> CameraData:
    return jax.tree_util.tree_map(lambda x: x[i], data)


def stack(datas: Sequence[CameraData]) -> CameraData:
    """Sequences of equal T and V as one batched `CameraData` (leading axis B) for the
    stage functions, which then solve all members at once (`solve_batch`)."""
    return jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *datas)


def _in_pixels(weights: MuVSWeights, data: CameraData) -> tuple[MuVSWeights, float]:
    """`weights` in the pixels of `data`'s cameras, and the Huber δ (px) of E_S.

    With s = mean focal length / `reference_focal` (one s for a whole batch): lengths in
    pixels scale by s (σ₁, slack, δ), and the weights of E_J and E_S by 1 / s², 1 / s⁴
    (their squared residuals grow as s², s⁴: the Geman-McClure cost is σ²ρ, and E_S
    multiplies each distance by the square root of a mask area), so every term's cost
    is that of the reference camera. Exact for a scene whose images are scaled by s.
    """
    if weights.reference_focal is None:
        return weights, 1.0
    f = np.asarray(data.K, np.float64)[..., [0, 1], [0, 1]]
    s = float(np.mean(f)) / weights.reference_focal
    if abs(s - 1.0) < 1e-6:  # the reference cameras themselves (float32 K)
        return weights, 1.0
    return weights.replace(
        keypoints=weights.keypoints / s**2, sigma=weights.sigma * s, sigma_monocular=weights.sigma_monocular * s,
        silhouette_slack=weights.silhouette_slack * s, silhouette_model=weights.silhouette_model / s**4,
        silhouette_mask=weights.silhouette_mask / s**4,
    ), s  # fmt: skip


def _sigma(data: CameraData, weights: MuVSWeights) -> float:
    """σ₁ for `data`: `weights.sigma_monocular` if no sequence (batch member) has
    detections in more than one view, else `weights.sigma`."""
    seen = np.asarray(jnp.any(data.confidence > 0, axis=(-3, -1)))  # (V,) or (batch, V)
    return weights.sigma if int(np.max(seen.sum(-1))) > 1 else weights.sigma_monocular


def _solve(problem: Problem, params: dict, data: CameraData, max_steps: int):
    run = solve_batch if _batched(data) else solve
    return run(problem, params, data, max_steps=max_steps)


def stage_one(
    data: CameraData,
    params0: dict,
    weights: MuVSWeights | str = "validated",
    silhouettes: bool = True,
    max_steps: int | None = None,
    floor=None,
) -> tuple[dict, dict]:
    """Per-frame fit (eq. 4.1-4.6): joints with an annealed prior, then + silhouettes.

    `max_steps` (default `weights.steps`) caps each solve. The terms run on the
    `compact` body (same energies, fewer points). `floor` = (up (3,), height): the plane
    {x: up·x = height} the feet stand on, adding the floor contact term
    (`MuVSWeights.floor`) to every solve; None (default): no such term.
    Returns ({pose, trans, betas (T, B)}, {stage: cost}).
    """
    p, costs, _ = _stage_one(data, params0, weights, silhouettes, max_steps, floor)
    return p, costs


def _stage_one(data, params0, weights, silhouettes, max_steps, floor) -> tuple[dict, dict, dict]:
    """`stage_one`, and the `Solution` of each solve by stage name."""
    weights = preset(weights)
    dtype = data.K.dtype
    p = {k: jnp.asarray(v, dtype) for k, v in params0.items()}
    costs, sols = {}, {}
    steps = weights.steps if max_steps is None else (max_steps,) * 3
    weights, delta = _in_pixels(weights, data)
    sigma = _sigma(data, weights)
    ground = _floor_spec(data, floor, weights.floor_sigma)
    joints_only = _stage_one_problem(sigma, weights.silhouette_stride, weights.silhouette_slack, False, delta, ground)
    joint_data = compact(data, 0)
    for i, factor in enumerate(weights.anneal):
        prob = _weighted(joints_only, weights, dtype, factor)
        sol = _solve(prob, p, joint_data, steps[0])
        p, sols[f"joints_{i}"] = sol.value, sol
        costs[f"joints_{i}"] = np.asarray(sol.cost).tolist()
        costs[f"joints_{i}_steps"] = np.asarray(sol.num_steps).tolist()
    if silhouettes and data.silhouettes is not None:
        prob = _weighted(_stage_one_problem(sigma, weights.silhouette_stride, weights.silhouette_slack, True, delta,
                                            ground), weights, dtype)  # fmt: skip
        sol = _solve(prob, p, compact(data, weights.silhouette_points, weights.silhouette_stride), steps[1])
        p, sols["silhouettes"] = sol.value, sol
        costs["silhouettes"] = np.asarray(sol.cost).tolist()
        costs["silhouettes_steps"] = np.asarray(sol.num_steps).tolist()
    return {k: np.asarray(v) for k, v in p.items()}, costs, sols


def stage_two(
    data: CameraData,
    params1: dict,
    weights: MuVSWeights | str = "validated",
    silhouettes: bool = False,
    max_steps: int | None = None,
    floor=None,
) -> tuple[dict, dict]:
    """Temporal fit (eq. 4.7-4.8) with β = median of the stage-1 shapes; `floor` as in
    `stage_one`.

    E_T is a basis term (`energies.camera.temporal_term`): the engine eliminates the DCT
    coefficients by their Kronecker structure (`jaxmocap.solve.basis`).
    Returns ({pose, trans, betas (B,), coef}, {"temporal": cost, "temporal_steps",
    "temporal_result"}).
    """
    out, costs, _ = _stage_two(data, params1, weights, silhouettes, max_steps, floor)
    return out, costs


def _stage_two(data, params1, weights, silhouettes, max_steps, floor) -> tuple[dict, dict, object]:
    """`stage_two`, and the `Solution` of its solve."""
    weights = preset(weights)
    dtype = data.K.dtype
    betas = np.median(np.asarray(params1["betas"]), -2)  # over frames: (B,) or (batch, B)
    data2 = dataclasses_replace(data, betas=jnp.asarray(betas, dtype))
    body = _member(data, 0).body if _batched(data) else data.body
    posed = forward(body, jnp.asarray(params1["pose"], dtype), data2.betas[..., None, :],
                    jnp.asarray(params1["trans"], dtype))  # fmt: skip
    joints = np.asarray(posed.joints)
    if _batched(data):
        coef = np.stack([dct_coefficients(j, weights.window, weights.num_dct) for j in joints])
    else:
        coef = dct_coefficients(joints, weights.window, weights.num_dct)
    p = {"pose": jnp.asarray(params1["pose"], dtype), "trans": jnp.asarray(params1["trans"], dtype),
         "coef": jnp.asarray(coef, dtype)}  # fmt: skip
    use_sil = silhouettes and data.silhouettes is not None
    data2 = compact(data2, weights.silhouette_points if use_sil else 0, weights.silhouette_stride)
    max_steps = weights.steps[2] if max_steps is None else max_steps
    w, delta = _in_pixels(weights, data)
    w = w.replace(temporal=_temporal_weight(data, params1, weights, delta))
    prob = _stage_two_problem(_sigma(data, w), w.silhouette_stride, w.silhouette_slack, use_sil, w.window,
                              w.num_dct, w.temporal_sigma, delta, _floor_spec(data, floor, w.floor_sigma))  # fmt: skip
    sol = _solve(_weighted(prob, w, dtype), p, data2, max_steps)
    out = {k: np.asarray(v) for k, v in sol.value.items()}
    out["betas"] = betas
    return out, {"temporal": np.asarray(sol.cost).tolist(), "temporal_steps": np.asarray(sol.num_steps).tolist(),
                 "temporal_result": np.asarray(sol.result).tolist()}, sol  # fmt: skip


def reprojection_px(data: CameraData, params: dict) -> float:
    """Median distance (px) of the model's keypoints to the detections (confidence > 0)
    over all frames and views; batched data: the median over members."""
    if _batched(data):
        return float(np.median([reprojection_px(_member(data, i), {k: v[i] for k, v in params.items()})
                                for i in range(data.keypoints.shape[0])]))  # fmt: skip
    kp = regress_keypoints(np.asarray(data.regressor, np.float64), *_full_pose(data, params))
    K, R, t = (np.asarray(a, np.float64) for a in (data.K, data.R, data.t))
    cam = np.einsum("vab,tkb->tvka", R, kp) + t[None, :, None]
    uv = np.einsum("vab,tvkb->tvka", K, cam)
    uv = uv[..., :2] / uv[..., 2:]
    seen = np.asarray(data.confidence) > 0
    err = np.linalg.norm(uv - np.asarray(data.keypoints, np.float64), axis=-1)[seen]
    return float(np.median(err)) if err.size else float("nan")


def _temporal_weight(data: CameraData, params1: dict, weights: MuVSWeights, scale: float) -> float:
    """λ_T for stage 2: in full when stage 1 leaves `weights.temporal_noise` px or more
    (at the reference focal length; `scale` converts), less in proportion to the
    residual variance below that (`MuVSWeights.temporal_noise`)."""
    if weights.temporal_noise is None:
        return weights.temporal
    error = reprojection_px(data, params1) / scale
    if not np.isfinite(error):
        return weights.temporal
    return weights.temporal * min(1.0, (error / weights.temporal_noise) ** 2)


def dataclasses_replace(data: CameraData, **changes) -> CameraData:
    """`data` with fields replaced (an equinox Module is immutable)."""
    keys = list(changes)
    return eqx.tree_at(
        lambda d: [getattr(d, k) for k in keys], data, [changes[k] for k in keys], is_leaf=lambda x: x is None
    )


# --- one camera: depth from the body's size and the ground -------------------------------

#: Relative spread (1σ) of body size (adult stature: SD ≈ 9 cm about 1.70 m, sexes pooled).
#: With one view, depth is the body's size in pixels read against the fitted body's size,
#: which the shape prior keeps near the mean body: this is that depth's relative error.
STATURE_CV = 0.055
#: Feet lift off the floor (a step, a jump): the ground gives the size from the frames whose
#: lowest point is lowest, this quantile of the per-frame scales (ours).
GROUND_QUANTILE = 0.25


def monocular_view(data: CameraData) -> int | None:
    """The one view that has detections, or None when there are none or several."""
    seen = np.flatnonzero(np.asarray(jnp.any(data.confidence > 0, axis=(0, 2))))
    return int(seen[0]) if len(seen) == 1 else None


def _full_pose(data: CameraData, params: dict):
    """Vertices (T, N, 3) and joints (T, 24, 3) (float64) of params on data's body."""
    betas = np.asarray(params["betas"], np.float64)
    T = len(params["pose"])
    betas = np.broadcast_to(betas if betas.ndim == 2 else betas[None], (T, betas.shape[-1]))
    out = forward(data.body, jnp.asarray(params["pose"], data.body.dtype), jnp.asarray(betas, data.body.dtype),
                  jnp.asarray(params["trans"], data.body.dtype))  # fmt: skip
    return np.asarray(out.vertices, np.float64), np.asarray(out.joints, np.float64)


def monocular_depth(data: CameraData, params: dict, floor=None) -> dict:
    """With one view: how far the body is along that camera's line of sight, how uncertain
    that is, and the scale `k` (about the camera centre) that the ground asks for.

    One view measures the body's size in pixels, not its depth: a body k times larger k
    times further away looks the same. Two estimates of the scale (ours; MuVS's monocular
    variant, Table 4.5, is evaluated after similarity alignment only):
    - the body's size: the fit's shape, which the shape prior keeps near the mean body:
      k = 1 ± `STATURE_CV` combined with the detections' scale error (median reprojection
      over the body's median pixel extent) and the frames' depth scatter (1.4826 MAD about
      a 9-frame running median, over the depth: the depth each frame's pose allows);
    - the ground, with `floor` = (up (3,), height) the plane {x: up·x = height} and the
      camera above it: per frame, the k that puts the body's lowest vertex on the floor
      (a point at height y below a camera at height h: k = h / (h - y)); the frames whose
      feet are down are the lower `GROUND_QUANTILE` of those k; error: the spread of k
      over all frames (1.4826 MAD), the frames' depth scatter (the feet are the fit's) and
      the angle of the feet under the horizon (δd/d = δα / (sin α cos α), δα the
      reprojection error over the focal length). Without a floor in the fit, on 3 CMU clips
      (one view of 4, 40 frames, the tables' detector) the fit stood 10-16 % too close at
      the right body size, which the ground only partly sees (k 0.99-1.05): unaligned MPJPE
      706 -> 664 mm, the truth 1.1-2.4σ away; started at the depths where the detected
      feet meet the floor (init 958 -> 445 mm), stage 1 returned to 4.08-4.25 m (692 mm).
      Why (ours, the development clips 02_04, 02_07, 131_01, stage 1 started at the true
      pose, shape and place): with λ_θ = 1 the fit walks to 0.86-0.93 of the true depth,
      with no pose prior to 0.56-0.63, with no shape prior to 0.57-0.97 with a body 0.65-1.11
      times as tall; the pose prior holds it back, so the pull is the keypoint term's. On
      the true keypoints it stays at 0.97-1.03 (so neither the keypoint regressor nor the
      focal length is off); with the detector's 3 px noise alone (no misses, outliers or
      swaps) it goes to 0.84-0.94: a limb's length in the image can shrink by turning it
      out of the image plane but not grow, so the limbs that noise lengthens set the
      scale and the body comes closer.
      The floor contact term in the stages (`multiview_smplify` with a floor) is what
      stops it; `experiments/muvs_monocular.py` measures it.
    The two are combined by their inverse variances.
    Returns {"view", "depth_m" (median pelvis depth after scaling by k),
    "depth_uncertainty_m" (1σ), "relative", "scale" (k), "from", "size": {...},
    "ground": {...} or None}.
    """
    view = monocular_view(data)
    if view is None:
        raise ValueError("monocular_depth: the data must have detections in exactly one view.")
    K, R, t = (np.asarray(a, np.float64)[view] for a in (data.K, data.R, data.t))
    verts, joints = _full_pose(data, params)
    per_frame = (joints[:, 0] @ R.T + t)[:, 2]
    depth = float(np.median(per_frame))
    # frames fitted independently (stage 1) scatter in depth as much as their poses can
    # trade depth for foreshortening: their spread about a running median is an error too
    scatter = 1.4826 * float(
        np.median(np.abs(per_frame - median_filter(per_frame, min(9, len(per_frame)), mode="nearest")))
    )
    # the detections' scale error: reprojection over the body's extent in the image
    kp = regress_keypoints(np.asarray(data.regressor, np.float64), verts, joints) @ R.T + t
    uv = kp[..., :2] / kp[..., 2:] * np.diag(K)[:2] + K[:2, 2]
    det = np.asarray(data.keypoints, np.float64)[:, view]
    seen = np.asarray(data.confidence)[:, view] > 0
    px = float(np.median(np.linalg.norm(uv - det, axis=-1)[seen])) if seen.any() else 0.0
    extents = [np.ptp(d[s], 0).max() for d, s in zip(det, seen) if s.sum() >= 2]
    extent = float(np.median(extents)) if extents else float("nan")
    size_rel = math.hypot(STATURE_CV, px / extent if extent > 0 else 0.0, scatter / depth)
    ground = None
    if floor is not None:
        up, height = np.asarray(floor[0], np.float64), float(floor[1])
        up = up / np.linalg.norm(up)
        centre = -R.T @ t
        h = float(up @ centre) - height
        lowest = (verts @ up).min(1) - height  # (T,)
        if h > 0 and np.any(lowest < h):
            k_t = h / (h - lowest[lowest < h])
            down = k_t[k_t <= np.quantile(k_t, GROUND_QUANTILE)]
            k_g = float(np.median(down))
            alpha = math.atan2(h, depth)
            angle = (px / float(np.mean(np.diag(K)[:2]))) / (math.sin(alpha) * math.cos(alpha))
            spread = 1.4826 * float(np.median(np.abs(k_t - np.median(k_t))))  # over all frames: the fit's feet
            ground_rel = math.hypot(spread, angle, scatter / depth)
            ground = {"scale": k_g, "relative": ground_rel, "camera_height_m": h, "frames": int(len(down))}
    if ground is None:
        k, rel, source = 1.0, size_rel, "the body's size in the image (shape prior: the mean body)"
    else:
        w_s, w_g = size_rel**-2, ground["relative"] ** -2
        k = (w_s * 1.0 + w_g * ground["scale"]) / (w_s + w_g)
        rel = (w_s + w_g) ** -0.5
        source = "the body's size in the image and where its feet meet the floor"
    return {"view": view, "depth_m": depth * k, "depth_uncertainty_m": depth * k * rel, "relative": rel, "scale": k,
            "from": source, "size": {"relative": size_rel, "reprojection_px": px, "body_extent_px": extent,
                                     "frame_scatter_m": scatter},
            "ground": ground}  # fmt: skip


def rescale_about_camera(data: CameraData, params: dict, scale: float, view: int, num_betas: int | None = None) -> dict:
    """params with the body scaled by `scale` about the centre of camera `view`: the same
    image, `scale` times the size and the distance. The larger body is the shape β' whose
    rest mesh is closest (least squares, up to a shift) to `scale` × the old one; every
    frame keeps its pose and moves its pelvis along its line of sight."""
    body = data.body
    betas = np.asarray(params["betas"], np.float64)
    B = betas.shape[-1] if num_betas is None else num_betas
    S = np.asarray(body.shapedirs, np.float64)[:B]  # (B, V, 3)
    Tm = np.asarray(body.v_template, np.float64)
    shared = betas if betas.ndim == 1 else np.median(betas, 0)
    target = scale * (Tm + np.einsum("b,bvc->vc", shared, S))
    A = np.concatenate([S.reshape(B, -1).T, np.tile(np.eye(3), (len(Tm), 1))], 1)  # β' and a shift
    new = np.linalg.lstsq(A, (target - Tm).reshape(-1), rcond=None)[0][:B]
    R, t = (np.asarray(a, np.float64)[view] for a in (data.R, data.t))
    centre = -R.T @ t
    _, joints = _full_pose(data, params)
    moved = {**params, "betas": np.broadcast_to(new, betas.shape).astype(betas.dtype).copy()}
    _, joints_new = _full_pose(data, moved)
    pelvis = centre + scale * (joints[:, 0] - centre)
    moved["trans"] = np.asarray(params["trans"]) + (pelvis - joints_new[:, 0]).astype(np.asarray(params["trans"]).dtype)
    return moved


def place_monocular(data: CameraData, params: dict, floor=None) -> tuple[dict, dict | None]:
    """(params, depth): with one view, params scaled about the camera by `monocular_depth`'s
    k (the ground's evidence on the body's size) and that depth record; with several views
    params unchanged and None. Batched data: per member (a list of depths, or None)."""
    if _batched(data):
        each = [place_monocular(_member(data, i), {k: v[i] for k, v in params.items()}, floor)
                for i in range(data.keypoints.shape[0])]  # fmt: skip
        depths = [e[1] for e in each]
        return {k: np.stack([e[0][k] for e in each]) for k in params}, None if depths == [None] * len(
            depths
        ) else depths
    view = monocular_view(data)
    if view is None:
        return params, None
    depth = monocular_depth(data, params, floor)
    if depth["scale"] != 1.0:
        params = rescale_about_camera(data, params, depth["scale"], view)
    return params, depth


def final_depth(data: CameraData, final: dict, placed: dict) -> dict:
    """`MuVSResult.depth`: `monocular_depth` of the final fit, with the scale k that
    `place_monocular` applied after stage 1 and that record's uncertainty (`placed`)."""
    depth = {
        **monocular_depth(data, final),
        "scale": placed["scale"],
        "from": placed["from"],
        "relative": placed["relative"],
        "ground": placed["ground"],
    }
    depth["depth_uncertainty_m"] = depth["depth_m"] * depth["relative"]
    return depth


def multiview_smplify(
    data: CameraData,
    weights: MuVSWeights | str = "validated",
    silhouettes: bool = True,
    temporal: bool = True,
    temporal_silhouettes: bool = False,
    params0: dict | None = None,
    resolve_swaps: bool = True,
    floor=None,
) -> MuVSResult:
    """MuVS on one sequence: stage 1 (+S if masks are given), then stage 2 (+T, +H).

    With `resolve_swaps` (default), views that swapped the legs are flipped back first
    (`resolve_left_right`, our addition, measured in the module docstring); False is MuVS
    as written. With one view the result says so (`MuVSResult.monocular`, `.depth`); where
    the floor is known, `floor` = (up (3,), height), both stages then hold the feet on it
    (the floor contact term, `MuVSWeights.floor`; with several views the stages get no
    floor, `_floor_for`) and after stage 1 the body is scaled about the camera by what the
    floor says of its size (`place_monocular`). `weights`: `MuVSWeights` or a preset name
    (`PRESETS`: "validated", the default, or "thesis")."""
    weights = preset(weights)
    data = resolve_left_right(data) if resolve_swaps else data
    p0 = initialise(data, weights.num_betas) if params0 is None else params0
    ground = _floor_for(data, floor)
    p1, costs, sols = _stage_one(data, p0, weights, silhouettes, None, ground)
    p1, depth = place_monocular(data, p1, floor)
    stage1 = {"poses": p1["pose"], "trans": p1["trans"], "betas": p1["betas"]}
    if not temporal:
        final = {"pose": p1["pose"], "trans": p1["trans"], "betas": np.median(p1["betas"], -2)}
    else:
        final, c2, sols["temporal"] = _stage_two(data, p1, weights, temporal_silhouettes, None, ground)
        costs = {**costs, **c2}
    if isinstance(depth, dict):
        depth = final_depth(data, final, depth)
    return MuVSResult(final["pose"], final["trans"], final["betas"], stage1, costs, depth is not None, depth, sols)


def _floor_for(data: CameraData, floor):
    """`floor` if every sequence (batch member) is seen by one view, else None: the floor
    contact term is for one view, whose depth nothing else measures. With two or more,
    triangulation measures it, and a contact term would only pull a jump's feet down."""
    if floor is None:
        return None
    members = [_member(data, i) for i in range(data.keypoints.shape[0])] if _batched(data) else [data]
    return floor if all(monocular_view(m) is not None for m in members) else None


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
