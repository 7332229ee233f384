"""The Video Inertial Poser (VIP, von Marcard ch. 4): body IMUs + one moving hand-held camera.

One person wearing S IMUs is filmed by a hand-held camera that carries an IMU of its own.
`video_inertial_poser` minimises, over the whole sequence at once (eq. 4.19),

    E = w_ori E_ori + w_acc E_acc + w_img E_img + w_prior E_prior

with E_ori / E_acc over the body sensors and the camera IMU (eq. 4.20-4.26), E_img the
confidence-weighted reprojection of COCO-18 detections (eq. 4.27-4.28) and E_prior the
Gaussian pose prior plus joint limits (eq. 4.29-4.30, the limits are SIP's, eq. 3.15).
Unknowns: every frame's pose, translation and camera pose, one heading angle per body
sensor and the initial pose x₀ that defines the sensor-to-bone offsets (eq. 4.7-4.9);
see `energies.visual_inertial` for the sensor model and the choices that are ours.

Initialisation (eq. 4.10): the Inertial Tracker, E_ori + prior per frame, with the
offsets of the given x₀ and no heading correction. The camera starts at its IMU's
orientation and, per frame, the translation that best reprojects the tracker's keypoints
onto the detections (linear least squares with the rotation known; our stand-in for the
per-hypothesis camera fit of eq. 4.13-4.14). The body translation starts at the given
one on every frame.

Association (eq. 4.11-4.18): `tracker_hypotheses` gives the Inertial Tracker keypoints of
each wearer that `methods.association` assigns detections to. For simulated scenes,
`app.scenarios.associated_keypoints` does it for a scenario's detections; pass its rows to
`app.scenarios.vip_sequence(keypoints=…)`, which by default takes the person's detections
by the simulator's identity labels (the "oracle" used by the ablations).

Variants (Tables 4.4-4.9): `free_heading=False` (VIP-noHeadParam), `free_heading=False,
free_x0=False` (VIP-vanilla), `tracker_with(…)` on a VIP result (VIP-IT), true
keypoints (VIP-2D) and true camera (`camera=…, free_camera=False`, VIP-Cam) are inputs.
"""

from __future__ import annotations

import dataclasses
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from .._checks import check_rate
from ..body.compact import compact_body
from ..body.kinematics import forward, shaped_joints
from ..body.model import Body
from ..energies.imu import GRAVITY_REACTION, joint_limit_term, mahalanobis_term
from ..energies.visual_inertial import (
    REFERENCE_IMAGE_HEIGHT,
    VIPData,
    camera_acceleration_term,
    camera_orientation_term,
    heading_acceleration_term,
    heading_orientation_term,
    image_term,
    initial_pose_term,
)
from ..geometry.keypoints import keypoint_regressor, regress_keypoints
from ..priors.pose_prior import PosePrior, default_pose_prior
from ..rotation import axis_angle_to_matrix, matrix_to_axis_angle
from ..solve import Problem, Solution, frame, sequence, solve, solve_batch, with_weights
from .association import AssociationModel, associate
from .weights import FitResult, Weights, renamed

__all__ = ["VIPWeights", "VIPResult", "vip_data", "inertial_tracker", "initial_camera", "video_inertial_poser",
           "tracker_hypotheses", "with_keypoints", "world_keypoints",
           "VIPScene", "video_inertial_scene"]  # fmt: skip


@renamed(prior="mahal")
@dataclasses.dataclass(frozen=True)
class VIPWeights(Weights):
    """Weights of eq. 4.19 (defaults: von Marcard §4.3: w_acc 0.2, w_img 1e-4, w_prior
    0.006; w_ori 1), each named after its term: mahal is the thesis's w_prior (`prior`
    until this release: the old name still works, with a DeprecationWarning). Ours: limit
    (SIP's w_limit, eq. 3.16) and x0, the pull of x₀ towards its given value
    (`energies.visual_inertial.initial_pose_term`)."""

    ori: float = 1.0
    acc: float = 0.2
    img: float = 1e-4
    mahal: float = 0.006
    limit: float = 0.1
    x0: float = 0.1

    def term_weights(self, num_sensors: int, free_camera: bool = True) -> dict:
        """{term: weight} of eq. 4.19-4.20: the IMU terms averaged over the sensors, the
        camera IMU counting as one when the camera is free (its terms cam_ori, cam_acc)."""
        n = num_sensors + 1 if free_camera else num_sensors
        w = {"ori": self.ori / n, "acc": self.acc / n, "img": self.img, "mahal": self.mahal, "limit": self.limit,
             "x0": self.x0}  # fmt: skip
        if free_camera:
            w.update(cam_ori=self.ori / n, cam_acc=self.acc / n)
        return w


