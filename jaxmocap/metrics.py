"""Pose accuracy metrics of von Marcard §2.5.2: MPJPE (eq. 2.72) and MPJAE (eq. 2.73-2.74).

- MPJPE d_pos = 1/(N_T N_J) Σ_t Σ_j ‖p_j(t) - p̃_j(t)‖, optionally after a per-frame
  Procrustes alignment (a rigid motion, no scale: "a global rigid body motion", §2.5.2),
  which IMU-only methods need since they cannot observe global position and heading.
- MPJAE d_ori = 1/(N_T N_J) Σ_t Σ_j ‖log(R̃_j(t) R_j(t)⁻¹)^∨‖, on *global* joint
  orientations (the orientation of each bone in the world frame).

Beside them, `literature_metrics` gives the learned-poser papers' numbers (DIP, TransPose,
PIP): SIP error, angular error, root-aligned joint and mesh errors in cm, and jitter.

Joint sets (SMPL joint names): §3.4.3 (TotalCapture) evaluates MPJPE on hips, knees,
ankles, neck, head, shoulders, elbows and wrists, and MPJAE on hips, knees, neck,
shoulders and elbows; §3.4.2 (TNT15) MPJPE on 13 virtual markers, the joints of hips,
knees, ankles, shoulders, elbows, wrists and neck. Every function returns per-frame,
per-joint errors; the `summary` helpers average them per sequence.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ._checks import check_finite
from .body.model import SMPL_JOINT_NAMES
from .rotation import geodesic_angle

__all__ = [
    "JOINT_SETS",
    "joint_indices",
    "procrustes_align",
    "position_errors",
    "angle_errors",
    "mpjpe",
    "mpjae",
    "pose_errors",
    "literature_metrics",
    "jitter",
    "summary",
    "object_pose_errors",
    "interaction_metrics",
]

_LR = lambda *names: tuple(f"{s}_{n}" for n in names for s in ("left", "right"))  # noqa: E731

#: Joint sets of the thesis, as SMPL joint names.
JOINT_SETS: dict[str, tuple[str, ...]] = {
    # §3.4.3, TotalCapture MPJPE: hips, knees, ankles, neck, head, shoulders, elbows, wrists.
    "totalcapture_mpjpe": (*_LR("hip", "knee", "ankle"), "neck", "head", *_LR("shoulder", "elbow", "wrist")),
    # §3.4.3, TotalCapture MPJAE: hips, knees, neck, shoulders, elbows.
    "totalcapture_mpjae": (*_LR("hip", "knee"), "neck", *_LR("shoulder", "elbow")),
    # §3.4.2, TNT15 virtual markers: hips, knees, ankles, shoulders, elbows, wrists, neck.
    "tnt15_mpjpe": (*_LR("hip", "knee", "ankle", "shoulder", "elbow", "wrist"), "neck"),
    # §3.4.2, TNT15 MPJAE: the validation IMUs (thighs, upper arms), i.e. the global
    # orientations of these bones (a fixed sensor-to-bone offset cancels in the geodesic).
    "tnt15_mpjae": _LR("hip", "shoulder"),
    # DIP's "SIP error": global orientations of the upper legs and upper arms (same bones).
    "sip_error": _LR("hip", "shoulder"),
    "all": SMPL_JOINT_NAMES,
}


def joint_indices(joints: str | Sequence[str] | Sequence[int] | None) -> np.ndarray:
    """Indices of a named set (`JOINT_SETS`), a list of names or indices; None = all 24."""
    if joints is None:
        return np.arange(len(SMPL_JOINT_NAMES))
    if isinstance(joints, str):
        if joints not in JOINT_SETS:
            raise ValueError(f"Unknown joint set {joints!r}; choose from {sorted(JOINT_SETS)}.")
        joints = JOINT_SETS[joints]
    out = []
    for j in joints:
        if isinstance(j, str):
            if j not in SMPL_JOINT_NAMES:
                raise ValueError(f"No joint {j!r}; SMPL joints are {list(SMPL_JOINT_NAMES)}.")
            out.append(SMPL_JOINT_NAMES.index(j))
        else:
            out.append(int(j))
    return np.asarray(out)


def procrustes_align(pred: Array, true: Array, scale: bool = False) -> Array:
    """pred (..., J, 3) moved by the rigid motion (and scale) that best fits it to true.

    Kabsch/Umeyama per leading index: R, t (s) = argmin Σ_j ‖s R p̃_j + t - p_j‖².
    """
    pred, true = jnp.asarray(pred), jnp.asarray(true)
    mp, mt = pred.mean(-2, keepdims=True), true.mean(-2, keepdims=True)
    a, b = pred - mp, true - mt
    H = jnp.einsum("...ja,...jb->...ab", a, b)  # Σ a bᵀ
    U, S, Vt = jnp.linalg.svd(H)
    d = jnp.sign(jnp.linalg.det(jnp.einsum("...ab,...bc->...ac", U, Vt)))
    D = jnp.ones_like(S).at[..., -1].set(d)
    R = jnp.einsum("...ba,...b,...cb->...ac", Vt, D, U)  # V D Uᵀ
    s = jnp.sum(S * D, -1) / jnp.sum(a * a, axis=(-2, -1)) if scale else jnp.ones(pred.shape[:-2], pred.dtype)
    return s[..., None, None] * jnp.einsum("...ab,...jb->...ja", R, a) + mt


def _same_shape(name_a, a, name_b, b, expected: str, trailing: int, idx) -> None:
    """Prediction and truth must have one shape (e.g. as many frames), ending in 3 or 3×3."""
    if a.shape != b.shape:
        raise ValueError(
            f"{name_a} has shape {a.shape} but {name_b} has {b.shape}; both must be {expected} "
            "with the same frames (trim or resample one of them)."
        )
    if a.ndim < trailing + 1 or a.shape[-trailing + 1 :] != (3,) * (trailing - 1) or a.shape[-1] != 3:
        raise ValueError(f"{name_a} has shape {a.shape}; expected {expected}.")
    if len(idx) and a.shape[-trailing] <= int(np.max(idx)):
        raise ValueError(
            f"{name_a} has shape {a.shape}: {a.shape[-trailing]} joints, but joint {int(np.max(idx))} is evaluated."
        )


def position_errors(pred_joints, true_joints, joints="totalcapture_mpjpe", align: str = "procrustes") -> Array:
    """‖p_j(t) - p̃_j(t)‖ per frame and joint of the set, metres: (..., T, J) -> (..., T, N_J).

    align: "procrustes" (per-frame rigid alignment on the evaluated joints, §2.5.2),
    "procrustes_scaled" (rigid plus one scale: body size drops out), "root" (pelvis
    positions subtracted) or "none".

    Non-finite input is not an error here (predictions of a failed fit are NaN by design):
    a NaN or inf joint gives NaN errors on its frame only (alignment is per frame), and
    `mpjpe(..., mask=)` drops such frames exactly.
    """
    idx = joint_indices(joints)
    pred, true = jnp.asarray(pred_joints), jnp.asarray(true_joints)
    _same_shape("pred_joints", pred, "true_joints", true, "(..., T, J, 3)", 2, idx)
    if align not in ("procrustes", "procrustes_scaled", "root", "none"):
        raise ValueError(f"align must be 'procrustes', 'procrustes_scaled', 'root' or 'none', got {align!r}.")
    return _position_errors(pred, true, tuple(int(i) for i in idx), align)


@functools.partial(jax.jit, static_argnames=("idx", "align"))
def _position_errors(pred, true, idx, align):
    """`position_errors` after its checks: one program, not one per eager operation."""
    if align == "root":
        pred, true = pred - pred[..., :1, :], true - true[..., :1, :]
    idx = np.asarray(idx, int)
    pred, true = pred[..., idx, :], true[..., idx, :]
    if align in ("procrustes", "procrustes_scaled"):
        pred = procrustes_align(pred, true, scale=align == "procrustes_scaled")
    return jnp.linalg.norm(pred - true, axis=-1)


def angle_errors(pred_rotations, true_rotations, joints="totalcapture_mpjae") -> Array:
    """‖log(R̃_j R_jᵀ)^∨‖ per frame and joint (eq. 2.74), degrees: (..., T, J, 3, 3) -> (..., T, N_J).

    A non-finite rotation gives NaN on its frame and joint only; `mpjae(..., mask=)`
    drops such frames exactly.
    """
    idx = joint_indices(joints)
    pred, true = jnp.asarray(pred_rotations), jnp.asarray(true_rotations)
    _same_shape("pred_rotations", pred, "true_rotations", true, "(..., T, J, 3, 3)", 3, idx)
    return _angle_errors(pred, true, tuple(int(i) for i in idx))


@functools.partial(jax.jit, static_argnames=("idx",))
def _angle_errors(pred, true, idx):
    """`angle_errors` after its checks: one program, not one per eager operation."""
    idx = np.asarray(idx, int)
    return jnp.degrees(geodesic_angle(pred[..., idx, :, :], true[..., idx, :, :]))


def mpjpe(pred_joints, true_joints, joints="totalcapture_mpjpe", align="procrustes", mask=None) -> Array:
    """MPJPE (eq. 2.72) in millimetres over frames (mask (T,) selects frames) and joints.

    NaN when an unmasked frame holds a non-finite joint (see `position_errors`).
    """
    e = position_errors(pred_joints, true_joints, joints, align) * 1000.0
    return _mean(e, mask)


def mpjae(pred_rotations, true_rotations, joints="totalcapture_mpjae", mask=None) -> Array:
    """MPJAE (eq. 2.73) in degrees over frames and joints."""
    return _mean(angle_errors(pred_rotations, true_rotations, joints), mask)


def _mean(e, mask):
    if mask is None:
        return e.mean(axis=(-2, -1))
    if jnp.shape(mask) != e.shape[:-1]:
        raise ValueError(f"mask has shape {jnp.shape(mask)}; expected the frames' shape {e.shape[:-1]}.")
    m = jnp.asarray(mask, bool)[..., None]
    # where, not e * m: a masked-out NaN frame must drop out (NaN * 0 is NaN).
    total = jnp.where(m, e, 0.0).sum(axis=(-2, -1))
    return total / (m.sum(axis=(-2, -1)) * e.shape[-1])


def _check_pair(pred_poses, true_poses, betas, pred_trans, true_trans):
    """Shapes and finiteness of a predicted and a true (T, 24, 3) trajectory, named."""
    if jnp.shape(pred_poses) != jnp.shape(true_poses):
        raise ValueError(
            f"pred_poses has shape {jnp.shape(pred_poses)} but true_poses has {jnp.shape(true_poses)}; "
            "both must be (T, 24, 3) with the same T (trim or resample one of them)."
        )
    for name, x in (("pred_poses", pred_poses), ("true_poses", true_poses), ("betas", betas),
                    ("pred_trans", pred_trans), ("true_trans", true_trans)):  # fmt: skip
        if x is not None:
            check_finite(name, x)  # named here, before the jit: inside it forward's checks see tracers


def _posed_pair(body, pred_poses, true_poses, betas, pred_trans, true_trans):
    """Forward kinematics of a predicted and a true (T, 24, 3) trajectory on one body."""
    from .body.kinematics import forward

    return forward(body, pred_poses, betas, pred_trans), forward(body, true_poses, betas, true_trans)


def _static_joints(joints):
    """A joint set as a hashable jit argument: a set's name, or a tuple of indices."""
    return joints if isinstance(joints, str) or joints is None else tuple(int(i) for i in joint_indices(joints))


