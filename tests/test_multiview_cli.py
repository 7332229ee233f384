"""`jaxmocap multiview` end to end on a recording written in the real file layouts (issue 17).

The fixture is what a lab would hand over: four Qualisys cameras (z-up world, mm, 1/64-px
intrinsics, mild distortion) in a `.qca.txt`, and OpenPose BODY_25B JSON folders named as
Pose2Sim names them (cam01_json, ...), with a second person in two views and one frame in
which a camera sees no one. The keypoints are the default body's BODY_25B keypoints of a
walk, projected through the lens distortion.
"""

import dataclasses
import json

import matplotlib.image
import numpy as np
import pytest
import trimesh

from jaxmocap.body.io import default_body
from jaxmocap.cli import main
from jaxmocap.formats import CalibratedCamera, save_calibration, write_openpose
from jaxmocap.geometry.camera import project_points, ring_cameras
from jaxmocap.geometry.keypoints import keypoint_regressor, regress_keypoints
from jaxmocap.methods.multiview import PRESETS, STATURE_CV
from jaxmocap.motion.amass import Z_UP_TO_Y_UP, load_amass
from jaxmocap.motion.library import walk
from jaxmocap.body import posed_vertices

# 16 frames and the demo's focal lengths (1000 + 30 px per camera): σ₁ in pixels follows the
# mean focal length, so stage 1 here is the compiled program of the demo's 16-frame fit.
W, H, T, FPS = 1280, 720, 16, 30.0
EMPTY = (3, 4)  # (view, frame): camera 4 sees no one in frame 4


def _cameras():
    """Four cameras on a 4.5 m ring around the walk, in a z-up world (Qualisys's)."""
    R, t = ring_cameras(4, 4.5, 1.6, [0.0, 0.9, 0.2], start_angle=0.4)  # y-up world
    # the same rig in z-up coordinates: x_y = Z x_z, so R_z = R Z
    rng = np.random.default_rng(0)
    cams = []
    for v in range(4):
        f = 1000.0 + 30.0 * v  # as the demo's cameras (see T)
        K = [[f, 0.0, W / 2 - 4.0 + 3 * v], [0.0, f, H / 2 + 2.0 - 2 * v], [0.0, 0.0, 1.0]]
        dist = [-0.12 + 0.02 * v, 0.04, 2e-4 * rng.normal(), 2e-4 * rng.normal(), -0.005]
        cams.append(CalibratedCamera(f"cam{v + 1:02d}", K, dist, R[v] @ Z_UP_TO_Y_UP, t[v], W, H))
    return cams


def _detections(cam, points_z, conf, rng):
    """OpenPose rows (K, 3) of world points (K, 3): distorted pixels, off-image points missed."""
    uv, z = project_points(cam.K, cam.dist, cam.R, cam.t, points_z)
    uv = uv + rng.normal(scale=0.3, size=uv.shape)
    inside = (z > 0) & (uv >= -0.5).all(-1) & (uv[:, 0] < W - 0.5) & (uv[:, 1] < H - 0.5)
    rows = np.concatenate([uv, np.full((len(uv), 1), conf)], -1)
    return np.where(inside[:, None], rows, 0.0)


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """(root, truth joints (T, 24, 3) y up, cameras) of a written recording."""
    root = tmp_path_factory.mktemp("lab")
    body = default_body("low")
    motion = walk(T, fps=FPS, body=body)
    verts, joints = posed_vertices(body, motion)
    reg = keypoint_regressor(body, "body25b")
    subject = regress_keypoints(reg, verts.astype(np.float64), joints.astype(np.float64)) @ Z_UP_TO_Y_UP  # z-up world
    other = subject[0] + np.array([1.3, -1.2, 0.0])  # a second person standing to the side
    cams = _cameras()
    rng = np.random.default_rng(1)
    people = np.zeros((4, T, 2, 25, 3))
    for v, cam in enumerate(cams):
        for t in range(T):
            if (v, t) == EMPTY:
                continue  # "people": []
            people[v, t, 0] = _detections(cam, subject[t], 0.85, rng)
            if v in (0, 2):  # the bystander comes first in these views
                people[v, t] = people[v, t, ::-1]
                people[v, t, 0] = _detections(cam, other, 0.7, rng)
    write_openpose(root / "pose", [f"{c.name}_json" for c in cams], list(people), "body25b")
    save_calibration(root / "Calib.qca.txt", cams, "qualisys")
    return root, joints.astype(np.float64), cams


