"""Videos in (issue 47, goal 8): the MediaPipe-33 layout, the detector on real Pose2Sim demo
videos, and what `jaxmocap multiview --videos` says when the detector is not installed.

The detector runs in a Python that has mediapipe 0.10.21 (`jaxmocap.formats.video`): the
tests that run it skip unless $JAXMOCAP_VIDEO_PYTHON (or this Python) has it and the
pose2sim package (its Demo videos and calibration) can be found: installed, or its wheel
unpacked on PYTHONPATH.
"""

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from jaxmocap.body.io import default_body
from jaxmocap.cli import main
from jaxmocap.formats import CalibratedCamera, read_config, read_openpose, save_calibration
from jaxmocap.formats.video import DETECTOR_ENV, DetectorMissing, detect_video, detector_python, find_videos
from jaxmocap.geometry.keypoints import BODY25_NAMES, KEYPOINT_FORMATS, flip_pairs, keypoint_regressor, rest_keypoints

# mediapipe's PoseLandmark enum, in order (its MOUTH_LEFT / MOUTH_RIGHT are our left_mouth / right_mouth)
POSE_LANDMARK = (
    "NOSE LEFT_EYE_INNER LEFT_EYE LEFT_EYE_OUTER RIGHT_EYE_INNER RIGHT_EYE RIGHT_EYE_OUTER LEFT_EAR RIGHT_EAR "
    "MOUTH_LEFT MOUTH_RIGHT LEFT_SHOULDER RIGHT_SHOULDER LEFT_ELBOW RIGHT_ELBOW LEFT_WRIST RIGHT_WRIST LEFT_PINKY "
    "RIGHT_PINKY LEFT_INDEX RIGHT_INDEX LEFT_THUMB RIGHT_THUMB LEFT_HIP RIGHT_HIP LEFT_KNEE RIGHT_KNEE LEFT_ANKLE "
    "RIGHT_ANKLE LEFT_HEEL RIGHT_HEEL LEFT_FOOT_INDEX RIGHT_FOOT_INDEX"
).split()


def _ours(name: str) -> str:
    side, _, rest = name.lower().partition("_")
    return f"{rest}_{side}" if side == "mouth" else name.lower()


def _detector():
    try:
        return detector_python()
    except DetectorMissing as e:
        pytest.skip(f"no Python with mediapipe 0.10.21 (set {DETECTOR_ENV}): {str(e).splitlines()[0]}")


def _demo(name: str = "Demo_SinglePerson") -> Path:
    spec = importlib.util.find_spec("Pose2Sim")
    if spec is None or not spec.submodule_search_locations:
        pytest.skip("pose2sim is not installed (its demo videos are the real recordings tested here)")
    demo = Path(next(iter(spec.submodule_search_locations))) / name
    if not (demo / "videos").is_dir():
        pytest.skip(f"{demo}: this pose2sim has no {name}/videos")
    return demo


# --- the layout ---------------------------------------------------------------------


def test_mediapipe33_names_follow_mediapipes_order():
    names = KEYPOINT_FORMATS["mediapipe33"]
    assert names == tuple(_ours(n) for n in POSE_LANDMARK)
    # every left point has its right partner (the leg-swap repair and the flips need them)
    assert len(flip_pairs(names)) == 16 and {names[a] for a, _ in flip_pairs(names)} == {
        n for n in names if n.startswith("left")
    }


