"""Pose2Sim-style project folders (issue 47, goal 1): where the pieces are, what Config.toml says.

The fixtures are written by hand in the layout of Pose2Sim's bundled Demo_SinglePerson and
Demo_Batch (pose2sim 0.10.49: Config.toml's [project] frame_rate / [pose] pose_model with
their comments, calibration/ beside the lab's Calib.qca.txt, pose/camNN_json/, trials
under a session); no file of Pose2Sim's is copied. Pure NumPy: no JAX compilation.
"""

import numpy as np
import pytest

from jaxmocap.formats import (
    KeypointFileError,
    ProjectError,
    load_calibration,
    read_config,
    read_openpose,
    read_project,
    write_openpose,
)
from jaxmocap.formats.project import POSE_MODELS

from test_formats import TOML  # two hand-checked Pose2Sim TOML cameras

# Pose2Sim's own lines, comments kept: tomllib must read them as Pose2Sim does.
CONFIG = """
[project]
multi_person = false # true for trials with multiple participants. If false, only the person with lowest reprojection error is analyzed
participant_height = 'auto' # 'auto', float (eg 1.72), or list of floats (eg [1.72, 1.40])  # meters
frame_rate = {rate} # fps # int or 'auto'. If 'auto', finds from video (or defaults to 60 fps if you work with images)
frame_range = 'auto' # 'auto', 'all', or range like [10,300].

[pose]
vid_img_extension = 'mp4'
pose_model = {model}  #With openpose: BODY_25B, BODY_25, BODY_135, COCO, MPII
mode = 'balanced'

[calibration]
calibration_type = 'convert' # 'convert' or 'calculate'
   [calibration.convert]
   convert_from = 'qualisys'
      [calibration.convert.qualisys]
      binning_factor = 1
"""


def _project(root, rate="60", model="'BODY_25B'", pose="pose"):
    root.mkdir(parents=True, exist_ok=True)
    (root / "Config.toml").write_text(CONFIG.format(rate=rate, model=model))
    write_openpose(root / pose, ["cam01_json", "cam02_json"], [np.zeros((2, 1, 25, 3))] * 2, "body25b",
                   name="{view}.{frame:04d}.json")  # fmt: skip
    (root / "calibration").mkdir(exist_ok=True)
    (root / "calibration" / "Calib_qualisys.toml").write_text(TOML)
    return root


def test_a_pose2sim_project_gives_keypoints_calibration_layout_and_frame_rate(tmp_path):
    root = _project(tmp_path / "Demo")
    (root / "calibration" / "Calib.qca.txt").write_text("<calibration/>")  # the file it was converted from
    (root / "videos").mkdir()
    (root / "pose" / "cam01_img").mkdir()  # Pose2Sim's rendered images: no JSON
    p = read_project(root)
    assert p.keypoints == root / "pose" and p.calibration == root / "calibration" / "Calib_qualisys.toml"
    assert [c.name for c in load_calibration(p.calibration)] == ["cam_a", "cam_b"]
    assert p.config.files == (root / "Config.toml",)
    assert (p.config.pose_model, p.config.layout, p.config.fps) == ("BODY_25B", "body25b", 60.0)
    assert read_config(root / "pose").fps == 60.0  # from the keypoint folder: its parent's Config.toml
    # synchronised keypoints are preferred, as Pose2Sim's triangulation does
    write_openpose(root / "pose-sync", ["cam01_json"], [np.zeros((1, 1, 25, 3))], "body25b")
    assert read_project(root).keypoints == root / "pose-sync"