def _run(args, capsys):
    code = main(["multiview", *map(str, args)])
    return code, capsys.readouterr()


def test_multiview_fits_a_body25b_qualisys_recording_end_to_end(recording, tmp_path, capsys):
    root, truth, _ = recording
    out = tmp_path / "out"
    code, io = _run(["--keypoints", root / "pose", "--calib", root / "Calib.qca.txt", "--out", out,
                     "--layout", "body25b", "--fps", FPS, "--floor", 0], capsys)  # fmt: skip
    assert code == 0, io.err
    assert "reproj   median" in io.out
    assert "note: --floor 0 is not used: 4 cameras see the person" in io.out  # depth is triangulated
    report = json.loads((out / "report.json").read_text())
    assert report["floor"] == {"height_m": 0.0, "used": False}
    final = report["reprojection"]["final"]
    assert final["overall"]["median_px"] < 10.0, final["overall"]
    assert all(s["median_px"] < 15.0 for s in final["per_view"].values()), final["per_view"]
    assert report["frames"]["count"] == T and report["frames"]["without_subject"] == []
    assert report["views"]["cam04_json"]["frames_with_subject"] == T - 1  # the empty frame
    assert report["views"]["cam01_json"]["frames_with_subject"] == T  # bystander not chosen
    assert report["world_up"] == "+z"
    assert set(report["timings_s"]) >= {"read", "select person", "stage 1", "stage 2", "write", "total"}
    jitter = report["jitter_mm_s2"]
    assert np.isfinite([jitter["stage1"], jitter["final"]]).all()
    assert jitter["final"] < 1.1 * jitter["stage1"], jitter  # stage 2 smooths, even on 16 frames
    assert "| cam04_json |" in (out / "report.md").read_text()

    with np.load(out / "smpl.npz") as f:
        assert f["poses"].shape == (T, 72) and f["trans"].shape == (T, 3) and f["betas"].shape == (16,)
        assert all(np.isfinite(f[k]).all() for k in ("poses", "trans", "betas"))
        assert float(f["mocap_framerate"]) == FPS and str(f["gender"]) == "neutral"
    # read back as AMASS (z up → y up): the fitted joints are where the walk's were
    body = default_body("low")
    motion = load_amass(out / "smpl.npz", body=body)
    _, joints = posed_vertices(body, motion)
    mpjpe = np.linalg.norm(joints - truth, axis=-1).mean()
    assert mpjpe < 0.05, f"MPJPE {1000 * mpjpe:.0f} mm after the AMASS round trip"

    for path in report["outputs"]["overlays"]:
        image = matplotlib.image.imread(out / path)
        assert image.ndim == 3 and min(image.shape[:2]) > 200
    meshes = [out / p for p in report["outputs"]["meshes"]]
    assert sum(p.suffix == ".ply" for p in meshes) == T and any(p.suffix == ".glb" for p in meshes)
    mesh = trimesh.load(meshes[0], process=False)
    assert mesh.vertices.shape == (body.num_vertices, 3) and np.isfinite(mesh.vertices).all()
    assert np.ptp(mesh.vertices[:, 1]) > 1.2  # written y up: the body's height is along y


