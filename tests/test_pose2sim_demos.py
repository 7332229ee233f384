"""The readers on Pose2Sim's own demo files (issue 47, goals 1, 2 and 7).

tests/data/pose2sim holds unchanged pieces of the demo projects in the pose2sim 0.4.15 and
0.8.4 wheels (README there): OpenPose BODY_25B JSON named ``cam01.0000.json`` with the
stray files the demo ships, a Qualisys calibration, Config.toml at the three places
Pose2Sim has kept it (project/User/, project/, session/participant/trial). Reading and
the layout check are NumPy only; one tiny fit runs the command end to end.
"""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from jaxmocap.app.layout import check_layout
from jaxmocap.body.io import default_body
from jaxmocap.cli import main
from jaxmocap.formats import (
    CalibratedCamera,
    KeypointFileError,
    align_views,
    load_calibration,
    read_config,
    read_openpose,
    read_project,
)
from jaxmocap.geometry.keypoints import BODY25_NAMES, BODY25B_NAMES, HALPE26_NAMES
from jaxmocap.geometry.triangulation import projection_matrices, select_person

DATA = Path(__file__).parent / "data" / "pose2sim"
SINGLE = DATA / "S01_Demo_SingleTrial"
CURRENT = DATA / "Demo_SinglePerson"  # pose2sim 0.10.49: settings only, and a video's header
SESSION = DATA / "S00_Demo_BatchSession"
STATIC = SESSION / "S00_P00_SingleParticipant" / "S00_P00_T00_StaticTrial"
MULTI = SESSION / "S00_P01_MultiParticipants" / "S00_P01_T02_Participants1-2"
CAMS = ("cam01_json", "cam02_json", "cam03_json", "cam04_json")


@pytest.fixture(scope="module")
def body():
    return default_body("low")


def _frames(name="{cam}.{frame:04d}.json", folder="cam{n:02d}_json", frames=range(6)):
    """The demo's frames, as {relative path: text} under another naming."""
    out = {}
    for n in range(1, 5):
        for f in frames:
            text = (SINGLE / "pose" / f"cam{n:02d}_json" / f"cam{n:02d}.{f:04d}.json").read_text()
            out[f"{folder.format(n=n)}/{name.format(cam=f'cam{n:02d}', frame=f)}"] = text
    return out


def _write(root: Path, files: dict) -> Path:
    for rel, text in files.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(text)
    return root


def _subject(recording, calibration):
    cameras = align_views(recording, calibration)
    return select_person(recording, cameras), projection_matrices(cameras)


# ----------------------------------------------------------------------------- projects


def test_the_08_single_trial_reads_with_no_flags_and_its_stray_files_are_named():
    p = read_project(SINGLE)
    assert p.keypoints == SINGLE / "pose" and p.calibration == SINGLE / "calibration"
    assert (p.config.pose_model, p.config.layout, p.config.fps) == ("BODY_25B", "body25b", 60.0)
    rec = read_openpose(p.keypoints, None)
    assert rec.views == CAMS and rec.frames.tolist() == list(range(6)) and rec.layout is None
    # del_000000_0.json ("people": []) would be a second frame 0 of cam03_json
    assert rec.ignored == ("cam03_json/del_000000_0.json", "cam03_json/del_000001_0.json")
    assert [k.shape[1] for k in rec.keypoints] == [2, 2, 1, 1]  # a second detection in cam01/02
    assert all((k[..., 2] > 0).sum() >= 140 for k in rec.keypoints)
    cameras = align_views(rec, load_calibration(p.calibration))
    assert [c.name for c in cameras] == ["cam_01", "cam_02", "cam_03", "cam_04"]
    assert {(c.width, c.height) for c in cameras} == {(1088, 1920)}


