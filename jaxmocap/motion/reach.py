"""Procedural reaches: edit a motion so that a body part touches a world point at one frame.

`reach` solves a small inverse-kinematics problem at that frame (the part's contact point on
the target, the planted feet where they were, the pose as close to the original as
possible) with `jaxmocap.solve`, then blends the change into the neighbouring frames. Used by
`sensors.objects.pick_and_place` for scenes of a person picking up, carrying and putting
down an object.

Contact parts, their joints and contact normals in the joint's rest frame (T-pose: palms
down, feet flat facing +z; the grips along the fingers) are in `CONTACT_PARTS`; the body
contact vertices are those skinned mostly to the part's bones (InterCap's annotated contact
vertices). A part's contact point is its contact vertex furthest along the posed normal.
"""

from __future__ import annotations

import dataclasses
import functools

import jax.numpy as jnp
import numpy as np

from ..body.kinematics import forward, forward_kinematics
from ..body.model import SMPL_JOINT_NAMES, SMPL_PARENTS
from ..rotation import axis_angle_to_matrix, host_exp, host_log, log_small

__all__ = [
    "CONTACT_PARTS",
    "ReachError",
    "ReachInfo",
    "blend_edit",
    "contact_joint",
    "contact_point",
    "contact_vertices",
    "reach",
]

_J = {n: i for i, n in enumerate(SMPL_JOINT_NAMES)}

#: part: (carrying joint, bones of its skin region, contact normal in the rest frame)
CONTACT_PARTS = {
    "left_hand": ("left_wrist", ("left_wrist", "left_hand"), (0.0, -1.0, 0.0)),
    "right_hand": ("right_wrist", ("right_wrist", "right_hand"), (0.0, -1.0, 0.0)),
    # Carrying by the fingers (a bag, a box by its handle): the object hangs beyond the
    # fingertips, so a hanging arm carries it beside the thigh, not into it.
    "left_grip": ("left_wrist", ("left_wrist", "left_hand"), (1.0, 0.0, 0.0)),
    "right_grip": ("right_wrist", ("right_wrist", "right_hand"), (-1.0, 0.0, 0.0)),
    "left_foot": ("left_ankle", ("left_ankle", "left_foot"), (0.0, 0.0, 1.0)),
    "right_foot": ("right_ankle", ("right_ankle", "right_foot"), (0.0, 0.0, 1.0)),
}

# Joints the solve may turn besides the reaching limb (root, spine, both legs) and their
# closeness weights per radian² about the local x (flexion), y (twist) and z (sideways) axes:
# bending forward at the hips and knees is cheap, leaning sideways or a bent knee hinge not.
_BASE = {"pelvis": (2.0, 1.0, 8.0), "spine1": (1.0, 2.0, 10.0), "spine2": (1.0, 2.0, 10.0),
         "spine3": (1.0, 2.0, 10.0), "left_hip": (0.3, 2.0, 3.0), "right_hip": (0.3, 2.0, 3.0),
         "left_knee": (0.3, 20.0, 20.0), "right_knee": (0.3, 20.0, 20.0), "left_ankle": (1.0, 5.0, 5.0),
         "right_ankle": (1.0, 5.0, 5.0)}  # fmt: skip
_LIMB_WEIGHT = (0.3, 0.3, 0.3)
_HANGING_WEIGHT = (0.05, 0.05, 0.05)  # local; their world orientation is kept (`_e_body`)
# Square roots of the weights (per m or rad): contact point and planted feet are near-hard
# constraints (1 mm of reach costs what 0.1 rad of pose does), the feet the harder, so an
# unreachable target leaves a gap rather than a sliding foot; the centre of mass stays over
# the feet (balance), and the knees bend one way only (a soft hinge limit at zero flexion).
_SQRT_W = {"reach": 100.0, "feet": 1000.0, "balance": 10.0**0.5, "knees": 10.0}


def contact_joint(part: str) -> int:
    """Index of the joint that carries `part` (ValueError naming the known parts if unknown)."""
    if part not in CONTACT_PARTS:
        raise ValueError(f"Unknown contact part {part!r}; choose from {sorted(CONTACT_PARTS)}.")
    return _J[CONTACT_PARTS[part][0]]


def contact_vertices(body, part: str) -> np.ndarray:
    """Indices of the body vertices skinned mostly (≥ 0.5) to the part's bones."""
    contact_joint(part)
    w = np.asarray(body.weights)
    bones = [_J[b] for b in CONTACT_PARTS[part][1]]
    return np.flatnonzero(w[:, bones].sum(1) >= 0.5)


