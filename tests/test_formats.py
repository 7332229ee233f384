"""Real-format input (issue 17, item 4): calibrations, OpenPose JSON, lens model, triangulation.

Expected pixels of the hand-written fixtures are worked out by hand in the comments, so
each reader is checked against the format's documented meaning, not against our writer.
Pure NumPy: no JAX compilation.
"""

import json

import numpy as np
import pytest

from jaxmocap.formats import (
    CalibratedCamera,
    CalibrationError,
    KeypointFileError,
    align_views,
    load_calibration,
    normalise_view_name,
    read_openpose,
    save_calibration,
    write_openpose,
)
from jaxmocap.formats.openpose import KEYPOINT_COUNTS
from jaxmocap.geometry.camera import distort_points, project_points, ring_cameras, undistort_pixels
from jaxmocap.geometry.triangulation import projection_matrices, select_person, triangulate

FORMATS = ("pose2sim", "qualisys", "easymocap", "npz")
POINT = np.array([0.5, 0.25, 0.0])


def _pixel(cam, points):
    return project_points(cam.K, cam.dist, cam.R, cam.t, points)[0]


# ------------------------------------------------------------------ hand-written fixtures

# cam_a: R = I, t = (0, 0, 5): POINT -> p_c = (0.5, 0.25, 5), x = 0.1, y = 0.05, r² = 0.0125,
#   k1 = 0.1 -> factor 1.00125 -> (0.100125, 0.0500625) -> u = 640 + 100.125, v = 360 + 50.0625.
# cam_b: Rodrigues (0, π/2, 0) = R_y(90°) = [[0,0,1],[0,1,0],[-1,0,0]], t = (0, 0, 4):
#   p_c = (0, 0.25, -0.5 + 4) -> u = 640, v = 360 + 1000 · 0.25 / 3.5.
PIXEL_A = (740.125, 410.0625)
PIXEL_B = (640.0, 360.0 + 1000 * 0.25 / 3.5)
TOML = """
[cam_01]
name = "cam_a"
size = [ 1280.0, 720.0]
matrix = [ [ 1000.0, 0.0, 640.0], [ 0.0, 1000.0, 360.0], [ 0.0, 0.0, 1.0]]
distortions = [ 0.1, 0.0, 0.0, 0.0]
rotation = [ 0.0, 0.0, 0.0]
translation = [ 0.0, 0.0, 5.0]
fisheye = false

[cam_02]
name = "cam_b"
size = [ 1280.0, 720.0]
matrix = [ [ 1000.0, 0.0, 640.0], [ 0.0, 1000.0, 360.0], [ 0.0, 0.0, 1.0]]
distortions = [ 0.0, 0.0, 0.0, 0.0]
rotation = [ 0.0, 1.5707963267948966, 0.0]
translation = [ 0.0, 0.0, 4.0]
fisheye = false

[metadata]
adjusted = false
error = 0.0
"""

# Qualisys (world z up). Both cameras sit at (0, -5000, 1000) mm looking along +y: the
# Qualisys camera axes in world coordinates are x = (1, 0, 0), y (up) = (0, 0, 1),
# z (backwards) = (0, -1, 0): rows of r. QPOINT = (0.5, 0, 1.25) m is (0.5, 5, 0.25) from
# the centre: OpenCV x = 0.5, y (down) = -0.25, z = 5 -> (0.1, -0.05).
# Camera 11: focal 64000/64 = 1000 px, centre (61440, 34560)/64 = (960, 540), k1 = 0.1:
#   (0.100125, -0.0500625) -> (1060.125, 489.9375), image 1920 x 1080.
# Camera 12: video is the sensor window left 100, top 50, 1280 x 720 (centre 740 - 100 = 640,
#   410 - 50 = 360) recorded at 540p = half of 1080p: f = 500, c = (640.5 / 2 - 0.5,
#   360.5 / 2 - 0.5) = (319.75, 179.75), image 640 x 360; pixel (369.75, 154.75).
QPOINT = np.array([0.5, 0.0, 1.25])
QCA = """<?xml version='1.0' encoding='ASCII'?>
<calibration created="2024-01-01" qtm-version="2023.3" type="regular" wandLength="601.0">
  <results std-dev="0.3" min-max-diff="1.0"/>
  <cameras>
    <camera active="1" avg-residual="0.4" model="Miqus Video" point-count="999" serial="11" viewrotation="0" video_resolution="1080p">
      <fov_marker left="0" top="0" right="1919" bottom="1079"/>
      <fov_marker_max left="0" top="0" right="1919" bottom="1079"/>
      <fov_video left="0" top="0" right="1919" bottom="1079"/>
      <fov_video_max left="0" top="0" right="1919" bottom="1079"/>
      <transform x="0.0" y="-5000.0" z="1000.0" r11="1" r12="0" r13="0" r21="0" r22="0" r23="1" r31="0" r32="-1" r33="0"/>
      <intrinsic focallength="9.3" sensorMinU="0" sensorMaxU="122816" sensorMinV="0" sensorMaxV="69056" focalLengthU="64000" focalLengthV="64000" centerPointU="61440" centerPointV="34560" skew="0" radialDistortion1="0.1" radialDistortion2="0" radialDistortion3="0" tangentalDistortion1="0" tangentalDistortion2="0"/>
    </camera>
    <camera active="1" avg-residual="0.4" model="Miqus Video" point-count="999" serial="12" viewrotation="0" video_resolution="540p">
      <fov_video left="100" top="50" right="1379" bottom="769"/>
      <transform x="0.0" y="-5000.0" z="1000.0" r11="1" r12="0" r13="0" r21="0" r22="0" r23="1" r31="0" r32="-1" r33="0"/>
      <intrinsic focallength="9.3" sensorMinU="0" sensorMaxU="122816" sensorMinV="0" sensorMaxV="69056" focalLengthU="64000" focalLengthV="64000" centerPointU="47360" centerPointV="26240" skew="0" radialDistortion1="0" radialDistortion2="0" radialDistortion3="0" tangentalDistortion1="0" tangentalDistortion2="0"/>
    </camera>
  </cameras>
</calibration>
"""