def test_backups_of_frames_are_not_frames(tmp_path):
    # pose2sim 0.8's batch demo ships cam02.0098.json.old beside cam02.0098.json
    root = _write(tmp_path, _frames())
    shutil.copy(root / "cam02_json" / "cam02.0005.json", root / "cam02_json" / "cam02.0005.json.old")
    rec = read_openpose(root, None)
    assert rec.frames.tolist() == list(range(6)) and rec.ignored == ()


def test_pose2sim_04_keeps_its_settings_in_user(tmp_path):
    root = shutil.copytree(DATA / "Demo", tmp_path / "Demo")
    _write(root / "pose", _frames(folder="cam{n}_json"))  # 0.4's folder names: cam1_json
    p = read_project(root)
    assert p.config.files == (root / "User" / "Config.toml",)
    assert (p.config.layout, p.config.fps, p.config.frame_range) == ("body25b", 60.0, None)  # frame_range = []
    assert p.calibration == root / "calibration" / "Calib_qualisys.toml"
    rec = read_openpose(p.keypoints, p.config.layout)
    assert [c.name for c in align_views(rec, load_calibration(p.calibration))] == [
        "cam_01", "cam_02", "cam_03", "cam_04"]  # fmt: skip  # by camera number: cam1_json = cam_01


def test_a_batch_trial_inherits_its_participants_and_sessions_settings_and_calibration():
    p = read_project(STATIC)
    assert p.config.files == (SESSION / "Config.toml", SESSION / "S00_P00_SingleParticipant" / "Config.toml",
                              STATIC / "Config.toml")  # fmt: skip
    assert (p.config.layout, p.config.fps) == ("body25b", 60.0)  # the session's; the others are comments
    assert p.config.sources == {key: SESSION / "Config.toml" for key in ("pose_model", "frame_rate", "frame_range")}
    assert p.calibration == SESSION / "S00_Calibration"
    rec = read_openpose(p.keypoints, None)
    assert rec.views == CAMS and rec.frames.tolist() == [0, 1, 2]  # Static_cam_01.00000.json
    assert len(align_views(rec, load_calibration(p.calibration))) == 4
    assert read_config(STATIC / "pose").files == p.config.files


def test_points_a_little_outside_the_image_are_kept_a_wrong_image_size_is_not():
    rec = read_openpose(MULTI / "pose", None)
    seen = rec.keypoints[0][..., 2] > 0
    assert rec.keypoints[0].shape[1] == 2 and rec.keypoints[0][..., 0][seen].min() < -40  # two people here
    calibration = load_calibration(SINGLE / "calibration")
    assert len(align_views(rec, calibration)) == 2
    half = [CalibratedCamera(c.name, c.K * [[0.5], [0.5], [1]], c.dist, c.R, c.t, 544, 960) for c in calibration]
    with pytest.raises(
        ValueError, match=r"view 'cam02_json' has detections in u .*outside camera 'cam_02''s 544 x 960"
    ):
        align_views(rec, half)


def test_pose2sim_010_halpe26_and_frame_rate_auto_from_the_videos_header(tmp_path):
    """Pose2Sim >= 0.9: pose_model = 'Body_with_feet' (RTMPose's HALPE_26, written as
    pose/cam01_json/cam01_000000.json), frame_rate = 'auto' (the videos' rate)."""
    root = shutil.copytree(CURRENT, tmp_path / "Demo_SinglePerson")
    shutil.copytree(SINGLE / "calibration", root / "calibration")
    halpe = _rewritten(read_openpose(SINGLE / "pose", "body25b"), HALPE26_NAMES, "halpe26")
    for view, kp in zip(halpe.views, halpe.keypoints):
        for frame, people in zip(halpe.frames, kp):
            rows = [{"person_id": [-1], "pose_keypoints_2d": p.ravel().tolist()} for p in people if p[:, 2].any()]
            _write(root / "pose", {f"{view}/{view[:5]}_{frame:06d}.json": json.dumps({"people": rows})})
    p = read_project(root)
    assert (p.config.pose_model, p.config.layout) == ("Body_with_feet", "halpe26")
    assert (p.config.fps, p.config.fps_from) == (60.0, root / "videos" / "cam01.mp4")
    rec = read_openpose(p.keypoints, None)
    assert rec.layout == "halpe26" and rec.views == CAMS and rec.frames.tolist() == list(range(6))
    subject, P = _subject(rec, load_calibration(p.calibration))
    assert (
        check_layout(subject, P, default_body("low"), 26, "halpe26").verdict == "unchecked"
    )  # the one 26-point layout
    # 'auto' without a readable video: not known (the command then warns and assumes 30, Pose2Sim's fallback)
    (root / "videos" / "cam01.mp4").write_bytes(b"not a video")
    assert read_config(root).fps is None and read_config(root).fps_from is None