def pose_errors(
    body,
    pred_poses,
    true_poses,
    betas=None,
    pred_trans=None,
    true_trans=None,
    position_joints="totalcapture_mpjpe",
    angle_joints="totalcapture_mpjae",
) -> dict:
    """Per-frame errors of a pose trajectory against the truth on `body` (forward kinematics).

    Returns a dict of NumPy arrays: "mpjpe" (T, N_J) mm after Procrustes, "mpjpe_root"
    (T, N_J) mm root-aligned without rotation, "mpjae" (T, N_J') degrees.
    """
    _check_pair(pred_poses, true_poses, betas, pred_trans, true_trans)
    out = _pose_errors(body, pred_poses, true_poses, betas, pred_trans, true_trans,
                       _static_joints(position_joints), _static_joints(angle_joints))  # fmt: skip
    return {k: np.asarray(v) for k, v in out.items()}


# One compiled program per call shape: eagerly, each operation would compile on its own.
@functools.partial(jax.jit, static_argnames=("position_joints", "angle_joints"))
def _pose_errors(body, pred_poses, true_poses, betas, pred_trans, true_trans, position_joints, angle_joints):
    pred, true = _posed_pair(body, pred_poses, true_poses, betas, pred_trans, true_trans)
    return {
        "mpjpe": position_errors(pred.joints, true.joints, position_joints, "procrustes") * 1000.0,
        "mpjpe_root": position_errors(pred.joints, true.joints, position_joints, "root") * 1000.0,
        "mpjae": angle_errors(pred.joint_rotations, true.joint_rotations, angle_joints),
    }


