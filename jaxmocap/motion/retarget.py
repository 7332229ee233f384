"""Retarget a source skeleton's motion (ASF/AMC, BVH) onto SMPL's 24-joint tree.

Method (global-orientation transfer with rest-direction alignment):

1. Each SMPL joint j is mapped to a source joint s(j) whose global rotation drives it,
   and to a source *point* q(j) (default s(j)) that plays the role of SMPL's joint
   centre. Tables for CMU ASF, CMU BVH (the 131_01-style names and Bruce Hahne's
   MotionBuilder-style names) are below; pass `mapping=` for other skeletons.
2. Source rotations are relative to the source rest pose (ASF: all DOFs zero; BVH: all
   channels zero). For a non-leaf SMPL joint j with primary child c (the only child;
   `neck` for spine3, `spine1` for the pelvis) let d_smpl = J_c − J_j (SMPL rest
   joints for the body shape) and d_src = q(c) − q(j) in the source rest pose. A_j is
   the minimal rotation taking d_smpl onto d_src, and

       G_smpl_j(t) = G_src_s(j)(t) · A_j,

   so the SMPL segment j→c points exactly where the source segment q(j)→q(c) points
   (up to the source's own rotations between s(j) and q(c), which SMPL lacks).
   Pelvis: A = I, since both rest poses stand upright facing +z with the left side at
   +x (checked for CMU ASF and BVH: left hip at +x, toes toward +z, y up).
   Leaves (feet, head, hands) use A = I: their rest orientations agree in both
   skeletons (head upright, soles flat, palms down), and the parent's A would tilt them
   by the parent segment's rest-direction difference (the head looked ~20° upwards
   with the neck's A). Joints whose source direction is degenerate (a zero-length
   source segment) use their parent's A. SMPL joints without any source joint
   get the identity local rotation.
   Rigs from animation tools (the CC rig of ../shared/data/cmu_cc) give each bone its own
   frame, so their all-channels-zero pose is no rest pose (legs and arms point up) and
   the minimal rotation A_j is a guess (a 180° turn about an arbitrary axis: hips came
   out twisted by ~170°). `rest="motion"` (chosen by `rest_kind` when a mapped segment
   points more than 120° away from SMPL's) fixes A_j from the clip instead:
   - a limb joint keeps A_j d_smpl ∥ d_src (positions as before) and takes the twist
     about d_smpl that brings the clip's local rotations, summed, closest to identity
     (max Σ_t tr(G_parent(t)ᵀ G_src(t) A_j), in closed form);
   - leaves and the spine (whose rest curvature is the rig's own) take the whole A_j
     that way (Kabsch);
   - the root aligns SMPL's rest torso (pelvis→neck, hip to hip) with the source's,
     both seen from the source root over the clip.
   The result does not depend on the frames the bones carry (a test re-frames a CMU rig).
3. Local rotations R_j = G_parent⁻¹ G_j, as axis-angle (scipy).
4. Root translation: the SMPL pelvis joint follows the source point q(pelvis) (CMU: the
   ASF root / BVH Hips, the pelvis centre between the hips), in metres, unscaled:
   trans = q_pelvis(t) − J_0. With `floor=True` (default) a constant vertical shift then
   puts the feet on y = 0: over the whole clip, the lowest SMPL ankle/foot joint sits
   at its rest-pose height above the body's soles (the lowest rest vertex). The source
   world frame is used as is (CMU is y up, like jaxmocap); `world_rotation` converts
   other frames.

Limitations: segment lengths are SMPL's (no IK), so with a body whose legs differ in
length from the subject's the feet slide a little; twist about a bone is the
source's, transported by the minimal rotation A_j.
"""

from __future__ import annotations

import numpy as np

from ..body.model import SMPL_JOINT_NAMES, SMPL_PARENTS
from ..rotation import host_exp, host_log
from .sequence import Motion
from .skeleton import SkeletonMotion

