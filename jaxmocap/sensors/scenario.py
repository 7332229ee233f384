"""Scenarios: motions + body shapes + sensor configuration + seed -> a padded batch of truth
and observations; saved in jaxmocap's npz format or DIP-IMU's pickle layout.

`make_scenario(motions, config, seed)` is the one entry point. Sequence i has
`config.people` people; person p performs motions[(i + p) % len(motions)] (a Motion, a
library name such as "walk", or a motion file path), resampled to `config.fps`, cropped
to at most `config.max_frames` frames at a random start (all people of a sequence share
the shortest length). Shapes β ~ N(0, betas_std²) on the first `num_betas` components.
People after the first are placed `spacing` m apart along x with a random heading. Every
body is lifted so that its lowest vertex over the sequence touches the ground y = 0.

Presets: `vip_config` (Video Inertial Poser, von Marcard ch. 4: IMUs, one hand-held
camera, COCO-18 detections) and `interaction_config` (InterCap, Huang ch. 5: one person
handling a rigid object, "box", "ball", "bottle" or the non-convex "chair", seen by a ring
of static RGB-D cameras: label images, noisy depth points with holes, BODY_25 detections;
`segmentation.object_candidates` turns its label images into instance-segmenter masks).
With an object, person 0's motion is edited (after the lift) to pick it up from the floor
and put it down again (`objects.pick_and_place`; `ScenarioConfig.reach=False`: unedited).

Randomness: `numpy.random.SeedSequence(seed)` spawns one child per sequence and that one
child per component (shape, placement, IMU, camera, detector, depth), so a sequence does
not change when other sequences or components are added or switched off.

Padding: sequences shorter than the longest are padded by repeating their last frame
(so padded rotations stay rotations and kernels see no NaN) and `mask` (N, T) marks
the real frames. Array keys and shapes (N sequences, P people, T frames, S sensors,
C views, K keypoints, D detection slots, M depth points; only those configured exist):

    mask (N, T) bool; length (N,)
    poses (N, P, T, 24, 3); trans (N, P, T, 3); betas (N, P, B); joints (N, P, T, 24, 3)
    imu_ori, imu_acc, imu_gyro      measured R̃_s^g, ã^s (sensor frame), ω̃^s; NaN = dropped
    imu_ori_true, imu_acc_true, imu_free_acc_true, imu_gyro_true   nominal sensor, no errors
    imu_misalignment (N, P, S, 3, 3); imu_heading (N, P, T, S); imu_vertices, imu_bones (S,)
    cam_K (N, C, 3, 3); cam_R (N, C, T, 3, 3); cam_t (N, C, T, 3) world-to-camera
    cam_imu_ori (N, T, 3, 3), cam_imu_acc (N, T, 3)  (camera-mounted IMU, noise-free)
    kp_true (N, P, C, T, K, 2); kp_depth (N, P, C, T, K)
    det_keypoints (N, C, T, D, K, 3) (u, v, conf); det_person (N, C, T, D) (-1 distractor,
        -2 empty slot); det_swapped (N, C, T, D, K)
    labels (N, C, T, H, W) int8: -1 background, -2 floor, p person, P object
    depth_points (N, C, T, M, 3) world; depth_labels (N, C, T, M); depth_valid (N, C, T, M)
    visible (N, C, T, P, V) bool vertex visibility per view
    obj_R (N, T, 3, 3), obj_t (N, T, 3), obj_vertices (No, 3), obj_faces (Fo, 3),
    contact (N, T) bool, contact_vertices (Nc,)
"""

from __future__ import annotations

import dataclasses
import json
import os
import pickle
from collections.abc import Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from .._checks import check_rate
from ..body.kinematics import BodyOutput, forward
from ..geometry.camera import intrinsics, project, ring_cameras
from ..geometry.imu_calibration import sensor_to_bone_offsets, virtual_bone_orientations
from ..geometry.keypoints import KEYPOINT_FORMATS, keypoint_regressor, regress_keypoints
from ..geometry.raster import rasterize_views, visible_vertices, window_for
from ..motion.reach import ReachError
from ..motion.sequence import Motion
from ..rotation import axis_angle_to_matrix
from .depth import DepthNoiseModel, depth_point_cloud
from .detector import DetectorErrorModel, detect
from .errors import IMUErrorModel, global_free_acceleration, simulate_imu
from .imu import imu_placement
from .moving_camera import camera_imu, handheld_trajectory
from .objects import CONTACT_PARTS, ObjectTrajectory, RigidObject, contact_trajectory, contact_vertices
from .objects import pick_and_place