class VIPResult(eqx.Module, FitResult):
    """poses (T, 24, 3), trans (T, 3), camera (T, 6) camera-to-world (axis-angle, centre),
    heading (S,) γ_s, x0 (24, 3), init: the Inertial Tracker's poses, solution: the engine's."""

    poses: Array
    trans: Array
    camera: Array
    heading: Array
    x0: Array
    init: Array
    solution: Solution

    @property
    def params(self) -> dict:
        """pose, trans, cam, heading, x0 by the problem's names (those held fixed: their given values)."""
        return {"pose": self.poses, "trans": self.trans, "cam": self.camera, "heading": self.heading, "x0": self.x0}


def _global_acceleration(R, a):
    return np.einsum("...ab,...b->...a", R, a) - np.asarray(GRAVITY_REACTION)


def vip_data(
    body: Body,
    bones,
    vertices,
    orientation,
    acceleration,
    x0,
    fps: float,
    cam_orientation,
    cam_acceleration,
    K,
    keypoints,
    image_height: int,
    betas=None,
    prior: PosePrior | None = None,
    dtype=jnp.float64,
) -> VIPData:
    """Check and calibrate one person's readings and detections into `VIPData`.

    Args:
        orientation (T, S, 3, 3) measured R̃_s^g, acceleration (T, S, 3) sensor frame ã^s
            (NaN = dropped; frame 0 must be complete: it is the calibration frame).
        x0: (24, 3) the given initial pose (axis-angle) at frame 0.
        cam_orientation (T, 3, 3), cam_acceleration (T, 3): the camera IMU (sensor frame
            = camera frame). Required: without it the camera pose is not observable
            apart from the images.
        K (3, 3); keypoints (T, 18, 3) COCO-18 rows (u, v, confidence) in undistorted
            pixels; a frame without detections has confidence 0 (or NaN) and is fitted
            from the IMUs alone.
    """
    check_rate("fps", fps)
    orientation = np.asarray(orientation, np.float64)
    acceleration = np.asarray(acceleration, np.float64)
    if orientation.ndim != 4 or orientation.shape[-2:] != (3, 3):
        raise ValueError(f"orientation has shape {orientation.shape}; expected (T, S, 3, 3).")
    T, S = orientation.shape[:2]
    if acceleration.shape != (T, S, 3):
        raise ValueError(f"acceleration has shape {acceleration.shape}; expected (T, S, 3) = ({T}, {S}, 3).")
    if len(bones) != S or len(vertices) != S:
        raise ValueError(f"{S} sensors in the readings but {len(bones)} bones and {len(vertices)} vertices.")
    if not np.isfinite(orientation[0]).all():
        raise ValueError("orientation: frame 0 has dropped samples; VIP calibrates the sensor-to-bone "
                         "offsets on frame 0 (eq. 4.9): start the sequence at a complete frame.")  # fmt: skip
    if cam_orientation is None or cam_acceleration is None:
        raise ValueError("VIP needs the camera IMU (cam_orientation (T, 3, 3) and cam_acceleration (T, 3)): "
                         "it fixes the world heading and the camera's motion (eq. 4.20-4.22).")  # fmt: skip
    cam_orientation = np.asarray(cam_orientation, np.float64)
    cam_acceleration = np.asarray(cam_acceleration, np.float64)
    if cam_orientation.shape != (T, 3, 3) or cam_acceleration.shape != (T, 3):
        raise ValueError(f"camera IMU must be (T, 3, 3) and (T, 3) with T = {T}; got {cam_orientation.shape} "
                         f"and {cam_acceleration.shape}.")  # fmt: skip
    keypoints = np.asarray(keypoints, np.float64)
    if keypoints.shape != (T, 18, 3):
        raise ValueError(
            f"keypoints have shape {keypoints.shape}; expected (T, 18, 3) COCO-18 rows (u, v, confidence), T = {T}."
        )
    K = np.asarray(K, np.float64)
    if K.shape != (3, 3):
        raise ValueError(f"K has shape {K.shape}; expected (3, 3).")
    uv, confidence = _detections(keypoints)
    if not (confidence > 0).any():
        raise ValueError("no frame has a detection (all confidences are 0 or NaN): VIP needs images; "
                         "use the Inertial Tracker or SIP for IMUs alone.")  # fmt: skip
    x0 = np.asarray(x0, np.float64)
    if x0.shape != (24, 3):
        raise ValueError(f"x0 has shape {x0.shape}; expected (24, 3) axis-angle.")
    betas = np.zeros(body.num_betas) if betas is None else np.asarray(betas, np.float64)
    body = body.astype(dtype)
    out = forward(body, jnp.asarray(x0, dtype), jnp.asarray(betas, dtype), jnp.zeros(3, dtype))
    b, v = np.asarray(bones), np.asarray(vertices)
    R_b0 = np.asarray(out.joint_rotations)[b]
    sensor_point = np.einsum("sba,sb->sa", R_b0, np.asarray(out.vertices)[v] - np.asarray(out.joints)[b])
    a = lambda x: jnp.asarray(x, dtype)  # noqa: E731
    # Ours, for speed: the terms pose a body of the keypoints' skinned points and the joints
    # (`body.compact`, exact), not the mesh: 29 points instead of 1229 on the default body.
    body, regressor, _ = compact_body(body, keypoint_regressor(body, "coco18"))
    return VIPData(
        orientation=a(orientation), orientation0=a(orientation[0]),
        acceleration=a(_global_acceleration(orientation, acceleration)), sensor_point=a(sensor_point),
        rest_joints=shaped_joints(body, a(betas)), prior=prior if prior is not None else default_pose_prior(dtype),
        body=body, betas=a(betas), cam_orientation=a(cam_orientation),
        cam_acceleration=a(_global_acceleration(cam_orientation, cam_acceleration)), K=a(K),
        regressor=a(regressor), keypoints=a(uv),
        confidence=a(confidence), pixel_scale=a(REFERENCE_IMAGE_HEIGHT / float(image_height)),
        heading=a(np.zeros(S)), x0=axis_angle_to_matrix(a(x0)), camera=jnp.broadcast_to(jnp.eye(4, dtype=dtype), (T, 4, 4)),
        fps=float(fps),
    )  # fmt: skip