__all__ = [
    "CC_BASE_MAP",
    "CMU_ASF_MAP",
    "CMU_BVH_HAHNE_MAP",
    "CMU_BVH_MAP",
    "MIXAMO_MAP",
    "OPTIONAL_JOINTS",
    "RIGS",
    "alignment",
    "detect_mapping",
    "detect_rig",
    "load_mapping",
    "minimal_rotation",
    "resolve_mapping",
    "rest_kind",
    "retarget",
    "retarget_rotations",
    "smpl_joint_positions",
    "smpl_rest",
    "strip_namespace",
]

# SMPL joint -> source joint name, or (rotation joint, point joint).
CMU_ASF_MAP: dict[str, str | tuple[str, str]] = {
    "pelvis": "root",
    "left_hip": "lfemur", "right_hip": "rfemur",
    "left_knee": "ltibia", "right_knee": "rtibia",
    "left_ankle": "lfoot", "right_ankle": "rfoot",
    "left_foot": "ltoes", "right_foot": "rtoes",
    # SMPL's 3 spine joints take CMU's lowerback/upperback/thorax; SMPL's neck takes
    # upperneck (so CMU's lowerneck bend goes into SMPL's neck local rotation).
    "spine1": "lowerback", "spine2": "upperback", "spine3": "thorax",
    "neck": "upperneck", "head": "head",
    "left_collar": "lclavicle", "right_collar": "rclavicle",
    "left_shoulder": "lhumerus", "right_shoulder": "rhumerus",
    "left_elbow": "lradius", "right_elbow": "rradius",
    # CMU "wrist" is the forearm-twist segment wrist→palm; "hand" carries the flexion.
    "left_wrist": "lwrist", "right_wrist": "rwrist",
    "left_hand": "lhand", "right_hand": "rhand",
}  # fmt: skip

# CMU BVH as shipped in ../shared (131_01.bvh: Hips, LHipJoint, LeftHip, LeftKnee, ...).
CMU_BVH_MAP: dict[str, str | tuple[str, str]] = {
    "pelvis": "Hips",
    "left_hip": "LeftHip", "right_hip": "RightHip",
    "left_knee": "LeftKnee", "right_knee": "RightKnee",
    "left_ankle": "LeftAnkle", "right_ankle": "RightAnkle",
    "left_foot": "LeftToe", "right_foot": "RightToe",
    "spine1": "lowerback", "spine2": "Chest", "spine3": "Chest2",
    "neck": "Neck", "head": "Head",
    "left_collar": "LeftCollar", "right_collar": "RightCollar",
    "left_shoulder": "LeftShoulder", "right_shoulder": "RightShoulder",
    "left_elbow": "LeftElbow", "right_elbow": "RightElbow",
    "left_wrist": "LeftWrist", "right_wrist": "RightWrist",
    # lhand sits on the wrist (zero offset); its segment ends at the fingers.
    "left_hand": ("lhand", "LFingers"), "right_hand": ("rhand", "RFingers"),
}  # fmt: skip

# Bruce Hahne's MotionBuilder-friendly CMU BVH release.
CMU_BVH_HAHNE_MAP: dict[str, str | tuple[str, str]] = {
    "pelvis": "Hips",
    "left_hip": "LeftUpLeg", "right_hip": "RightUpLeg",
    "left_knee": "LeftLeg", "right_knee": "RightLeg",
    "left_ankle": "LeftFoot", "right_ankle": "RightFoot",
    "left_foot": "LeftToeBase", "right_foot": "RightToeBase",
    "spine1": "LowerBack", "spine2": "Spine", "spine3": "Spine1",
    "neck": "Neck1", "head": "Head",
    "left_collar": "LeftShoulder", "right_collar": "RightShoulder",
    "left_shoulder": "LeftArm", "right_shoulder": "RightArm",
    "left_elbow": "LeftForeArm", "right_elbow": "RightForeArm",
    "left_wrist": "LeftHand", "right_wrist": "RightHand",
    "left_hand": ("LeftFingerBase", "LeftHandIndex1"),
    "right_hand": ("RightFingerBase", "RightHandIndex1"),
}  # fmt: skip