def test_mediapipe33_names_match_the_installed_mediapipe():
    python = _detector()
    code = "import mediapipe as mp; print(' '.join(l.name for l in mp.solutions.pose.PoseLandmark))"
    out = subprocess.run([python, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert tuple(out) == tuple(POSE_LANDMARK)


@pytest.mark.parametrize("resolution", ["low", "full"])
def test_mediapipe33_regressor_on_the_body(resolution):
    body = default_body(resolution)
    reg = keypoint_regressor(body, "mediapipe33")
    names = KEYPOINT_FORMATS["mediapipe33"]
    assert reg.shape == (33, body.num_vertices + 24) and np.allclose(reg.sum(1), 1.0)
    # the limb joints are the same rows as OpenPose's (one definition of "left knee")
    b25 = keypoint_regressor(body, "body25")
    for joint in ("shoulder", "elbow", "wrist", "hip", "knee", "ankle", "heel"):
        for side in ("left", "right"):
            n = f"{side}_{joint}"
            assert np.array_equal(reg[names.index(n)], b25[BODY25_NAMES.index(n)]), n
    # where the extra points sit on the rest mesh (y up, facing +z, left = +x, arms out along x)
    p = dict(zip(names, rest_keypoints(body, "mediapipe33")))
    for side, s in (("left", 1.0), ("right", -1.0)):
        inner, eye, outer = (s * p[f"{side}_eye{x}"][0] for x in ("_inner", "", "_outer"))
        assert 0.005 < inner < eye < outer < 0.07
        assert p[f"{side}_mouth"][1] < p["nose"][1] < p[f"{side}_eye"][1]
        assert s * p[f"{side}_mouth"][0] > 0.01
        wrist = p[f"{side}_wrist"]
        for hand in ("pinky", "index", "thumb"):
            assert 0.02 < s * (p[f"{side}_{hand}"][0] - wrist[0]) < 0.15, (side, hand)
        assert p[f"{side}_index"][2] > p[f"{side}_pinky"][2]  # palms down, thumbs forward
        assert p[f"{side}_thumb"][2] > wrist[2] + 0.02
        foot = p[f"{side}_foot_index"]
        assert foot[2] > p[f"{side}_ankle"][2] + 0.08 and foot[2] > p[f"{side}_heel"][2] + 0.1
        assert foot[1] < p[f"{side}_ankle"][1] - 0.02


def test_33_point_openpose_files_read_as_mediapipe33(tmp_path):
    # as Pose2Sim writes BlazePose detections: OpenPose JSON with 99 numbers a person
    rows = np.arange(99, dtype=float).reshape(33, 3) % 7 + 1.0
    folder = tmp_path / "pose" / "cam01_json"
    folder.mkdir(parents=True)
    for f in (0, 1, 3):
        person = {"person_id": [-1], "pose_keypoints_2d": (rows + f).ravel().tolist()}
        (folder / f"cam01_{f:06d}.json").write_text(json.dumps({"version": 1.3, "people": [person]}))
    rec = read_openpose(tmp_path / "pose", None)
    assert rec.layout == "mediapipe33" and rec.frames.tolist() == [0, 1, 3]
    assert rec.keypoints[0].shape == (3, 1, 33, 3) and np.allclose(rec.keypoints[0][2, 0], rows + 3)
    (tmp_path / "Config.toml").write_text("[pose]\npose_model = 'BLAZEPOSE'\n")
    assert read_config(tmp_path / "pose").layout == "mediapipe33"


# --- the detector on a real recording -----------------------------------------------


@pytest.fixture(scope="module")
def detected():
    """MediaPipe Pose on frames 10..15 of Pose2Sim's single-person demo, cameras 1 and 3."""
    python = _detector()
    demo = _demo()
    return demo, {
        cam: detect_video(demo / "videos" / f"{cam}.mp4", python, slice(10, 16)) for cam in ("cam01", "cam03")
    }


def test_the_detector_finds_the_person_in_a_real_video(detected):
    _, dets = detected
    names = KEYPOINT_FORMATS["mediapipe33"]
    for cam, det in dets.items():
        assert det.frames.tolist() == list(range(10, 16)) and det.keypoints.shape == (6, 33, 3)
        assert det.fps == pytest.approx(60.0) and det.mediapipe == "0.10.21"
        kp = det.keypoints
        body = [names.index(f"{s}_{j}") for s in ("left", "right") for j in ("shoulder", "hip", "knee")]
        assert (kp[:, body, 2] > 0.5).all(), cam  # a standing person in full view
        assert ((kp[..., 0] >= -0.5) & (kp[..., 0] < det.width) & (kp[..., 1] < det.height))[kp[..., 2] > 0].all()
        nose, hip, ankle = (kp[:, names.index(n), 1] for n in ("nose", "left_hip", "left_ankle"))
        assert (nose < hip).all() and (hip < ankle).all(), cam  # upright in the image
        assert np.abs(np.diff(kp[:, names.index("left_hip"), :2], axis=0)).max() < 40  # 60 fps: small steps


def test_real_detections_agree_with_the_recordings_calibration(detected):
    """Two views triangulated through Pose2Sim's calibration: the rays meet (pixels) and the
    skeleton has a person's proportions (metres), which holds only if the layout's points,
    the pixel convention and the calibration belong together."""
    from jaxmocap.formats import KeypointRecording, align_views, load_calibration
    from jaxmocap.geometry.triangulation import projection_matrices, triangulate, undistort_recording

    demo, dets = detected
    views = tuple(f"{c}_json" for c in dets)
    rec = KeypointRecording(
        views, "mediapipe33", dets["cam01"].frames, tuple(d.keypoints[:, None] for d in dets.values())
    )
    cameras = align_views(rec, load_calibration(demo / "calibration" / "Calib.qca.txt"))
    kp = np.stack([k[:, 0] for k in undistort_recording(rec, cameras)])  # (V, T, 33, 3)
    X, err = triangulate(projection_matrices(cameras), kp[..., :2], kp[..., 2])
    names = KEYPOINT_FORMATS["mediapipe33"]
    limbs = [names.index(f"{s}_{j}") for s in ("left", "right") for j in ("shoulder", "elbow", "hip", "knee", "ankle")]
    assert np.nanmedian(err[:, :, limbs]) < 15.0  # px, 1920-px-high images
    d = lambda a, b: np.linalg.norm(X[:, names.index(a)] - X[:, names.index(b)], axis=-1)  # noqa: E731
    assert 0.25 < np.median(d("left_shoulder", "right_shoulder")) < 0.5
    assert 0.3 < np.median(d("left_hip", "left_knee")) < 0.6 and 0.3 < np.median(d("right_knee", "right_ankle")) < 0.6


# --- without the detector -----------------------------------------------------------


@pytest.fixture
def video_folder(tmp_path):
    videos = tmp_path / "videos"
    videos.mkdir()
    for cam in ("cam01", "cam02"):
        (videos / f"{cam}.mp4").write_bytes(b"\x00\x00\x00\x18ftypmp42")  # never read: checks come first
    K = [[1000.0, 0.0, 540.0], [0.0, 1000.0, 960.0], [0.0, 0.0, 1.0]]
    cams = [CalibratedCamera(c, K, [0.0] * 5, np.eye(3), [0.0, 0.0, 3.0 + i], 1080, 1920)
            for i, c in enumerate(("cam01", "cam02"))]  # fmt: skip
    save_calibration(tmp_path / "Calib.qca.txt", cams, "qualisys")
    return videos, tmp_path / "Calib.qca.txt"


def _run(args, capsys):
    code = main(["multiview", *map(str, args)])
    return code, capsys.readouterr()


def test_cli_says_how_to_install_the_detector(video_folder, tmp_path, capsys, monkeypatch):
    videos, calib = video_folder
    monkeypatch.delenv(DETECTOR_ENV, raising=False)
    missing = tmp_path / "no-venv" / "bin" / "python"
    code, io = _run(["--videos", videos, "--calib", calib, "--out", tmp_path / "fit", "--detector-python", missing],
                    capsys)  # fmt: skip
    assert code == 2 and io.err.startswith(f"jaxmocap multiview: error: --detector-python = {missing}: no such file")
    assert "mediapipe==0.10.21" in io.err and "video_constraints.txt" in io.err and "python3 -m venv" in io.err
    assert not (tmp_path / "fit").exists()  # refused before anything was written

    # a Python without mediapipe (a bare venv's) names what is missing, and the same fix
    bare = tmp_path / "bare"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(bare)], check=True)
    monkeypatch.setenv(DETECTOR_ENV, str(bare / "bin" / "python"))
    code, io = _run(["--videos", videos, "--calib", calib, "--out", tmp_path / "fit"], capsys)
    assert code == 2 and "missing: mediapipe" in io.err and "mediapipe==0.10.21" in io.err
    assert f"set {DETECTOR_ENV}" in io.err


