"""AMASS-style ``.npz`` motion files, converted between AMASS's z-up and jaxmocap's y-up.

File keys (as AMASS ships them):
    poses: (T, 156) SMPL-H, (T, 72) SMPL, (T, 165) SMPL-X or (T, 66) body-only
        axis-angle, joint-major (joint k is columns 3k..3k+2). Alternatively AMASS's
        split form root_orient (T, 3) + pose_body (T, 63).
    trans: (T, 3) metres.     betas: (B,) (AMASS: 16 for SMPL-H, 10 for SMPL).
    gender: str (may be stored as bytes or a 0-d array).
    mocap_framerate (or mocap_frame_rate): frames per second.

Layouts. Joints 0..21 (pelvis to wrists) are the same in SMPL, SMPL-H and SMPL-X. SMPL's
joints 22/23 (left_hand/right_hand: the whole hand as one rigid part) have no
counterpart in SMPL-H/SMPL-X, whose fingers are separate joints; loading those sets 22/23
to zero rotation (flat hand) and drops the finger, jaw and eye rotations.

World frame. AMASS is z up; jaxmocap is y up (SMPL's template frame). Loading rotates
the world by R = rot_x(−90°): (x, y, z) ↦ (x, z, −y). SMPL's root rotation acts about
the pelvis joint j0 = J(β)_0, not about the origin: a posed point is
R_root (x − j0) + j0 + trans + ..., so rotating the world by R needs

    R_root' = R · R_root,     trans' = R (trans + j0) − j0,

and saving does the inverse, trans = Rᵀ (trans' + j0) − j0, so load ∘ save is the
identity. j0 depends on the body and its shape: pass `body=` for an exact conversion
(j0 = shaped_joints(body, betas)[0]); by default the bundled `jaxmocap.default_body()`
is used, or, if it is not installed, SMPL's neutral mean-shape pelvis
`SMPL_NEUTRAL_PELVIS`. (AMASS trans values are meant for the SMPL-H model of the
file's gender; with another body the pelvis is off by the difference in j0.)
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..rotation import host_rotate
from .sequence import Motion
from .skeleton import MotionFileError, check_file, read_npz

__all__ = ["SMPL_NEUTRAL_PELVIS", "Z_UP_TO_Y_UP", "load_amass", "pelvis_rest", "save_amass"]

#: World rotation from AMASS (z up) to jaxmocap (y up): rot_x(−90°).
Z_UP_TO_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
#: SMPL neutral mean-shape rest pelvis joint (metres), the fallback j0.
SMPL_NEUTRAL_PELVIS = np.array([-0.00179506, -0.22333345, 0.02821913])

_LAYOUTS = {72: "smpl", 66: "body", 156: "smplh", 165: "smplx"}


def pelvis_rest(body=None, betas=None) -> np.ndarray:
    """j0 = J(β)_0 for `body` (default body, else SMPL_NEUTRAL_PELVIS), float64 (3,)."""
    if body is None:
        try:
            from ..body.io import default_body

            body = default_body()
        except (OSError, ValueError):  # not installed yet: SMPL's value
            return SMPL_NEUTRAL_PELVIS.copy()
    from .retarget import smpl_rest

    return smpl_rest(body, betas)[0][0]


def rotate_world(poses: np.ndarray, trans: np.ndarray, R: np.ndarray, j0: np.ndarray):
    """Rotate the world by R: root ↦ R·root, trans ↦ R(trans + j0) − j0."""
    poses = poses.copy()
    poses[:, 0] = host_rotate(R, poses[:, 0])
    return poses, (trans + j0) @ R.T - j0


def _gender(value) -> str:
    g = np.asarray(value)
    g = g.item() if g.size == 1 else g
    if isinstance(g, bytes):
        g = g.decode()
    g = str(g).strip().lower()
    return g if g in ("male", "female", "neutral") else "neutral"


def load_amass(path, body=None, _arrays: dict | None = None) -> Motion:
    """Read an AMASS-style npz (z up) as a y-up `Motion` (see the module docstring).

    Args:
        path: the .npz file.
        body: body whose rest pelvis j0 pivots the z-up → y-up conversion (default:
            the bundled default body, else SMPL's neutral pelvis).
    Raises:
        FileNotFoundError if missing; MotionFileError (a ValueError) naming the file for
        unreadable files, missing keys, wrong shapes and NaN/inf values.
    """
    path = check_file(path)
    d = read_npz(path) if _arrays is None else _arrays  # `load_motion` has read it already
    try:
        return _from_arrays(path, d, body)
    except (TypeError, IndexError, ValueError) as e:
        if isinstance(e, MotionFileError):
            raise
        raise MotionFileError(f"{path}: {type(e).__name__}: {e}") from e


def _from_arrays(path: Path, d: dict, body) -> Motion:
    """The body of `load_amass`: checks and the z-up -> y-up conversion of the arrays."""
    if "poses" in d:
        poses = np.asarray(d["poses"], np.float64)
    elif "root_orient" in d and "pose_body" in d:
        poses = np.concatenate([np.asarray(d["root_orient"]), np.asarray(d["pose_body"])], -1).astype(np.float64)
    else:
        raise MotionFileError(
            f"{path}: no 'poses' (or 'root_orient' + 'pose_body') key; keys are {sorted(d)}. "
            "AMASS motion files need poses, trans, betas, gender and mocap_framerate."
        )
    missing = [k for k in ("trans",) if k not in d]
    rate_key = next((k for k in ("mocap_framerate", "mocap_frame_rate") if k in d), None)
    if rate_key is None:
        missing.append("mocap_framerate")
    if missing:
        raise MotionFileError(f"{path}: missing key(s) {missing}; keys are {sorted(d)}.")
    if poses.ndim != 2 or poses.shape[1] not in _LAYOUTS:
        raise MotionFileError(
            f"{path}: poses has shape {poses.shape}; expected (T, 72) SMPL, (T, 156) SMPL-H, "
            "(T, 165) SMPL-X or (T, 66) body-only axis-angle."
        )
    T = poses.shape[0]
    trans = np.asarray(d["trans"], np.float64)
    if trans.shape != (T, 3):
        raise MotionFileError(f"{path}: trans has shape {trans.shape}; expected ({T}, 3) to match poses.")
    betas = np.asarray(d.get("betas", np.zeros(0)), np.float64).reshape(-1)
    rate = np.asarray(d[rate_key]).reshape(-1)
    if rate.size != 1:
        raise MotionFileError(f"{path}: {rate_key} holds {rate.size} values; expected one frame rate.")
    fps = float(rate[0])
    for key, value in (("poses", poses), ("trans", trans), ("betas", betas)):
        if not np.isfinite(value).all():
            raise MotionFileError(f"{path}: {key} contains NaN or inf.")
    if T == 0 or not (np.isfinite(fps) and fps > 0):
        raise MotionFileError(f"{path}: needs at least one frame and a positive frame rate (got {T}, {fps}).")

    smpl = np.zeros((T, 24, 3))
    if _LAYOUTS[poses.shape[1]] == "smpl":
        smpl[:] = poses.reshape(T, 24, 3)
    else:  # SMPL-H / SMPL-X / body only: joints 0..21; SMPL hands 22/23 stay zero.
        smpl[:, :22] = poses[:, :66].reshape(T, 22, 3)
    j0 = pelvis_rest(body, betas)
    smpl, trans = rotate_world(smpl, trans, Z_UP_TO_Y_UP, j0)
    return Motion(
        poses=smpl,
        trans=trans,
        fps=fps,
        betas=betas,
        gender=_gender(d.get("gender", "neutral")),
        name=str(path),
    )


def save_amass(motion: Motion, path, body=None, layout: str = "auto") -> Path:
    """Write `motion` (y up) as an AMASS-style npz (z up); the inverse of `load_amass`.

    Args:
        motion: the motion.
        path: output .npz path.
        body: the body whose pelvis j0 pivots the conversion (use the same as for loading).
        layout: "smplh" (156 columns, AMASS's usual; SMPL hand joints 22/23 must be
            zero, they cannot be stored), "smpl" (72 columns, all 24 joints) or "auto"
            (SMPL-H unless joints 22/23 are rotated).
    """
    from .._checks import output_npz

    path = output_npz(path, "save_amass")
    hands = np.abs(motion.poses[:, 22:]).max() if motion.num_frames else 0.0
    if layout == "auto":
        layout = "smpl" if hands > 0 else "smplh"
    if layout not in ("smpl", "smplh"):
        raise ValueError(f"layout must be 'auto', 'smpl' or 'smplh', got {layout!r}.")
    if layout == "smplh" and hands > 0:
        raise ValueError("SMPL-H files cannot hold SMPL's hand joints 22/23; use layout='smpl'.")
    j0 = pelvis_rest(body, motion.betas)
    poses, trans = rotate_world(motion.poses, motion.trans, Z_UP_TO_Y_UP.T, j0)
    T = motion.num_frames
    flat = (
        poses.reshape(T, 72)
        if layout == "smpl"
        else np.concatenate([poses[:, :22].reshape(T, 66), np.zeros((T, 90))], 1)
    )
    # AMASS tools expect 16 (SMPL-H) or 10 (SMPL) betas: a motion without shape (CMU
    # clips carry none) is the mean shape, written as zeros rather than an empty array.
    betas = motion.betas if motion.betas.size else np.zeros(16 if layout == "smplh" else 10)
    np.savez(
        path,
        poses=flat,
        trans=trans,
        betas=betas,
        gender=np.array(motion.gender),
        mocap_framerate=np.array(motion.fps),
    )
    return path
