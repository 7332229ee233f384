"""2D keypoint layouts: COCO-18 / BODY_25 / BODY_25B / HALPE_26 / MediaPipe-33 and their regressors on the body.

Regressor: a (K, V + J) matrix 𝒦 with keypoints = 𝒦 · [posed vertices; posed joints]
(`regress_keypoints`), built per body from its rest mesh:
  - body joints (shoulders, elbows, wrists, hips, knees, ankles) = the model's joints posed
    by forward kinematics, Huang's R_θ(J_i(β)) (eq. 4.3), not 𝒥 applied to the posed mesh:
    linear blend skinning collapses the skin at a bent joint, and 𝒥 of that mesh moved
    the elbow 10 cm into the arm at 90° (on Pose2Sim's real demo a fitted upper arm came
    out 0.77 of the triangulated length; 0.94 now, experiments/results/multiview_real.md);
  - neck = mean of the shoulder joints, MidHip = mean of the hip joints (OpenPose's
    definitions);
  - face and feet (nose, eyes, ears, big/small toes, heels) = single vertices picked with
    `surface.ray_vertex`: the skin point straight out from a joint-relative point, among
    vertices skinned mostly to the head / foot bones. Offsets in `_SURFACE` (metres, rest
    pose, y up, facing +z).
  - BODY_25B's upper neck (below the chin, from MPII's "upper neck") = the mean of SMPL's
    neck and head joints; its head top = the crown vertex straight above the head joint.
  - MediaPipe Pose's 33 landmarks (BlazePose: `jaxmocap.formats.video`) add eye corners,
    mouth corners, three hand points and the foot's tip, all single skin vertices as
    above; its shoulders, elbows, wrists, hips, knees and ankles are joints like the
    others' (BlazePose was trained on the same kind of joint-centre annotations as COCO).
OpenPose's hips sit lower and more lateral than SMPL's; we keep SMPL's (documented
difference, as in SMPLify's use of 𝒥 for the hips).

How each layout maps onto SMPL (index in each layout; J(x) = joint x posed, mean(·) = mean
of joints, vertex(x) = a skin vertex near joint x; left/right mirror each other):

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

The simulated detector (`DetectorErrorModel`, `detect`) is `jaxmocap.sensors.detector`.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jax import Array

from ..body.model import SMPL_JOINT_NAMES, Body
from .surface import ray_vertex, rest_joints

__all__ = [
    "COCO18_NAMES",
    "BODY25_NAMES",
    "BODY25B_NAMES",
    "MEDIAPIPE33_NAMES",
    "HALPE26_NAMES",
    "KEYPOINT_FORMATS",
    "keypoint_regressor",
    "regress_keypoints",
    "rest_keypoints",
    "flip_pairs",
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
    """(K, V + J) keypoint regressor for `layout` (a `KEYPOINT_FORMATS` name) on `body`:
    its first V columns weigh the posed vertices, the last J the posed joints."""
    if not hasattr(body, "J_regressor") or not hasattr(body, "num_vertices"):
        raise ValueError(
            f"keypoint_regressor: body must be a jaxmocap Body (e.g. default_body()), got {type(body).__name__}."
        )
    if layout not in KEYPOINT_FORMATS:
        raise ValueError(f"Unknown keypoint layout {layout!r}; choose from {sorted(KEYPOINT_FORMATS)}.")
    names = KEYPOINT_FORMATS[layout]
    V, J = body.num_vertices, np.shape(body.J_regressor)[0]
    joints = rest_joints(body)
    out = np.zeros((len(names), V + J))
    for k, name in enumerate(names):
        if name in _JOINT_ROWS:
            rows = [_J[j] for j in _JOINT_ROWS[name]]
            out[k, V + np.asarray(rows)] = 1.0 / len(rows)
        else:
            out[k, _surface_vertex(body, name, joints)] = 1.0
    return out


def regress_keypoints(regressor: Array, vertices: Array, joints: Array | None = None) -> Array:
    """3D keypoints (..., K, 3) = 𝒦 · [vertices; joints] of a posed body.

    regressor: (K, V + J) (`keypoint_regressor`), or (K, V) for one that reads the mesh
    alone; vertices (..., V, 3) and joints (..., J, 3) posed (`BodyOutput`'s). NumPy
    inputs give a NumPy answer in their own precision, others a JAX array.
    """
    xp = np if isinstance(vertices, np.ndarray) and (joints is None or isinstance(joints, np.ndarray)) else jnp
    n, V = regressor.shape[-1], vertices.shape[-2]
    if n != V:
        if joints is None or n != V + joints.shape[-2]:
            got = f"{V} vertices" + ("" if joints is None else f" and {joints.shape[-2]} joints")
            raise ValueError(
                f"regress_keypoints: the regressor has {n} columns but was given {got}; a regressor of "
                "`keypoint_regressor` reads the posed vertices and joints: pass both (output.vertices, output.joints)."
            )
        # two products, not one over the concatenation: no (..., V + J, 3) copy per evaluation
        reg = xp.asarray(regressor, vertices.dtype)
        return xp.einsum("kv,...vc->...kc", reg[:, :V], vertices) + xp.einsum(
            "kj,...jc->...kc", reg[:, V:], xp.asarray(joints, vertices.dtype)
        )
    return xp.einsum("kv,...vc->...kc", xp.asarray(regressor, vertices.dtype), vertices)


def rest_keypoints(body: Body, layout: str = "coco18") -> np.ndarray:
    """(K, 3) keypoints of `layout` on `body`'s mean shape in its rest pose, NumPy float64."""
    points = np.concatenate([np.asarray(body.v_template, np.float64), rest_joints(body)])
    return keypoint_regressor(body, layout) @ points