# ------------------------------------------------------------------------------- naming


@pytest.mark.parametrize("name", [
    "{cam}_{frame:012d}_keypoints.json",  # OpenPose's own
    "{cam}_{frame:06d}.json",  # Pose2Sim >= 0.9 / RTMLib
    "{cam}.{frame:04d}.json",  # the demo's
    "frame_{frame:05d}.json",
    "{frame}.json",
])  # fmt: skip
def test_every_naming_of_the_demo_frames_reads_the_same(tmp_path, name):
    reference = read_openpose(SINGLE / "pose", "body25b")
    rec = read_openpose(_write(tmp_path, _frames(name)), "body25b")
    assert rec.views == CAMS and rec.frames.tolist() == reference.frames.tolist() and rec.ignored == ()
    for a, b in zip(rec.keypoints, reference.keypoints):
        np.testing.assert_array_equal(a, b)


def test_one_folder_holding_every_cameras_files_is_split_by_their_names(tmp_path):
    # OpenPose run on each video with one --write_json folder
    files = _frames("{cam}_{frame:012d}_keypoints.json", folder="all")
    files["all/desktop_000000000000_keypoints.json"] = '{"people": []}'  # one stray
    rec = read_openpose(_write(tmp_path, files) / "all", None)
    assert rec.views == ("cam01", "cam02", "cam03", "cam04") and rec.frames.tolist() == list(range(6))
    assert rec.ignored == ("desktop_000000000000_keypoints.json",)
    assert [c.name for c in align_views(rec, load_calibration(SINGLE / "calibration"))][0] == "cam_01"
    assert read_openpose(tmp_path / "all", None, views=["cam03"]).views == ("cam03",)
    (tmp_path / "all").rename(tmp_path / "pose")  # so in a project
    shutil.copytree(SINGLE / "calibration", tmp_path / "calibration")
    assert read_project(tmp_path).keypoints == tmp_path / "pose"
    with pytest.raises(KeypointFileError, match=r"pose/cam05: missing camera folder; cameras present in .*'cam04'"):
        read_openpose(tmp_path / "pose", None, views=["cam05"])


def test_a_camera_folder_named_two_ways_as_often_is_refused(tmp_path):
    files = {k: v for k, v in _frames().items() if k.startswith("cam01_json")}
    files.update({k.replace("cam01.", "cam02."): v for k, v in files.items()})  # another camera's copies
    with pytest.raises(
        KeypointFileError,
        match=r"cam01_json: frame files named in two ways, 6 like 'cam01\.0000\.json' "
        r"and 6 like 'cam02\.0000\.json'; a camera folder holds one camera",
    ):
        read_openpose(_write(tmp_path, files), None)


# ------------------------------------------------------------------- frames and cameras


