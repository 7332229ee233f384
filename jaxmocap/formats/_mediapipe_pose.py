"""MediaPipe Pose (BlazePose, the legacy `mp.solutions.pose`) on one video: the detector's side.

Run by `jaxmocap.formats.video` as a script, in the Python that has mediapipe (which may
be another environment than jaxmocap's: mediapipe 0.10.21, the last release that ships the
pose model, needs numpy < 2, and jax 0.10 needs numpy >= 2). So this file imports nothing
from jaxmocap and only numpy, OpenCV (which mediapipe brings) and mediapipe:

    python _mediapipe_pose.py VIDEO OUT.npz [--start N] [--stop N]

OUT.npz: frames (T,) frame numbers (0 = the video's first frame), keypoints (T, 33, 3)
rows (u, v, confidence) in pixels with OpenPose's convention (pixel centres at integers;
undetected: all 0), fps, width, height, mediapipe (its version). Exit status 3 with one
line on stderr when mediapipe (or its pose model) is missing, 4 when the video cannot be
read.

Settings: model_complexity=1 (pose_landmark_full.tflite, shipped inside the wheel; 0 and 2
would be downloaded at run time), tracking between frames (static_image_mode=False: the
person detector runs only when the track is lost), and smooth_landmarks=False: the fit's
DCT stage is the only temporal smoothing, and the detections stay per-frame measurements.
"""

import argparse
import sys

MISSING, UNREADABLE = 3, 4


def _fail(code: int, message: str):
    print(message, file=sys.stderr, flush=True)
    sys.exit(code)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("video")
    p.add_argument("out")
    p.add_argument("--start", type=int, default=0)
    p.add_argument("--stop", type=int, default=None)
    p.add_argument("--check", action="store_true", help="only check that mediapipe and its pose model are here")
    args = p.parse_args(argv)
    try:
        import mediapipe as mp
        import cv2
        import numpy as np
    except ImportError as e:  # no name: a module that is there but cannot load (e.g. OpenCV without libGL)
        _fail(MISSING, f"missing: {e.name} ({e})" if e.name else f"an import failed: {e}")
    from pathlib import Path

    model = Path(mp.__file__).parent / "modules" / "pose_landmark" / "pose_landmark_full.tflite"
    if not hasattr(getattr(mp, "solutions", None), "pose") or not model.is_file():
        _fail(
            MISSING,
            f"mediapipe {mp.__version__} has no pose model (mediapipe/modules/pose_landmark/"
            "pose_landmark_full.tflite); 0.10.21 is the last release that ships it.",
        )
    if args.check:
        print(f"mediapipe {mp.__version__}, opencv {cv2.__version__}, numpy {np.__version__}")
        return 0

    capture = cv2.VideoCapture(args.video)
    if not capture.isOpened():
        _fail(UNREADABLE, f"{args.video}: OpenCV cannot open this video (not a video, or a codec it lacks).")
    fps = float(capture.get(cv2.CAP_PROP_FPS) or 0.0)
    width = int(capture.get(cv2.CAP_PROP_FRAME_WIDTH))
    height = int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT))
    frames, rows = [], []
    with mp.solutions.pose.Pose(static_image_mode=False, model_complexity=1, smooth_landmarks=False,
                                enable_segmentation=False) as pose:  # fmt: skip
        index = -1
        while args.stop is None or index + 1 < args.stop:
            ok, image = capture.read()
            if not ok:
                break
            index += 1
            if index < args.start:
                continue
            found = pose.process(cv2.cvtColor(image, cv2.COLOR_BGR2RGB)).pose_landmarks
            kp = np.zeros((33, 3))
            if found is not None:
                h, w = image.shape[:2]
                lm = np.array([(p.x, p.y, p.visibility) for p in found.landmark])
                # normalised image coordinates (0..1 from edge to edge) to OpenPose pixels
                # (centres at integers); confidence = visibility, 0 outside the image
                kp[:, 0] = lm[:, 0] * w - 0.5
                kp[:, 1] = lm[:, 1] * h - 0.5
                inside = (lm[:, 0] >= 0) & (lm[:, 0] <= 1) & (lm[:, 1] >= 0) & (lm[:, 1] <= 1)
                kp[:, 2] = np.where(inside, np.clip(lm[:, 2], 0.0, 1.0), 0.0)
                kp[kp[:, 2] <= 0] = 0.0
            frames.append(index)
            rows.append(kp)
    capture.release()
    if index < 0:
        _fail(UNREADABLE, f"{args.video}: no frame could be decoded.")
    np.savez(args.out, frames=np.asarray(frames, np.int64), keypoints=np.asarray(rows, np.float64).reshape(-1, 33, 3),
             fps=fps, width=width, height=height, mediapipe=mp.__version__)  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