@pytest.mark.parametrize("rate, model, fps, layout", [
    ("'auto'", "'body_25'", None, "body25"),  # any case; 'auto' = from the video: unknown here
    ("29.97", "'COCO'", 29.97, "coco18"),
    ("'auto'", "'Body_with_feet'", None, "halpe26"),  # Pose2Sim >= 0.9's default: RTMPose's HALPE_26
])  # fmt: skip
def test_config_values_map_to_layouts_and_rates(tmp_path, rate, model, fps, layout):
    root = _project(tmp_path / "p", rate=rate, model=model)
    config = read_config(root)
    assert (config.fps, config.layout) == (fps, layout)
    assert set(POSE_MODELS.values()) == {"body25", "body25b", "coco18", "halpe26", "mediapipe33"}
    assert config.frame_range is None  # 'auto': every frame


def test_frame_range_is_pose2sims_start_stop_positions(tmp_path):
    root = _project(tmp_path / "p")
    text = (root / "Config.toml").read_text()
    (root / "Config.toml").write_text(text.replace("frame_range = 'auto'", "frame_range = [10, 300]"))
    assert read_config(root).frame_range == (10, 300)
    for bad in ("[300, 10]", "[1, 2, 3]", "'some'"):
        (root / "Config.toml").write_text(text.replace("frame_range = 'auto'", f"frame_range = {bad}"))
        with pytest.raises(ProjectError, match=r"Config\.toml: \[project\] frame_range must be \[start, stop\]"):
            read_config(root)


def test_a_trial_reads_its_session_config_and_calibration(tmp_path):
    session = _project(tmp_path / "Demo_Batch", rate="30", model="'BODY_25'")
    trial = tmp_path / "Demo_Batch" / "Trial_1"
    write_openpose(trial / "pose", ["cam01_json"], [np.zeros((1, 1, 25, 3))], "body25b")
    (trial / "Config.toml").write_text("[project]\nframe_rate = 50\n")  # overrides the session's
    p = read_project(trial)
    assert p.calibration == session / "calibration" / "Calib_qualisys.toml"
    assert p.config.files == (session / "Config.toml", trial / "Config.toml")
    assert (p.config.fps, p.config.layout) == (50.0, "body25")  # pose_model from the session


def test_project_problems_name_the_file_and_the_fix(tmp_path):
    root = _project(tmp_path / "p", model="'Whole_body'")
    with pytest.raises(
        ProjectError,
        match=r"Config\.toml: pose_model = 'Whole_body' has no jaxmocap layout.*BODY_25B.*"
        r"pose_model = 'Body_with_feet'",
    ):
        _ = read_project(root).config.layout
    with pytest.raises(
        KeypointFileError, match=r"p: no camera folders.*/p/pose; or the project folder itself as `jaxmocap multiview "
    ):
        read_openpose(root, None)  # the project given where its keypoint folder belongs
    (root / "Config.toml").write_text(CONFIG.format(rate="-5", model="'BODY_25B'"))
    with pytest.raises(ProjectError, match=r"Config\.toml: \[project\] frame_rate must be a positive.*-5"):
        read_config(root)
    (root / "Config.toml").write_text("[project\nframe_rate = 60")
    with pytest.raises(ProjectError, match=r"Config\.toml: not valid TOML"):
        read_config(root)
    (root / "calibration" / "Calib_board.toml").write_text(TOML)
    with pytest.raises(
        ProjectError, match=r"several calibration files \['Calib_board\.toml', 'Calib_qualisys\.toml'\].*--calib"
    ):
        read_project(root)
    empty = tmp_path / "empty"
    (empty / "calibration").mkdir(parents=True)
    with pytest.raises(ProjectError, match=r"empty: no keypoints.*pose/.*--keypoints"):
        read_project(empty)
    write_openpose(empty / "pose", ["cam01_json"], [np.zeros((1, 1, 25, 3))], "body25b")
    (empty / "calibration").rmdir()
    with pytest.raises(ProjectError, match=r"empty: no calibration folder.*--calib"):
        read_project(empty)
    assert read_project(empty, need_calibration=False).calibration is None  # --calib given instead
    assert read_config(empty) == read_config(tmp_path / "nowhere")  # no Config.toml: nothing said