def tracker_hypotheses(datas, bones) -> np.ndarray:
    """Keypoints (P, T, 18, 3) of each wearer's Inertial Tracker poses at translation 0 (IMUs do
    not observe position): the hypotheses of the first association (eq. 4.11)."""
    return np.stack([world_keypoints(d, inertial_tracker(d, bones), np.zeros((d.num_frames, 3))) for d in datas])


def _tracker_problem(bones: tuple[int, ...]) -> Problem:
    terms = [heading_orientation_term(bones, 1.0, False, False), mahalanobis_term(1.0, 1.0),
             joint_limit_term(1.0, 1.0)]  # fmt: skip
    return Problem(terms, {"pose": frame("so3")})


def _bones(data: VIPData, bones) -> tuple[int, ...]:
    bones = tuple(int(b) for b in bones)
    if len(bones) != data.orientation.shape[1]:
        raise ValueError(f"{len(bones)} bones for {data.orientation.shape[1]} sensors.")
    return bones


def inertial_tracker(
    data: VIPData, bones, heading=None, x0=None, mahal: float = 0.003, limit: float = 0.1, max_steps: int = 20
) -> Array:
    """The Inertial Tracker (eq. 4.10): E_ori + prior per frame (all frames solved at once;
    the problem is block-diagonal in time). heading (S,) and x0 (24, 3) default to no
    correction and the given initial pose; with VIP's estimates this is VIP-IT. -> (T, 24, 3)."""
    bones = _bones(data, bones)
    if heading is not None:
        data = eqx.tree_at(lambda d: d.heading, data, jnp.asarray(heading, data.heading.dtype))
    if x0 is not None:
        data = eqx.tree_at(lambda d: d.x0, data, axis_angle_to_matrix(jnp.asarray(x0, data.x0.dtype)))
    S = len(bones)
    problem = _weighted(
        _tracker_problem(bones), {"ori": 1.0 / S, "mahal": mahal, "limit": limit}, data.orientation.dtype
    )
    T = data.num_frames
    pose0 = jnp.broadcast_to(matrix_to_axis_angle(data.x0), (T, 24, 3))
    sol = solve(problem, {"pose": pose0}, data, max_steps=max_steps)
    return sol.value["pose"]