def contact_point(body, vertices, joints, joint_rotations, part: str) -> tuple[np.ndarray, np.ndarray, int]:
    """(contact point c (3,), contact normal n (3,), c's vertex index) of one posed frame.

    vertices (V, 3), joints (J, 3), joint_rotations (J, 3, 3); c is the part's contact
    vertex furthest from its joint along n = R_joint · (the part's rest-frame normal).
    """
    j = contact_joint(part)
    region = contact_vertices(body, part)
    n = np.asarray(joint_rotations[j], np.float64) @ np.asarray(CONTACT_PARTS[part][2])
    pts = np.asarray(vertices, np.float64)[region]
    k = int(np.argmax((pts - np.asarray(joints[j], np.float64)) @ n))
    return pts[k], n, int(region[k])


@dataclasses.dataclass(frozen=True)
class ReachInfo:
    """How well a reach went: `gap` (m) from the contact point to the target, `foot_drift`
    (m, largest planted foot joint displacement), the contact `vertex` and LM `steps`."""

    gap: float
    foot_drift: float
    vertex: int
    steps: int


class ReachError(ValueError):
    """The target is out of reach: `gap` (m) is what remains; `poses`, `trans` and `info`
    hold the closest edit found."""

    def __init__(self, message: str, poses: np.ndarray, trans: np.ndarray, info: ReachInfo):
        super().__init__(message)
        self.poses, self.trans, self.info, self.gap = poses, trans, info, info.gap