# EasyMocap: the same camera as cam_a, as OpenCV's FileStorage writes it (data over two
# lines, scientific notation, unquoted and quoted names, CRLF line ends).
INTRI = """%YAML:1.0
---
names:
  - "cam_a"
  - cam_b
K_cam_a: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 1.0000000000000000e+03, 0., 6.4e+02, 0., 1000.,
       360., 0., 0., 1. ]
dist_cam_a: !!opencv-matrix
   rows: 1
   cols: 5
   dt: d
   data: [ 1.0000000000000001e-01, 0., 0., 0., 0. ]
H_cam_a: 720
W_cam_a: 1280
K_cam_b: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 1000., 0., 640., 0., 1000., 360., 0., 0., 1. ]
dist_cam_b: !!opencv-matrix
   rows: 5
   cols: 1
   dt: d
   data: [ 0., 0., 0., 0., 0. ]
""".replace("\n", "\r\n")
EXTRI = """%YAML:1.0
---
names:
  - "cam_a"
  - "cam_b"
R_cam_a: !!opencv-matrix
   rows: 3
   cols: 1
   dt: d
   data: [ 0., 0., 0. ]
T_cam_a: !!opencv-matrix
   rows: 3
   cols: 1
   dt: d
   data: [ 0., 0., 5. ]
R_cam_b: !!opencv-matrix
   rows: 3
   cols: 1
   dt: d
   data: [ 0., 1.5707963267948966, 0. ]
Rot_cam_b: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 0., 0., 1., 0., 1., 0., -1., 0., 0. ]
T_cam_b: !!opencv-matrix
   rows: 3
   cols: 1
   dt: d
   data: [ 0., 0., 4. ]
""".replace("\n", "\r\n")


def test_pose2sim_toml_fixture_projects_to_the_hand_computed_pixels(tmp_path):
    path = tmp_path / "Calib.toml"
    path.write_text(TOML)
    assert [c.name for c in load_calibration(tmp_path)] == ["cam_a", "cam_b"]  # its folder
    a, b = load_calibration(path)
    assert (a.name, b.name, a.width, a.height) == ("cam_a", "cam_b", 1280, 720)
    np.testing.assert_allclose(_pixel(a, POINT), PIXEL_A, atol=1e-9)
    np.testing.assert_allclose(_pixel(b, POINT), PIXEL_B, atol=1e-9)