def summary(errors: dict) -> dict:
    """Per-sequence mean ± std (over frames and joints) of each per-frame error array."""
    return {k: {"mean": float(np.mean(v)), "std": float(np.std(v))} for k, v in errors.items()}


def jitter(positions, fps: float, mask=None) -> Array:
    """Mean jerk magnitude ‖d³p/dt³‖ of (..., T, N, 3) positions in m, km/s³ (third differences).

    As the learned-poser papers report smoothness (TransPose, PIP): the mean over frames
    t = 0..T-4 and points of ‖p(t+3) - 3p(t+2) + 3p(t+1) - p(t)‖ · fps³ / 1000. With a
    frame mask (..., T) (padded batches), only differences of four real frames count.
    """
    p = jnp.asarray(positions)
    if p.ndim < 3 or p.shape[-1] != 3 or p.shape[-3] < 4:
        raise ValueError(f"positions has shape {p.shape}; expected (..., T >= 4, N, 3).")
    d3 = p[..., 3:, :, :] - 3 * p[..., 2:-1, :, :] + 3 * p[..., 1:-2, :, :] - p[..., :-3, :, :]
    per_frame = jnp.linalg.norm(d3, axis=-1).mean(axis=-1)
    if mask is not None:
        m = jnp.asarray(mask, bool)
        mask = m[..., 3:] & m[..., 2:-1] & m[..., 1:-2] & m[..., :-3]
    return _frame_mean(per_frame, mask) * float(fps) ** 3 / 1000.0