def test_cli_checks_the_videos_against_the_calibration_first(video_folder, tmp_path, capsys, monkeypatch):
    videos, calib = video_folder
    monkeypatch.setenv(DETECTOR_ENV, str(tmp_path / "nowhere"))  # the detector is looked for last
    (videos / "cam07.mp4").write_bytes(b"")
    code, io = _run(["--videos", videos, "--calib", calib, "--out", tmp_path / "fit"], capsys)
    assert code == 2 and "cam07" in io.err and "mediapipe" not in io.err
    (videos / "cam07.mp4").unlink()
    empty = tmp_path / "empty"
    empty.mkdir()
    code, io = _run(["--videos", empty, "--calib", calib, "--out", tmp_path / "fit"], capsys)
    assert code == 2 and "no video" in io.err
    code, io = _run(["--videos", videos, "--keypoints", empty, "--calib", calib, "--out", tmp_path / "fit"], capsys)
    assert code == 2 and "--videos and --keypoints" in io.err


def test_find_videos_names_cameras_by_file(tmp_path):
    for name in ("cam10.mp4", "cam2.MOV", "notes.txt", "cam1.avi"):
        (tmp_path / name).write_bytes(b"")
    assert [p.name for p in find_videos(tmp_path)] == ["cam1.avi", "cam2.MOV", "cam10.mp4"]
    (tmp_path / "cam1.mp4").write_bytes(b"")
    with pytest.raises(ValueError, match=r"several videos named \['cam1'\]"):
        find_videos(tmp_path)


def test_the_detector_script_imports_nothing_from_jaxmocap():
    # it runs in another environment, where jaxmocap (and numpy 2) may be absent
    import ast

    import jaxmocap.formats.video as video

    tree = ast.parse(Path(video._WORKER).read_text())
    modules = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    modules |= {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    assert modules == {"argparse", "sys", "cv2", "mediapipe", "numpy", "pathlib"}


def test_a_project_folder_gives_the_calibration_and_output_for_its_videos(video_folder, tmp_path, capsys, monkeypatch):
    # Pose2Sim's layout: PROJECT/videos, PROJECT/calibration/Calib.qca.txt, no pose/ folder yet
    videos, calib = video_folder
    project = tmp_path / "Demo"
    (project / "calibration").mkdir(parents=True)
    calib.rename(project / "calibration" / calib.name)
    videos.rename(project / "videos")
    monkeypatch.setenv(DETECTOR_ENV, str(tmp_path / "nowhere"))
    code, io = _run([project, "--videos", project / "videos"], capsys)
    # everything before the detector was found and accepted: only the detector is missing
    assert code == 2 and f"{DETECTOR_ENV} = {tmp_path / 'nowhere'}: no such file" in io.err
    assert not (project / "multiview").exists()