__all__ = [
    "CameraConfig",
    "ScenarioConfig",
    "Scenario",
    "make_scenario",
    "save_scenario",
    "load_scenario",
    "save_dip",
    "resolve_motion",
    "vip_config",
    "interaction_config",
]

FORMAT_VERSION = 1


@dataclasses.dataclass(frozen=True)
class CameraConfig:
    """Cameras of a scenario: `num_views` static views on a ring, or one hand-held camera.

    width/height in pixels, vertical field of view in degrees, distance (m) from the
    scene centre and camera height (m). `moving`: hand-held (one view, see
    `moving_camera.handheld_trajectory`); `camera_imu`: an IMU on the (first) camera.
    """

    num_views: int = 1
    width: int = 256
    height: int = 192
    fov_degrees: float = 55.0
    distance: float = 4.0
    camera_height: float = 1.4
    moving: bool = False
    camera_imu: bool = False

    def __post_init__(self):
        for name in ("num_views", "width", "height"):
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or v < 1:
                raise ValueError(f"CameraConfig.{name} must be an int >= 1, got {v!r}.")
        if not 0 < self.fov_degrees < 180:
            raise ValueError(f"CameraConfig.fov_degrees must lie in (0, 180), got {self.fov_degrees}.")
        if not (np.isfinite(self.distance) and self.distance > 0):
            raise ValueError(f"CameraConfig.distance must be > 0 metres, got {self.distance}.")