def _weighted(problem: Problem, weights: dict, dtype) -> Problem:
    """`problem` with traced weights (a new value does not recompile)."""
    return with_weights(problem, {k: jnp.asarray(v, dtype) for k, v in weights.items()})


def initial_camera(data: VIPData, poses, trans) -> np.ndarray:
    """Camera-to-world poses (T, 6) (axis-angle, centre): rotation from the camera IMU, and
    per frame the centre whose projection of the posed keypoints best fits the detections
    (weighted linear least squares, x̂ × (R X + t) = 0); frames with fewer than 3
    detected keypoints take the centre of the nearest fitted frame."""
    X = world_keypoints(data, poses, trans)  # (T, 18, 3)
    Rc = np.asarray(data.cam_orientation, np.float64)
    T = len(X)
    if not np.isfinite(Rc).all():
        raise ValueError("the camera IMU has dropped orientation samples; fill them before VIP.")
    Kinv = np.linalg.inv(np.asarray(data.K, np.float64))
    uv = np.asarray(data.keypoints, np.float64)
    conf = np.asarray(data.confidence, np.float64)
    centres = np.full((T, 3), np.nan)
    for t in range(T):
        ok = conf[t] > 0
        if ok.sum() < 3:
            continue
        rays = np.einsum("ab,kb->ka", Kinv, np.concatenate([uv[t, ok], np.ones((ok.sum(), 1))], -1))
        R = Rc[t].T  # world to camera
        hat = np.zeros((len(rays), 3, 3))
        hat[:, 0, 1], hat[:, 0, 2], hat[:, 1, 2] = -rays[:, 2], rays[:, 1], -rays[:, 0]
        hat = hat - np.swapaxes(hat, 1, 2)
        w = np.sqrt(conf[t, ok])[:, None, None]
        A = (w * hat).reshape(-1, 3)
        b = -(w * np.einsum("kab,kb->ka", hat, X[t, ok] @ R.T)[..., None]).reshape(-1)
        tt, *_ = np.linalg.lstsq(A, b, rcond=None)
        centres[t] = -R.T @ tt
    good = np.flatnonzero(np.isfinite(centres).all(-1))
    if len(good) == 0:
        raise ValueError("no frame has 3 or more detected keypoints: the camera cannot be placed.")
    near = good[np.abs(np.arange(T)[:, None] - good[None]).argmin(1)]
    centres = centres[near]
    return np.concatenate([np.asarray(matrix_to_axis_angle(jnp.asarray(Rc))), centres], -1)


def _vip_problem(
    bones: tuple[int, ...], fps: float, free_heading: bool, free_x0: bool, free_camera: bool, sigma: float
) -> Problem:
    terms = [
        heading_orientation_term(bones, 1.0, free_heading, free_x0),
        heading_acceleration_term(bones, fps, 1.0, free_heading),
        image_term(1.0, sigma, free_camera),
        mahalanobis_term(1.0, 1.0),
        joint_limit_term(1.0, 1.0),
    ]
    unknowns = {"pose": frame("so3"), "trans": frame()}
    if free_camera:
        terms += [camera_orientation_term(1.0), camera_acceleration_term(fps, 1.0)]
        unknowns["cam"] = frame("se3")
    if free_heading:
        unknowns["heading"] = sequence("angle")
    if free_x0:
        terms.append(initial_pose_term(1.0))
        unknowns["x0"] = sequence("so3")
    return Problem(terms, unknowns)