def test_qualisys_fixture_honours_mm_transform_window_and_video_resolution(tmp_path):
    path = tmp_path / "Calib.qca.txt"
    path.write_text(QCA)
    c11, c12 = load_calibration(path)
    assert (c11.name, c11.width, c11.height) == ("11", 1920, 1080)
    assert (c12.name, c12.width, c12.height) == ("12", 640, 360)
    np.testing.assert_allclose(c11.center, [0.0, -5.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(_pixel(c11, QPOINT), (1060.125, 489.9375), atol=1e-9)
    np.testing.assert_allclose(_pixel(c12, QPOINT), (369.75, 154.75), atol=1e-9)


def test_easymocap_fixture_matches_and_either_file_or_folder_reads(tmp_path):
    (tmp_path / "intri.yml").write_bytes(INTRI.encode())
    (tmp_path / "extri.yml").write_bytes(EXTRI.encode())
    for path in (tmp_path, tmp_path / "intri.yml", tmp_path / "extri.yml"):
        a, b = load_calibration(path)
        assert (a.name, b.name, a.width, a.height, b.width) == ("cam_a", "cam_b", 1280, 720, 0)
        np.testing.assert_allclose(_pixel(a, POINT), PIXEL_A, atol=1e-9)
        np.testing.assert_allclose(_pixel(b, POINT), PIXEL_B, atol=1e-9)


def test_easymocap_names_that_look_like_numbers_stay_strings(tmp_path):
    cams = [CalibratedCamera(n, c.K, c.dist, c.R, c.t, 1280, 720) for n, c in zip(("01", "02"), _rig(2))]
    save_calibration(tmp_path, cams, "easymocap")
    for f in ("intri.yml", "extri.yml"):  # as OpenCV writes them: names unquoted
        text = (tmp_path / f).read_bytes().replace(b'- "01"', b"- 01").replace(b'- "02"', b"- 02")
        (tmp_path / f).write_bytes(text)
    assert [c.name for c in load_calibration(tmp_path)] == ["01", "02"]


def _rig(num_views=4, width=1280, height=720, seed=0):
    rng = np.random.default_rng(seed)
    R, t = ring_cameras(num_views, 4.0, 1.5, [0.3, 0.9, 0.2], start_angle=0.3)
    cams = []
    for v in range(num_views):
        f = 900 + 40 * v
        K = [[f, 0.0, width / 2 + 7 * v], [0.0, f * 1.01, height / 2 - 5 * v], [0.0, 0.0, 1.0]]
        dist = [-0.2 + 0.05 * v, 0.05, 1e-3 * rng.normal(), 1e-3 * rng.normal(), -0.01]
        cams.append(CalibratedCamera(f"cam{v + 1:02d}", K, dist, R[v], t[v], width, height))
    return cams


@pytest.mark.parametrize("fmt", FORMATS)
def test_every_writer_round_trips_through_its_reader(tmp_path, fmt):
    cams = _rig()
    points = np.random.default_rng(1).uniform([-0.5, 0.0, -0.5], [1.0, 1.8, 1.0], (50, 3))
    path = (
        tmp_path
        / {
            "pose2sim": "Calib.toml",
            "qualisys": "Calib.qca.txt",
            "easymocap": "calib",
            "npz": "c.npz",
        }[fmt]
    )
    save_calibration(path, cams, fmt)
    back = load_calibration(path)  # format inferred from the path
    assert [c.name for c in back] == [c.name for c in cams]
    for c, d in zip(cams, back):
        assert (d.width, d.height) == (c.width, c.height)
        np.testing.assert_allclose(_pixel(d, points), _pixel(c, points), atol=1e-7)
        np.testing.assert_allclose(d.dist, c.dist, atol=1e-15)


def test_hand_written_fixtures_survive_every_writer(tmp_path):
    (tmp_path / "Calib.toml").write_text(TOML)
    cams = load_calibration(tmp_path / "Calib.toml")
    names = {
        "pose2sim": "out/cal.toml",
        "qualisys": "out/cal.qca.txt",
        "easymocap": "em",
        "npz": "out/cal.npz",
    }
    (tmp_path / "out").mkdir()
    for fmt in FORMATS:
        save_calibration(tmp_path / names[fmt], cams, fmt)
        a, b = load_calibration(tmp_path / names[fmt], format=fmt)
        np.testing.assert_allclose(_pixel(a, POINT), PIXEL_A, atol=1e-9)
        np.testing.assert_allclose(_pixel(b, POINT), PIXEL_B, atol=1e-9)


def test_pinhole_camera_moves_opencv_pixels_to_jaxmocap_pixel_centres():
    from jaxmocap.geometry.camera import pinhole_camera, project

    cam = _rig(1)[0]
    pin = pinhole_camera(cam)
    X = np.array([[0.3, 1.0, 0.2], [0.5, 0.4, -0.1]])
    ideal = undistort_pixels(_pixel(cam, X), cam.K, cam.dist)  # OpenCV: centres at integers
    uv, _ = project(pin.K, pin.R, pin.t, X)
    np.testing.assert_allclose(np.asarray(uv), ideal + 0.5, atol=1e-9)
    assert (pin.width, pin.height) == (1280, 720)


# ---------------------------------------------------------------------------- lens model


def test_distortion_matches_the_opencv_formula():
    k1, k2, p1, p2, k3 = 0.1, -0.05, 0.002, -0.003, 0.01
    x, y = 0.3, -0.2
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
    expected = (
        x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
        y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y,
    )
    np.testing.assert_allclose(distort_points([x, y], [k1, k2, p1, p2, k3]), expected, rtol=1e-15)


@pytest.mark.parametrize("dist", [[-0.28, 0.09, 1e-3, -2e-3, -0.01], [0.12, -0.03, -1e-3, 1e-3, 0.0]])
def test_undistortion_inverts_distortion_to_1e6_px_over_the_image(dist):
    K = np.array([[1100.0, 0.0, 955.0], [0.0, 1105.0, 545.0], [0.0, 0.0, 1.0]])
    u, v = np.meshgrid(np.linspace(0, 1919, 97), np.linspace(0, 1079, 55))
    uv = np.stack([u, v], -1)
    ideal = undistort_pixels(uv, K, dist)
    assert np.isfinite(ideal).all()
    xy = (ideal - K[:2, 2]) / np.diag(K)[:2]
    again = distort_points(xy, dist) * np.diag(K)[:2] + K[:2, 2]
    assert np.abs(again - uv).max() < 1e-6
    # and the other way: ideal pixels -> distorted -> undistorted
    xy = (uv - K[:2, 2]) / np.diag(K)[:2] * 0.8
    distorted = distort_points(xy, dist) * np.diag(K)[:2] + K[:2, 2]
    np.testing.assert_allclose(undistort_pixels(distorted, K, dist), xy * np.diag(K)[:2] + K[:2, 2], atol=1e-6)


# ------------------------------------------------------------------------------ OpenPose


def _random_people(rng, T, P, K=25, width=1280, height=720):
    kp = np.zeros((T, P, K, 3))
    kp[..., 0] = rng.uniform(0, width - 1, (T, P, K))
    kp[..., 1] = rng.uniform(0, height - 1, (T, P, K))
    kp[..., 2] = rng.uniform(0.05, 1.0, (T, P, K)) * (rng.random((T, P, K)) > 0.1)
    kp[..., :2] *= kp[..., 2:] > 0  # undetected keypoints are (0, 0, 0), as OpenPose writes them
    return kp


def test_openpose_round_trip_with_several_people_empty_frames_and_a_missing_file(tmp_path):
    rng = np.random.default_rng(0)
    frames = np.array([10, 11, 12, 14, 15])
    kps = [_random_people(rng, 5, 3), _random_people(rng, 5, 2), _random_people(rng, 5, 1)]
    kps[0][1] = 0.0  # nobody in frame 11 of cam01
    kps[1][:, 1] = 0.0  # cam02 never sees a second person: one slot after reading
    views = ["cam01", "cam02", "cam03"]
    write_openpose(tmp_path, views, kps, "body25", frames=frames)
    text = json.loads((tmp_path / "cam01" / "cam01_000000000011_keypoints.json").read_text())
    assert text["people"] == [] and text["version"] == 1.3
    person = json.loads((tmp_path / "cam01" / "cam01_000000000010_keypoints.json").read_text())["people"][0]
    assert person["person_id"] == [-1] and len(person["pose_keypoints_2d"]) == 75
    assert person["face_keypoints_2d"] == [] and person["hand_left_keypoints_2d"] == []
    (tmp_path / "cam03" / "cam03_000000000014_keypoints.json").unlink()  # a dropped frame
    (tmp_path / "cam02" / "cam02_000000000016_keypoints.json").write_text(
        json.dumps({"version": 1.3, "people": []})
    )  # a frame only cam02 has
    rec = read_openpose(tmp_path, "body25")
    assert rec.views == ("cam01", "cam02", "cam03") and rec.layout == "body25"
    np.testing.assert_array_equal(rec.frames, [10, 11, 12, 14, 15, 16])
    assert [k.shape for k in rec.keypoints] == [(6, 3, 25, 3), (6, 1, 25, 3), (6, 1, 25, 3)]
    np.testing.assert_array_equal(rec.keypoints[0][:5], kps[0])
    np.testing.assert_array_equal(rec.keypoints[1][:5], kps[1][:, :1])
    assert not rec.keypoints[2][3].any() and not rec.keypoints[0][5].any()
    np.testing.assert_array_equal(rec.keypoints[2][[0, 1, 2, 4]], kps[2][[0, 1, 2, 4]])
    # views in a given order, natural sorting otherwise
    assert read_openpose(tmp_path, "body25", views=["cam03", "cam01"]).views == ("cam03", "cam01")


def test_layout_counts_and_body25b_order_match_the_sensor_layouts():
    from jaxmocap.geometry.keypoints import BODY25B_NAMES, KEYPOINT_FORMATS

    assert {k: len(v) for k, v in KEYPOINT_FORMATS.items()} == KEYPOINT_COUNTS
    assert BODY25B_NAMES[:5] == ("nose", "left_eye", "right_eye", "left_ear", "right_ear")
    assert BODY25B_NAMES[17:19] == ("upper_neck", "head_top") and BODY25B_NAMES[24] == "right_heel"


def test_body25b_extra_joints_sit_where_the_names_say():
    import jaxmocap
    from jaxmocap.geometry.keypoints import BODY25B_NAMES, rest_keypoints

    body = jaxmocap.default_body("low")
    rest = np.asarray(body.v_template, np.float64)
    kp = rest_keypoints(body, "body25b")
    y = {n: kp[i, 1] for i, n in enumerate(BODY25B_NAMES)}
    assert y["head_top"] == pytest.approx(rest[:, 1].max())  # the crown
    assert y["left_shoulder"] < y["upper_neck"] < y["nose"] < y["left_eye"] < y["head_top"]


# ------------------------------------------------------------------------- triangulation


def test_triangulation_from_four_views_is_exact():
    cams = _rig()
    rng = np.random.default_rng(2)
    X = rng.uniform([-0.5, 0.0, -0.5], [1.0, 1.8, 1.0], (7, 3))
    uv = np.stack([undistort_pixels(_pixel(c, X), c.K, c.dist) for c in cams])
    conf = rng.uniform(0.2, 1.0, (4, 7))
    conf[:, 6] = [0.9, 0, 0, 0]  # one view only: NaN
    uv[1, 0, 0] += 300.0  # a wrong pixel in a view with confidence 0 changes nothing...
    conf[1, 0] = 0.0
    points, err = triangulate(projection_matrices(cams), uv, conf)
    np.testing.assert_allclose(points[:6], X[:6], atol=1e-9)
    assert np.isnan(points[6]).all() and np.isnan(err[:, 6]).all()
    assert err[1, 0] == pytest.approx(300.0, abs=1e-6)  # ...but its error is reported
    assert np.abs(np.delete(err[:, :6], 0, axis=1)).max() < 1e-7


def _body(rng, centre):
    """25 joints of a body-sized cloud around `centre` (m)."""
    return centre + rng.uniform([-0.25, -0.7, -0.12], [0.25, 0.7, 0.12], (25, 3))


def test_select_person_picks_the_consistent_subject_not_person_zero(tmp_path):
    rng = np.random.default_rng(3)
    cams = _rig(seed=4)
    T, V = 6, 4
    step = np.array([0.02, 0.0, 0.01])
    subject, other, third = (_body(rng, c) for c in ([0.3, 0.9, 0.2], [1.0, 0.9, 0.6], [-0.4, 0.9, -0.3]))
    truth = np.zeros((V, T, 25, 2))
    dets = [[] for _ in range(V)]
    for t in range(T):
        people = {"subject": subject + t * step, "other": other - t * step, "third": third}
        for v, cam in enumerate(cams):
            truth[v, t] = undistort_pixels(_pixel(cam, people["subject"]), cam.K, cam.dist)
            rows = {}
            for name, X in people.items():
                if name == "third" and v >= 2:  # the third person is seen by two views only
                    continue
                if name == "subject" and (v, t) == (3, 2):  # cam04 misses the subject in frame 2
                    continue
                kp = np.concatenate([_pixel(cam, X), np.full((25, 1), 0.9)], -1)
                if name == "other" and t == 0:  # half-occluded in the first frame
                    kp[::2] = 0.0
                rows[name] = kp
            distractor = np.concatenate([rng.uniform([0, 0], [1279, 719], (25, 2)), rng.uniform(0.1, 0.6, (25, 1))], -1)
            order = list(rows)
            rng.shuffle(order)
            if v == 1 and "subject" in order:  # first in some views, last in others
                order.remove("subject")
                order.insert(0, "subject")
            if v == 0:
                order.remove("subject")
                order.append("subject")
            dets[v].append(np.stack([rows[n] for n in order] + [distractor]))
    P = max(len(d) for view in dets for d in view)
    padded = [np.stack([np.concatenate([d, np.zeros((P - len(d), 25, 3))]) for d in view]) for view in dets]
    views = [c.name for c in cams]
    write_openpose(tmp_path, views, padded, "body25")
    rec = read_openpose(tmp_path, "body25")
    shuffled = [cams[i] for i in (2, 0, 3, 1)]  # calibration order differs from the folders'
    out = select_person(rec, shuffled)
    assert out.shape == (V, T, 25, 3)
    seen = np.ones((V, T), bool)
    seen[3, 2] = False
    np.testing.assert_allclose(out[..., :2][seen], truth[seen], atol=1e-6)
    assert (out[..., 2][seen] == 0.9).all()
    assert not out[3, 2].any()  # only inconsistent detections left there: confidence 0


def test_select_person_with_one_view_follows_the_most_confident_person_in_2d(tmp_path):
    cam = _rig(1)[0]
    T = 4
    shape = np.random.default_rng(0).uniform([-50, -150], [50, 150], (18, 2))  # a person's 2D layout
    a = np.concatenate([shape + [400.0, 300.0] + np.arange(T)[:, None, None] * 5, np.full((T, 18, 1), 0.9)], -1)
    b = np.concatenate([np.tile(shape + [900.0, 300.0], (T, 1, 1)), np.full((T, 18, 1), 0.5)], -1)
    b[2:, :, 2] = 1.0  # later more confident, but not the person followed
    write_openpose(tmp_path, [cam.name], [np.stack([b, a], 1)], "coco18")
    rec = read_openpose(tmp_path, "coco18")
    out = select_person(rec, [cam])
    ideal = undistort_pixels(a[..., :2], cam.K, cam.dist)
    np.testing.assert_allclose(out[0, ..., :2], ideal, atol=1e-9)


# ------------------------------------------------------------------------------ bad input


def test_view_names_match_exactly_then_normalised_else_both_sets_are_listed(tmp_path):
    cams = _rig(3)
    kp = [np.zeros((1, 1, 25, 3))] * 3
    write_openpose(tmp_path / "a", ["Cam_3", "cam1_json", "CAM02"], kp, "body25")
    rec = read_openpose(tmp_path / "a", "body25", views=["Cam_3", "cam1_json", "CAM02"])
    assert [c.name for c in align_views(rec, cams)] == ["cam03", "cam01", "cam02"]
    assert normalise_view_name("cam01") == normalise_view_name("Cam_1") == ("cam", "1")
    # Pose2Sim names intrinsic calibrations after the image folders: matched by camera number
    numbered = [
        CalibratedCamera(f"int_cam{i:02d}_img", c.K, c.dist, c.R, c.t, 1280, 720) for i, c in enumerate(cams, 1)
    ]
    write_openpose(tmp_path / "p2s", ["cam02_json", "cam01_json"], kp[:2], "body25")
    rec = read_openpose(tmp_path / "p2s", "body25", views=["cam02_json", "cam01_json"])
    assert [c.name for c in align_views(rec, numbered)] == ["int_cam02_img", "int_cam01_img"]
    write_openpose(tmp_path / "b", ["left", "cam01"], kp[:2], "body25")
    rec = read_openpose(tmp_path / "b", "body25")
    with pytest.raises(
        ValueError,
        match=r"views \['cam01', 'left'\] do not match calibration cameras \['cam01', 'cam02', 'cam03'\]: 'left' \(no camera\)",
    ):
        align_views(rec, cams)


def test_missing_camera_folder_names_it(tmp_path):
    write_openpose(tmp_path, ["cam01"], [np.zeros((2, 1, 25, 3))], "body25")
    with pytest.raises(KeypointFileError, match=r"cam09: missing camera folder.*\['cam01'\]"):
        read_openpose(tmp_path, "body25", views=["cam01", "cam09"])
    (tmp_path / "empty").mkdir()
    with pytest.raises(KeypointFileError, match="empty: no OpenPose"):
        read_openpose(tmp_path, "body25", views=["empty"])


def test_body25_file_read_as_coco18_says_which_layout_fits(tmp_path):
    kp = _random_people(np.random.default_rng(0), 1, 1)
    write_openpose(tmp_path, ["cam01"], [kp], "body25")
    with pytest.raises(
        KeypointFileError,
        match=r"cam01_000000000000_keypoints\.json.*75 numbers.*'coco18' expects 54.*'body25' or 'body25b'",
    ):
        read_openpose(tmp_path, "coco18")
    halpe = tmp_path / "halpe" / "cam01"
    halpe.mkdir(parents=True)
    (halpe / "cam01_000000000000_keypoints.json").write_text(
        json.dumps({"people": [{"pose_keypoints_2d": [1.0] * 78}]})
    )
    with pytest.raises(KeypointFileError, match=r"78 numbers.*'body25' expects 75.*the layout that fits is 'halpe26'"):
        read_openpose(tmp_path / "halpe", "body25")
    assert read_openpose(tmp_path / "halpe", None).layout == "halpe26"  # Pose2Sim >= 0.9's RTMPose files
    whole = tmp_path / "whole" / "cam01"  # COCO_133 (RTMPose whole body): no layout of ours
    whole.mkdir(parents=True)
    (whole / "cam01_000000.json").write_text(json.dumps({"people": [{"pose_keypoints_2d": [1.0] * 399}]}))
    with pytest.raises(
        KeypointFileError,
        match=r"399 numbers.*no known layout has 399 numbers \(body25: 75, body25b: 75, coco18: 54, halpe26: 78, mediapipe33: 99\)",
    ):
        read_openpose(tmp_path / "whole", "body25")
    with pytest.raises(KeypointFileError, match="layout='body_25' is not known"):
        read_openpose(tmp_path, "body_25")


def test_truncated_json_names_the_file(tmp_path):
    write_openpose(tmp_path, ["cam01"], [_random_people(np.random.default_rng(0), 3, 2)], "body25")
    bad = tmp_path / "cam01" / "cam01_000000000001_keypoints.json"
    bad.write_text(bad.read_text()[:-40])
    with pytest.raises(KeypointFileError, match=r"cam01_000000000001_keypoints\.json: not valid JSON"):
        read_openpose(tmp_path, "body25")


def test_unknown_or_broken_calibrations_name_the_file(tmp_path):
    path = tmp_path / "calib.dat"
    path.write_text("hello")
    with pytest.raises(CalibrationError, match=r"calib\.dat: cannot tell the calibration format"):
        load_calibration(path)
    with pytest.raises(CalibrationError, match=r"unknown calibration format 'vicon'"):
        load_calibration(path, format="vicon")
    with pytest.raises(CalibrationError, match=r"nothere\.toml: no such file"):
        load_calibration(tmp_path / "nothere.toml")
    (tmp_path / "bad.qca.txt").write_text(
        QCA.replace('<transform x="0.0" y="-5000.0"', '<transform x="0.0" y="oops"', 1)
    )
    with pytest.raises(CalibrationError, match=r"bad\.qca\.txt \(camera 11\): <transform y='oops'> is not a number"):
        load_calibration(tmp_path / "bad.qca.txt")
    (tmp_path / "cut.qca.txt").write_text(QCA[:-200])
    with pytest.raises(CalibrationError, match=r"cut\.qca\.txt: not valid XML"):
        load_calibration(tmp_path / "cut.qca.txt")
    (tmp_path / "em").mkdir()
    (tmp_path / "em" / "intri.yml").write_bytes(INTRI.encode())
    with pytest.raises(CalibrationError, match=r"extri\.yml: no such file"):
        load_calibration(tmp_path / "em")
    (tmp_path / "fish.toml").write_text(TOML.replace("fisheye = false", "fisheye = true", 1))
    with pytest.raises(CalibrationError, match=r"fish\.toml \[cam_01\]: fisheye cameras are not supported"):
        load_calibration(tmp_path / "fish.toml")


def test_wrong_image_size_is_caught_where_it_shows(tmp_path):
    path = tmp_path / "swapped.toml"
    path.write_text(TOML.replace("size = [ 1280.0, 720.0]", "size = [ 720.0, 1280.0]", 1))
    with pytest.raises(CalibrationError, match=r"swapped\.toml \[cam_01\].*principal point .*outside.*swapped"):
        load_calibration(path)
    # a calibration of a smaller video mode than the detections came from
    small = [CalibratedCamera(c.name, c.K / [[2], [2], [1]], c.dist, c.R, c.t, 640, 360) for c in _rig(2)]
    kp = np.zeros((1, 1, 25, 3))
    kp[0, 0, :, :2] = [1000.0, 600.0]
    kp[0, 0, :, 2] = 0.8
    write_openpose(tmp_path / "kp", ["cam01", "cam02"], [kp, kp * 0], "body25")
    with pytest.raises(ValueError, match=r"view 'cam01'.*outside camera 'cam01''s 640 x 360 image"):
        align_views(read_openpose(tmp_path / "kp", "body25"), small)


def test_select_person_keeps_a_noisy_subject_with_swapped_legs(tmp_path):
    rng = np.random.default_rng(5)
    cams = _rig(3, seed=6)
    subject, other = _body(rng, np.array([0.3, 0.9, 0.2])), _body(rng, np.array([1.0, 0.9, -0.3]))
    T = 4
    kps = [np.zeros((T, 2, 25, 3)) for _ in cams]
    for v, cam in enumerate(cams):
        for t in range(T):
            for slot, X in ((v % 2, subject), (1 - v % 2, other)):
                kps[v][t, slot, :, :2] = _pixel(cam, X + 0.01 * t) + rng.normal(0, 2.0, (25, 2))
                kps[v][t, slot, :, 2] = rng.uniform(0.5, 1.0, 25)
            kps[v][t, 1 - v % 2, ::3] = 0.0  # the other person is partly hidden: less support
    left, right = [12, 13, 14], [9, 10, 11]  # BODY_25 legs
    kps[0][1, 0, left + right] = kps[0][1, 0, right + left]  # cam01 swaps the subject's legs in frame 1
    write_openpose(tmp_path, [c.name for c in cams], kps, "body25")
    out = select_person(read_openpose(tmp_path, "body25"), cams)
    for v, cam in enumerate(cams):  # the subject's own detections, swap and all, undistorted
        expected = undistort_pixels(kps[v][:, v % 2, :, :2], cam.K, cam.dist)
        np.testing.assert_allclose(out[v, ..., :2], expected, atol=1e-6)
        np.testing.assert_array_equal(out[v, ..., 2], kps[v][:, v % 2, :, 2])


def test_formats_is_the_data_layer_and_imports_no_observation_models():
    import subprocess
    import sys
    from pathlib import Path

    code = "import sys, jaxmocap.formats; print(' '.join(m for m in sys.modules if m.startswith('jaxmocap.')))"
    root = Path(__file__).resolve().parents[1]  # this checkout, not an installed copy
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=root).stdout
    assert "jaxmocap.formats.openpose" in loaded.split()
    layers = {m.split(".")[1] for m in loaded.split()}
    assert not layers & {"sensors", "energies", "methods", "priors", "solve"}


@pytest.mark.parametrize(
    "name, expected",
    [
        ("{view}_{frame:012d}_keypoints.json", "cam01_000000000012_keypoints.json"),  # OpenPose
        ("{view}_{frame:06d}.json", "cam01_000012.json"),  # Pose2Sim / RTMLib
        ("{view}.{frame:04d}.json", "cam01.0012.json"),  # camNN_json/camNN.FFFF.json
        ("frame_{frame:04d}.json", "frame_0012.json"),
        ("{frame:04d}.json", "0012.json"),
        ("{view}_{frame}.JSON", "cam01_12.JSON"),
    ],
)
def test_every_per_frame_naming_reads_the_frame_number_from_the_last_digits(tmp_path, name, expected):
    rng = np.random.default_rng(0)
    kps = [_random_people(rng, 3, 1), _random_people(rng, 3, 1)]
    write_openpose(tmp_path, ["cam01", "cam02"], kps, "body25b", frames=[11, 12, 13], name=name)
    assert (tmp_path / "cam01" / expected).exists()
    (tmp_path / "cam01" / "notes.json").write_text("{}")  # no number: not a frame
    rec = read_openpose(tmp_path, None)
    assert rec.layout is None  # 25 points: BODY_25 or BODY_25B, decided later
    assert rec.views == ("cam01", "cam02") and rec.frames.tolist() == [11, 12, 13]
    np.testing.assert_array_equal(rec.keypoints[1], kps[1])
    assert read_openpose(tmp_path, "body25b").layout == "body25b"


def test_frames_are_matched_by_number_with_gaps_kept_and_disjoint_cameras_refused(tmp_path):
    rng = np.random.default_rng(1)
    kps = [_random_people(rng, 4, 1, K=18), _random_people(rng, 3, 1, K=18)]
    write_openpose(tmp_path, ["cam01"], kps[:1], "coco18", frames=[1, 2, 3, 5], name="{view}.{frame:04d}.json")
    write_openpose(tmp_path, ["cam02"], kps[1:], "coco18", frames=[2, 3, 4], name="{view}.{frame:04d}.json")
    rec = read_openpose(tmp_path, None)
    assert rec.layout == "coco18"  # the only 18-point layout
    assert rec.frames.tolist() == [1, 2, 3, 4, 5]
    assert [p.tolist() for p in rec.present] == [[True, True, True, False, True], [False, True, True, True, False]]
    np.testing.assert_array_equal(rec.keypoints[1][1:4], kps[1])  # cam02's frame 2 is row 1, not 0
    assert not rec.keypoints[0][3].any() and not rec.keypoints[1][[0, 4]].any()
    # a camera numbered from another start shares no frame: refused, not appended
    write_openpose(tmp_path, ["cam03"], kps[1:], "coco18", frames=[102, 103, 104], name="{view}.{frame:04d}.json")
    with pytest.raises(
        KeypointFileError, match=r"'cam03' shares no frame number.*cam01 1..5, cam02 2..4, cam03 102..104"
    ):
        read_openpose(tmp_path, None)
    assert read_openpose(tmp_path, None, views=["cam03"]).frames.tolist() == [102, 103, 104]
    # a file named otherwise is a stray, left out and listed; one named alike repeats a frame
    (tmp_path / "cam02" / "cam02.0003_keypoints.json").write_text('{"people": []}')
    rec = read_openpose(tmp_path, None, views=["cam02"])
    assert rec.ignored == ("cam02/cam02.0003_keypoints.json",) and rec.frames.tolist() == [2, 3, 4]
    (tmp_path / "cam02" / "cam02.03.json").write_text('{"people": []}')
    with pytest.raises(KeypointFileError, match=r"frame 3 appears twice: cam02\.0003\.json and cam02\.03\.json"):
        read_openpose(tmp_path, None, views=["cam02"])
