"""`jaxmocap multiview --videos DIR`: MediaPipe Pose on one video per camera, then the
multi-view fit of `app.multiview.fit_recording` on its detections.

The detections are kept in ``OUT/keypoints/<camera>_json/`` (OpenPose-style JSON, layout
"mediapipe33"), so `jaxmocap multiview --keypoints OUT/keypoints --calib FILE --layout
mediapipe33` refits them without detecting again; ``OUT/keypoints/detection.json`` says
what the detector saw. Every input (output folder, calibration, cameras' names, the
detector's Python) is checked before the first video is read.
"""

from __future__ import annotations

import json

import numpy as np

__all__ = ["fit_videos"]


def _check_names(videos, calibration, videos_dir, calib_path):
    """The calibration's cameras for the videos (matched as `align_views` matches keypoint
    folders), refused before any detection when one is missing."""
    from ..formats import KeypointRecording, align_views

    empty = np.zeros((1, 1, 33, 3))
    recording = KeypointRecording(tuple(f"{v.stem}_json" for v in videos), "mediapipe33", np.zeros(1, np.int64),
                                  tuple(empty for _ in videos))  # fmt: skip
    try:
        return align_views(recording, calibration)
    except ValueError as e:
        raise ValueError(f"videos in {videos_dir} and cameras in {calib_path}: {e}") from None


def fit_videos(
    videos_dir,
    calib_path,
    out_dir,
    detector_python=None,
    frames: slice | None = None,
    views=None,
    fps: float | None = None,
    log=None,
    **fit_options,
) -> dict:
    """Detect the people in `videos_dir` (one video per camera) and fit SMPL to them.

    Args:
        videos_dir: folder with one video per camera, named like the calibration's cameras
            (``cam01.mp4`` for camera ``cam01``; `formats.video.find_videos`).
        calib_path, out_dir: as `app.multiview.fit_recording`.
        detector_python: the Python that has mediapipe 0.10.21 (`formats.video.detector_python`).
        frames: frame numbers (0 = each video's first frame) to detect and fit; default all.
        views: cameras (video stems) to use; default all.
        fps: overrides the videos' own frame rate.
        log: one line per finding (`fit_recording`'s), the detector's included.
        fit_options: passed on to `fit_recording` (body, temporal, weights, progress, ...).
    Returns:
        `fit_recording`'s report, with "detection" (`formats.video.detect_videos`'s summary).
    Raises:
        ValueError (VideoError, CalibrationError, ...) naming the input; DetectorMissing
        with the install instructions when no Python with mediapipe's pose model is found.
    """
    from .._checks import output_folder
    from ..formats import load_calibration
    from ..formats.video import detect_videos, detector_python as find_detector, find_videos
    from .multiview import fit_recording

    out_dir = output_folder(out_dir, create=False)
    videos = find_videos(videos_dir)
    if views is not None:
        known = {v.stem for v in videos}
        missing = [v for v in views if v not in known]
        if missing:
            raise ValueError(f"--views {missing}: no such video in {videos_dir} (there are {sorted(known)}).")
        videos = [v for v in videos if v.stem in set(views)]
    _check_names(videos, load_calibration(calib_path), videos_dir, calib_path)
    if fps is not None and not (not isinstance(fps, bool) and float(fps) > 0):
        raise ValueError(f"fps must be a positive number of frames per second, got {fps!r}.")
    python = find_detector(detector_python)

    keypoints_dir = output_folder(out_dir, create=True) / "keypoints"
    for video in videos:  # earlier detections of these cameras (other frames) must not mix in
        for old in (keypoints_dir / f"{video.stem}_json").glob(f"{video.stem}_[0-9]*.json"):
            old.unlink()
    summary = detect_videos(videos_dir, keypoints_dir, python, frames, [v.stem for v in videos], log)
    (keypoints_dir / "detection.json").write_text(json.dumps(summary, indent=1), encoding="utf-8")
    if fps is None and summary["fps"] is None:
        raise ValueError(f"{videos_dir}: the videos do not store a frame rate; give it with --fps.")
    report = fit_recording(keypoints_dir, calib_path, out_dir, layout="mediapipe33",
                           fps=fps if fps is not None else summary["fps"], frames=frames, log=log,
                           **fit_options)  # fmt: skip
    report["detection"] = summary
    return report
