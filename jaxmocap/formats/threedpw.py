"""3DPW sequence files (von Marcard et al. 2018, "3D Poses in the Wild"), read into jaxmocap's layout.

Layout, from the dataset's readme.txt and the public loaders that read the real files
(SPIN / VIBE `pw3d.py`, PIP's `preprocess_3dpw`): a Python-2 pickle (read as latin1) of a
dict; P = 1 or 2 people, T image frames at 30 Hz, "P ×" a list with one entry per person.

    sequence         str
    genders          P × 'm' | 'f'                (the readme says "gender")
    betas            P × (10,) or (300,) SMPL shape coefficients (the first 10 are kept)
    poses, trans     P × (T, 72), (T, 3): SMPL axis-angle and root translation, world frame
    poses2d          P × (T, 3, 18): OpenPose COCO-18 x, y, confidence, one ROW per
                     channel (the readme says "poses2D"); zeros where not detected
    cam_poses        (T, 4, 4) world-to-camera [R t; 0 1]
    cam_intrinsics   (3, 3) K
    campose_valid    P × (T,) bool: the camera pose is aligned with that person's image
    jointPositions   P × (T, 72): SMPL's 24 joints, world frame            (optional here)
    poses_60Hz, trans_60Hz   P × the IMUs' 60 Hz poses and translations   (optional here)
    img_frame_ids    (T,) index of each image frame in the 60 Hz arrays   (optional here)

World frame: 3DPW's is y up (VIP's tracking frame, whose heading drift is a rotation about
y, von Marcard eq. 4.8), as jaxmocap's is, so by default nothing is rotated. For a file
re-exported with another up axis, `world_rotation` R (e.g. `motion.amass.Z_UP_TO_Y_UP`)
maps it exactly as AMASS loading does: root ← R·root, trans ← R(trans + j0) − j0 with j0
the body's rest pelvis (SMPL rotates the root about j0, not the origin), joints ← R·joints,
and world-to-camera R_c ← R_c Rᵀ with t unchanged, so projections are unchanged.

Image size: not in the pickle. 3DPW's frames are 1080 × 1920 (portrait) or 1920 × 1080
(landscape); `image_size=None` picks the one whose centre is nearest K's principal point.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .._files import load_array_pickle
from ..motion.sequence import Motion
from ..motion.skeleton import MotionFileError, check_file

__all__ = ["IMAGE_SIZES", "ThreeDPWSequence", "load_threedpw", "valid_span"]

#: (width, height) of 3DPW's video frames: portrait and landscape phone video.
IMAGE_SIZES = ((1080, 1920), (1920, 1080))
FPS = 30.0

# Canonical key -> the spellings found in files and in the readme.
_REQUIRED = {
    "poses": ("poses",), "trans": ("trans",), "betas": ("betas",), "genders": ("genders", "gender"),
    "poses2d": ("poses2d", "poses2D"), "campose_valid": ("campose_valid",), "cam_poses": ("cam_poses",),
    "cam_intrinsics": ("cam_intrinsics",),
}  # fmt: skip
_PER_PERSON = ("poses", "trans", "betas", "genders", "poses2d", "campose_valid")


@dataclasses.dataclass(frozen=True)
class ThreeDPWSequence:
    """One 3DPW sequence in jaxmocap's conventions (world y up, metres, OpenCV camera).

    poses (P, T, 24, 3) axis-angle; trans (P, T, 3); betas (P, 10); genders P × "male" |
    "female"; keypoints (P, T, 18, 3) COCO-18 (u, v, confidence) pixels; valid (P, T) bool
    (campose_valid); cam_R (T, 3, 3), cam_t (T, 3) world-to-camera (p_c = R p + t); K (3, 3);
    width, height in pixels; joints (P, T, 24, 3) or None; poses_60hz / trans_60hz: per
    person (T60, 24, 3) / (T60, 3) or None; img_frame_ids (T,) or None.
    """

    name: str
    poses: np.ndarray
    trans: np.ndarray
    betas: np.ndarray
    genders: tuple[str, ...]
    keypoints: np.ndarray
    valid: np.ndarray
    cam_R: np.ndarray
    cam_t: np.ndarray
    K: np.ndarray
    width: int
    height: int
    joints: np.ndarray | None = None
    poses_60hz: tuple[np.ndarray, ...] | None = None
    trans_60hz: tuple[np.ndarray, ...] | None = None
    img_frame_ids: np.ndarray | None = None
    fps: float = FPS

    @property
    def num_people(self) -> int:
        return self.poses.shape[0]

    @property
    def num_frames(self) -> int:
        return self.poses.shape[1]

    @property
    def camera_to_world(self) -> np.ndarray:
        """(T, 4, 4) camera-to-world [Rᵀ  −Rᵀt; 0 1]."""
        out = np.zeros((self.num_frames, 4, 4))
        out[:, :3, :3] = np.swapaxes(self.cam_R, -1, -2)
        out[:, :3, 3] = self.camera_centres
        out[:, 3, 3] = 1.0
        return out

    @property
    def camera_centres(self) -> np.ndarray:
        """(T, 3) camera centres −Rᵀt in the world."""
        return -np.einsum("tba,tb->ta", self.cam_R, self.cam_t)

    def motion(self, person: int = 0) -> Motion:
        """Person `person`'s 30 Hz motion as a `Motion` (SMPL betas, the file's gender)."""
        return Motion(self.poses[person], self.trans[person], self.fps, self.betas[person], self.genders[person],
                      f"{self.name}[{person}]")  # fmt: skip


def valid_span(valid) -> slice:
    """The longest run of True in `valid` (T,) as a slice (the first one on ties).

    Raises ValueError when there is none."""
    v = np.concatenate([[False], np.asarray(valid, bool), [False]])
    edges = np.flatnonzero(np.diff(v.astype(np.int8)))
    if len(edges) == 0:
        raise ValueError("no valid frame: campose_valid is False everywhere for this person.")
    starts, stops = edges[::2], edges[1::2]
    i = int(np.argmax(stops - starts))
    return slice(int(starts[i]), int(stops[i]))


def _text(value) -> str:
    value = value.item() if isinstance(value, np.ndarray) and value.size == 1 else value
    return value.decode("latin1") if isinstance(value, bytes) else str(value)


def _gender(value) -> str:
    g = _text(value).strip().lower()
    return {"m": "male", "f": "female"}.get(g, g if g in ("male", "female") else "neutral")


def _image_size(K: np.ndarray) -> tuple[int, int]:
    centre = K[:2, 2]
    return min(IMAGE_SIZES, key=lambda wh: float(np.linalg.norm(np.asarray(wh) / 2.0 - centre)))


def _array(path, name, value, shape, note="") -> np.ndarray:
    """`value` as float64 with `shape` (None = any length), or MotionFileError naming it."""
    try:
        a = np.asarray(value, np.float64)
    except (TypeError, ValueError) as e:
        raise MotionFileError(f"{path}: {name} is not numeric ({e}).") from e
    if a.ndim != len(shape) or any(s is not None and s != n for s, n in zip(shape, a.shape)):
        want = ", ".join("T" if s is None else str(s) for s in shape)
        raise MotionFileError(f"{path}: {name} has shape {a.shape}; expected ({want}){note}.")
    return a


def _tuple(arrays):
    return None if arrays is None else tuple(arrays)


def load_threedpw(path, image_size: tuple[int, int] | None = None, world_rotation=None, body=None) -> ThreeDPWSequence:
    """Read a 3DPW sequence file (`sequenceFiles/*/name.pkl`) into a `ThreeDPWSequence`.

    Args:
        path: the pickle.
        image_size: (width, height) in pixels; default: 1080 × 1920 or 1920 × 1080, whichever
            centre is nearest the principal point.
        world_rotation: (3, 3) rotation from the file's world to jaxmocap's y-up world;
            default the identity (3DPW is y up, module docstring).
        body: the body whose rest pelvis pivots a non-identity `world_rotation` (default
            the bundled default body; use the SMPL model of the file's gender to be exact).
    Raises:
        FileNotFoundError; MotionFileError (a ValueError) naming the file and the problem:
        not a pickle, missing keys (named), person counts or frame counts that disagree,
        wrongly shaped arrays. Only numpy arrays and plain containers are unpickled.
    """
    path = check_file(path)
    try:
        data = load_array_pickle(path)
    except Exception as e:  # a non-pickle or a damaged one can raise almost anything
        raise MotionFileError(f"{path}: not a 3DPW sequence pickle ({type(e).__name__}: {e}).") from e
    if not isinstance(data, dict):
        raise MotionFileError(f"{path}: the pickle holds a {type(data).__name__}, not a 3DPW sequence dict.")
    data = {_text(k): v for k, v in data.items()}
    found = {key: next((s for s in spellings if s in data), None) for key, spellings in _REQUIRED.items()}
    missing = [key for key, spelling in found.items() if spelling is None]
    if missing:
        raise MotionFileError(f"{path}: missing key(s) {missing}; a 3DPW sequence file has "
                              f"{sorted(_REQUIRED)}; this one has {sorted(data)}.")  # fmt: skip
    d = {key: data[spelling] for key, spelling in found.items()}
    counts = {key: len(d[key]) if isinstance(d[key], (list, tuple)) else None for key in _PER_PERSON}
    if "jointPositions" in data:
        d["joints"] = data["jointPositions"]
        counts["jointPositions"] = len(d["joints"]) if isinstance(d["joints"], (list, tuple)) else None
    if None in counts.values() or len(set(counts.values())) != 1 or not counts["poses"]:
        raise MotionFileError(f"{path}: inconsistent person counts {counts}; every per-person key must be "
                              "a list with one entry per person (1 or 2).")  # fmt: skip
    cam = _array(path, "cam_poses", d["cam_poses"], (None, 4, 4))
    T = len(cam)
    K = _array(path, "cam_intrinsics", d["cam_intrinsics"], (3, 3))

    def per_person(key, shape):
        note = f" (T = {T} frames, as cam_poses)"
        return np.stack([_array(path, f"{key}[{p}]", v, shape, note) for p, v in enumerate(d[key])])

    poses = per_person("poses", (T, 72)).reshape(-1, T, 24, 3)
    trans = per_person("trans", (T, 3))
    kp = np.swapaxes(per_person("poses2d", (T, 3, 18)), -1, -2)  # rows x, y, conf -> (T, 18, 3)
    valid = per_person("campose_valid", (T,)).astype(bool)
    joints = per_person("joints", (T, 72)).reshape(-1, T, 24, 3) if "joints" in d else None
    betas = np.zeros((len(poses), 10))
    for p, b in enumerate(d["betas"]):
        b = np.asarray(b, np.float64).reshape(-1)[:10]
        betas[p, : len(b)] = b
    for name, a in (("poses", poses), ("trans", trans), ("betas", betas), ("cam_poses", cam), ("cam_intrinsics", K)):
        if not np.isfinite(a).all():
            raise MotionFileError(f"{path}: {name} contains NaN or inf.")
    kp[..., 2] = np.where(np.isfinite(kp).all(-1), kp[..., 2], 0.0)  # an undetected joint: confidence 0
    cam_R, cam_t = cam[:, :3, :3], cam[:, :3, 3]
    sixty = {}
    for key, width in (("poses_60Hz", 72), ("trans_60Hz", 3)):
        if isinstance(data.get(key), (list, tuple)) and len(data[key]) == len(poses):
            arrays = [_array(path, f"{key}[{p}]", v, (None, width)) for p, v in enumerate(data[key])]
            sixty[key] = [a.reshape(len(a), 24, 3) if width == 72 else a for a in arrays]
    if world_rotation is not None:
        from ..motion.amass import pelvis_rest, rotate_world

        R = np.asarray(world_rotation, np.float64)
        if R.shape != (3, 3) or not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            raise ValueError(f"world_rotation must be a (3, 3) rotation matrix, got {R.tolist()}.")
        for p in range(len(poses)):
            j0 = pelvis_rest(body, betas[p])
            poses[p], trans[p] = rotate_world(poses[p], trans[p], R, j0)
            if len(sixty) == 2 and len(sixty["poses_60Hz"][p]) == len(sixty["trans_60Hz"][p]):
                sixty["poses_60Hz"][p], sixty["trans_60Hz"][p] = rotate_world(
                    sixty["poses_60Hz"][p], sixty["trans_60Hz"][p], R, j0
                )
            else:
                sixty = {}  # a translation cannot be rotated without its pose: not returned
        joints = None if joints is None else joints @ R.T
        cam_R = cam_R @ R.T
    ids = data.get("img_frame_ids")
    width, height = _image_size(K) if image_size is None else (int(image_size[0]), int(image_size[1]))
    return ThreeDPWSequence(
        name=_text(data.get("sequence", path.stem)), poses=poses, trans=trans, betas=betas,
        genders=tuple(_gender(g) for g in d["genders"]), keypoints=kp, valid=valid, cam_R=cam_R, cam_t=cam_t,
        K=K, width=width, height=height, joints=joints, poses_60hz=_tuple(sixty.get("poses_60Hz")),
        trans_60hz=_tuple(sixty.get("trans_60Hz")), img_frame_ids=None if ids is None else np.asarray(ids).reshape(-1),
    )  # fmt: skip