def _frame_mean(per_frame, mask):
    """Mean over the last (frame) axis, over the frames of `mask` only where given."""
    if mask is None:
        return per_frame.mean(axis=-1)
    if jnp.shape(mask) != per_frame.shape:
        raise ValueError(f"mask has shape {jnp.shape(mask)}; expected the frames' shape {per_frame.shape}.")
    m = jnp.asarray(mask, per_frame.dtype)
    return (per_frame * m).sum(axis=-1) / m.sum(axis=-1)


def literature_metrics(
    body, pred_poses, true_poses, fps: float, betas=None, pred_trans=None, true_trans=None, mask=None
) -> dict:
    """The learned-poser papers' metrics of a (T, 24, 3) pose trajectory against the truth.

    Returns floats: "sip_error_deg" (global rotation error of upper arms and upper legs),
    "angular_error_deg" (global rotation error over all 24 joints), "position_error_cm"
    (joints, root-aligned: pelvis positions subtracted), "mesh_error_cm" (vertices,
    root-aligned), "jitter_root_km_s3" (of root-relative joints) and "jitter_global_km_s3"
    (of world joints; needs the translations to mean anything). Both sides use `betas`,
    so the numbers measure pose, not body size. `mask` (T,) bool keeps the real frames of
    a padded trajectory (padding to a few lengths spares a compilation per length).
    """
    _check_pair(pred_poses, true_poses, betas, pred_trans, true_trans)
    return {k: float(v) for k, v in _literature_metrics(body, pred_poses, true_poses, float(fps), betas, pred_trans,
                                                         true_trans, mask).items()}  # fmt: skip


