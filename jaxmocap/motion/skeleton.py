"""A source skeleton in motion (what the ASF/AMC and BVH readers produce), and file errors.

`SkeletonMotion` is format-neutral: per-frame **global** joint rotations and positions
in metres, in the file's own world frame (for CMU data that is already y up, subject
facing +z, left side +x — the same as SMPL's; see `retarget`).

Conventions:
    * a joint is the pivot of a rigid segment: `rotations[t, j]` rotates the segment
      that starts at `positions[t, j]` (ASF: the bone starting there; BVH: the offsets
      of the joint's children);
    * `rotations` are *relative to the rest pose*: rest-world → posed-world, so at the
      rest pose every rotation is the identity and a rest-frame vector d of segment j
      is posed as `rotations[t, j] @ d`;
    * `rest_positions` (N, 3) are the joint positions of the rest pose with the root
      at the origin; `tips` (N, 3) are each joint's own rest segment vector (ASF bone
      direction x length; BVH: offset of its only child or End Site, zero if the joint
      has several children or none).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

__all__ = ["MotionFileError", "SkeletonMotion", "check_file", "read_npz"]


class MotionFileError(ValueError):
    """A motion file is unreadable, truncated, inconsistent or of an unknown kind."""


def check_file(path) -> Path:
    """`path` as a Path; FileNotFoundError naming it if it is not an existing file."""
    path = Path(path)
    if path.is_dir():  # "not found" would mislead: it is there, but a folder
        raise FileNotFoundError(f"{path} is a folder; give a motion file inside it.")
    if not path.is_file():
        raise FileNotFoundError(f"Motion file not found: {path}")
    return path


def read_npz(path: Path) -> dict:
    """Every array of an .npz file (no pickles); MotionFileError naming the file otherwise.

    A file that is not a zip archive is refused before numpy sees it: numpy would
    otherwise suggest `allow_pickle=True`, i.e. executing the file's contents.
    """
    import zipfile

    if not zipfile.is_zipfile(path):
        raise MotionFileError(
            f"{path}: not an .npz file (no zip archive inside); it may be truncated, or "
            "another format with an .npz name."
        )
    try:
        # Our own handle: np.load leaks its file when a truncated zip makes it raise.
        with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as f:
            return {k: f[k] for k in f.files}
    except Exception as e:  # zipfile / zlib / format / object-array errors
        raise MotionFileError(f"Cannot read {path} as an .npz file: {type(e).__name__}: {e}") from e


@dataclasses.dataclass(frozen=True)
class SkeletonMotion:
    """A source skeleton's motion (NumPy).

    Attributes:
        names: joint names, root first, each after its parent.
        parents: parent index per joint (-1 for the root).
        rest_positions: (N, 3) rest joint positions, metres, root at the origin.
        tips: (N, 3) each joint's own rest segment vector, metres (zero if undefined).
        rotations: (T, N, 3, 3) global rotations relative to the rest pose.
        positions: (T, N, 3) global joint positions, metres.
        fps: frames per second.
        name: the source file, for messages.
    """

    names: tuple[str, ...]
    parents: tuple[int, ...]
    rest_positions: np.ndarray
    tips: np.ndarray
    rotations: np.ndarray
    positions: np.ndarray
    fps: float
    name: str = ""

    @property
    def num_frames(self) -> int:
        return self.rotations.shape[0]

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"{self.name or 'skeleton'} has no joint {name!r}; it has {list(self.names)}.") from None

    def end_positions(self) -> np.ndarray:
        """(T, N, 3) posed end point of each joint's own segment (`tips` rotated)."""
        return self.positions + np.einsum("tnab,nb->tna", self.rotations, self.tips)
