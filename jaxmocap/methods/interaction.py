"""InterCap (Huang ch. 5): a person and the rigid object they handle, from multi-view RGB-D.

1. **Object-only tracking** (§5.2.2, eq. 5.1): frame by frame, each view keeps the
   segmentation candidate overlapping the rendering of the previous frame's fit most
   (`geometry.masks.select_candidate`), then the object's 6-DoF pose is fitted to
   the kept masks and the object-labelled depth points (`object_mask`, `object_depth`),
   starting from the previous frame. The first frame starts at the centroid of its object
   points under each of the 24 axis-aligned rotations (coarse, then fine); the lowest
   cost wins.
2. **Human-only** (§5.2.3, eq. 5.2-5.5): MuVS's per-frame keypoint fit (`multiview.stage_one`
   without silhouettes: E_J with Geman-McClure ρ, confidences and per-joint weights, E_θ,
   E_β), then E_D, E_α and E_P added, in ICP rounds: visible vertices and the closest of
   them to every body point are re-found from the current fit between solves.
3. **Joint fit, all frames** (§5.2.4, eq. 5.6-5.7): β* = the mean of the per-frame shapes;
   body poses, translations and object poses of every frame together, with E_J, E_D, E_O,
   the priors, E_A, E_B, body-object penetration, ground support for both, and contact
   E_C in the frames flagged Q_t.
4. **Contact frames** (ours; the thesis annotates them by hand): `detect_contact` flags the
   frames where a hand is within reach of the object and moves with it, with hysteresis.
5. **Acceptance** (ours): `accept_object` keeps the joint fit's object pose in the frames
   where it explains the object's observations (E_O) no worse than the track.

Every problem is a `jaxmocap.solve.Problem` of the terms in `energies.interaction` and
`energies.camera`; weights are traced (ablations reuse one compiled solve).
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from scipy.spatial import cKDTree

from ..body.kinematics import forward
from ..body.model import Body
from ..energies.camera import CameraData, keypoint_term, pose_prior_term, shape_term, silhouette_data
from ..energies.interaction import (
    InteractionData,
    bend_term,
    body_depth_term,
    body_spheres,
    contact_term,
    ground_term,
    object_depth_term,
    object_ground_term,
    object_mask_term,
    object_smoothness_term,
    penetration_term,
    self_penetration_term,
    smoothness_term,
)
from ..energies.posed import CombinedData
from ..geometry.masks import select_candidate
from ..geometry.raster import rasterize_views, visible_vertices, window_for
from ..motion.reach import CONTACT_PARTS, contact_vertices
from ..objects import RigidObject
from ..priors.pose_prior import PosePrior
from ..rotation import host_exp, host_log
from ..solve import Problem, frame, solve, with_weights
from .multiview import MuVSWeights, camera_data, dataclasses_replace, initialise, stage_one
from .weights import FitResult, Weights

__all__ = [
    "InterCapWeights",
    "InteractionObservations",
    "InterCapResult",
    "contact_region",
    "object_sdf",
    "track_object",
    "fit_human",
    "detect_contact",
    "fit_joint",
    "accept_object",
    "intercap",
]


@dataclasses.dataclass(frozen=True)
class InterCapWeights(Weights):
    """Weights of eq. 5.1-5.7 (Huang gives none: ours, set on synthetic scenes of the
    training clips; see experiments/intercap_tables.py). 0 switches a term off. The
    weights carry their terms' names (`term_weights`); `CONSTANTS` configure the terms.

    Units: keypoints in px (Geman-McClure σ px), masks in px, distances in m, so the
    metric terms carry large weights. body_points/object_points: points per view and frame
    kept for E_D and E_O; mask_points: mask samples per view and frame.
    accel_delta: Huber δ (m per frame²) of E_A and E_B (eq. 5.6), None for quadratic. 1 cm
    per frame² is about the jitter of the per-frame fits (white noise of σ ≈ 5 mm gives
    √6 σ); quadratic, the 1e5 weights pulled a bottle carried at 0.2 m per frame² 0.2 m
    off its observations on average (tables' scene 04, 30 frames: ADD-S 6.0 -> 199 mm)
    because E_O's depth part saturates (Geman-McClure σ = 2 cm) while the prior grows.

    smooth, object_smooth: λ_A, λ_B of eq. 5.6 (ours: the thesis gives none) as Gaussian
    priors on the accelerations, λ = 1/(2σ²) with σ the RMS per coordinate of true
    accelerations at 30 fps on the development scenes (subjects 02 and 131: the tables'
    bottle and box scenes of 30 frames): body vertices σ_A = 38 mm per frame², the
    object's box corners σ_B = 60 mm per frame². At 1e5 (σ = 2.2 mm per frame², below the
    fits' own jitter) E_A flattened the real motion (bottle scene: MPJPE 32.0 -> 37.7 mm,
    wrists 44 -> 82 mm, with the truth's E_A cost above the fit's) and E_B the carried
    object's; at these weights the bottle scene goes 32.0 -> 27.5 mm, ADD-S 6.0 -> 6.0 mm.
    """

    keypoints: float = 1.0
    sigma: float = 100.0
    pose_prior: float = 20.0
    shape: float = 50.0
    body_depth: float = 2e4
    bend: float = 1.0
    self_penetration: float = 1e4
    object_mask: float = 1.0
    object_depth: float = 1e5
    smooth: float = 350.0
    object_smooth: float = 140.0
    penetration: float = 1e5
    ground: float = 1e5
    object_ground: float = 1e5
    contact: float = 1e5
    accel_delta: float | None = 0.01
    body_points: int = 256
    object_points: int = 128
    mask_points: int = 96
    icp_rounds: int = 2

    CONSTANTS = ("sigma", "accel_delta", "body_points", "object_points", "mask_points", "icp_rounds")


@dataclasses.dataclass(frozen=True)
class InteractionObservations:
    """Calibrated static RGB-D views of one person and one object (NumPy).

    K, R, t: (V, 3, 3), (V, 3, 3), (V, 3) intrinsics and world-to-camera extrinsics.
    keypoints: (T, V, K, 3) detections (u, v, confidence) in the `layout`'s order.
    body_points, body_valid: (T, V, M, 3) world points segmented as the person, (T, V, M).
    object_points, object_valid: the same for the object.
    candidates: (T, V, C, H, W) bool object segmentation candidates per view (§5.2.2).
    obj: the object's mesh; fps: frame rate; floor: ground height (y up).
    """

    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    keypoints: np.ndarray
    body_points: np.ndarray
    body_valid: np.ndarray
    object_points: np.ndarray
    object_valid: np.ndarray
    candidates: np.ndarray
    obj: RigidObject
    fps: float = 30.0
    floor: float = 0.0
    layout: str = "body25"

    def __post_init__(self):
        T, V = np.shape(self.keypoints)[:2]
        expect = {
            "K": (V, 3, 3), "R": (V, 3, 3), "t": (V, 3), "body_points": (T, V, None, 3), "body_valid": (T, V, None),
            "object_points": (T, V, None, 3), "object_valid": (T, V, None), "candidates": (T, V, None, None, None),
        }  # fmt: skip
        for name, shape in expect.items():
            got = np.shape(getattr(self, name))
            if len(got) != len(shape) or any(e is not None and g != e for g, e in zip(got, shape)):
                want = "(" + ", ".join("·" if e is None else str(e) for e in shape) + ")"
                raise ValueError(f"InteractionObservations.{name} must have shape {want} for T={T} frames and "
                                 f"V={V} views (from keypoints {np.shape(self.keypoints)}); got {got}.")  # fmt: skip
        for name in ("body_points", "object_points"):
            valid = np.asarray(getattr(self, name.replace("points", "valid")), bool)
            if not np.isfinite(np.asarray(getattr(self, name))[valid]).all():
                raise ValueError(
                    f"InteractionObservations.{name} has NaN or inf among its valid points; mark them invalid."
                )

    @property
    def num_frames(self) -> int:
        return int(np.shape(self.keypoints)[0])

    @property
    def image_size(self) -> tuple[int, int]:
        """(H, W) of the candidate masks."""
        return tuple(np.shape(self.candidates)[-2:])

    @classmethod
    def from_scenario(cls, scenario, i: int = 0, seed: int = 0, num_distractors: int = 2) -> InteractionObservations:
        """Moved to `jaxmocap.app.scenarios.interaction_observations`; this alias goes in the next release."""
        from ..app.scenarios import interaction_observations

        return interaction_observations(scenario, i, seed, num_distractors)


@dataclasses.dataclass(frozen=True)
class InterCapResult(FitResult):
    """poses (T, 24, 3) axis-angle, trans (T, 3), betas (B,), object_R (T, 3, 3), object_t
    (T, 3), contact (T,) bool (the frames E_C acted on), and the stages' outcomes.
    solution: the engine's `Solution` of the last solve of the human-only ("human") and
    joint ("joint") fits (`FitResult`; the object tracker's per-frame solves are not kept)."""

    poses: np.ndarray
    trans: np.ndarray
    betas: np.ndarray
    object_R: np.ndarray
    object_t: np.ndarray
    contact: np.ndarray
    stages: dict
    solution: dict = dataclasses.field(default_factory=dict)

    @property
    def params(self) -> dict:
        """The fitted unknowns: the body's, and the object's pose as (R, t)."""
        return {"pose": self.poses, "trans": self.trans, "betas": self.betas, "object_R": self.object_R,
                "object_t": self.object_t}  # fmt: skip


def contact_region(body: Body, part: str, depth: float = 0.015) -> np.ndarray:
    """InterCap's annotated contact vertices of a hand or foot (Huang Fig. 5.3), chosen
    automatically: the part's vertices (`sensors.objects.contact_vertices`) within `depth`
    (m) of its extreme along the part's contact normal in the rest pose (palm, sole)."""
    if part not in CONTACT_PARTS:
        raise ValueError(f"unknown contact region {part!r}; choose from {sorted(CONTACT_PARTS)}.")
    ids = contact_vertices(body, part)
    n = np.asarray(CONTACT_PARTS[part][2])
    along = np.asarray(body.v_template, np.float64)[ids] @ n
    return ids[along >= along.max() - depth]


# --- rigid poses as (ω, t) ------------------------------------------------------------------


def _pose6(R, t) -> np.ndarray:
    return np.concatenate([host_log(R), np.asarray(t, np.float64)], -1)


def _matrices(pose6) -> tuple[np.ndarray, np.ndarray]:
    pose6 = np.asarray(pose6, np.float64)
    return host_exp(pose6[..., :3]), pose6[..., 3:]


def _cube_rotations() -> np.ndarray:
    """The 24 rotations of a cube (axis-aligned orientations)."""
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            M = np.zeros((3, 3))
            M[np.arange(3), perm] = signs
            if np.linalg.det(M) > 0:
                out.append(M)
    return np.stack(out)


# --- problems (terms are equinox modules: equal settings, equal problems, one compiled solve) --

_OBJECT_TERMS = ("object_mask", "object_depth")
_HUMAN_TERMS = ("keypoints", "pose_prior", "body_depth", "bend", "self_penetration")
_JOINT_TERMS = _HUMAN_TERMS + _OBJECT_TERMS + ("smooth", "object_smooth", "penetration", "ground", "object_ground",
                                               "contact")  # fmt: skip


def _problem(names: tuple[str, ...], sigma: float, accel_delta: float | None = None) -> Problem:
    """The terms `names` at unit weights; E_O's depth σ is `_weighted`'s (an array there)."""
    makers = {
        "keypoints": lambda: keypoint_term(sigma), "pose_prior": pose_prior_term, "shape": shape_term,
        "body_depth": body_depth_term, "bend": bend_term, "self_penetration": self_penetration_term,
        "object_mask": object_mask_term, "object_depth": object_depth_term,
        "smooth": lambda: smoothness_term(delta=accel_delta),
        "object_smooth": lambda: object_smoothness_term(delta=accel_delta),  # eq. 5.6: see accel_delta
        "penetration": penetration_term, "ground": ground_term, "object_ground": object_ground_term,
        "contact": contact_term,
    }  # fmt: skip
    unknowns = {}
    if set(names) & set(_HUMAN_TERMS):
        unknowns.update(pose=frame("so3"), trans=frame())
    if "shape" in names:
        unknowns["betas"] = frame()
    if set(names) & set(_OBJECT_TERMS + ("contact", "penetration", "object_smooth", "object_ground")):
        unknowns["object"] = frame("se3")
    return Problem([makers[n]() for n in names], unknowns)


def _weighted(names, weights: InterCapWeights, dtype, off=(), depth_sigma: float = 0.02) -> Problem:
    names = tuple(names)
    problem = _problem(names, weights.sigma, weights.accel_delta)
    if "object_depth" in names:  # E_O's σ traced like the weights: the coarse and fine trackers share one program
        k = names.index("object_depth")
        problem = eqx.tree_at(lambda p: p.terms[k].loss.sigma, problem, jnp.asarray(depth_sigma, dtype))
    w = weights.term_weights()
    return with_weights(problem, {n: jnp.asarray(0.0 if n in off else w[n], dtype) for n in names})


# --- data --------------------------------------------------------------------------------------


def object_sdf(obj: RigidObject):
    """The object's SDF as every InterCap term and metric reads it (48³ grid, 10 cm margin:
    the hand's contact vertices stay inside the grid while they approach)."""
    return obj.sdf(48, 0.1)


@functools.lru_cache(maxsize=32)
def _surface(obj: RigidObject, count: int = 400, seed: int = 0) -> np.ndarray:
    """Evenly spread surface samples of the object (its frame; built once per object)."""
    import trimesh

    pts, _ = trimesh.sample.sample_surface_even(obj.mesh, count, seed=seed)
    return np.concatenate([np.asarray(pts, np.float64), np.asarray(obj.vertices, np.float64)])


def _subsample(points, valid, count: int, seed: int = 0):
    """At most `count` valid points per (frame, view), valid ones first (deterministic)."""
    T, V, M = valid.shape
    rng = np.random.default_rng(seed)
    order = np.argsort(~valid + rng.random(valid.shape) * 0.5, axis=-1, kind="stable")[..., :count]
    pts = np.take_along_axis(points, order[..., None], axis=2)
    ok = np.take_along_axis(valid, order, axis=2)
    pad = count - pts.shape[2]
    if pad > 0:
        pts = np.concatenate([pts, np.zeros((T, V, pad, 3))], 2)
        ok = np.concatenate([ok, np.zeros((T, V, pad), bool)], 2)
    return np.nan_to_num(pts).astype(np.float64), ok


def _interaction_data(
    obs: InteractionObservations,
    body: Body,
    masks,
    weights: InterCapWeights,
    betas=None,
    contact=None,
    body_match=None,
    contact_ids=None,
    dtype=jnp.float32,
) -> InteractionData:
    T, V = obs.num_frames, len(obs.K)
    obj = obs.obj
    surface = _surface(obj)
    lo, hi = obj.vertices.min(0), obj.vertices.max(0)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    bp, bv = _subsample(obs.body_points, obs.body_valid, weights.body_points, 1)
    op, ov = _subsample(obs.object_points, obs.object_valid, weights.object_points, 2)
    sil = silhouette_data(masks, weights.mask_points) if masks is not None else None
    spheres = body_spheres(body, betas)
    a = lambda x: jnp.asarray(x, dtype)  # noqa: E731
    return InteractionData(
        surface=a(surface), corners=a(corners), sdf=object_sdf(obj), object_masks=sil,
        object_points=a(op), object_valid=jnp.asarray(ov), body_points=a(bp), body_valid=jnp.asarray(bv),
        body_match=jnp.asarray(np.zeros((T, V, bp.shape[2]), np.int32) if body_match is None else body_match, jnp.int32),
        contact=a(np.zeros(T) if contact is None else contact),
        contact_vertices=jnp.asarray(np.zeros(1, np.int32) if contact_ids is None else contact_ids, jnp.int32),
        floor=a(obs.floor), sphere_weights=a(spheres["sphere_weights"]), sphere_radius=a(spheres["sphere_radius"]),
        sphere_pairs=jnp.asarray(spheres["sphere_pairs"], jnp.int32),
    )  # fmt: skip


# --- 1. object-only tracking (eq. 5.1) --------------------------------------------------------


def _render_masks(obs: InteractionObservations, R, t, window: int) -> np.ndarray:
    """The object posed at (R, t) rendered in every view: (V, H, W) bool."""
    H, W = obs.image_size
    verts = obs.obj.vertices @ np.asarray(R).T + np.asarray(t)
    out = []
    for v in range(len(obs.K)):
        _, label = rasterize_views(
            obs.K[v].astype(np.float32), obs.R[v][None].astype(np.float32), obs.t[v][None].astype(np.float32),
            verts[None].astype(np.float32), obs.obj.faces, np.zeros(len(obs.obj.faces)), W, H, window=window,
        )  # fmt: skip
        out.append(np.asarray(label[0]) >= 0)
    return np.stack(out)


def track_object(
    obs: InteractionObservations,
    weights: InterCapWeights = InterCapWeights(),
    max_steps: int = 30,
    body: Body | None = None,
    progress: bool = False,
) -> dict:
    """Object-only tracking, frame by frame (module docstring, step 1).

    Returns {"R": (T, 3, 3), "t": (T, 3), "masks": (T, V, H, W) the kept candidates,
    "chosen": (T, V) candidate index (-1: none), "observed": (T,) bool (any mask or point)}.
    A frame where the object is seen in no view keeps the previous frame's pose.
    """
    from ..body.io import default_body

    body = default_body("low") if body is None else body
    T, V = obs.num_frames, len(obs.K)
    H, W = obs.image_size
    cand = np.asarray(obs.candidates, bool)
    dtype = jnp.float32
    names = _OBJECT_TERMS
    problem = _weighted(names, weights, dtype)
    # One frame at a time: every frame's data has the shape of frame 0's (one compilation).
    full = _interaction_data(obs, body, np.zeros((T, V, H, W), bool), weights, dtype=dtype)
    cam = _cameras(obs, body, dtype)

    def frame_data(t, mask):
        one = slice(t, t + 1)
        part = dataclasses_replace(
            full, object_masks=silhouette_data(mask[None], weights.mask_points), object_points=full.object_points[one],
            object_valid=full.object_valid[one], body_points=full.body_points[one], body_valid=full.body_valid[one],
            body_match=full.body_match[one], contact=full.contact[one],
        )  # fmt: skip
        return CombinedData((cam, part))

    run = functools.partial(_solve_object, problem, max_steps=max_steps)
    # Frame 0: the centroid of its object points under 24 axis-aligned rotations, each
    # solved first with a wide depth σ (0.1 m: from a centroid start the 2 cm σ of the
    # tracking would ignore the far points and can stop with the visible side inside the
    # object), then refined; the lowest cost wins.
    coarse = _weighted(names, weights, dtype, depth_sigma=0.1)
    run_coarse = functools.partial(_solve_object, coarse, max_steps=max_steps)
    seen0 = np.asarray(obs.object_valid[0])
    if not seen0.any():
        raise ValueError("the object has no depth points in the first frame: track_object needs it seen at the start.")
    centroid = np.asarray(obs.object_points[0])[seen0].mean(0)
    first_mask = np.zeros((V, H, W), bool)
    for v in range(V):  # frame 0: the candidate holding most object points' projections
        first_mask[v] = _best_by_points(obs, cand[0, v], v, seen0)
    data0 = frame_data(0, first_mask)
    best = None
    for Rc in _cube_rotations():
        p0 = {"object": jnp.asarray(_pose6(Rc, centroid - Rc @ obs.obj.vertices.mean(0))[None], dtype)}
        sol = run(run_coarse(p0, data0).value, data0)
        if best is None or float(sol.cost) < best[0]:
            best = (float(sol.cost), np.asarray(sol.value["object"][0]))
    pose = best[1]
    Rs, ts = np.zeros((T, 3, 3)), np.zeros((T, 3))
    masks = np.zeros((T, V, H, W), bool)
    chosen = np.full((T, V), -1)
    observed = np.zeros(T, bool)
    R0, t0 = _matrices(pose)
    window = window_for(obs.K[0], obs.R, obs.t, (obs.obj.vertices @ R0.T + t0)[None], obs.obj.faces)
    iterator = range(T)
    if progress:
        from tqdm import tqdm

        iterator = tqdm(iterator, desc="object", leave=False)
    for t in iterator:
        Rp, tp = _matrices(pose)
        ref = _render_masks(obs, Rp, tp, window)
        pick = select_candidate(cand[t], ref)
        chosen[t] = pick
        for v in range(V):
            if pick[v] >= 0:
                masks[t, v] = cand[t, v, pick[v]]
        observed[t] = masks[t].any() or np.asarray(obs.object_valid[t]).any()
        if observed[t]:
            sol = run({"object": jnp.asarray(pose[None], dtype)}, frame_data(t, masks[t]))
            if np.isfinite(np.asarray(sol.value["object"])).all():
                pose = np.asarray(sol.value["object"][0], np.float64)
        Rs[t], ts[t] = _matrices(pose)
    return {"R": Rs, "t": ts, "masks": masks, "chosen": chosen, "observed": observed}


@eqx.filter_jit
def _solve_object(problem, params, data, max_steps):
    """One frame's object solve, compiled once for every frame and both σ (problems differ in arrays only)."""
    return solve(problem, params, data, max_steps=max_steps)


def _best_by_points(obs, candidates, v, seen) -> np.ndarray:
    """The candidate of view v covering most projected object points of frame 0."""
    from ..geometry.camera import project

    pts = np.asarray(obs.object_points[0])[seen]
    uv, z = project(jnp.asarray(obs.K[v]), jnp.asarray(obs.R[v]), jnp.asarray(obs.t[v]), jnp.asarray(pts))
    uv, z = np.asarray(uv), np.asarray(z)
    H, W = candidates.shape[-2:]
    col, row = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
    ok = (z > 0) & (col >= 0) & (col < W) & (row >= 0) & (row < H)
    if not ok.any() or not len(candidates):
        return np.zeros((H, W), bool)
    hits = candidates[:, row[ok], col[ok]].sum(1)
    return candidates[int(np.argmax(hits))] if hits.max() > 0 else np.zeros((H, W), bool)


# --- 2. human-only (eq. 5.2-5.5) ---------------------------------------------------------------


def _cameras(obs: InteractionObservations, body: Body, dtype, prior: PosePrior | None = None) -> CameraData:
    return camera_data(body, obs.K, obs.R, obs.t, obs.keypoints, obs.layout, prior=prior, dtype=dtype)


# One program per shape: run eagerly, the vmapped visibility test compiled each of its operations.
_visible_per_frame = jax.jit(jax.vmap(visible_vertices, in_axes=(None, None, None, 0, 0)))


def _correspondences(obs, body, poses, betas, trans, points, valid) -> np.ndarray:
    """For every body point, the closest vertex visible in its view (E_D, eq. 5.4): (T, V, M)."""
    T, V, M = valid.shape
    out = forward(body, jnp.asarray(poses, body.dtype), jnp.asarray(betas, body.dtype), jnp.asarray(trans, body.dtype))
    verts = np.asarray(out.vertices, np.float64)
    H, W = obs.image_size
    Rb = np.repeat(obs.R[:, None], T, 1).reshape(V * T, 3, 3)
    tb = np.repeat(obs.t[:, None], T, 1).reshape(V * T, 3)
    vb = np.broadcast_to(verts[None], (V,) + verts.shape).reshape(V * T, *verts.shape[1:])
    match = np.zeros((T, V, M), np.int32)
    faces = np.asarray(body.faces)
    for v in range(V):
        sl = slice(v * T, (v + 1) * T)
        window = window_for(obs.K[v], Rb[sl], tb[sl], vb[sl], faces)
        depth, _ = rasterize_views(obs.K[v].astype(np.float32), Rb[sl].astype(np.float32), tb[sl].astype(np.float32),
                                   vb[sl].astype(np.float32), faces, np.zeros(len(faces)), W, H, window=window)  # fmt: skip
        vis = np.asarray(_visible_per_frame(
            jnp.asarray(obs.K[v], jnp.float32), jnp.asarray(obs.R[v], jnp.float32), jnp.asarray(obs.t[v], jnp.float32),
            jnp.asarray(verts, jnp.float32), depth))  # fmt: skip
        for t in range(T):
            ids = np.flatnonzero(vis[t])
            if not len(ids) or not valid[t, v].any():
                continue
            _, k = cKDTree(verts[t, ids]).query(points[t, v])
            match[t, v] = ids[k]
    return match


def fit_human(
    obs: InteractionObservations,
    body: Body | None = None,
    weights: InterCapWeights = InterCapWeights(),
    prior: PosePrior | None = None,
    max_steps: int = 40,
) -> dict:
    """Human-only, per frame (module docstring, step 2): {pose, trans, betas (T, B)}."""
    return _fit_human(obs, body, weights, prior, max_steps)[0]


def _fit_human(obs, body, weights, prior, max_steps: int = 40) -> tuple[dict, object]:
    """`fit_human`, and the `Solution` of its last solve (None without ICP rounds)."""
    from ..body.io import default_body

    body = default_body("low") if body is None else body
    dtype = jnp.float32
    cam = _cameras(obs, body, dtype, prior)
    muvs = MuVSWeights(
        keypoints=weights.keypoints,
        sigma=weights.sigma,
        pose_prior=weights.pose_prior,
        shape=weights.shape,
        reference_focal=None,
    )  # fmt: skip  (InterCap's weights are in its own pixels)
    p, _ = stage_one(cam, initialise(cam, muvs.num_betas), muvs, silhouettes=False, max_steps=max_steps)
    names = ("keypoints", "pose_prior", "shape", "body_depth", "bend", "self_penetration")
    problem = _weighted(names, weights, dtype)
    bp, bv = _subsample(obs.body_points, obs.body_valid, weights.body_points, 1)
    sol = None
    for _ in range(weights.icp_rounds):
        match = _correspondences(obs, body, p["pose"], p["betas"], p["trans"], bp, bv)
        data = _interaction_data(obs, body, None, weights, np.median(p["betas"], 0), body_match=match, dtype=dtype)
        sol = solve(problem, {k: jnp.asarray(v, dtype) for k, v in p.items()}, CombinedData((cam, data)),
                    max_steps=max_steps)  # fmt: skip
        p = {k: np.asarray(v) for k, v in sol.value.items()}
    return p, sol


# --- 4. contact frames (ours) -------------------------------------------------------------------


def detect_contact(
    body: Body,
    human: dict,
    obj: dict,
    sdf_object: RigidObject,
    fps: float,
    parts=("left_grip", "right_grip", "left_hand", "right_hand"),
    reach: float = 0.08,
    speed: float = 0.1,
    moving: float = 0.15,
    touch: float = 0.03,
    min_frames: int = 3,
) -> tuple[np.ndarray, str]:
    """Frames in which a hand holds the object, from the two fits alone (no annotation).

    Per part (a `contact_region`) and frame, on trajectories smoothed over 5 frames (the
    per-frame fits jitter): the part is within `reach` (m) of the object surface, and
    either the object moves (speed above `moving` m/s: something must carry it, and the
    nearest hand is the only candidate) or, for a still object, the part touches it
    (within `touch`) and is still in the object's frame (below `speed` m/s): a hand
    merely passing near a resting object is not holding it. Hysteresis: a contact starts
    after `min_frames` such frames in a row and ends after `min_frames` frames without.

    Returns ((T,) bool contact frames, the part holding longest; the first of `parts` when none holds).
    """
    poses, betas, trans = (np.asarray(human[k]) for k in ("pose", "betas", "trans"))
    betas = betas if betas.ndim == 1 else betas.mean(0)
    out = forward(body, jnp.asarray(poses, body.dtype), jnp.asarray(betas, body.dtype), jnp.asarray(trans, body.dtype))
    verts = np.asarray(out.vertices, np.float64)
    Ro, to = np.asarray(obj["R"], np.float64), np.asarray(obj["t"], np.float64)
    sdf = object_sdf(sdf_object)
    T = len(verts)
    smooth = lambda x: _moving_average(x, 5)  # noqa: E731
    centre = smooth(to + np.einsum("tab,b->ta", Ro, sdf_object.vertices.mean(0)))
    obj_speed = np.linalg.norm(np.gradient(centre, axis=0), axis=-1) * fps
    best = (-1, np.zeros(T, bool), parts[0])
    # Every part's vertices in the object frame, their distances in one compiled call.
    regions = [contact_region(body, part) for part in parts]
    local_all = np.einsum("tba,tnb->tna", Ro, verts[:, np.concatenate(regions)] - to[:, None])
    dist_all = np.asarray(_sdf_at(sdf, jnp.asarray(local_all, jnp.float32)), np.float64)
    bounds = np.cumsum([0] + [len(r) for r in regions])
    for part, lo, hi in zip(parts, bounds[:-1], bounds[1:]):
        local = local_all[:, lo:hi]  # object frame
        d = smooth(dist_all[:, lo:hi].min(1))
        rel = np.linalg.norm(np.gradient(smooth(local.mean(1)), axis=0), axis=-1) * fps
        holding = (d < reach) & ((obj_speed > moving) | ((rel < speed) & (d < touch)))
        state = _hysteresis(holding, ~holding, min_frames)
        if state.sum() > best[0]:
            best = (int(state.sum()), state, part)
    return best[1], best[2]


@jax.jit
def _sdf_at(sdf, points):
    """`sdf(points)` as one program per shape (eagerly, each trilinear lookup op compiled)."""
    return sdf(points)


def _moving_average(x: np.ndarray, width: int) -> np.ndarray:
    """Centred moving average along axis 0 (edges: the available frames)."""
    x = np.asarray(x, np.float64)
    c = np.cumsum(np.concatenate([np.zeros((1,) + x.shape[1:]), x]), 0)
    T, h = len(x), width // 2
    lo, hi = np.clip(np.arange(T) - h, 0, T), np.clip(np.arange(T) + h + 1, 0, T)
    return (c[hi] - c[lo]) / (hi - lo).reshape((-1,) + (1,) * (x.ndim - 1))


def _hysteresis(on: np.ndarray, off: np.ndarray, min_frames: int) -> np.ndarray:
    """State that switches on after `min_frames` `on` frames in a row and off after as many `off` ones."""
    state = np.zeros(len(on), bool)
    active, run = False, 0
    for t in range(len(on)):
        run = run + 1 if (off[t] if active else on[t]) else 0
        if run >= min_frames:  # switch, back to where the run began
            active, run = not active, 0
            state[t - min_frames + 1 : t + 1] = active
        else:
            state[t] = active
    return state


# --- 3. joint fit over all frames (eq. 5.6-5.7) -------------------------------------------------


def fit_joint(
    obs: InteractionObservations,
    human: dict,
    obj: dict,
    contact,
    body: Body | None = None,
    weights: InterCapWeights = InterCapWeights(),
    off=(),
    parts=("right_hand", "left_hand"),
    prior: PosePrior | None = None,
    max_steps: int = 40,
) -> dict:
    """Joint fit of every frame (module docstring, step 3) from the human-only and object
    fits; `contact` (T,) Q_t; `off`: term names switched off (ablations).

    Returns {pose, trans, betas (B,), object_R, object_t, costs}.
    """
    return _fit_joint(obs, human, obj, contact, body, weights, off, parts, prior, max_steps)[0]


def _fit_joint(obs, human, obj, contact, body, weights, off, parts, prior, max_steps: int = 40) -> tuple[dict, object]:
    """`fit_joint`, and the `Solution` of its last solve (None without ICP rounds)."""
    from ..body.io import default_body

    body = default_body("low") if body is None else body
    unknown = set(off) - set(_JOINT_TERMS)
    if unknown:
        raise ValueError(f"unknown term(s) {sorted(unknown)} in off; the joint fit has {list(_JOINT_TERMS)}.")
    dtype = jnp.float32
    betas = np.asarray(human["betas"]).mean(0) if np.ndim(human["betas"]) == 2 else np.asarray(human["betas"])
    cam = dataclasses_replace(_cameras(obs, body, dtype, prior), betas=jnp.asarray(betas, dtype))
    problem = _weighted(_JOINT_TERMS, weights, dtype, off)
    ids = np.concatenate([contact_vertices(body, p) for p in parts])  # E_C: the closest of them touches
    p = {"pose": jnp.asarray(human["pose"], dtype), "trans": jnp.asarray(human["trans"], dtype),
         "object": jnp.asarray(_pose6(obj["R"], obj["t"]), dtype)}  # fmt: skip
    bp, bv = _subsample(obs.body_points, obs.body_valid, weights.body_points, 1)
    costs, sol = {}, None
    for r in range(weights.icp_rounds):
        match = _correspondences(obs, body, np.asarray(p["pose"]), betas, np.asarray(p["trans"]), bp, bv)
        data = _interaction_data(obs, body, obj["masks"], weights, betas, np.asarray(contact, np.float64), match, ids,
                                 dtype)  # fmt: skip
        sol = solve(problem, p, CombinedData((cam, data)), max_steps=max_steps)
        p = sol.value
        costs[f"round_{r}"] = {k: float(v) for k, v in sol.costs.items()}
    R, t = _matrices(np.asarray(p["object"]))
    return {"pose": np.asarray(p["pose"]), "trans": np.asarray(p["trans"]), "betas": betas, "object_R": R,
            "object_t": t, "costs": costs}, sol  # fmt: skip


def accept_object(
    obs: InteractionObservations,
    obj: dict,
    joint: dict,
    body: Body | None = None,
    weights: InterCapWeights = InterCapWeights(),
) -> dict:
    """Acceptance rule after the joint fit (ours; the thesis has none): per frame, the joint
    fit's object pose is kept only if it explains the object's own observations at least
    as well as the object-only track, i.e. E_O (eq. 5.1, the tracker's energy: the kept
    masks and object points, the same weights) is no higher there; otherwise the tracked
    pose stands. The joint energy (eq. 5.6) may trade the object's evidence for the
    body's (E_C, the penetration term, E_B); this rule lets the body take the contact and
    the object keep what its own data say. Frames without object data keep the joint pose.

    Returns {object_R (T, 3, 3), object_t (T, 3), accepted (T,) bool, cost_separate (T,),
    cost_joint (T,)}.
    """
    from ..body.io import default_body

    body = default_body("low") if body is None else body
    dtype = jnp.float32
    T = obs.num_frames
    problem = _weighted(_OBJECT_TERMS, weights, dtype)
    data = CombinedData((_cameras(obs, body, dtype), _interaction_data(obs, body, obj["masks"], weights, dtype=dtype)))
    frames = np.eye(T, dtype=bool)

    def per_frame(R, t) -> np.ndarray:
        p = {"object": jnp.asarray(_pose6(R, t), dtype)}
        return np.array([float(_cost(problem, p, data, jnp.asarray(frames[k]))) for k in range(T)])

    sep = per_frame(obj["R"], obj["t"])
    jnt = per_frame(joint["object_R"], joint["object_t"])
    keep = jnt <= sep
    return {"object_R": np.where(keep[:, None, None], joint["object_R"], obj["R"]),
            "object_t": np.where(keep[:, None], joint["object_t"], obj["t"]), "accepted": keep,
            "cost_separate": sep, "cost_joint": jnt}  # fmt: skip


@eqx.filter_jit
def _cost(problem, params, data, frame_mask):
    """`problem.cost`, one program for every frame and every call with equal settings."""
    return problem.cost(params, data, frame_mask)


def intercap(
    obs: InteractionObservations,
    body: Body | None = None,
    weights: InterCapWeights = InterCapWeights(),
    contact=None,
    off=(),
    prior: PosePrior | None = None,
    progress: bool = False,
) -> InterCapResult:
    """The whole method: object tracking, human fit, contact frames (detected unless
    `contact` (T,) is given; E_C then acts on the grips of both hands), joint fit."""
    from ..body.io import default_body

    body = default_body("low") if body is None else body
    obj = track_object(obs, weights, body=body, progress=progress)
    human, human_sol = _fit_human(obs, body, weights, prior)
    parts = ("right_grip", "left_grip")
    if contact is None:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            contact, part = detect_contact(body, human, obj, obs.obj, obs.fps)
        parts = (part,)
    joint, joint_sol = _fit_joint(obs, human, obj, contact, body, weights, off, parts, prior)
    kept = accept_object(obs, obj, joint, body, weights)
    return InterCapResult(
        poses=joint["pose"], trans=joint["trans"], betas=joint["betas"], object_R=kept["object_R"],
        object_t=kept["object_t"], contact=np.asarray(contact, bool),
        stages={"object": obj, "human": human, "joint": joint, "accept": kept},
        solution={k: v for k, v in (("human", human_sol), ("joint", joint_sol)) if v is not None},
    )  # fmt: skip