@functools.partial(jax.jit, static_argnames=("fps",))
def _literature_metrics(body, pred_poses, true_poses, fps, betas, pred_trans, true_trans, mask):
    pred, true = _posed_pair(body, pred_poses, true_poses, betas, pred_trans, true_trans)
    root = lambda o, x: x - o.joints[..., :1, :]  # noqa: E731
    rel = root(pred, pred.joints)
    mean = lambda e: _frame_mean(e.mean(axis=-1), mask)  # noqa: E731  (..., T, N) -> over N, then real frames
    return {
        "sip_error_deg": mean(angle_errors(pred.joint_rotations, true.joint_rotations, "sip_error")),
        "angular_error_deg": mean(angle_errors(pred.joint_rotations, true.joint_rotations, "all")),
        "position_error_cm": mean(jnp.linalg.norm(rel - root(true, true.joints), axis=-1)) * 100,
        "mesh_error_cm": mean(jnp.linalg.norm(root(pred, pred.vertices) - root(true, true.vertices), axis=-1)) * 100,
        "jitter_root_km_s3": jitter(rel, fps, mask),
        "jitter_global_km_s3": jitter(pred.joints, fps, mask),
    }


# --- a person and an object (InterCap, Huang §5.4) ---------------------------------------------


def object_pose_errors(pred_R, pred_t, true_R, true_t, vertices, mask=None, symmetry=None) -> dict:
    """Rigid object pose errors per sequence (mm, °): `add_s_mm`, the mean distance of each
    predicted vertex to the closest true one (ADD-S: a symmetric object's equivalent poses
    count as right), `centre_mm` (the vertex centroid), `rotation_deg` (geodesic, the least
    over the object's `symmetry`, a `objects.Symmetry` such as `RigidObject.symmetry`: a
    box flipped onto itself scores 0) and `rotation_raw_deg` (geodesic, no symmetry).
    Frames where `mask` is False are left out."""
    from scipy.spatial import cKDTree

    from .objects import rotation_error_deg

    v = np.asarray(vertices, np.float64)
    pred = np.einsum("tab,nb->tna", np.asarray(pred_R, np.float64), v) + np.asarray(pred_t, np.float64)[:, None]
    true = np.einsum("tab,nb->tna", np.asarray(true_R, np.float64), v) + np.asarray(true_t, np.float64)[:, None]
    keep = np.ones(len(pred), bool) if mask is None else np.asarray(mask, bool)
    add_s = np.array([cKDTree(true[t]).query(pred[t])[0].mean() for t in np.flatnonzero(keep)])
    centre = np.linalg.norm(pred.mean(1) - true.mean(1), axis=-1)[keep]
    raw = rotation_error_deg(pred_R, true_R)[keep]
    modulo = rotation_error_deg(pred_R, true_R, symmetry)[keep]
    return {"add_s_mm": 1e3 * float(add_s.mean()), "centre_mm": 1e3 * float(centre.mean()),
            "rotation_deg": float(modulo.mean()), "rotation_raw_deg": float(raw.mean())}  # fmt: skip