def camera_matrices(cam: Array) -> Array:
    """(T, 6) (axis-angle, centre) -> (T, 4, 4) camera-to-world."""
    top = jnp.concatenate([axis_angle_to_matrix(cam[:, :3]), cam[:, 3:, None]], -1)
    bottom = jnp.broadcast_to(jnp.asarray([0.0, 0.0, 0.0, 1.0], cam.dtype), (cam.shape[0], 1, 4))
    return jnp.concatenate([top, bottom], -2)


def video_inertial_poser(
    data: VIPData,
    bones,
    weights: VIPWeights = VIPWeights(),
    free_heading: bool = True,
    free_x0: bool = True,
    camera=None,
    free_camera: bool = True,
    init=None,
    init_trans=None,
    sigma: float = 100.0,
    max_steps: int = 30,
    start: VIPResult | None = None,
) -> VIPResult:
    """VIP fusion (eq. 4.19-4.30) from the Inertial Tracker (eq. 4.10).

    Args:
        data: `vip_data` / `app.scenarios.vip_sequence`; bones: the bone of each body sensor.
        weights: `VIPWeights`; free_heading / free_x0: estimate γ_s / x₀ (False keeps
            them at 0 / the given x₀: VIP-noHeadParam, VIP-vanilla).
        camera: (T, 6) camera-to-world start (default `initial_camera`); with
            free_camera=False it is held fixed (VIP-Cam with the true camera).
        init, init_trans: (T, 24, 3), (T, 3) start (default: IT poses, x₀'s translation 0).
        sigma: E_img's Geman-McClure σ in reference pixels.
        start: a previous result to continue from (every unknown, headings and x₀ too):
            the second round of `video_inertial_scene`.
    """
    problem, params, data, fixed = _fusion_setup(data, bones, weights, free_heading, free_x0, camera, free_camera, init,
                                                 init_trans, sigma, start)  # fmt: skip
    return _result(solve(problem, params, data, max_steps=max_steps), data, *fixed)


def _fusion_setup(data, bones, weights, free_heading, free_x0, camera, free_camera, init, init_trans, sigma, start):
    """The weighted problem, start values and data of one VIP fusion solve, and (camera
    start, tracker poses) for the result."""
    if start is not None:
        init, init_trans, camera = start.poses, start.trans, start.camera
    bones = _bones(data, bones)
    T, S = data.num_frames, len(bones)
    dtype = data.orientation.dtype
    poses = inertial_tracker(data, bones) if init is None else jnp.asarray(init, dtype)
    trans = jnp.zeros((T, 3), dtype) if init_trans is None else jnp.asarray(init_trans, dtype)
    if poses.shape != (T, 24, 3) or trans.shape != (T, 3):
        raise ValueError(f"init must be (T, 24, 3) and init_trans (T, 3), T = {T}; got {poses.shape}, {trans.shape}.")
    cam = initial_camera(data, poses, trans) if camera is None else np.asarray(camera, np.float64)
    if cam.shape != (T, 6):
        raise ValueError(f"camera has shape {cam.shape}; expected (T, 6) camera-to-world (axis-angle, centre).")
    problem = _vip_problem(bones, data.fps, free_heading, free_x0, free_camera, float(sigma))
    problem = weights.weigh(problem, dtype, num_sensors=S, free_camera=free_camera)
    params = {"pose": poses, "trans": trans}
    if free_camera:
        params["cam"] = jnp.asarray(cam, dtype)
    else:
        data = eqx.tree_at(lambda d: d.camera, data, camera_matrices(jnp.asarray(cam, dtype)))
    if free_heading:
        params["heading"] = jnp.zeros(S, dtype) if start is None else jnp.asarray(start.heading, dtype)
    if free_x0:
        params["x0"] = matrix_to_axis_angle(data.x0) if start is None else jnp.asarray(start.x0, dtype)
    tracker = poses if start is None else start.init
    return problem, params, data, (jnp.asarray(cam, dtype), tracker)


