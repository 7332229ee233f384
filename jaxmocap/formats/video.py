"""Videos in: MediaPipe Pose (BlazePose) run offline on one video per camera, written as
OpenPose-style JSON that `read_openpose` reads (layout "mediapipe33").

The detector is mediapipe's legacy pose solution: its weights (`pose_detection.tflite`,
`pose_landmark_full.tflite`) ship inside the mediapipe 0.10.21 wheel, so nothing is
downloaded; later releases ship no pose model. That release needs numpy < 2 and
jaxmocap's jax needs numpy >= 2, so one environment cannot hold both: the detector runs
as a subprocess (`_mediapipe_pose.py`, which imports nothing from jaxmocap) in the Python
that has mediapipe, found in this order: the `python` argument (`--detector-python`),
the JAXMOCAP_VIDEO_PYTHON environment variable, this Python. `INSTALL_HINT` says how to
make that environment (`video_constraints.txt` beside this file pins it).

Videos: every ``*.mp4``/``.avi``/``.mov``/``.mkv``/``.webm`` file of a folder is one camera,
named by the file's stem (``cam01.mp4`` -> camera ``cam01``, folder ``cam01_json``,
matched to the calibration by `align_views`). Frame n is the video's n-th decoded frame,
from 0; the cameras are taken as synchronised frame by frame (as Pose2Sim's demo videos
are). One person per view: BlazePose tracks the most prominent person in each video.
"""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

from .openpose import write_openpose

__all__ = [
    "DETECTOR_ENV",
    "INSTALL_HINT",
    "VIDEO_SUFFIXES",
    "DetectorMissing",
    "VideoDetections",
    "VideoError",
    "detect_video",
    "detect_videos",
    "detector_python",
    "find_videos",
]

VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".webm")
DETECTOR_ENV = "JAXMOCAP_VIDEO_PYTHON"
_WORKER = Path(__file__).with_name("_mediapipe_pose.py")
_MISSING = 3  # the worker's exit status when mediapipe or its pose model is missing
_CONSTRAINTS = Path(__file__).with_name("video_constraints.txt")
INSTALL_HINT = (
    "the video detector is MediaPipe Pose; mediapipe 0.10.21 is the last release that ships its model, "
    "and it needs numpy < 2, which jaxmocap's jax cannot use, so it gets an environment of its own "
    "(Python 3.12 at most: mediapipe 0.10.21 has no wheel for 3.13):\n"
    "    python3 -m venv ~/.venvs/jaxmocap-video\n"
    f"    ~/.venvs/jaxmocap-video/bin/pip install -c {_CONSTRAINTS} mediapipe==0.10.21\n"
    f"then pass --detector-python ~/.venvs/jaxmocap-video/bin/python (or set {DETECTOR_ENV} to it)."
)


class VideoError(ValueError):
    """A video folder or file is missing or unreadable."""


class DetectorMissing(ValueError):
    """No Python with mediapipe's pose model was found (the message says how to install one)."""


@dataclasses.dataclass(frozen=True, eq=False)
class VideoDetections:
    """MediaPipe Pose on one video. frames: (T,) frame numbers; keypoints: (T, 33, 3)
    (u, v, confidence) OpenPose pixels, all 0 where no person was found; fps, width,
    height: the video's; mediapipe: the detector's version."""

    frames: np.ndarray
    keypoints: np.ndarray
    fps: float
    width: int
    height: int
    mediapipe: str


def find_videos(folder) -> list[Path]:
    """The videos of `folder` (one per camera), in natural order of their names."""
    from .._files import natural_key

    folder = Path(folder)
    if not folder.is_dir():
        raise VideoError(f"{folder}: no such folder; give the folder holding one video per camera (--videos DIR).")
    videos = sorted((p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in VIDEO_SUFFIXES),
                    key=lambda p: natural_key(p.name))  # fmt: skip
    if not videos:
        raise VideoError(f"{folder}: no video ({', '.join('*' + s for s in VIDEO_SUFFIXES)}); give the folder "
                         "holding one video per camera.")  # fmt: skip
    stems = [p.stem for p in videos]
    if len(set(stems)) < len(stems):
        twice = sorted({s for s in stems if stems.count(s) > 1})
        raise VideoError(f"{folder}: several videos named {twice} (one camera each); keep one per camera.")
    return videos


def detector_python(python=None) -> str:
    """The Python that runs the detector (module docstring); DetectorMissing with
    `INSTALL_HINT` when none of the candidates has mediapipe's pose model."""
    named = python or os.environ.get(DETECTOR_ENV)
    candidate = str(named) if named else sys.executable
    if named and not Path(candidate).exists():
        source = "--detector-python" if python else DETECTOR_ENV
        raise DetectorMissing(f"{source} = {candidate}: no such file; {INSTALL_HINT}")
    try:
        run = subprocess.run(
            [candidate, str(_WORKER), "-", "-", "--check"], capture_output=True, text=True, timeout=120
        )
    except (OSError, subprocess.SubprocessError) as e:
        raise DetectorMissing(f"{candidate} cannot be run ({e}); {INSTALL_HINT}") from None
    if run.returncode != 0:
        why = (run.stderr.strip().splitlines() or [f"exit status {run.returncode}"])[-1]
        raise DetectorMissing(f"{candidate}: {why}; {INSTALL_HINT}")
    return candidate


