"""2D keypoints: COCO-18 / BODY_25 / BODY_25B / HALPE_26 / MediaPipe-33 regressors on the body and a detector error model.

Regressor: a (K, V) matrix 𝒦 with keypoints = 𝒦 · vertices (posed mesh), built per body
from its rest mesh:
  - body joints (shoulders, elbows, wrists, hips, knees, ankles) = rows of 𝒥 (SMPL's
    joint regressor), so they move exactly like the model's joints;
  - neck = mean of the shoulder rows, MidHip = mean of the hip rows (OpenPose's
    definitions);
  - face and feet (nose, eyes, ears, big/small toes, heels) = single vertices picked with
    `imu.ray_vertex`: the skin point straight out from a joint-relative point, among
    vertices skinned mostly to the head / foot bones. Offsets in `_SURFACE` (metres, rest
    pose, y up, facing +z).
  - BODY_25B's upper neck (below the chin, from MPII's "upper neck") = the mean of SMPL's
    neck and head rows; its head top = the crown vertex straight above the head joint.
  - MediaPipe Pose's 33 landmarks (BlazePose: `jaxmocap.formats.video`) add eye corners,
    mouth corners, three hand points and the foot's tip, all single skin vertices as
    above; its shoulders, elbows, wrists, hips, knees and ankles are 𝒥's rows like the
    others' (BlazePose was trained on the same kind of joint-centre annotations as COCO).
OpenPose's hips sit lower and more lateral than SMPL's; we keep SMPL's (documented
difference, as in SMPLify's use of 𝒥 for the hips).

How each layout maps onto SMPL (index in each layout; J(x) = row x of 𝒥, mean(·) = mean
of rows, vertex(x) = a skin vertex near joint x; left/right mirror each other):

    keypoint          coco18  body25  body25b  halpe26  SMPL
    nose                 0       0       0           0  vertex(head), front of the face
    neck                 1       1       -          18  mean(J(left_shoulder), J(right_shoulder))
    upper_neck           -       -      17           -  mean(J(neck), J(head))
    head_top             -       -      18          17  vertex(head), top of the skull
    right_shoulder       2       2       6           6  J(right_shoulder)
    right_elbow          3       3       8           8  J(right_elbow)
    right_wrist          4       4      10          10  J(right_wrist)
    left_shoulder        5       5       5           5  J(left_shoulder)
    left_elbow           6       6       7           7  J(left_elbow)
    left_wrist           7       7       9           9  J(left_wrist)
    mid_hip              -       8       -          19  mean(J(left_hip), J(right_hip))
    right_hip            8       9      12          12  J(right_hip)
    right_knee           9      10      14          14  J(right_knee)
    right_ankle         10      11      16          16  J(right_ankle)
    left_hip            11      12      11          11  J(left_hip)
    left_knee           12      13      13          13  J(left_knee)
    left_ankle          13      14      15          15  J(left_ankle)
    right_eye           14      15       2           2  vertex(head), 3.2 cm right, 3.5 cm up
    left_eye            15      16       1           1  vertex(head), 3.2 cm left, 3.5 cm up
    right_ear           16      17       4           4  vertex(head), to the right
    left_ear            17      18       3           3  vertex(head), to the left
    left_big_toe         -      19      19          20  vertex(left_foot), front, medial
    left_small_toe       -      20      20          22  vertex(left_foot), front, lateral
    left_heel            -      21      21          24  vertex(left_ankle), back
    right_big_toe        -      22      22          21  vertex(right_foot), front, medial
    right_small_toe      -      23      23          23  vertex(right_foot), front, lateral
    right_heel           -      24      24          25  vertex(right_ankle), back

Orders follow OpenPose's `poseParameters.cpp` (POSE_COCO_BODY_PARTS, POSE_BODY_25_BODY_PARTS,
POSE_BODY_25B_BODY_PARTS, where index 17 is called "Neck" but is the upper neck) and, for
HALPE_26 (AlphaPose's Halpe full body; RTMPose's, run by Pose2Sim >= 0.9 as its default
"Body_with_feet"), Pose2Sim's `skeletons.py` ids: its "Head" is the top of the head, its
"Neck" and "Hip" are OpenPose's neck and mid-hip.

MediaPipe-33 ("mediapipe33", the order of mediapipe's `PoseLandmark`; its "mouth_left" and
"mouth_right" are named left_mouth / right_mouth here so that left/right pairs are found
the same way as for the other layouts; "foot_index" is the tip of the foot):

    keypoint               index (left, right)   SMPL
    nose                   0                     as above
    eye_inner, eye, eye_outer  (1, 4), (2, 5), (3, 6)  vertex(head), 1.7 / 3.2 / 4.7 cm to the side, 3.5 cm up
    ear                    (7, 8)                as above
    mouth                  (9, 10)               vertex(head), 2.5 cm to the side, 3.5 cm down
    shoulder .. wrist      (11, 12) .. (15, 16)  J(...)
    pinky, index           (17, 18), (19, 20)    vertex(hand), the knuckles at the back / front of the hand
    thumb                  (21, 22)              vertex(wrist), 4 cm out, towards the front
    hip .. ankle           (23, 24) .. (27, 28)  J(...)
    heel                   (29, 30)              as above
    foot_index             (31, 32)              vertex(foot), front, at the second toe

Detector error model (`DetectorErrorModel`, `detect`): per view and frame, every person's
keypoints get pixel noise, confidences that fall with the error, missed joints (and all
joints outside the image), uniform outliers inside the person's box, left/right swaps
over runs of frames (separately for arms, legs and face), missed people, and distractor
detections (human-shaped false positives). Output is padded per frame with the identity
of each detection (-1: distractor) kept for evaluating association (von Marcard §4.3.2).
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np
from jax import Array

from ..body.model import SMPL_JOINT_NAMES, Body
from .imu import ray_vertex, rest_joints

__all__ = [
    "COCO18_NAMES",
    "BODY25_NAMES",
    "BODY25B_NAMES",
    "MEDIAPIPE33_NAMES",
    "HALPE26_NAMES",
    "KEYPOINT_FORMATS",
    "keypoint_regressor",
    "regress_keypoints",
    "DetectorErrorModel",
    "Detections",
    "detect",
    "flip_pairs",
    "person_track",
]

COCO18_NAMES = (
    "nose", "neck", "right_shoulder", "right_elbow", "right_wrist", "left_shoulder",
    "left_elbow", "left_wrist", "right_hip", "right_knee", "right_ankle", "left_hip",
    "left_knee", "left_ankle", "right_eye", "left_eye", "right_ear", "left_ear",
)  # fmt: skip
BODY25_NAMES = (
    "nose", "neck", "right_shoulder", "right_elbow", "right_wrist", "left_shoulder",
    "left_elbow", "left_wrist", "mid_hip", "right_hip", "right_knee", "right_ankle",
    "left_hip", "left_knee", "left_ankle", "right_eye", "left_eye", "right_ear", "left_ear",
    "left_big_toe", "left_small_toe", "left_heel", "right_big_toe", "right_small_toe",
    "right_heel",
)  # fmt: skip
BODY25B_NAMES = (
    "nose", "left_eye", "right_eye", "left_ear", "right_ear", "left_shoulder",
    "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_hip",
    "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle", "upper_neck",
    "head_top", "left_big_toe", "left_small_toe", "left_heel", "right_big_toe",
    "right_small_toe", "right_heel",
)  # fmt: skip
HALPE26_NAMES = (
    "nose", "left_eye", "right_eye", "left_ear", "right_ear", "left_shoulder",
    "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_hip",
    "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle", "head_top", "neck",
    "mid_hip", "left_big_toe", "right_big_toe", "left_small_toe", "right_small_toe",
    "left_heel", "right_heel",
)  # fmt: skip
MEDIAPIPE33_NAMES = (
    "nose", "left_eye_inner", "left_eye", "left_eye_outer", "right_eye_inner", "right_eye",
    "right_eye_outer", "left_ear", "right_ear", "left_mouth", "right_mouth", "left_shoulder",
    "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_pinky",
    "right_pinky", "left_index", "right_index", "left_thumb", "right_thumb", "left_hip",
    "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle", "left_heel",
    "right_heel", "left_foot_index", "right_foot_index",
)  # fmt: skip
KEYPOINT_FORMATS = {
    "coco18": COCO18_NAMES, "body25": BODY25_NAMES, "body25b": BODY25B_NAMES, "halpe26": HALPE26_NAMES,
    "mediapipe33": MEDIAPIPE33_NAMES,
}  # fmt: skip

_J = {n: i for i, n in enumerate(SMPL_JOINT_NAMES)}
_JOINT_ROWS = {
    n: (n,) for n in (
        "left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist",
        "right_wrist", "left_hip", "right_hip", "left_knee", "right_knee", "left_ankle",
        "right_ankle",
    )
}  # fmt: skip
_JOINT_ROWS["neck"] = ("left_shoulder", "right_shoulder")
_JOINT_ROWS["mid_hip"] = ("left_hip", "right_hip")
_JOINT_ROWS["upper_neck"] = ("neck", "head")  # BODY_25B: between the neck base and the skull base

# name: (joint, offset from it (left side; mirrored for right), outward direction, bone)
_SURFACE = {
    "nose": ("head", (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), "head"),
    "left_eye": ("head", (0.032, 0.035, 0.0), (0.0, 0.0, 1.0), "head"),
    "left_ear": ("head", (0.0, 0.01, 0.0), (1.0, 0.0, 0.0), "head"),
    "left_big_toe": ("left_foot", (-0.015, 0.0, 0.0), (0.0, 0.0, 1.0), "left_foot"),
    "left_small_toe": ("left_foot", (0.03, 0.0, -0.02), (0.0, 0.0, 1.0), "left_foot"),
    "left_heel": ("left_ankle", (0.0, -0.03, 0.0), (0.0, 0.0, -1.0), "left_ankle"),
    "head_top": ("head", (0.0, 0.0, 0.01), (0.0, 1.0, 0.0), "head"),
    # MediaPipe's extra points. Rest pose: arms out along ±x, palms down, thumbs forward (+z).
    "left_eye_inner": ("head", (0.017, 0.035, 0.0), (0.0, 0.0, 1.0), "head"),
    "left_eye_outer": ("head", (0.047, 0.035, 0.0), (0.0, 0.0, 1.0), "head"),
    "left_mouth": ("head", (0.025, -0.035, 0.0), (0.0, 0.0, 1.0), "head"),
    "left_index": ("left_hand", (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), "left_hand"),
    "left_pinky": ("left_hand", (0.0, 0.0, 0.0), (0.0, 0.0, -1.0), "left_hand"),
    "left_thumb": ("left_wrist", (0.04, 0.0, 0.0), (0.0, 0.0, 1.0), "left_wrist"),
    "left_foot_index": ("left_foot", (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), "left_foot"),
}


def flip_pairs(names: tuple[str, ...]) -> list[tuple[int, int]]:
    """Index pairs (left, right) of a keypoint layout."""
    return [
        (i, names.index(n.replace("left", "right")))
        for i, n in enumerate(names)
        if n.startswith("left") and n.replace("left", "right") in names
    ]


def _surface_vertex(body: Body, name: str, joints: np.ndarray) -> int:
    right = name.startswith("right")
    key = name.replace("right", "left") if right else name
    joint, offset, direction, bone = _SURFACE[key]
    if right:
        joint, bone = joint.replace("left", "right"), bone.replace("left", "right")
        offset = (-offset[0], offset[1], offset[2])
        direction = (-direction[0], direction[1], direction[2])
    point = joints[_J[joint]] + np.asarray(offset)
    if bone in ("left_foot", "right_foot", "left_hand", "right_hand"):
        # The low-resolution mesh merges the toes into the foot and the fingers into the
        # hand; accept the bone above.
        try:
            return ray_vertex(body, point, direction, _J[bone])
        except ValueError:
            bone = bone.replace("foot", "ankle").replace("hand", "wrist")
    return ray_vertex(body, point, direction, _J[bone])


def keypoint_regressor(body: Body, layout: str = "coco18") -> np.ndarray:
    """(K, V) keypoint regressor for `layout` (a `KEYPOINT_FORMATS` name) on `body`."""
    if not hasattr(body, "J_regressor") or not hasattr(body, "num_vertices"):
        raise ValueError(f"keypoint_regressor: body must be a jaxmocap Body (e.g. default_body()), got {type(body).__name__}.")
    if layout not in KEYPOINT_FORMATS:
        raise ValueError(f"Unknown keypoint layout {layout!r}; choose from {sorted(KEYPOINT_FORMATS)}.")
    names = KEYPOINT_FORMATS[layout]
    Jreg = np.asarray(body.J_regressor, np.float64)
    joints = rest_joints(body)
    out = np.zeros((len(names), body.num_vertices))
    for k, name in enumerate(names):
        if name in _JOINT_ROWS:
            rows = [_J[j] for j in _JOINT_ROWS[name]]
            out[k] = Jreg[rows].mean(0)
        else:
            out[k, _surface_vertex(body, name, joints)] = 1.0
    return out


def regress_keypoints(regressor: Array, vertices: Array) -> Array:
    """3D keypoints 𝒦 v: (K, V) x (..., V, 3) -> (..., K, 3)."""
    return jnp.einsum("kv,...vc->...kc", jnp.asarray(regressor, vertices.dtype), vertices)


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
        # A negative std or a rate above 1 made the simulator fail deep inside NumPy, or not at all.
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) or not (np.isfinite(v) and v >= 0):
                raise ValueError(f"DetectorErrorModel.{f.name} must be a finite number >= 0, got {v!r}.")
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
        g = "face" if ("eye" in n or "ear" in n) else "arms" if any(
            s in n for s in ("shoulder", "elbow", "wrist")
        ) else "legs"
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