# Reallusion Character Creator rig (../shared/data/cmu_cc): CMU motion re-exported from
# iClone. Its twist, "share", finger and face bones are left out (hands stay at rest).
CC_BASE_MAP: dict[str, str | tuple[str, str]] = {
    "pelvis": "CC_Base_Hip",  # the root: the spine hangs from it; CC_Base_Pelvis carries only the legs
    "left_hip": "CC_Base_L_Thigh", "right_hip": "CC_Base_R_Thigh",
    "left_knee": "CC_Base_L_Calf", "right_knee": "CC_Base_R_Calf",
    "left_ankle": "CC_Base_L_Foot", "right_ankle": "CC_Base_R_Foot",
    "left_foot": "CC_Base_L_ToeBase", "right_foot": "CC_Base_R_ToeBase",
    "spine1": "CC_Base_Waist", "spine2": "CC_Base_Spine01", "spine3": "CC_Base_Spine02",
    "neck": "CC_Base_NeckTwist01", "head": "CC_Base_Head",
    "left_collar": "CC_Base_L_Clavicle", "right_collar": "CC_Base_R_Clavicle",
    "left_shoulder": "CC_Base_L_Upperarm", "right_shoulder": "CC_Base_R_Upperarm",
    "left_elbow": "CC_Base_L_Forearm", "right_elbow": "CC_Base_R_Forearm",
    "left_wrist": "CC_Base_L_Hand", "right_wrist": "CC_Base_R_Hand",
}  # fmt: skip

# Mixamo (Adobe) characters, usually with a "mixamorig:" namespace, which is ignored.
MIXAMO_MAP: dict[str, str | tuple[str, str]] = {
    "pelvis": "Hips",
    "left_hip": "LeftUpLeg", "right_hip": "RightUpLeg",
    "left_knee": "LeftLeg", "right_knee": "RightLeg",
    "left_ankle": "LeftFoot", "right_ankle": "RightFoot",
    "left_foot": "LeftToeBase", "right_foot": "RightToeBase",
    "spine1": "Spine", "spine2": "Spine1", "spine3": "Spine2",
    "neck": "Neck", "head": "Head",
    "left_collar": "LeftShoulder", "right_collar": "RightShoulder",
    "left_shoulder": "LeftArm", "right_shoulder": "RightArm",
    "left_elbow": "LeftForeArm", "right_elbow": "RightForeArm",
    "left_wrist": "LeftHand", "right_wrist": "RightHand",
    "left_hand": "LeftHandMiddle1", "right_hand": "RightHandMiddle1",
}  # fmt: skip

# Built-in rigs, tried in this order: the first whose required joints the source has.
RIGS: dict[str, tuple[str, dict]] = {
    "cmu_asf": ("CMU ASF/AMC skeleton", CMU_ASF_MAP),
    "cmu_bvh": ("CMU BVH (131_01-style names)", CMU_BVH_MAP),
    "cmu_bvh_hahne": ("CMU BVH, MotionBuilder-friendly release (B. Hahne)", CMU_BVH_HAHNE_MAP),
    "cc": ("Reallusion Character Creator / iClone (CC_Base_*)", CC_BASE_MAP),
    "mixamo": ("Mixamo", MIXAMO_MAP),
}

# SMPL joints a map may leave out (rigs without toes or fingers): they keep their rest
# pose relative to the parent. Every other SMPL joint must be mapped.
OPTIONAL_JOINTS = ("left_foot", "right_foot", "left_hand", "right_hand")

# Primary child of each SMPL joint (-1 for leaves): the only child, neck for spine3.
_CHILD = [-1] * 24
for _j, _p in enumerate(SMPL_PARENTS[1:], 1):
    if _CHILD[_p] == -1:
        _CHILD[_p] = _j
_CHILD[9] = SMPL_JOINT_NAMES.index("neck")