def _result(sol: Solution, data: VIPData, cam, init) -> VIPResult:
    v = sol.value
    return VIPResult(
        poses=v["pose"], trans=v["trans"], camera=v.get("cam", cam), heading=v.get("heading", data.heading),
        x0=v.get("x0", matrix_to_axis_angle(data.x0)), init=init, solution=sol,
    )  # fmt: skip


def with_keypoints(data: VIPData, keypoints) -> VIPData:
    """`data` with new detections (T, 18, 3) (u, v, confidence; NaN or confidence 0 = missing),
    e.g. the rows an association gave this person; a frame without any is fitted from the
    IMUs alone."""
    keypoints = np.asarray(keypoints, np.float64)
    if keypoints.shape != (data.num_frames, 18, 3):
        raise ValueError(f"keypoints have shape {keypoints.shape}; expected ({data.num_frames}, 18, 3).")
    uv, confidence = _detections(keypoints)
    dtype = data.keypoints.dtype
    return eqx.tree_at(
        lambda d: (d.keypoints, d.confidence), data, (jnp.asarray(uv, dtype), jnp.asarray(confidence, dtype))
    )


def _detections(keypoints: np.ndarray):
    """(T, 18, 3) rows (u, v, confidence) -> pixels (T, 18, 2), confidences (T, 18), with
    NaN rows and negative confidences as missing (confidence 0)."""
    finite = np.isfinite(keypoints).all(-1)
    return np.nan_to_num(keypoints[..., :2]), np.where(finite, keypoints[..., 2], 0.0).clip(0.0, None)


def world_keypoints(data: VIPData, poses, trans) -> np.ndarray:
    """COCO-18 keypoints (T, 18, 3) in the world of the posed model."""
    dtype = data.body.dtype
    out = forward(data.body, jnp.asarray(poses, dtype), data.betas, jnp.asarray(trans, dtype))
    return np.asarray(regress_keypoints(data.regressor, out.vertices, out.joints), np.float64)


@dataclasses.dataclass(frozen=True)
class VIPScene:
    """`video_inertial_scene`'s answer: people, one `VIPResult` per IMU wearer after the last
    round; associations, one per round; seconds, the wall time of each stage."""

    people: tuple
    associations: tuple
    seconds: dict