def test_frames_are_matched_by_number_across_cameras_and_gaps_stay_gaps(tmp_path):
    files = _frames()
    del files["cam02_json/cam02.0002.json"]  # one camera misses a frame
    for n in range(1, 5):
        del files[f"cam{n:02d}_json/cam{n:02d}.0004.json"]  # every camera misses frame 4
    rec = read_openpose(_write(tmp_path, files), "body25b")
    assert rec.frames.tolist() == [0, 1, 2, 3, 5]  # frame 5 stays frame 5: `_complete_frames` refills 4
    assert rec.present[1].tolist() == [True, True, False, True, True]
    assert not rec.keypoints[1][2].any() and rec.keypoints[0][2].any()
    reference = read_openpose(SINGLE / "pose", "body25b")
    np.testing.assert_array_equal(rec.keypoints[2][4], reference.keypoints[2][5])
    from jaxmocap.app.multiview import _complete_frames

    full = _complete_frames(rec)
    assert full.frames.tolist() == list(range(6)) and not any(p[4] for p in full.present)


def test_a_camera_whose_frame_numbers_overlap_no_other_is_named(tmp_path):
    files = {k.replace("cam04.00", "cam04.01"): v for k, v in _frames().items()}  # cam04 numbered 100..105
    root = _write(tmp_path, files)
    with pytest.raises(
        KeypointFileError,
        match=r"camera folder 'cam04_json' shares no frame number with the other "
        r"cameras \(frame numbers: cam01_json 0..5, .*cam04_json 100..105\)",
    ):
        read_openpose(root, None)
    assert read_openpose(root, None, views=CAMS[:3]).views == CAMS[:3]  # or leave it out


# ----------------------------------------------------------------------------- layout


def _rewritten(rec, names, layout):
    """The demo's BODY_25B detections rewritten in another layout, as its files would hold
    them (neck and mid-hip: OpenPose's means of the shoulders and hips, where both are seen)."""
    out = []
    for kp in rec.keypoints:
        new = np.zeros((*kp.shape[:2], len(names), 3))
        for k, name in enumerate(names):
            if name in BODY25B_NAMES:
                new[..., k, :] = kp[..., BODY25B_NAMES.index(name), :]
            else:
                a, b = ("left_shoulder", "right_shoulder") if name == "neck" else ("left_hip", "right_hip")
                pa, pb = kp[..., BODY25B_NAMES.index(a), :], kp[..., BODY25B_NAMES.index(b), :]
                both = (pa[..., 2] > 0) & (pb[..., 2] > 0)
                new[..., k, :] = np.where(both[..., None], 0.5 * (pa + pb), 0.0)
        out.append(new)
    return rec.__class__(rec.views, layout, rec.frames, tuple(out), rec.present)


def _as_body25(rec):
    return _rewritten(rec, BODY25_NAMES, "body25")


def test_the_layout_is_told_from_the_real_skeleton_both_ways(body):
    rec = read_openpose(SINGLE / "pose", None)
    calibration = load_calibration(SINGLE / "calibration")
    subject, P = _subject(rec, calibration)
    check = check_layout(subject, P, body, 25)
    assert (check.layout, check.verdict) == ("body25b", "detected")
    assert check.scores["body25"] > 3 * check.scores["body25b"], check.scores  # measured: 0.49 vs 0.08
    assert check_layout(subject, P, body, 25, "body25b", "Config.toml").verdict == "confirmed"
    with pytest.raises(ValueError, match=r"--layout says the keypoints are body25, but.*pass --layout body25b"):
        check_layout(subject, P, body, 25, "body25", "--layout")
    # the other way: the same people written as BODY_25
    subject25, _ = _subject(_as_body25(rec), calibration)
    check = check_layout(subject25, P, body, 25)
    assert (check.layout, check.verdict) == ("body25", "detected"), check.scores
    assert check.scores["body25b"] > 3 * check.scores["body25"], check.scores
    with pytest.raises(
        ValueError,
        match=r"Config\.toml \(pose_model = 'BODY_25B'\) says the keypoints are body25b.*"
        r"pass --layout body25 or correct",
    ):
        check_layout(subject25, P, body, 25, "body25b", "Config.toml (pose_model = 'BODY_25B')")