def _free_joints(part: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(free joints, their closeness weights (K, 3), planted foot joints, joints whose world
    orientation is kept: the hanging shoulders and the part's own joint)."""
    base = [_J[n] for n in _BASE]
    chain, j = [], contact_joint(part)
    while j not in base:  # the reaching limb, up to the trunk
        chain.append(j)
        j = SMPL_PARENTS[j]
    # The other arms hang as they did in the world (not turning with a bending trunk).
    hanging = [_J[f"{s}_shoulder"] for s in ("left", "right") if _J[f"{s}_shoulder"] not in chain]
    free = base + chain[::-1] + hanging
    weights = list(_BASE.values()) + [_LIMB_WEIGHT] * len(chain) + [_HANGING_WEIGHT] * len(hanging)
    # A reaching foot is not planted.
    moving = part.split("_")[0] if part.endswith("_foot") else None
    planted = [_J[f"{s}_{n}"] for s in ("left", "right") if s != moving for n in ("ankle", "foot")]
    kept = hanging + [contact_joint(part)]
    return np.asarray(free), np.asarray(weights), np.asarray(planted), np.asarray(kept)


# --- the inverse-kinematics problem (one frame; module-level functions: one compilation) ----


def _posed(x, d):
    """(global rotations, joints, contact vertex, centre of mass) of the frame, (1, ...) each.

    Forward kinematics plus linear blend skinning of the one contact vertex (its pose blend
    shape included); the centre of mass is the mean of all skinned vertices without pose
    blend shapes, Σ_j R_j (S_j - W_j J_j) + W_j p_j + t (S_j, W_j: `_com`). Not posing the
    mesh makes an LM step about 8x cheaper.
    """

    local = d["local"].at[:, d["free"]].set(x["free"])
    R, p = forward_kinematics(SMPL_PARENTS, local, d["rest"])
    t = x["trans"]
    v = d["v_rest"] + (local[:, 1:] - jnp.eye(3, dtype=t.dtype)).reshape(1, -1) @ d["v_dirs"]
    c = jnp.einsum("j,tjab,tjb->ta", d["v_w"], R, v[:, None] - d["rest"]) + d["v_w"] @ p[0] + t
    com = jnp.einsum("tjab,jb->ta", R, d["S"] - d["W"][:, None] * d["rest"]) + d["W"] @ p[0] + t
    return R, p + t[:, None], c, com


def _e_body(x, d):
    """Contact point - target, planted feet, horizontal centre of mass, world orientations."""
    R, joints, c, com = _posed(x, d)
    horizontal = jnp.asarray([1.0, 0.0, 1.0], c.dtype)
    return jnp.concatenate([
        _SQRT_W["reach"] * (c - d["target"])[:, None],
        _SQRT_W["feet"] * (joints[:, d["planted"]] - d["feet"]),
        _SQRT_W["balance"] * (horizontal * (com - d["com"]))[:, None],
        log_small(jnp.swapaxes(d["kept"], -1, -2) @ R[:, d["keep"]]),
    ], axis=1)  # fmt: skip


def _e_pose(x, d):
    """Closeness to the original local rotations, and the knees' one-way hinge limit."""
    close = d["sqrt_w"] * log_small(jnp.swapaxes(d["local"][:, d["free"]], -1, -2) @ x["free"])
    knees = log_small(x["free"][:, d["knees"]]) * jnp.asarray([1.0, 0.0, 0.0], x["free"].dtype)
    return jnp.concatenate([close, _SQRT_W["knees"] * jnp.minimum(knees, 0.0)], axis=1)


def _e_trans(x, d):
    return (x["trans"] - d["trans"])[:, None]


@functools.lru_cache(maxsize=1)
def _problem():
    from ..solve import Problem, Term, frame

    # Every residual of the posed body in one term: one linearisation of the kinematics.
    return Problem(
        [Term("body", _e_body), Term("pose", _e_pose, reads=(("free", None),)),
         Term("trans", _e_trans, reads=(("trans", None),))],
        {"free": frame("so3")},
    )  # fmt: skip


def _com(body, v_shaped) -> tuple[np.ndarray, np.ndarray]:
    """(S_j, W_j) = (Σ_v w_vj v_v, Σ_v w_vj) / V: the mean skinned vertex is their posed sum."""
    w = np.asarray(body.weights, np.float64)
    return w.T @ v_shaped / len(w), w.sum(0) / len(w)


def _frame(body, pose, betas, trans, part) -> tuple[np.ndarray, int, np.ndarray, np.ndarray]:
    """(contact point, its vertex, joints (J, 3), global rotations (J, 3, 3)) of one pose,
    by the full forward pass (in float64 where JAX has it)."""
    out = forward(body, jnp.asarray(pose), jnp.asarray(betas), jnp.asarray(trans))
    c, _, k = contact_point(body, out.vertices, out.joints, out.joint_rotations, part)
    return c, k, np.asarray(out.joints, np.float64), np.asarray(out.joint_rotations, np.float64)


def blend_edit(poses, trans, frame: int, pose_edit, trans_edit, blend: int) -> tuple[np.ndarray, np.ndarray]:
    """Blend a new pose at `frame` into the motion: R(t) = R(t) exp(w(t) log(R(frame)ᵀ R_edit))
    per joint, trans(t) + w(t) (trans_edit - trans(frame)), w a raised cosine over ±`blend`
    frames (1 at `frame`, 0 from `blend` frames away: those frames are returned unchanged)."""
    poses, trans = np.asarray(poses, np.float64), np.asarray(trans, np.float64)
    d = np.abs(np.arange(len(poses)) - frame)
    w = np.where(d < blend, 0.5 * (1.0 + np.cos(np.pi * d / blend)), 0.0)
    R = host_exp(poses)
    delta = host_log(np.swapaxes(R[frame], -1, -2) @ host_exp(pose_edit))
    inside = w > 0
    out = poses.copy()
    out[inside] = host_log(R[inside] @ host_exp(w[inside, None, None] * delta))
    out[frame] = pose_edit  # exactly the edit, not its round trip
    return out, trans + w[:, None] * (np.asarray(trans_edit, np.float64) - trans[frame])


def reach(
    body,
    poses,
    trans,
    betas,
    frame: int,
    part: str,
    target,
    blend: int = 15,
    tolerance: float | None = 0.01,
    max_steps: int = 500,
    return_info: bool = False,
):
    """Edit a motion so that at `frame` the contact point of `part` touches `target`.

    Method: a one-frame inverse-kinematics solve (`jaxmocap.solve`, Levenberg-Marquardt) over
    the root translation and orientation, spine, hips, knees, ankles and the reaching limb,
    with near-hard terms putting the contact point (`contact_point`) on the target and the
    planted feet's ankle and toe joints where they were, soft ones keeping the centre of mass
    over the feet, the reaching hand's (or foot's) and the hanging arms' world orientations,
    the knees bending forward only, and a closeness term Σ_j ‖W_j log(R_j,origᵀ R_j)‖² +
    ‖t - t_orig‖² (cheap: bending forward at hips and knees; dear: leaning sideways), whose
    result `blend_edit` blends into ±`blend` frames. If the contact vertex changes with the
    pose, the solve is repeated for the new one (at most three times).

    Args:
        body: the body model; poses (T, 24, 3) axis-angle, trans (T, 3), betas (B,): the
            motion (y up, metres).
        frame: the frame of contact; part: a key of `CONTACT_PARTS`; target: (3,) world point.
        blend: half-width (frames) of the blend window; frames `blend` or more away from
            `frame` are returned unchanged.
        tolerance: largest accepted gap (m) between contact point and target; past it a
            `ReachError` (a ValueError) carries the gap and the closest edit. None: never raise.
        max_steps: LM step limit; return_info: also return a `ReachInfo`.
    Returns:
        (poses (T, 24, 3), trans (T, 3)) edited, float64; with `return_info` also a ReachInfo.
    """
    poses, trans = np.asarray(poses, np.float64), np.asarray(trans, np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (24, 3) or trans.shape != (len(poses), 3):
        raise ValueError(f"reach needs poses (T, 24, 3) and trans (T, 3); got {poses.shape} and {trans.shape}.")
    T = len(poses)
    if isinstance(frame, bool) or not isinstance(frame, (int, np.integer)) or not 0 <= frame < T:
        raise ValueError(f"reach frame {frame!r} is outside the motion's {T} frames: use an int in 0 .. {T - 1}.")
    contact_joint(part)
    target = np.asarray(target, np.float64)
    if target.shape != (3,) or not np.all(np.isfinite(target)):
        raise ValueError(f"reach target must be a finite world point (3,), got {target!r}.")
    if isinstance(blend, bool) or not isinstance(blend, (int, np.integer)) or blend < 1:
        raise ValueError(f"reach blend must be an int >= 1 (frames), got {blend!r}.")
    if not (np.all(np.isfinite(poses)) and np.all(np.isfinite(trans))):
        raise ValueError("reach: poses and trans must be finite (no NaN frames).")
    from ..solve import VonMarcardLM, solve

    dtype = body.dtype
    free, weights, planted, keep = _free_joints(part)
    betas = np.asarray(betas, np.float64)[: body.num_betas]
    v_shaped = np.asarray(body.v_template, np.float64) + np.einsum(
        "kvc,k->vc", np.asarray(body.shapedirs, np.float64)[: len(betas)], betas
    )
    rest = np.asarray(body.J_regressor, np.float64) @ v_shaped
    S, W = _com(body, v_shaped)
    _, vertex, J0, G0 = _frame(body, poses[frame], betas, trans[frame], part)
    com = np.einsum("jab,jb->a", G0, S - W[:, None] * rest) + W @ (J0 - trans[frame]) + trans[frame]
    data = {
        "local": axis_angle_to_matrix(jnp.asarray(poses[frame : frame + 1], dtype)),
        "rest": jnp.asarray(rest, dtype), "S": jnp.asarray(S, dtype), "W": jnp.asarray(W, dtype),
        "free": jnp.asarray(free), "planted": jnp.asarray(planted), "keep": jnp.asarray(keep),
        "knees": jnp.asarray(np.flatnonzero(np.isin(free, [_J["left_knee"], _J["right_knee"]]))),
        "sqrt_w": jnp.asarray(np.sqrt(weights)[None], dtype), "target": jnp.asarray(target[None], dtype),
        "trans": jnp.asarray(trans[frame : frame + 1], dtype), "feet": jnp.asarray(J0[None, planted], dtype),
        "kept": jnp.asarray(G0[None, keep], dtype), "com": jnp.asarray(com[None], dtype),
    }  # fmt: skip

    def with_vertex(k):  # the skinning inputs of contact vertex k
        return data | {"v_rest": jnp.asarray(v_shaped[k], dtype), "v_w": jnp.asarray(body.weights[k], dtype),
                       "v_dirs": jnp.asarray(body.posedirs[:, k], dtype)}  # fmt: skip

    params = {"free": jnp.asarray(poses[frame : frame + 1, free], dtype), "trans": data["trans"]}
    steps = 0
    for _ in range(3):
        sol = solve(
            _problem(), params, with_vertex(vertex), max_steps=max_steps, solver=VonMarcardLM(rtol=1e-4, atol=1e-5)
        )
        params, steps = sol.value, steps + int(sol.num_steps)
        pose = poses[frame].copy()
        pose[free] = np.asarray(params["free"][0], np.float64)
        t_new = np.asarray(params["trans"][0], np.float64)
        c, new_vertex, joints, _ = _frame(body, pose, betas, t_new, part)
        if new_vertex == vertex:
            break
        vertex = new_vertex
    gap = float(np.linalg.norm(c - target))
    drift = float(np.max(np.linalg.norm(joints[planted] - J0[planted], axis=-1)))
    info = ReachInfo(gap, drift, vertex, steps)
    poses, trans = blend_edit(poses, trans, frame, pose, t_new, blend)
    if tolerance is not None and gap > tolerance:
        raise ReachError(
            f"reach: the {part} cannot reach {np.round(target, 3).tolist()} at frame {frame} with the feet "
            f"planted: its contact point stays {100 * gap:.1f} cm away (tolerance {100 * tolerance:.1f} cm). "
            "Move the target closer to the body, or pass tolerance=None to accept the closest pose.",
            poses, trans, info,
        )  # fmt: skip
    return (poses, trans, info) if return_info else (poses, trans)