@dataclasses.dataclass(frozen=True)
class ScenarioConfig:
    """Everything but the motions and the seed (see the module docstring)."""

    fps: float = 30.0
    max_frames: int = 120
    people: int = 1
    betas_std: float = 1.0
    num_betas: int = 10
    spacing: float = 1.5
    imu_set: str | None = "sip6"
    imu_errors: IMUErrorModel = IMUErrorModel()
    cameras: CameraConfig | None = None
    keypoints: str | None = None
    detector: DetectorErrorModel = DetectorErrorModel.off()
    silhouettes: bool = False
    depth_points: int = 0
    depth_noise: DepthNoiseModel = DepthNoiseModel()
    object: str | None = None
    contact_part: str = "right_hand"
    reach: bool = True  # edit the motion to pick the object up from / put it down on the floor

    def __post_init__(self):
        check_rate("ScenarioConfig.fps", self.fps)
        for name, low in (("max_frames", 1), ("people", 1), ("num_betas", 0), ("depth_points", 0)):
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or v < low:
                raise ValueError(f"ScenarioConfig.{name} must be an int >= {low}, got {v!r}.")
        for name in ("betas_std", "spacing"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ValueError(f"ScenarioConfig.{name} must be finite and >= 0, got {v!r}.")
        if not isinstance(self.reach, bool):
            raise ValueError(f"ScenarioConfig.reach must be True or False, got {self.reach!r}.")

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> ScenarioConfig:
        d = dict(d)
        d["imu_errors"] = IMUErrorModel(**d["imu_errors"])
        d["detector"] = DetectorErrorModel(**d["detector"])
        d["depth_noise"] = DepthNoiseModel(**d["depth_noise"])
        d["cameras"] = None if d["cameras"] is None else CameraConfig(**d["cameras"])
        d.setdefault("reach", False)  # files written before the reach edit existed
        return cls(**d)


@dataclasses.dataclass(frozen=True)
class Scenario:
    """A batch of sequences: `arrays` (keys in the module docstring) and JSON-able `meta`."""

    arrays: dict
    meta: dict

    def __getitem__(self, key: str) -> np.ndarray:
        try:
            return self.arrays[key]
        except KeyError:
            raise KeyError(f"No array {key!r}; this scenario has {sorted(self.arrays)}.") from None

    @property
    def num_sequences(self) -> int:
        return len(self.arrays["mask"])

    @property
    def config(self) -> ScenarioConfig:
        return ScenarioConfig.from_dict(self.meta["config"])

    def sequence(self, i: int) -> dict:
        """Sequence i unpadded: arrays with a frame axis cut to its length."""
        if (
            isinstance(i, bool)
            or not isinstance(i, (int, np.integer))
            or not -self.num_sequences <= i < self.num_sequences
        ):
            raise IndexError(
                f"sequence {i!r}: this scenario has {self.num_sequences} sequences (0 .. {self.num_sequences - 1})."
            )
        n = int(self.arrays["length"][i])
        out = {}
        for k, v in self.arrays.items():
            # By key, never by shape: with as many sequences as sensors (or object
            # vertices) a shape test took the shared (S,) arrays for per-sequence ones.
            if k in _SHARED:
                out[k] = v
                continue
            v = v[i]
            ax = _time_axis(k)
            out[k] = v[(slice(None),) * ax + (slice(0, n),)] if ax >= 0 else v
        return out


# Frame axis of each per-sequence array after removing the sequence axis.
_TIME_AXIS = {
    "mask": 0, "poses": 1, "trans": 1, "joints": 1, "imu_ori": 1, "imu_acc": 1, "imu_gyro": 1,
    "imu_ori_true": 1, "imu_acc_true": 1, "imu_free_acc_true": 1, "imu_gyro_true": 1,
    "imu_heading": 1, "cam_R": 1, "cam_t": 1, "cam_imu_ori": 0, "cam_imu_acc": 0,
    "kp_true": 2, "kp_depth": 2, "det_keypoints": 1, "det_person": 1, "det_swapped": 1,
    "labels": 1, "depth_points": 1, "depth_labels": 1, "depth_valid": 1, "visible": 1,
    "obj_R": 0, "obj_t": 0, "contact": 0,
}  # fmt: skip


# Arrays shared by every sequence (no leading sequence axis); all others have one.
_SHARED = frozenset({"length", "imu_vertices", "imu_bones", "obj_vertices", "obj_faces", "contact_vertices"})


def _time_axis(key):
    return _TIME_AXIS.get(key, -1)


def resolve_motion(item, fps: float, body=None) -> Motion:
    """A Motion from a Motion, a `library.MOTIONS` name or a motion file path."""
    from ..motion import library
    from ..motion.io import load_motion

    if isinstance(item, Motion):
        return item.resample(fps)
    if isinstance(item, str) and item in library.MOTIONS:
        return library.MOTIONS[item](num_frames=int(round(4 * fps)), fps=fps, body=body)
    path = Path(item)
    if not path.exists():
        raise ValueError(f"Motion {item!r} is neither a library motion ({sorted(library.MOTIONS)}) nor a file.")
    return load_motion(path, fps=fps)


@jax.jit
def _forward_jit(body, poses, betas, trans):
    return forward(body, poses, betas, trans)


def _posed(body, poses, betas, trans) -> BodyOutput:
    """forward() with the frame count padded to a multiple of 32 (fewer compilations)."""
    T = len(poses)
    pad = -T % 32
    ext = lambda x: np.concatenate([x, np.repeat(x[-1:], pad, 0)]) if pad else x  # noqa: E731
    out = _forward_jit(body, jnp.asarray(ext(poses), body.dtype), jnp.asarray(betas, body.dtype),
                       jnp.asarray(ext(trans), body.dtype))  # fmt: skip
    # Cut on the host: slicing (and the lift below) eagerly compiled a program per length.
    return jax.tree_util.tree_map(lambda x: np.asarray(x)[:T], out)


@jax.jit
def _keypoints_2d_jit(regressor, K, R, t, vertices, joints):
    """Keypoints of P bodies (P, T, V, 3), (P, T, J, 3) seen by C cameras R (C, T, 3, 3):
    (C, P, T, K, ...). One program per shape; run eagerly, the regression and projection compiled ~13."""
    kp3 = regress_keypoints(regressor, vertices, joints)
    return project(K, R[:, None], t[:, None], kp3[None])


@jax.jit
def _visibility_jit(K, R, t, vertices, depth):
    """(B, P, V) visibility for B (view, frame) pairs of P bodies."""
    per_body = jax.vmap(visible_vertices, in_axes=(None, None, None, 0, None))
    return jax.vmap(per_body, in_axes=(None, 0, 0, 0, 0))(K, R, t, vertices, depth)


def _rotate_motion(body, poses, trans, betas, yaw, offset):
    """The motion rotated by `yaw` about the vertical through the origin, then shifted."""
    from ..rotation import host_compose, host_exp

    poses = poses.copy()
    poses[:, 0] = host_compose([0.0, yaw, 0.0], poses[:, 0])
    Q = host_exp([0.0, yaw, 0.0])
    j0 = np.asarray(body.J_regressor[0] @ (body.v_template + np.einsum("kvc,k->vc", np.asarray(body.shapedirs), betas)))
    trans = (trans + j0) @ Q.T - j0 + offset
    return poses, trans


def _spawn(seed: int, n: int) -> list[np.random.SeedSequence]:
    return np.random.SeedSequence(seed).spawn(n)


_COMPONENTS = ("shape", "placement", "imu", "camera", "detector", "depth")


def make_scenario(
    motions: Sequence,
    config: ScenarioConfig = ScenarioConfig(),
    seed: int = 0,
    body=None,
    num_sequences: int | None = None,
    progress: bool = False,
) -> Scenario:
    """A deterministic batch of sequences with truth and simulated observations.

    Args:
        motions: Motions, library names or motion file paths (see module docstring).
        config: sensors, errors, shapes, cameras; seed: the only source of randomness.
        body: the body model (default: `default_body("low")`).
        num_sequences: default len(motions).
        progress: show a tqdm bar over sequences.
    Returns:
        A Scenario (arrays padded over time with `mask`).
    """
    from ..body.io import default_body

    body = default_body("low") if body is None else body
    if config.keypoints is not None and config.keypoints not in KEYPOINT_FORMATS:
        raise ValueError(f"keypoints must be one of {sorted(KEYPOINT_FORMATS)} or None.")
    if (config.keypoints or config.silhouettes or config.depth_points) and config.cameras is None:
        raise ValueError("Keypoints, silhouettes and depth need `cameras` in the ScenarioConfig.")
    if config.num_betas > body.num_betas:
        raise ValueError(f"num_betas={config.num_betas} but the body has {body.num_betas}.")
    if len(motions) == 0:
        raise ValueError("make_scenario needs at least one motion.")
    if num_sequences is not None and (isinstance(num_sequences, bool) or not isinstance(num_sequences, (int, np.integer))
                                      or num_sequences < 1):  # fmt: skip
        raise ValueError(f"num_sequences must be an int >= 1 (or None: one per motion), got {num_sequences!r}.")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be an int >= 0, got {seed!r}.")
    N = len(motions) if num_sequences is None else num_sequences
    cache = _MOTION_CACHE
    placement = imu_placement(body, config.imu_set) if config.imu_set else None
    regressor = keypoint_regressor(body, config.keypoints) if config.keypoints else None
    obj = _make_object(config.object) if config.object else None
    seqs = []
    iterator = range(N)
    if progress:
        from tqdm import tqdm

        iterator = tqdm(iterator, desc="sequences", leave=False)
    for i, ss in zip(iterator, _spawn(seed, N)):
        rngs = dict(zip(_COMPONENTS, (np.random.default_rng(s) for s in ss.spawn(len(_COMPONENTS)))))
        items = [motions[(i + p) % len(motions)] for p in range(config.people)]
        seqs.append(_make_sequence(body, items, config, rngs, cache, placement, regressor, obj))
    arrays = _pad_and_stack(seqs)
    if placement is not None:
        arrays["imu_vertices"] = np.asarray(placement.vertices)
        arrays["imu_bones"] = np.asarray(placement.bones)
    if obj is not None:
        arrays["obj_vertices"], arrays["obj_faces"] = obj.vertices, obj.faces
        arrays["contact_vertices"] = contact_vertices(body, config.contact_part)
    meta = {
        "format": "jaxmocap_scenario",
        "version": FORMAT_VERSION,
        "seed": int(seed),
        "config": config.to_dict(),
        "names": [s["name"] for s in seqs],
        "body": {"kind": body.kind, "num_vertices": body.num_vertices},
        "sensor_names": list(placement.names) if placement else [],
        "sensor_set": config.imu_set,
        "keypoint_names": list(KEYPOINT_FORMATS[config.keypoints]) if config.keypoints else [],
        "object": config.object,
    }
    return Scenario(arrays, meta)


def vip_config(
    imu_set: str = "totalcapture13",
    bystanders: int = 0,
    max_frames: int = 300,
    fps: float = 30.0,
    imu_errors: IMUErrorModel | None = None,
    detector: DetectorErrorModel | None = None,
    width: int = 320,
    height: int = 240,
) -> ScenarioConfig:
    """A Video Inertial Poser scene (von Marcard ch. 4, 3DPW-like): person 0 wears the IMUs
    of `imu_set` ("totalcapture13" or "sip6"), `bystanders` more people walk beside them
    (the simulator gives everyone IMUs; VIP reads person 0's only), one hand-held camera
    orbits them with sway and tremor and carries an IMU, COCO-18 detections come through
    the detector error model (default OpenPose-like: noise, misses, left/right swaps,
    false detections) and IMU errors default to Xsens-like ones with a 10° heading offset
    per sensor (1σ) plus drift (§2.4, §4.2.4)."""
    if not isinstance(bystanders, (int, np.integer)) or not 0 <= bystanders <= 3:
        raise ValueError(f"bystanders must be an int in 0 .. 3, got {bystanders!r}.")
    if imu_errors is None:
        imu_errors = dataclasses.replace(IMUErrorModel.xsens(), heading_offset=float(np.radians(10.0)))
    return ScenarioConfig(
        fps=fps, max_frames=max_frames, people=1 + bystanders, betas_std=1.0, imu_set=imu_set, imu_errors=imu_errors,
        cameras=CameraConfig(num_views=1, moving=True, camera_imu=True, width=width, height=height),
        keypoints="coco18", detector=DetectorErrorModel.openpose() if detector is None else detector,
    )  # fmt: skip


def interaction_config(
    object: str = "box",
    num_views: int = 4,
    max_frames: int = 60,
    fps: float = 30.0,
    depth_points: int = 768,
    width: int = 256,
    height: int = 192,
    contact_part: str = "right_grip",
    detector: DetectorErrorModel | None = None,
    depth_noise: DepthNoiseModel | None = None,
    reach: bool = True,
) -> ScenarioConfig:
    """An InterCap scene (Huang ch. 5): one person handles `object` ("box", "ball",
    "bottle" or "chair"; it rests, moves with `contact_part` over the middle half of the
    frames, then rests again; with `reach` (default) it rests on the floor beside the person,
    whose motion is edited to bend down and pick it up at the first contact frame and to set
    it down on the floor at the last one, `objects.pick_and_place`; with reach=False the
    motion is left as it is and the object rests where the hand is at the first and last
    contact frames, in mid-air), seen by `num_views` static RGB-D cameras on a ring 3.5 m
    plus the walked distance out (Kinect-like depth: σ_z ≈ 2 cm at 4 m, 5 % holes), with
    label images (person 0, object 1; `segmentation.object_candidates` turns them into
    instance-segmenter output), `depth_points` points per view and frame (0: no depth),
    and BODY_25 detections with a moderate error model (OpenPose's misses and outliers,
    2 px noise, no left/right swaps and no false detections: Huang ch. 5 fits one
    person). No IMUs; shapes β ~ N(0, 0.5²)."""
    if object not in _OBJECTS:
        raise ValueError(f"Unknown object {object!r}; choose from {sorted(_OBJECTS)}.")
    if contact_part not in CONTACT_PARTS:
        raise ValueError(f"Unknown contact part {contact_part!r}; choose from {sorted(CONTACT_PARTS)}.")
    for name, v, low in (("num_views", num_views, 1), ("max_frames", max_frames, 1), ("width", width, 1),
                         ("height", height, 1), ("depth_points", depth_points, 0)):  # fmt: skip
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < low:
            raise ValueError(f"interaction_config: {name} must be an int >= {low}, got {v!r}.")
    check_rate("interaction_config: fps", fps)
    if detector is None:
        detector = dataclasses.replace(
            DetectorErrorModel.openpose(), pixel_noise=2.0, swap_rate=0.0, distractor_rate=0.0, max_distractors=0
        )
    elif not isinstance(detector, DetectorErrorModel):
        raise ValueError(f"interaction_config: detector must be a DetectorErrorModel or None, got {detector!r}.")
    if not isinstance(reach, bool):
        raise ValueError(f"interaction_config: reach must be True or False, got {reach!r}.")
    if depth_noise is None:
        depth_noise = DepthNoiseModel(missing_rate=0.05)
    elif not isinstance(depth_noise, DepthNoiseModel):
        raise ValueError(f"interaction_config: depth_noise must be a DepthNoiseModel or None, got {depth_noise!r}.")
    return ScenarioConfig(
        fps=fps, max_frames=max_frames, people=1, betas_std=0.5, imu_set=None,
        cameras=CameraConfig(num_views=num_views, width=width, height=height, distance=3.5),
        keypoints="body25", detector=detector, silhouettes=True, depth_points=depth_points,
        depth_noise=depth_noise, object=object, contact_part=contact_part, reach=reach,
    )  # fmt: skip


# Loaded files and generated library motions, keyed by (item, fps): CMU clips take seconds
# to parse and retarget, and several sets reuse them.
_MOTION_CACHE: dict = {}


_OBJECTS = {"box": RigidObject.box, "ball": RigidObject.ball, "bottle": RigidObject.cylinder,
            "chair": RigidObject.chair}  # fmt: skip


def _make_object(name: str) -> RigidObject:
    if name not in _OBJECTS:
        raise ValueError(f"Unknown object {name!r}; choose from {sorted(_OBJECTS)}.")
    return _OBJECTS[name]()


def _make_sequence(body, items, config, rngs, cache, placement, regressor, obj) -> dict:
    fps, P = config.fps, config.people
    motions = []
    for it in items:
        if not isinstance(it, (str, Path)):
            motions.append(resolve_motion(it, fps, body))
            continue
        key = (str(it), fps, body.num_vertices)
        if key not in cache:
            cache[key] = resolve_motion(it, fps, body)
        motions.append(cache[key])
    T = min(config.max_frames, min(m.num_frames for m in motions))
    out = {"name": " + ".join(m.name for m in motions)}
    people = []
    for p, m in enumerate(motions):
        start = int(rngs["placement"].integers(0, m.num_frames - T + 1))
        poses, trans = m.poses[start : start + T].copy(), m.trans[start : start + T].copy()
        betas = np.zeros(body.num_betas)
        betas[: config.num_betas] = rngs["shape"].normal(scale=config.betas_std, size=config.num_betas)
        if p > 0:
            yaw = rngs["placement"].uniform(-np.pi, np.pi)
            offset = np.array([config.spacing * p * (-1) ** p, 0.0, 0.0])
            poses, trans = _rotate_motion(body, poses, trans - trans[:1] * [1, 0, 1], betas, yaw, offset)
        posed = _posed(body, poses, betas, trans)
        lift = -float(np.min(np.asarray(posed.vertices)[..., 1]))
        trans[:, 1] += lift
        posed = BodyOutput(
            vertices=posed.vertices + np.asarray([0.0, lift, 0.0], posed.vertices.dtype),
            joints=posed.joints + np.asarray([0.0, lift, 0.0], posed.joints.dtype),
            joint_rotations=posed.joint_rotations,
        )
        people.append((poses, trans, betas, posed))
    rest = None  # the object's pose before the pick-up, when the motion is edited to reach it
    if obj is not None and config.reach:
        # Before anything is derived from person 0's motion: the reaches edit it.
        poses, trans, betas, _ = people[0]
        start, end = _contact_range(T)
        try:
            handling = pick_and_place(obj, body, poses, trans, betas, start, end, config.contact_part,
                                      blend=max(1, round(fps / 2)))  # fmt: skip
        except ReachError as e:
            hint = "interaction_config(reach=False) keeps the motion as it is"
            raise ValueError(f"{out['name']}: {e} ({hint}).") from e
        edited = _posed(body, handling.poses, betas, handling.trans)
        people[0] = (handling.poses, handling.trans, betas, edited)
        rest = handling.rest
    out["poses"] = np.stack([x[0] for x in people])
    out["trans"] = np.stack([x[1] for x in people])
    out["betas"] = np.stack([x[2] for x in people])
    out["joints"] = np.stack([np.asarray(x[3].joints) for x in people])
    verts = [np.asarray(x[3].vertices) for x in people]

    if placement is not None:
        res = {k: [] for k in ("imu_ori", "imu_acc", "imu_gyro", "imu_ori_true", "imu_acc_true",
                               "imu_free_acc_true", "imu_gyro_true", "imu_misalignment", "imu_heading")}  # fmt: skip
        for poses, trans, betas, posed in people:
            ideal, meas, err = simulate_imu(
                body, placement, poses, betas, trans, fps, config.imu_errors, rngs["imu"], output=posed
            )
            for k, v in (("imu_ori", meas.orientation), ("imu_acc", meas.acceleration),
                         ("imu_gyro", meas.angular_velocity), ("imu_ori_true", ideal.orientation),
                         ("imu_acc_true", ideal.acceleration), ("imu_free_acc_true", ideal.free_acceleration),
                         ("imu_gyro_true", ideal.angular_velocity), ("imu_misalignment", err.misalignment),
                         ("imu_heading", err.heading)):  # fmt: skip
                res[k].append(np.asarray(v))
        out.update({k: np.stack(v) for k, v in res.items()})

    cams = config.cameras
    if cams is None:
        if obj is not None:
            _add_object(out, body, people, verts, config, obj, rest)
        return out
    pelvis = out["joints"][:, :, 0].mean(0)  # (T, 3) centre of the people
    K = intrinsics(cams.width, cams.height, cams.fov_degrees)
    if cams.moving:
        R, t = handheld_trajectory(pelvis, fps, rngs["camera"], distance=cams.distance, height=cams.camera_height)
        R, t = R[None], t[None]
        if cams.num_views > 1:
            raise ValueError("A moving (hand-held) camera scenario has exactly one view.")
    else:
        centre = pelvis.mean(0)
        spread = np.linalg.norm(pelvis - centre, axis=-1).max()
        start = rngs["camera"].uniform(-0.3, 0.3)
        R, t = ring_cameras(cams.num_views, cams.distance + spread, cams.camera_height, centre, start)
        R, t = np.repeat(R[:, None], T, 1), np.repeat(t[:, None], T, 1)
    C = len(R)
    out["cam_K"] = np.repeat(K[None], C, 0)
    out["cam_R"], out["cam_t"] = R, t
    if cams.camera_imu:
        imu = camera_imu(R[0], t[0], fps)
        out["cam_imu_ori"] = np.asarray(imu.orientation[:, 0])
        out["cam_imu_acc"] = np.asarray(imu.acceleration[:, 0])

    if obj is not None:
        _add_object(out, body, people, verts, config, obj, rest)

    if regressor is not None:
        uv, z = _keypoints_2d_jit(jnp.asarray(regressor), jnp.asarray(K), jnp.asarray(R), jnp.asarray(t),
                                  jnp.asarray(np.stack(verts)),
                                  jnp.asarray(np.stack([np.asarray(x[3].joints) for x in people])))  # fmt: skip
        uv, z = np.swapaxes(np.asarray(uv), 0, 1), np.swapaxes(np.asarray(z), 0, 1)
        out["kp_true"], out["kp_depth"] = uv, z
        names = KEYPOINT_FORMATS[config.keypoints]
        dets = [detect(uv[:, c], z[:, c], cams.width, cams.height, names, config.detector, rngs["detector"])
                for c in range(C)]  # fmt: skip
        out["det_keypoints"] = np.stack([d.keypoints for d in dets])
        out["det_person"] = np.stack([d.person for d in dets])
        out["det_swapped"] = np.stack([d.swapped for d in dets])

    if config.silhouettes or config.depth_points:
        scene_v = np.concatenate(verts + ([out["obj_world"]] if obj is not None else []), 1)  # (T, Nv, 3)
        F = body.faces
        V = body.num_vertices
        faces = [F + p * V for p in range(P)]
        labels = [np.full(len(F), p) for p in range(P)]
        if obj is not None:
            faces.append(obj.faces + P * V)
            labels.append(np.full(len(obj.faces), P))
        faces, labels = np.concatenate(faces), np.concatenate(labels)
        Rb, tb = R.reshape(C * T, 3, 3), t.reshape(C * T, 3)
        Vb = np.broadcast_to(scene_v[None], (C, *scene_v.shape)).reshape(C * T, *scene_v.shape[1:])
        dtype = np.float32
        window = window_for(K, Rb, tb, Vb, faces)
        depth, label = rasterize_views(
            K.astype(dtype), Rb.astype(dtype), tb.astype(dtype), Vb.astype(dtype), faces, labels,
            cams.width, cams.height, window=window, floor=bool(config.depth_points),
        )  # fmt: skip
        depth, label = np.asarray(depth), np.asarray(label)
        out["labels"] = label.reshape(C, T, cams.height, cams.width).astype(np.int8)
        if config.depth_points:
            M = config.depth_points
            pts = np.zeros((C * T, M, 3), np.float32)
            lab = np.zeros((C * T, M), np.int8)
            val = np.zeros((C * T, M), bool)
            for b in range(C * T):
                pts[b], lab[b], val[b] = depth_point_cloud(
                    K, Rb[b], tb[b], depth[b], label[b], M, rngs["depth"], config.depth_noise
                )
            out["depth_points"] = pts.reshape(C, T, M, 3)
            out["depth_labels"] = lab.reshape(C, T, M)
            out["depth_valid"] = val.reshape(C, T, M)
            body_v = np.broadcast_to(np.stack(verts, 1)[None], (C, T, P, V, 3)).reshape(C * T, P, V, 3)
            # Padded to a power of two like rasterize_views' batch (pairs are independent).
            pad = (1 << (C * T - 1).bit_length()) - C * T
            ext = lambda x: np.concatenate([x, np.repeat(x[-1:], pad, 0)]).astype(np.float32)  # noqa: E731
            vis = _visibility_jit(jnp.asarray(K, np.float32), jnp.asarray(ext(Rb)), jnp.asarray(ext(tb)),
                                  jnp.asarray(ext(body_v)), jnp.asarray(ext(depth)))  # fmt: skip
            out["visible"] = np.asarray(vis)[: C * T].reshape(C, T, P, V)
    out.pop("obj_world", None)
    return out


def _contact_range(T: int) -> tuple[int, int]:
    """The contact frames [start, end) of an object scene: the middle half."""
    return T // 4, max(T // 4 + 1, (3 * T) // 4)


def _add_object(out, body, people, verts, config, obj, rest=None):
    _, _, _, posed = people[0]
    start, end = _contact_range(len(verts[0]))
    traj, contact = contact_trajectory(
        obj, body, verts[0], np.asarray(posed.joints), np.asarray(posed.joint_rotations),
        start, end, config.contact_part, rest=rest,
    )  # fmt: skip
    out["obj_R"], out["obj_t"], out["contact"] = traj.rotations, traj.translations, contact
    out["obj_world"] = ObjectTrajectory(traj.rotations, traj.translations).vertices(obj)


_KEEP_F64 = ("poses", "trans", "betas")


def _pad_and_stack(seqs: list[dict]) -> dict:
    lengths = np.array([s["poses"].shape[1] for s in seqs])
    T = int(lengths.max())
    arrays = {"length": lengths, "mask": np.arange(T)[None] < lengths[:, None]}
    for key in seqs[0]:
        if key == "name":
            continue
        ax = _time_axis(key)
        stacked = []
        for s in seqs:
            v = np.asarray(s[key])
            if ax >= 0 and v.shape[ax] < T:
                idx = [slice(None)] * v.ndim
                idx[ax] = slice(-1, None)
                v = np.concatenate([v, np.repeat(v[tuple(idx)], T - v.shape[ax], ax)], ax)
            stacked.append(v)
        a = np.stack(stacked)
        if a.dtype == np.float64 and key not in _KEEP_F64:
            a = a.astype(np.float32)
        arrays[key] = a
    return arrays


def save_scenario(scenario: Scenario, path) -> Path:
    """Write jaxmocap's own npz (compressed; atomic: temp file + rename). `.npz` is
    appended to other names; missing folders are created; an existing folder is refused."""
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"save_scenario: path {str(path)!r} is a folder; give a file name, e.g. "
                         f"{str(path / 'scenario.npz')!r}.")  # fmt: skip
    if path.suffix != ".npz":
        path = path.with_name(path.name + ".npz")
    if path.is_dir():
        raise ValueError(f"save_scenario: {str(path)!r} is a folder; give another file name.")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez_compressed(tmp, meta_json=np.array(json.dumps(scenario.meta)), **scenario.arrays)
    os.replace(tmp, path)
    return path