def detect_rig(src: SkeletonMotion) -> tuple[str, dict]:
    """(name, map) of the first built-in rig of `RIGS` whose required joints `src` has."""
    names = set(src.names)
    for name, (_, table) in RIGS.items():
        if all(_joint(v, 0) in names and _joint(v, 1) in names for k, v in table.items() if k not in OPTIONAL_JOINTS):
            return name, table
    raise ValueError(
        f"No built-in SMPL joint map fits the skeleton of {src.name or 'this motion'} "
        f"(joints {list(src.names)[:12]}...; built-in rigs: {', '.join(RIGS)}). Pass "
        "mapping={smpl_joint: source_joint} or the path of a TOML/JSON file holding that table "
        "(`jaxmocap.motion.retarget.load_mapping`)."
    )


def detect_mapping(src: SkeletonMotion) -> dict:
    """The built-in map fitting `src` (ValueError otherwise); see `detect_rig`."""
    return detect_rig(src)[1]


def _joint(v, k: int) -> str:
    return v if isinstance(v, str) else v[k]


def load_mapping(path) -> dict:
    """A joint map from a TOML or JSON file: {smpl_joint: source_joint or [rotation, point]}.

    The table may sit at the top level or under a `[map]` table (TOML) / "map" key (JSON).
    """
    import json
    import tomllib
    from pathlib import Path

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such joint-map file.")
    try:
        text = path.read_text()
        table = json.loads(text) if path.suffix.lower() == ".json" else tomllib.loads(text)
    except (ValueError, UnicodeDecodeError) as e:
        raise ValueError(f"{path}: not a TOML/JSON joint map ({type(e).__name__}: {e}).") from e
    table = table.get("map", table)
    bad = {
        k: v
        for k, v in table.items()
        if not (isinstance(v, str) or (isinstance(v, list) and len(v) == 2 and all(isinstance(x, str) for x in v)))
    }
    if bad:
        raise ValueError(
            f'{path}: each entry must be smpl_joint = "source joint" or ["rotation joint", "point joint"]; got {bad}.'
        )
    return {k: v if isinstance(v, str) else tuple(v) for k, v in table.items()}


def resolve_mapping(mapping, src: SkeletonMotion) -> tuple[str, dict]:
    """(rig name, map) for `mapping`: None (detect), a built-in rig name, a file or a dict."""
    from pathlib import Path

    if mapping is None:
        return detect_rig(src)
    if isinstance(mapping, str) and mapping in RIGS:
        return mapping, RIGS[mapping][1]
    if isinstance(mapping, (str, Path)):
        return str(mapping), load_mapping(mapping)
    if isinstance(mapping, dict):
        return "user map", mapping
    raise TypeError(
        f"mapping must be None, a built-in rig name ({', '.join(RIGS)}), a TOML/JSON file or a dict; "
        f"got {type(mapping).__name__}."
    )


def strip_namespace(src: SkeletonMotion) -> SkeletonMotion:
    """`src` with joint-name namespaces ("mixamorig:Hips" -> "Hips") removed, if unambiguous."""
    import dataclasses

    short = tuple(n.rsplit(":", 1)[-1] for n in src.names)
    if short == src.names or len(set(short)) < len(short):
        return src
    return dataclasses.replace(src, names=short)