def test_camera_names_that_match_no_keypoint_folder_are_listed(recording, tmp_path, capsys):
    root, _, cams = recording
    renamed = [CalibratedCamera(f"Miqus_{'ABCD'[i]}", c.K, c.dist, c.R, c.t, W, H) for i, c in enumerate(cams)]
    save_calibration(tmp_path / "other.qca.txt", renamed, "qualisys")
    code, io = _run(["--keypoints", root / "pose", "--calib", tmp_path / "other.qca.txt", "--out", tmp_path / "o",
                     "--layout", "body25b"], capsys)  # fmt: skip
    assert code == 2
    assert io.err.startswith("jaxmocap multiview: error: align_views:") and io.err.count("\n") == 1
    assert "cam01_json" in io.err and "Miqus_A" in io.err
    # the calibration of another video mode: detections fall outside the image it gives
    small = [CalibratedCamera(c.name, np.diag([0.5, 0.5, 1.0]) @ c.K, c.dist, c.R, c.t, W // 2, H // 2) for c in cams]
    save_calibration(tmp_path / "small.qca.txt", small, "qualisys")
    code, io = _run(["--keypoints", root / "pose", "--calib", tmp_path / "small.qca.txt", "--out", tmp_path / "o",
                     "--layout", "body25b"], capsys)  # fmt: skip
    assert code == 2 and "outside camera 'cam01'" in io.err and "640 x 360 image" in io.err
    code, io = _run(["--keypoints", root / "pose", "--calib", root / "Calib.qca.txt", "--out", tmp_path / "o",
                     "--layout", "coco18"], capsys)  # fmt: skip
    assert code == 2 and "75 numbers" in io.err and "'body25' or 'body25b'" in io.err
    assert not (tmp_path / "o").exists()


def test_missing_keypoint_folders_and_empty_frame_ranges_are_named(recording, tmp_path, capsys):
    root, _, _ = recording
    calib = root / "Calib.qca.txt"
    code, io = _run(["--keypoints", tmp_path / "nope", "--calib", calib, "--out", tmp_path / "o"], capsys)
    assert code == 2 and str(tmp_path / "nope") in io.err and "no such folder" in io.err
    code, io = _run(["--keypoints", root / "pose", "--calib", calib, "--out", tmp_path / "o",
                     "--views", "cam01_json,cam09_json", "--layout", "body25b"], capsys)  # fmt: skip
    assert code == 2 and "cam09_json: missing camera folder" in io.err
    code, io = _run(["--keypoints", root / "pose", "--calib", calib, "--out", tmp_path / "o",
                     "--frames", "100:200", "--layout", "body25b"], capsys)  # fmt: skip
    assert code == 2 and "frames 100:200 selects no frame" in io.err and "0..15" in io.err
    with pytest.raises(SystemExit):
        main(["multiview", "--keypoints", str(root), "--calib", str(calib), "--out", "o", "--frames", "7"])
    assert "START:STOP" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()  # nothing written before the inputs are checked


def test_masks_are_undistorted_onto_the_fit_pixels_and_bad_ones_are_named(tmp_path):
    from PIL import Image

    from jaxmocap.app.multiview import read_masks
    from jaxmocap.geometry.camera import undistort_pixels

    cam = _cameras()[0]
    centre, radius = np.array([150.0, 120.0]), 40.0  # near a corner: the lens moves it ~10 px
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    video = np.linalg.norm(undistort_pixels(np.stack([u, v], -1), cam.K, cam.dist) - centre, axis=-1) < radius
    folder = tmp_path / "masks" / "cam01_json"
    folder.mkdir(parents=True)
    Image.fromarray(np.uint8(255 * video)).save(folder / "cam01_json_000000000003.png")
    rgba = np.zeros((H, W, 4), np.uint8)
    rgba[..., 3] = 255 * video  # a transparent background counts as "no person"
    Image.fromarray(rgba).save(folder / "cam01_json_000000000005.png")

    masks = read_masks(tmp_path / "masks", ["cam01_json"], [3, 4, 5], [cam])
    assert masks.shape == (3, 1, H, W) and not masks[1].any()  # frame 4 has no file
    disk = np.linalg.norm(np.stack([u, v], -1) - centre, axis=-1) < radius
    for m in (masks[0, 0], masks[2, 0]):
        assert (m & disk).sum() / (m | disk).sum() > 0.95
    assert (video & disk).sum() / (video | disk).sum() < 0.8  # so undistortion mattered

    Image.fromarray(np.zeros((H // 2, W // 2), np.uint8)).save(folder / "cam01_json_000000000006.png")
    with pytest.raises(
        ValueError, match=r"000000000006\.png: mask is 640 x 360 px but camera 'cam01' records 1280 x 720"
    ):
        read_masks(tmp_path / "masks", ["cam01_json"], [6], [cam])
    with pytest.raises(ValueError, match=r"cam02_json: missing mask folder.*\['cam01_json'\]"):
        read_masks(tmp_path / "masks", ["cam02_json"], [3], [cam])
    with pytest.raises(ValueError, match=r"need 1\d\.\d GiB.*--frames"):
        read_masks(tmp_path / "masks", ["cam01_json"], range(5000), [cam])


def test_frame_ranges_are_frame_numbers_and_unseen_frames_start_from_their_neighbours():
    from jaxmocap.app.multiview import _fill_empty_frames, _frame_filter, jitter

    frames = np.array([10, 11, 12, 14, 15])
    assert _frame_filter(frames, None).tolist() == [0, 1, 2, 3, 4]
    assert _frame_filter(frames, slice(11, 15)).tolist() == [1, 2, 3]
    assert _frame_filter(frames, slice(None, None, 2)).tolist() == [0, 2, 3]  # 10, 12, 14
    with pytest.raises(ValueError, match="frames 20:30 selects no frame.*10..15"):
        _frame_filter(frames, slice(20, 30))
    params = {"trans": np.arange(5.0)[:, None] * [1.0, 0.0, 0.0], "pose": np.full((5, 24, 3), np.nan)}
    params["pose"][[0, 3]] = 0.0
    filled = _fill_empty_frames(params, np.array([False, True, True, False, True]))
    assert filled["trans"][:, 0].tolist() == [0.0, 0.0, 3.0, 3.0, 3.0] and not np.isnan(filled["pose"]).any()
    assert jitter(np.zeros((2, 24, 3)), 30.0) != jitter(np.zeros((2, 24, 3)), 30.0)  # NaN below 3 frames
    line = np.linspace(0.0, 1.0, 10)[:, None, None] * np.ones((1, 24, 3))
    assert jitter(line, 30.0) == pytest.approx(0.0, abs=1e-9)  # uniform motion has no jitter


# ------------------------------------------------------------- issue 47: a lab's folders in


def test_inputs_are_checked_before_any_fit(recording, tmp_path, capsys):
    root, _, _ = recording
    calib = root / "Calib.qca.txt"
    (tmp_path / "file").write_text("")
    code, io = _run(["--keypoints", root / "pose", "--calib", calib, "--out", tmp_path / "file"], capsys)
    assert code == 2 and "file' is a file, not a folder" in io.err and io.out == ""
    code, io = _run(["--keypoints", root / "pose", "--calib", calib, "--out", tmp_path / "file" / "sub"], capsys)
    assert code == 2 and "cannot be created" in io.err
    code, io = _run([], capsys)
    assert code == 2 and "missing --keypoints DIR, --calib FILE, --out DIR" in io.err
    # BODY_25B detections named BODY_25: refused after reading, before fitting
    code, io = _run(["--keypoints", root / "pose", "--calib", calib, "--out", tmp_path / "o", "--layout", "body25"],
                    capsys)  # fmt: skip
    assert code == 2 and "--layout says the keypoints are body25" in io.err and "--layout body25b" in io.err
    assert "read     4 cameras: cam01_json 16 frames (0..15)" in io.out
    assert "warning: the frame rate is not known" in io.err  # no --fps, no Config.toml
    assert not (tmp_path / "o").exists()


def test_frame_numbers_missing_in_every_camera_become_empty_frames():
    from jaxmocap.app.multiview import _complete_frames
    from jaxmocap.formats import KeypointRecording

    kp = np.ones((4, 1, 25, 3))
    rec = KeypointRecording(("a",), "body25", np.array([2, 4, 8, 10]), (kp,), (np.ones(4, bool),))
    full = _complete_frames(rec)
    assert full.frames.tolist() == [2, 4, 6, 8, 10]  # every 2nd frame written: step 2
    assert full.present[0].tolist() == [True, True, False, True, True] and not full.keypoints[0][2].any()
    np.testing.assert_array_equal(full.keypoints[0][[0, 1, 3, 4]], kp)
    with pytest.raises(ValueError, match="frame numbers jump from 10 to 9000.*--frames"):
        _complete_frames(KeypointRecording(("a",), "body25", np.array([1, 2, 10, 9000]), (kp,)))


@pytest.fixture(scope="module")
def demo_recording(tmp_path_factory):
    from jaxmocap.app.multiview_demo import write_demo_recording

    root = tmp_path_factory.mktemp("demo") / "recording"
    return root, write_demo_recording(root, frames=6)


def test_the_demo_recording_is_a_pose2sim_project_in_camnn_ffff_naming(demo_recording):
    from jaxmocap.formats import read_openpose, read_project

    root, truth = demo_recording
    assert (root / "pose" / "cam01_json" / "cam01.0001.json").is_file()
    assert not (root / "pose" / "cam04_json" / "cam04.0004.json").exists() and truth["dropped"] == (3, 4)
    project = read_project(root)
    assert (project.config.layout, project.config.fps) == ("body25b", 60.0)
    rec = read_openpose(project.keypoints, None)
    assert rec.frames.tolist() == [1, 2, 3, 4, 5, 6] and rec.present[3].tolist() == [1, 1, 1, 0, 1, 1]


def test_one_camera_says_depth_is_unobserved_and_how_uncertain_it_is(demo_recording, tmp_path, capsys):
    root, _ = demo_recording
    code, io = _run([root, "--views", "cam01_json", "--no-temporal", "--out", tmp_path / "mono"], capsys)
    assert code == 0, io.err
    assert "fps      60, from" in io.out and "layout   body25b (from" in io.out  # Config.toml, no flags
    assert "warning: one camera (cam01): depth along its line of sight is not observed" in io.err
    report = json.loads((tmp_path / "mono" / "report.json").read_text())
    assert report["monocular"] is True and report["frames"]["fps"] == 60.0
    assert (
        report["weights"]["pose_prior"] == PRESETS["validated"].pose_prior != PRESETS["thesis"].pose_prior
    )  # the default
    depth = report["depth"]
    assert (
        3.0 < depth["depth_m"] < 6.0 and 0.04 * depth["depth_m"] < depth["depth_uncertainty_m"] < 0.2 * depth["depth_m"]
    )
    # the method's record (`MuVSResult.depth`): the body's size, the detections' scale error
    # and the frames' depth scatter; no floor is given to the fit, so nothing was rescaled
    assert depth["camera"] == "cam01" and depth["view"] == 0 and depth["scale"] == 1.0 and depth["ground"] is None
    size = depth["size"]
    assert depth["relative"] == pytest.approx(size["relative"], rel=0.5) and size["frame_scatter_m"] >= 0
    assert depth["relative"] >= STATURE_CV and size["body_extent_px"] > 0 and size["reprojection_px"] > 0
    assert depth["depth_uncertainty_m"] == pytest.approx(depth["depth_m"] * depth["relative"])
    assert abs(depth["floor"]["ratio"] - 1) < 0.1, depth  # the demo's body is the mean body, on the floor
    assert (
        "- warning: one camera (cam01): depth along its line of sight is not observed"
        in (tmp_path / "mono" / "report.md").read_text()
    )


def test_one_camera_stands_on_a_given_floor(demo_recording, tmp_path, capsys):
    root, _ = demo_recording
    code, io = _run([root, "--views", "cam01_json", "--no-temporal", "--floor", "nan", "--out", tmp_path / "x"], capsys)
    assert code != 0 and "floor must be a finite height" in io.err and not (tmp_path / "x").exists()
    code, io = _run([root, "--views", "cam01_json", "--no-temporal", "--floor", 0, "--out", tmp_path / "m"], capsys)
    assert code == 0, io.err
    report = json.loads((tmp_path / "m" / "report.json").read_text())
    assert report["monocular"] is True and report["floor"] == {"height_m": 0.0, "used": True}
    depth = report["depth"]
    # the ground's evidence entered the depth record (without a floor it is None); on these 6
    # frames the stages leave the body 10-11 % close and the ground's scale moves it back
    # (measured 1.097 before keypoints at joints were the posed joints, 1.110 after) ...
    assert depth["ground"] is not None and depth["ground"]["frames"] > 0 and 1.0 < depth["scale"] < 1.15
    # ... and the fitted feet meet the floor where the detected feet's rays cut it (the demo's
    # body is the mean body, standing on z = 0)
    assert abs(depth["floor"]["ratio"] - 1) < 0.05, depth["floor"]


def test_multiview_demo_writes_a_lab_recording_and_fits_it(tmp_path, capsys):
    code, io = _run(["demo", "--out", tmp_path / "demo", "--no-temporal", "--weights", "thesis"], capsys)
    assert code == 0, io.err
    for line in (
        "demo     writing a synthetic 4-camera recording",
        "cam04_json 15 frames (1..16)",
        "layout   body25b (from",
        "confirmed by the skeleton",
        "fps      60",
        "demo     MPJPE",
    ):
        assert line in io.out, (line, io.out)
    report = json.loads((tmp_path / "demo" / "fit" / "report.json").read_text())
    assert report["monocular"] is False and report["layout"] == "body25b" and report["frames"]["count"] == 16
    assert (report["weights"]["pose_prior"], report["weights"]["shape"]) == (
        20.0,
        50.0,
    )  # --weights thesis reached the fit
    assert report["reprojection"]["final"]["overall"]["median_px"] < 6.0
    assert (tmp_path / "demo" / "recording" / "Config.toml").is_file()
    assert (tmp_path / "demo" / "fit" / "smpl.npz").is_file()


def test_the_floor_gives_a_second_depth_from_the_standing_foot():
    from jaxmocap.app.multiview import ground_depth

    # z-up world, camera 1.6 m above the floor looking along +y (x right, y down = -z)
    R = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    cam = CalibratedCamera("c", [[1000.0, 0.0, 640.0], [0.0, 1000.0, 360.0], [0.0, 0.0, 1.0]], np.zeros(5), R,
                           -R @ [0.0, 0.0, 1.6], 1280, 720)  # fmt: skip
    names = ["left_ankle", "right_ankle", "nose"]
    world = np.array([[0.1, 4.0, 0.0], [-0.1, 3.0, 0.2], [0.0, 3.5, 1.6]])  # standing foot, lifted (nearer) foot
    uv, _ = project_points(cam.K, cam.dist, cam.R, cam.t, world)
    det = np.concatenate([uv, np.ones((3, 1))], -1)[None]
    floor = ground_depth(cam, det, world[None], names, "+z")
    # the lifted foot's ray meets the floor at 3.0 * 1.6 / 1.4 = 3.43 m, nearer than 4 m but behind that foot
    assert floor == pytest.approx({"ground_depth_m": 4.0, "fitted_depth_m": 4.0, "ratio": 1.0})
    assert ground_depth(cam, det, 1.1 * world[None], names, "+z")["ratio"] == pytest.approx(1 / 1.1)  # fit 10 % too far
    assert ground_depth(cam, det, world[None], names, "-z") is None  # the camera would be below that floor


def test_config_frame_range_selects_positions_before_any_fit(demo_recording, tmp_path, capsys):
    import shutil

    root = tmp_path / "trial"
    shutil.copytree(demo_recording[0], root)
    config = root / "Config.toml"
    config.write_text(config.read_text().replace("frame_range = 'all'", "frame_range = [10, 20]"))
    code, io = _run([root], capsys)  # no flags: the output would go to trial/multiview
    assert code == 2 and "Config.toml: frame_range = [10, 20] selects no frame; the recording has 6" in io.err
    assert not (root / "multiview").exists()
    shutil.rmtree(root / "calibration")
    code, io = _run([root, "--calib", demo_recording[0] / "calibration" / "Calib_demo.toml"], capsys)
    assert code == 2 and "selects no frame" in io.err  # the calibration given, not looked for


def test_frames_one_camera_sees_are_named_in_a_multi_camera_fit():
    from jaxmocap.app.multiview import _one_view_warning

    kp = np.zeros((6, 3, 25, 3))
    kp[:, :, :, 2] = 0.9
    kp[[1, 2, 4], 1:] = 0.0  # only camera 0 sees frames 11, 12, 14
    message = _one_view_warning(kp, np.arange(10, 16))
    assert message.startswith("warning: 3 of 6 frames have the subject in one camera only (frame numbers 11..12, 14)")
    assert _one_view_warning(kp[:, :1], np.arange(10, 16)) is None  # one camera: the monocular warning says it
    assert _one_view_warning(np.full((2, 2, 25, 3), 0.9), np.arange(2)) is None


def test_a_camera_sharing_few_frame_numbers_is_warned_about():
    from jaxmocap.app.multiview import _overlap_warnings
    from jaxmocap.formats import KeypointRecording

    frames = np.arange(0, 35)
    a = b = frames < 20
    c = frames >= 15  # numbered from another start: 5 of its 20 numbers shared by chance
    rec = KeypointRecording(("a", "b", "c"), "body25", frames, (np.zeros((35, 1, 25, 3)),) * 3, (a, b, c))
    assert _overlap_warnings(rec) == [
        "warning: camera folder 'c' shares only 5 of its 20 frame numbers with the other cameras; are the cameras "
        "synchronised and numbered alike?"
    ]
    assert _overlap_warnings(dataclasses.replace(rec, present=(a, b, frames >= 5))) == []  # 15 of 30 shared