def video_inertial_scene(
    datas,
    bones,
    detections,
    weights: VIPWeights = VIPWeights(),
    rounds: int = 2,
    model: AssociationModel | None = None,
    max_steps: int = 30,
    log=None,
    **fusion,
) -> VIPScene:
    """The whole Video Inertial Poser (§4.3) for the IMU wearers of one recording.

    Inertial Tracker per wearer (eq. 4.10) → association of the detections with the wearers
    (eq. 4.11-4.18) → fusion (eq. 4.19-4.30); association and fusion are then repeated once
    (`rounds=2`, the thesis), the second association from the fused poses and camera, the
    second fusion continuing from the first.

    datas: one `VIPData` per wearer (`vip_data`; their own keypoints are ignored: the
        detections are assigned here), all of the same length and the same camera.
    detections: (T, D, 18, 3) every person detected per frame (u, v, confidence), rows of
        zeros or NaN where a frame has fewer than D; an empty frame is fine.
    fusion: options of `video_inertial_poser` (free_heading, free_x0, sigma, ...).

    The wearers are solved as one batch (`solve_batch`: one compiled program). Ours: each
    wearer keeps their own camera unknowns (the camera is shared in the thesis's joint
    problem); the second association maps every wearer into the first wearer's camera
    world, so that the intra-frame costs compare one camera (positions known, eq. 4.18).
    """
    datas = list(datas)
    if not datas:
        raise ValueError("no IMU wearers: pass one VIPData per person wearing IMUs.")
    if rounds < 1:
        raise ValueError(f"rounds must be >= 1, got {rounds}.")
    T = datas[0].num_frames
    if any(d.num_frames != T for d in datas):
        raise ValueError(f"the wearers' sequences differ in length: {[d.num_frames for d in datas]}.")
    detections = np.asarray(detections, np.float64)
    if detections.ndim != 4 or detections.shape[0] != T or detections.shape[2:] != (18, 3):
        raise ValueError(f"detections have shape {detections.shape}; expected (T, D, 18, 3) with T = {T}.")
    say = log or (lambda *_: None)
    bones = _bones(datas[0], bones)
    seconds = {"tracker": 0.0, "association": 0.0, "fusion": 0.0}
    d0 = datas[0]
    clock = time.perf_counter()
    hyp = tracker_hypotheses(datas, bones)
    seconds["tracker"] += time.perf_counter() - clock
    cam_R, results, associations = np.asarray(d0.cam_orientation), None, []
    for r in range(rounds):
        clock = time.perf_counter()
        assoc = associate(hyp, d0.K, cam_R, detections, model=model, positions_known=r > 0)
        seconds["association"] += time.perf_counter() - clock
        associations.append(assoc)
        say(f"round {r + 1}: {int((assoc.index >= 0).sum())} detections assigned to {len(datas)} wearer(s)")
        lacking = [k for k in range(len(datas)) if not (assoc.keypoints[k][..., 2] > 0).any()]
        if lacking:
            raise ValueError(f"wearer(s) {lacking} were assigned no detection in any frame: VIP cannot place them "
                             "in the image; check the detections, or fit them with the Inertial Tracker alone.")  # fmt: skip
        clock = time.perf_counter()
        setups = [_fusion_setup(with_keypoints(d, assoc.keypoints[k]), bones, weights, fusion.get("free_heading", True),
                                fusion.get("free_x0", True), None, True, None, None, fusion.get("sigma", 100.0),
                                None if results is None else results[k]) for k, d in enumerate(datas)]  # fmt: skip
        if len(setups) == 1:  # the program `video_inertial_poser` compiles
            results = [_result(solve(*setups[0][:3], max_steps=max_steps), setups[0][2], *setups[0][3])]
        else:
            stack = lambda *xs: jnp.stack(xs)  # noqa: E731
            params = jax.tree.map(stack, *[s[1] for s in setups])
            data = jax.tree.map(stack, *[s[2] for s in setups])
            sol = solve_batch(setups[0][0], params, data, max_steps=max_steps)
            results = [_result(jax.tree.map(lambda x, k=k: x[k], sol), s[2], *s[3]) for k, s in enumerate(setups)]
        seconds["fusion"] += time.perf_counter() - clock
        say(f"round {r + 1}: fused, costs {[float(x.solution.cost) for x in results]}")
        # Next hypotheses: each wearer's fused keypoints seen from the first wearer's camera.
        cams = [np.asarray(camera_matrices(x.camera)) for x in results]
        hyp = np.stack([into_camera(world_keypoints(d, x.poses, x.trans), cams[k], cams[0])
                        for k, (d, x) in enumerate(zip(datas, results))])  # fmt: skip
        cam_R = cams[0][:, :3, :3]
    return VIPScene(tuple(results), tuple(associations), seconds)


def into_camera(X, cam_from, cam_to):
    """Points (T, N, 3) fitted with camera-to-world poses cam_from (T, 4, 4), re-expressed so
    that cam_to sees them as cam_from did."""
    Rf, cf, Rt, ct = cam_from[:, :3, :3], cam_from[:, :3, 3], cam_to[:, :3, :3], cam_to[:, :3, 3]
    local = np.einsum("tba,tnb->tna", Rf, X - cf[:, None])
    return np.einsum("tab,tnb->tna", Rt, local) + ct[:, None]


# Moved to the app layer (`jaxmocap.app.scenarios`, the adapters over a scenario's named
# arrays); the old names resolve there until the next release.
def __getattr__(name: str):
    if name in ("from_scenario", "tracker_keypoints", "associated_keypoints"):
        from ..app.scenarios import associated_keypoints, tracker_keypoints, vip_sequence

        return {"from_scenario": vip_sequence, "tracker_keypoints": tracker_keypoints,
                "associated_keypoints": associated_keypoints}[name]  # fmt: skip
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