def minimal_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking direction `a` onto direction `b` (3x3)."""
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    axis = np.cross(a, b)
    s, c = np.linalg.norm(axis), float(np.dot(a, b))
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        # Antiparallel: half turn about any axis orthogonal to a.
        ortho = np.cross(a, [1.0, 0, 0] if abs(a[0]) < 0.9 else [0, 1.0, 0])
        return host_exp(np.pi * ortho / np.linalg.norm(ortho))
    return host_exp(axis / s * np.arctan2(s, c))


def smpl_rest(body, betas=None) -> tuple[np.ndarray, float]:
    """(rest joints (24, 3), lowest rest vertex height) of `body` with shape `betas`.

    Uses the public forward pass at zero pose (float64 if jax_enable_x64 is on), so it
    does not depend on the body's internal array layout.
    """
    from ..body.kinematics import forward

    nb = body.num_betas
    b = np.zeros(nb) if betas is None else np.asarray(betas, np.float64).reshape(-1)[:nb]
    out = forward(body, np.zeros((body.num_joints, 3), body.dtype), b if b.size else None)
    joints = np.asarray(out.joints, np.float64)
    return joints, float(np.asarray(out.vertices)[:, 1].min())


def _resolve(mapping: dict, src: SkeletonMotion) -> tuple[list, list]:
    unknown = [k for k in mapping if k not in SMPL_JOINT_NAMES]
    if unknown:
        raise ValueError(f"mapping has keys {unknown} that are not SMPL joints {list(SMPL_JOINT_NAMES)}.")
    missing = [n for n in SMPL_JOINT_NAMES if n not in mapping and n not in OPTIONAL_JOINTS]
    if missing:
        raise ValueError(
            f"mapping leaves SMPL joints {missing} unmapped; give each a joint of "
            f"{src.name or 'the skeleton'} (joints: {list(src.names)}). Only {list(OPTIONAL_JOINTS)} "
            "may be left out (they keep their rest pose)."
        )
    rot_idx, pt_idx = [None] * 24, [None] * 24
    for k, v in mapping.items():
        j = SMPL_JOINT_NAMES.index(k)
        r, p = (v, v) if isinstance(v, str) else v
        if r not in src.names or p not in src.names:
            if k in OPTIONAL_JOINTS:
                continue  # a rig without toes or fingers: rest pose
            missing = r if r not in src.names else p
            raise ValueError(f"mapping[{k!r}] names {missing!r}, which {src.name or 'the skeleton'} does not have.")
        rot_idx[j], pt_idx[j] = src.names.index(r), src.names.index(p)
    return rot_idx, pt_idx


# In "motion" mode the spine's rest curvature is the rig's own (the CC rig's 5-15 cm
# segments bend 20-40° against SMPL's): the root carries the torso's axis, and each spine
# joint keeps the clip's mean bend at zero instead of copying its segment direction.
_SPINE = tuple(SMPL_JOINT_NAMES.index(n) for n in ("spine1", "spine2", "spine3"))


def rest_kind(src: SkeletonMotion, rest_joints: np.ndarray, mapping: dict) -> str:
    """'zero' if the source's all-channels-zero pose stands like SMPL's rest, else 'motion'.

    Measured on the mapped segments: every segment of a standing zero pose lies within
    120° of SMPL's rest direction (CMU BVH's arms hang down: 90°); animation rigs whose
    bones carry their own frames (the CC rig: legs and arms point up at zero) do not.
    """
    _, pt_idx = _resolve(mapping, src)
    for j in range(1, 24):
        c = _CHILD[j]
        if c < 0 or pt_idx[j] is None or pt_idx[c] is None:
            continue
        d_src = src.rest_positions[pt_idx[c]] - src.rest_positions[pt_idx[j]]
        d_smpl = rest_joints[c] - rest_joints[j]
        # Past 120° the minimal rotation stops meaning anything (at 180° its axis is arbitrary).
        cos = np.dot(d_src, d_smpl) / max(np.linalg.norm(d_src) * np.linalg.norm(d_smpl), 1e-12)
        if np.linalg.norm(d_src) > 1e-6 and cos < -0.5:
            return "motion"
    return "zero"


def alignment(src: SkeletonMotion, rest_joints: np.ndarray, mapping: dict, rest: str = "auto") -> np.ndarray:
    """(24, 3, 3) rest alignments A_j (see the module docstring; `rest` as in `retarget`)."""
    if rest == "auto":
        rest = rest_kind(src, rest_joints, mapping)
    if rest not in ("zero", "motion"):
        raise ValueError(f"rest must be 'auto', 'zero' or 'motion', got {rest!r}.")
    rot_idx, pt_idx = _resolve(mapping, src)
    A = np.zeros((24, 3, 3))
    A[0] = np.eye(3) if rest == "zero" else _root_alignment(src, rest_joints, rot_idx, pt_idx)
    for j in range(1, 24):
        c, p = _CHILD[j], SMPL_PARENTS[j]
        d_src = d_smpl = np.zeros(3)
        if c >= 0 and pt_idx[j] is not None and pt_idx[c] is not None:
            d_src = src.rest_positions[pt_idx[c]] - src.rest_positions[pt_idx[j]]
            d_smpl = rest_joints[c] - rest_joints[j]
        has_direction = np.linalg.norm(d_src) > 1e-6 and np.linalg.norm(d_smpl) > 1e-9
        if rest == "zero":
            A[j] = np.eye(3) if c < 0 else A[p]
            if has_direction:
                A[j] = minimal_rotation(d_smpl, d_src)
        elif rot_idx[j] is not None:
            # The parent's SMPL rotation over the clip, G_p = G_src · A_p (unmapped: its parent's).
            q = p
            while rot_idx[q] is None:
                q = SMPL_PARENTS[q]
            M = np.einsum("tba,tbc->ac", src.rotations[:, rot_idx[q]] @ A[q], src.rotations[:, rot_idx[j]])
            limb = has_direction and j not in _SPINE
            A[j] = _twist_closest(M, d_smpl, d_src) if limb else _closest_rotation(M)
    return A


def _root_alignment(src: SkeletonMotion, rest_joints: np.ndarray, rot_idx: list, pt_idx: list) -> np.ndarray:
    """A_0 taking SMPL's rest torso (up: pelvis→neck, left: right hip→left hip) onto the
    source's, both seen from the source root over the clip (its zero pose says nothing)."""
    i = {n: SMPL_JOINT_NAMES.index(n) for n in ("pelvis", "neck", "left_hip", "right_hip")}
    if any(pt_idx[j] is None for j in i.values()):
        return np.eye(3)
    q = src.positions[:, [pt_idx[i[n]] for n in ("pelvis", "neck", "left_hip", "right_hip")]]
    G0 = src.rotations[:, rot_idx[0]]
    src_v = [np.einsum("tba,tb->a", G0, q[:, 1] - q[:, 0]), np.einsum("tba,tb->a", G0, q[:, 2] - q[:, 3])]
    J = rest_joints
    smpl_v = [J[i["neck"]] - J[i["pelvis"]], J[i["left_hip"]] - J[i["right_hip"]]]
    H = sum(np.outer(a / np.linalg.norm(a), b / np.linalg.norm(b)) for a, b in zip(smpl_v, src_v))
    return _closest_rotation(H)