def load_scenario(path) -> Scenario:
    """Read a file written by `save_scenario`; MotionFileError naming the file if unreadable."""
    from ..motion.skeleton import MotionFileError, check_file, read_npz

    d = read_npz(check_file(path))
    if "meta_json" not in d:
        raise ValueError(f"{path} is not a jaxmocap scenario file (no meta_json).")
    try:
        meta = json.loads(str(d.pop("meta_json")))
    except ValueError as e:
        raise MotionFileError(f"{path}: its meta_json is not JSON ({e}).") from e
    arrays = d
    if meta.get("format") != "jaxmocap_scenario":
        raise ValueError(f"{path}: unknown format {meta.get('format')!r}.")
    return Scenario(arrays, meta)


def save_dip(scenario: Scenario, folder, person: int = 0) -> list[Path]:
    """One DIP-IMU-layout pickle per sequence: imu_ori (N,17,3,3), imu_acc (N,17,3), gt (N,72).

    As in DIP-IMU, orientations are calibrated virtual bone orientations (Huang eq. 6.5-6.6,
    offsets from the first frame and its true pose; no heading reset, so heading errors
    remain), accelerations are global with gravity removed (R̃ ã - g), dropped samples
    are NaN and gt holds the SMPL-tree axis-angle poses. Needs the "xsens17" sensor set.
    """
    if scenario.meta.get("sensor_set") != "xsens17":
        raise ValueError(
            f"DIP-IMU's layout has the 17 Xsens sensors; this scenario uses "
            f"{scenario.meta.get('sensor_set')!r}. Make it with ScenarioConfig(imu_set='xsens17')."
        )
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    bones = scenario["imu_bones"]
    paths = []
    for i in range(scenario.num_sequences):
        s = scenario.sequence(i)
        R = s["imu_ori"][person].astype(np.float64)
        acc = s["imu_acc"][person].astype(np.float64)
        poses = s["poses"][person]
        first = np.flatnonzero(np.isfinite(R).all((-1, -2)).all(-1))
        t0 = int(first[0]) if len(first) else 0
        R_bone0 = np.asarray(_global_rotations(poses[t0 : t0 + 1]))[0][bones]
        offsets = np.asarray(sensor_to_bone_offsets(jnp.asarray(R_bone0), jnp.asarray(R[t0])))
        data = {
            "imu_ori": np.asarray(virtual_bone_orientations(jnp.asarray(R), jnp.asarray(offsets)), np.float32),
            "imu_acc": global_free_acceleration(R, acc).astype(np.float32),
            "gt": poses.reshape(len(poses), 72).astype(np.float32),
        }
        path = folder / f"s{i:03d}.pkl"
        tmp = path.with_suffix(".pkl.tmp")
        with open(tmp, "wb") as f:
            pickle.dump(data, f, protocol=4)
        os.replace(tmp, path)
        paths.append(path)
    return paths


def _global_rotations(poses):
    from ..body.kinematics import forward_kinematics
    from ..body.model import SMPL_PARENTS

    local = axis_angle_to_matrix(jnp.asarray(poses))
    R, _ = forward_kinematics(SMPL_PARENTS, local, jnp.zeros((*poses.shape[:-2], 24, 3), local.dtype))
    return R
