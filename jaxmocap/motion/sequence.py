"""A motion: per-frame SMPL-tree joint rotations and root translation at a frame rate.

World frame convention used throughout jaxmocap: metres, **y up**, right-handed, as in
SMPL's template (the body faces +z at zero root rotation, its left side is +x).
Readers of files with other conventions (AMASS is z up) convert on load.
"""

from __future__ import annotations

import dataclasses

import numpy as np

__all__ = ["Motion"]


@dataclasses.dataclass(frozen=True)
class Motion:
    """A motion sequence on SMPL's 24-joint tree (NumPy arrays; feed them to `forward`).

    Attributes:
        poses: (T, 24, 3) axis-angle joint rotations relative to the parent, root first.
        trans: (T, 3) root translation in metres, world frame y up.
        fps: frames per second.
        betas: (B,) body shape coefficients (may be empty).
        gender: "neutral", "male" or "female".
        name: where the motion came from (file name, generator), for reports.
    """

    poses: np.ndarray
    trans: np.ndarray
    fps: float
    betas: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    gender: str = "neutral"
    name: str = ""

    def __post_init__(self):
        for name in ("poses", "trans", "betas"):
            if np.iscomplexobj(getattr(self, name)):  # float64 would drop the imaginary part silently
                raise ValueError(f"Motion.{name} is complex; give real numbers.")
        poses = np.asarray(self.poses, np.float64)
        trans = np.asarray(self.trans, np.float64)
        if poses.ndim != 3 or poses.shape[1:] != (24, 3):
            raise ValueError(f"Motion.poses has shape {poses.shape}; expected (T, 24, 3).")
        if trans.shape != (poses.shape[0], 3):
            raise ValueError(f"Motion.trans has shape {trans.shape}; expected ({poses.shape[0]}, 3) to match poses.")
        if poses.shape[0] == 0:
            raise ValueError("Motion.poses has 0 frames; a motion needs at least one (empty slice?).")
        if not (np.isfinite(poses).all() and np.isfinite(trans).all()):
            raise ValueError("Motion poses/trans contain NaN or inf.")
        try:
            # Text and booleans convert to floats ("30", True), which would hide a mistake.
            fps_ok = (not isinstance(self.fps, (str, bytes, bool, np.bool_)) and np.ndim(self.fps) == 0
                      and np.isfinite(float(self.fps)) and float(self.fps) > 0)  # fmt: skip
        except (TypeError, ValueError):
            fps_ok = False
        if not fps_ok:
            raise ValueError(f"Motion.fps must be a finite number > 0, got {self.fps!r}.")
        betas = np.asarray(self.betas, np.float64).reshape(-1)
        if not np.isfinite(betas).all():
            raise ValueError("Motion.betas contain NaN or inf.")
        object.__setattr__(self, "poses", poses)
        object.__setattr__(self, "trans", trans)
        object.__setattr__(self, "betas", betas)
        object.__setattr__(self, "fps", float(self.fps))

    def __repr__(self) -> str:
        # Short: the arrays would print thousands of numbers.
        return (
            f"Motion({self.name or 'unnamed'!r}: {self.num_frames} frames at {self.fps:g} fps "
            f"({self.duration:.2f} s), {self.betas.size} betas, {self.gender})"
        )

    @property
    def num_frames(self) -> int:
        return self.poses.shape[0]

    @property
    def duration(self) -> float:
        """Seconds from the first to the last frame."""
        return (self.num_frames - 1) / self.fps

    def __getitem__(self, frames) -> Motion:
        """Frames by slice or index array, e.g. `motion[::4]` (fps is not changed)."""
        poses = self.poses[frames]
        if poses.ndim == 2:
            raise ValueError("Index a Motion with a slice or an index array, not a single frame.")
        if poses.shape[0] == 0:
            raise ValueError(f"motion[{frames!r}] selects no frames of the {self.num_frames}; a Motion needs >= 1.")
        return dataclasses.replace(self, poses=poses, trans=self.trans[frames])

    def replace(self, **changes) -> Motion:
        return dataclasses.replace(self, **changes)

    def resample(self, fps: float) -> Motion:
        """The motion at `fps`: slerp per joint rotation, linear root translation.

        Frames are taken at times k / fps for k = 0 .. floor(duration · fps) (+ a tiny
        tolerance), so 120 → 30 Hz keeps every 4th frame exactly and gives
        ceil(T / 4) frames. No low-pass filtering is applied before downsampling.
        """
        from scipy.interpolate import interp1d

        from ..rotation import host_slerp

        fps = float(fps)
        if not (np.isfinite(fps) and fps > 0):
            raise ValueError(f"fps must be a finite number > 0, got {fps}.")
        if fps == self.fps:
            return self
        T = self.num_frames
        if T == 1:
            return dataclasses.replace(self, fps=fps)
        times = np.arange(T) / self.fps
        n = int(np.floor(self.duration * fps + 1e-6)) + 1
        new_times = np.minimum(np.arange(n) / fps, times[-1])
        poses = np.empty((n, 24, 3))
        for j in range(24):
            poses[:, j] = host_slerp(times, self.poses[:, j], new_times)
        trans = interp1d(times, self.trans, axis=0)(new_times)
        return dataclasses.replace(self, poses=poses, trans=trans, fps=fps)

    def mirrored(self) -> Motion:
        """The motion reflected through the body's sagittal plane (x -> -x): left and right
        joints swap, each axis-angle (x, y, z) becomes (x, -y, -z), translation x flips.

        Exact for a left-right symmetric skeleton (SMPL's and the default body's are, to
        their mesh's symmetry); a data augmentation for the learned parts.
        """
        from ..body.model import SMPL_JOINT_NAMES

        index = {n: i for i, n in enumerate(SMPL_JOINT_NAMES)}
        swap = [index[n.replace("left", "@").replace("right", "left").replace("@", "right")] for n in SMPL_JOINT_NAMES]
        poses = self.poses[:, swap] * np.array([1.0, -1.0, -1.0])
        trans = self.trans * np.array([-1.0, 1.0, 1.0])
        return dataclasses.replace(self, poses=poses, trans=trans, name=f"{self.name} (mirrored)")

    def time_scaled(self, speed: float) -> Motion:
        """The same motion performed `speed` times as fast, at the same frame rate
        (slerp resampling; speed 1.2 gives 1/1.2 as many frames)."""
        if not (np.isfinite(speed) and speed > 0):
            raise ValueError(f"speed must be a finite number > 0, got {speed!r}.")
        if speed == 1.0:
            return self
        fast = dataclasses.replace(self, fps=self.fps * speed).resample(self.fps)
        return dataclasses.replace(fast, name=f"{self.name} (x{speed:g} speed)")