def _closest_rotation(M: np.ndarray) -> np.ndarray:
    """argmax_R tr(M R) over rotations (Kabsch): the R making M R closest to a multiple of I."""
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    return Vt.T @ D @ U.T


def _twist_closest(M: np.ndarray, d_smpl: np.ndarray, d_src: np.ndarray) -> np.ndarray:
    """A = A₀ R(k, φ) with A d_smpl ∥ d_src, the twist φ about k = d_smpl maximising tr(M A).

    A₀ is the minimal rotation; tr(M A₀ R(k, φ)) = a cos φ + b sin φ + const with
    a = tr N − kᵀNk, b = tr(N [k]×), N = M A₀ (Rodrigues), so φ = atan2(b, a).
    """
    k = d_smpl / np.linalg.norm(d_smpl)
    A0 = minimal_rotation(d_smpl, d_src)
    N = M @ A0
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    phi = np.arctan2(np.trace(N @ K), np.trace(N) - k @ N @ k)
    return A0 @ host_exp(phi * k)


def retarget_rotations(src: SkeletonMotion, rest_joints: np.ndarray, mapping: dict, rest: str = "auto") -> np.ndarray:
    """(T, 24, 3, 3) SMPL global rotations G_j = G_src · A_j (identity local if unmapped)."""
    rot_idx, _ = _resolve(mapping, src)
    A = alignment(src, rest_joints, mapping, rest)
    T = src.num_frames
    G = np.zeros((T, 24, 3, 3))
    for j in range(24):
        if rot_idx[j] is None:
            G[:, j] = G[:, SMPL_PARENTS[j]]
        else:
            G[:, j] = src.rotations[:, rot_idx[j]] @ A[j]
    return G


def _rotate_world(src: SkeletonMotion, W: np.ndarray) -> SkeletonMotion:
    """The same motion expressed in a world frame rotated by W (G ↦ W G Wᵀ, p ↦ W p)."""
    import dataclasses

    return dataclasses.replace(
        src,
        rest_positions=src.rest_positions @ W.T,
        tips=src.tips @ W.T,
        rotations=W @ src.rotations @ W.T,
        positions=src.positions @ W.T,
    )