def interaction_metrics(
    body_vertices,
    joints,
    true_joints,
    object_R,
    object_t,
    sdf,
    contact,
    body_points=None,
    body_valid=None,
    object_points=None,
    object_valid=None,
    contact_vertices=None,
    object_vertices=None,
    floor: float = 0.0,
    thresholds=(0.005, 0.007, 0.020),
) -> dict:
    """The InterCap numbers of one fitted sequence (Huang §5.4; lengths in mm).

    Args:
        body_vertices (T, N, 3), joints (T, J, 3): the fitted body; true_joints (T, J, 3).
        object_R (T, 3, 3), object_t (T, 3): the fitted object; sdf: its `ObjectSDF`.
        contact (T,) bool: the true contact frames (penetration and contact statistics).
        body_points/object_points (T, V, M, 3) with *_valid (T, V, M): observed point
            clouds (mean vertex-to-point-cloud distance; the object's by its SDF).
        contact_vertices: body vertices that should touch the object in contact frames.
        object_vertices: (No, 3) the object mesh's vertices (object ground depth).
    Returns:
        mpjpe_mm (no alignment: calibrated views see absolute positions);
        penetration_mean_mm and penetration_le_{5,7,20}mm: in contact frames, the deepest
        body vertex inside the object, its mean and the fraction of frames at most that deep;
        contact_gap_mm: in contact frames, mean distance of the closest contact vertex to
        the object surface (0 when touching or inside);
        body_ground_mm, object_ground_mm: mean depth of the lowest point below the floor;
        body_to_points_mm, object_to_points_mm: mean distance of observed points to the fit.
    """
    from scipy.spatial import cKDTree

    verts = np.asarray(body_vertices, np.float64)
    R, t = np.asarray(object_R, np.float64), np.asarray(object_t, np.float64)
    contact = np.asarray(contact, bool)
    local = lambda x: np.einsum("tba,tnb->tna", R, x - t[:, None])  # noqa: E731
    sdf_of = lambda x: np.asarray(sdf(jnp.asarray(x, jnp.float32)), np.float64)  # noqa: E731
    d_body = sdf_of(local(verts))  # (T, N)
    depth = np.maximum(-d_body.min(1), 0.0)[contact]
    out = {"mpjpe_mm": 1e3 * float(np.linalg.norm(np.asarray(joints) - np.asarray(true_joints), axis=-1).mean())}
    out["penetration_mean_mm"] = 1e3 * float(depth.mean()) if depth.size else 0.0
    for th in thresholds:
        out[f"penetration_le_{1e3 * th:g}mm"] = float((depth <= th).mean()) if depth.size else 1.0
    if contact_vertices is not None and contact.any():
        gap = np.maximum(d_body[:, np.asarray(contact_vertices)].min(1), 0.0)[contact]
        out["contact_gap_mm"] = 1e3 * float(gap.mean())
    out["body_ground_mm"] = 1e3 * float(np.maximum(floor - verts[..., 1].min(1), 0.0).mean())
    if object_vertices is not None:
        low = (np.einsum("tab,nb->tna", R, np.asarray(object_vertices, np.float64)) + t[:, None])[..., 1].min(1)
        out["object_ground_mm"] = 1e3 * float(np.maximum(floor - low, 0.0).mean())
    if object_points is not None:
        pts, ok = np.asarray(object_points, np.float64), np.asarray(object_valid, bool)
        T, V, M, _ = pts.shape
        d = np.abs(sdf_of(local(pts.reshape(T, V * M, 3)))).reshape(T, V, M)
        out["object_to_points_mm"] = 1e3 * float(d[ok].mean()) if ok.any() else float("nan")
    if body_points is not None:
        pts, ok = np.asarray(body_points, np.float64), np.asarray(body_valid, bool)
        d = [cKDTree(verts[i]).query(pts[i][ok[i]])[0] for i in range(len(verts)) if ok[i].any()]
        out["body_to_points_mm"] = 1e3 * float(np.concatenate(d).mean()) if d else float("nan")
    return out