# --------------------------------------------------------------------- the command


def _run(args, capsys):
    code = main(["multiview", *map(str, args)])
    return code, capsys.readouterr()


def test_bad_inputs_stop_the_command_before_any_fit(tmp_path, capsys):
    root = shutil.copytree(SINGLE, tmp_path / "S01")
    (tmp_path / "file").write_text("")
    code, io = _run([root, "--out", tmp_path / "file"], capsys)
    assert code == 2 and "--out) '" in io.err and "is a file, not a folder" in io.err and io.out == ""
    code, io = _run([root, "--out", tmp_path / "file" / "sub"], capsys)
    assert code == 2 and "cannot be created" in io.err and io.out == ""
    # named BODY_25 against BODY_25B detections: refused once read, nothing written
    code, io = _run([root, "--out", tmp_path / "o", "--layout", "body25"], capsys)
    assert code == 2 and "--layout says the keypoints are body25" in io.err and not (tmp_path / "o").exists()
    assert "read     4 cameras: cam01_json 6 frames (0..5)" in io.out
    assert "warning: not read, named unlike the other frames of their camera: cam03_json/del_000000_0.json" in io.err
    # a calibration without one of the cameras
    text = (root / "calibration" / "Calib.qca.txt").read_text()
    start = text.rindex("<camera ", 0, text.index('serial="cam_04"'))
    (root / "calibration" / "Calib.qca.txt").write_text(text[:start] + text[text.index("</camera>", start) + 9 :])
    code, io = _run([root, "--out", tmp_path / "o"], capsys)
    assert code == 2 and "'cam04_json' (no camera)" in io.err and not (tmp_path / "o").exists()
    # a Config.toml frame_rate that is no rate
    config = root / "Config.toml"
    config.write_text(config.read_text().replace("frame_rate = 60", "frame_rate = 0"))
    code, io = _run([root, "--out", tmp_path / "o"], capsys)
    assert code == 2 and "Config.toml: [project] frame_rate must be a positive number" in io.err


class _FitStarted(Exception):
    pass


def test_the_demo_project_needs_no_flags(tmp_path, capsys, monkeypatch):
    """Everything the fit needs comes from the folder; stopped where the fit begins (the
    fit itself: test_multiview_cli)."""
    import jaxmocap.methods.multiview as muvs

    def started(*args, **kwargs):
        raise _FitStarted

    monkeypatch.setattr(muvs, "camera_data", started)
    root = shutil.copytree(SINGLE, tmp_path / "S01")
    with pytest.raises(_FitStarted):
        main(["multiview", str(root)])
    out = capsys.readouterr().out
    assert f"fps      60, from {root / 'Config.toml'} (frame_rate)" in out
    assert f"layout   body25b (from {root / 'Config.toml'} (pose_model = 'BODY_25B'); confirmed by the skeleton" in out
    assert not (root / "multiview").exists()  # the default --out: nothing written before the fit
    # --fps against the project's frame_rate: the given one, said
    with pytest.raises(_FitStarted):
        main(["multiview", str(root), "--fps", "50"])
    assert "warning: fps 50 as given, but " in capsys.readouterr().err


def test_a_camera_that_never_sees_the_subject_is_named():
    from jaxmocap.app.multiview import _blind_view_warning

    kp = np.zeros((4, 3, 25, 3))
    kp[:, :2, :, 2] = 0.8
    assert _blind_view_warning(kp, ("a", "b", "c")) == (
        "warning: camera folder 'c' never shows the subject the other cameras agree on (no one detected, another "
        "person, or a wrong camera in the calibration); fitted without them.")  # fmt: skip
    assert "camera folders 'b', 'c' never show the" in _blind_view_warning(kp[:, [0, 2, 2]], ("a", "b", "c"))
    kp[:, 2, 0, 2] = 0.5
    assert _blind_view_warning(kp, ("a", "b", "c")) is None