def retarget(
    src: SkeletonMotion,
    body=None,
    betas=None,
    mapping: dict | None = None,
    fps: float | None = None,
    floor: bool = True,
    world_rotation=None,
    name: str | None = None,
    rest: str = "auto",
) -> Motion:
    """Retarget `src` onto SMPL's tree for `body` (default `jaxmocap.default_body()`).

    Args:
        src: the source motion (from `load_asf_amc` / `load_bvh`).
        body: the SMPL-layout body whose rest joints define the target bone directions.
        betas: its shape (default zeros); stored in the Motion.
        mapping: {SMPL joint name: source joint or (rotation joint, point joint)}, the
            path of a TOML/JSON file holding that table, or a built-in rig name (`RIGS`:
            cmu_asf, cmu_bvh, cmu_bvh_hahne, cc, mixamo); default: the first built-in rig
            whose joints the source has. Namespaces ("mixamorig:Hips") are ignored. Every
            SMPL joint but `OPTIONAL_JOINTS` (toes, finger bases) must be mapped; twist and
            helper bones need no entry (the mapped joints' global rotations include them).
        fps: resample to this rate (slerp), default: the source's rate.
        floor: shift vertically so the feet touch y = 0 (see the module docstring).
        world_rotation: 3x3 rotation from the source world frame to jaxmocap's (y up);
            default identity (right for CMU data).
        name: the Motion's name (default: the source file).
        rest: what the source rotations are relative to. "zero": the all-channels-zero
            pose is a standing rest pose (CMU ASF/BVH, Mixamo); "motion": it is not (rigs
            whose bones carry their own frames, e.g. the CC rig), so each A_j's twist
            (and the whole A_j of leaves) is the one that keeps the clip's mean local
            rotation closest to identity; "auto" (default): `rest_kind` decides.
    """
    if body is None:
        from ..body.io import default_body

        body = default_body()
    if world_rotation is not None:
        src = _rotate_world(src, np.asarray(world_rotation, np.float64))
    src = strip_namespace(src)
    _, mapping = resolve_mapping(mapping, src)
    rest_joints, sole = smpl_rest(body, betas)
    G = retarget_rotations(src, rest_joints, mapping, rest)
    parents = np.array(SMPL_PARENTS)
    local = np.concatenate([G[:, :1], np.swapaxes(G[:, parents[1:]], -1, -2) @ G[:, 1:]], axis=1)
    poses = host_log(local)
    _, pt_idx = _resolve(mapping, src)
    trans = src.positions[:, pt_idx[0]] - rest_joints[0]
    if floor:
        joints = smpl_joint_positions(G, rest_joints, trans)
        feet = [SMPL_JOINT_NAMES.index(n) for n in ("left_ankle", "right_ankle", "left_foot", "right_foot")]
        clearance = (rest_joints[feet, 1] - sole).min()
        trans = trans + np.array([0.0, clearance - joints[:, feet, 1].min(), 0.0])
    nb = body.num_betas
    motion = Motion(
        poses=poses,
        trans=trans,
        fps=src.fps,
        betas=np.zeros(0) if betas is None else np.asarray(betas, np.float64).reshape(-1)[:nb],
        gender=getattr(body, "gender", "neutral"),
        name=src.name if name is None else name,
    )
    return motion if fps is None or float(fps) == src.fps else motion.resample(fps)


def smpl_joint_positions(global_rotations: np.ndarray, rest_joints: np.ndarray, trans: np.ndarray) -> np.ndarray:
    """(T, 24, 3) posed SMPL joints from global rotations (NumPy forward kinematics)."""
    T = global_rotations.shape[0]
    pos = np.zeros((T, 24, 3))
    pos[:, 0] = rest_joints[0] + trans
    for j in range(1, 24):
        p = SMPL_PARENTS[j]
        pos[:, j] = pos[:, p] + global_rotations[:, p] @ (rest_joints[j] - rest_joints[p])
    return pos