def detect_video(path, python: str | None = None, frames: slice | None = None) -> VideoDetections:
    """MediaPipe Pose on the video at `path` (module docstring).

    python: the detector's Python (default: `detector_python()`); frames: a slice of frame
    numbers (start/stop, no step) to detect, default all.
    """
    path = Path(path)
    if not path.is_file():
        raise VideoError(f"{path}: no such video file.")
    python = detector_python() if python is None else str(python)
    args = []
    if frames is not None:
        if frames.step not in (None, 1):
            raise ValueError(f"frames must be a slice without a step, got {frames}.")
        args += [] if frames.start is None else ["--start", str(max(0, frames.start))]
        args += [] if frames.stop is None else ["--stop", str(frames.stop)]
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "detections.npz"
        run = subprocess.run([python, str(_WORKER), str(path), str(out), *args], capture_output=True, text=True)
        if run.returncode != 0:
            why = (run.stderr.strip().splitlines() or [f"exit status {run.returncode}"])[-1]
            if run.returncode == _MISSING:
                raise DetectorMissing(f"{python}: {why}; {INSTALL_HINT}")
            raise VideoError(f"{path}: the detector failed ({python}): {why}")
        with np.load(out) as z:
            return VideoDetections(frames=z["frames"], keypoints=z["keypoints"], fps=float(z["fps"]),
                                   width=int(z["width"]), height=int(z["height"]), mediapipe=str(z["mediapipe"]))  # fmt: skip


def detect_videos(
    videos_dir,
    out_dir,
    python=None,
    frames: slice | None = None,
    views=None,
    log: Callable[[str], None] | None = None,
) -> dict:
    """Detect every video of `videos_dir` and write the detections as OpenPose JSON.

    Args:
        videos_dir: folder with one video per camera (`find_videos`).
        out_dir: gets one folder per camera, ``<camera>_json/<camera>_<frame:06d>.json``
            (Pose2Sim's naming), with 33 points per person ("mediapipe33").
        python: the detector's Python (`detector_python`); frames: frame numbers to detect.
        views: camera names (video stems) to detect, default all.
        log: called with one line per video.
    Returns:
        {"views": camera names, "fps": the videos' frame rate (None when they do not say),
        "frames": per camera the number of frames read, "detected": per camera the
        number with a person, "seconds": per camera the detector's wall time,
        "mediapipe": version}.
    Raises:
        VideoError for a missing or unreadable folder or video, or videos of different
        frame rates; DetectorMissing with the install instructions.
    """
    import time

    videos = find_videos(videos_dir)
    if views is not None:
        wanted = list(views)
        unknown = [v for v in wanted if v not in {p.stem for p in videos}]
        if unknown:
            raise VideoError(f"{videos_dir}: no video for camera(s) {unknown}; there are {[p.stem for p in videos]}.")
        videos = [p for v in wanted for p in videos if p.stem == v]
    python = detector_python(python)
    out_dir = Path(out_dir)
    summary = {"views": [], "fps": None, "frames": {}, "detected": {}, "seconds": {}, "mediapipe": None}
    rates = {}
    for video in videos:
        start = time.perf_counter()
        det = detect_video(video, python, frames)
        seconds = time.perf_counter() - start
        name = video.stem
        write_openpose(out_dir, [f"{name}_json"], [det.keypoints[:, None]], "mediapipe33", frames=det.frames,
                       name=name + "_{frame:06d}.json")  # fmt: skip
        seen = int((det.keypoints[..., 2] > 0).any(-1).sum())
        summary["views"].append(name)
        summary["frames"][name] = len(det.frames)
        summary["detected"][name] = seen
        summary["seconds"][name] = round(seconds, 2)
        summary["mediapipe"] = det.mediapipe
        if det.fps > 0:
            rates[name] = det.fps
        if log is not None:
            log(f"video    {video.name}: {det.width}x{det.height}, {det.fps:g} fps, {len(det.frames)} frames, "
                f"a person in {seen} (MediaPipe Pose {det.mediapipe}, {seconds:.0f} s)")  # fmt: skip
    if rates:
        if max(rates.values()) - min(rates.values()) > 1e-3 * max(rates.values()):
            raise VideoError(f"{videos_dir}: the videos have different frame rates {rates}; the cameras must be "
                             "synchronised frame by frame (resample them to one rate).")  # fmt: skip
        summary["fps"] = float(np.median(list(rates.values())))
    return summary
