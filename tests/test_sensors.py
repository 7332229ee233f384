"""Sensor simulation: closed-form IMU physics, calibration, cameras, rasteriser, scenarios.

Everything runs on the low-resolution default body in float64 (conftest enables x64),
with short sequences and one shared scenario to keep compilation cheap.
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import equinox as eqx
import jax
import jax.numpy as jnp

import jaxmocap
from jaxmocap.body.model import SMPL_JOINT_NAMES, SMPL_PARENTS
from jaxmocap.formats.dip import load_dip
from jaxmocap.geometry import camera, imu_calibration, keypoints, raster
from jaxmocap.objects import RigidObject
from jaxmocap.sensors import depth, detector, errors, imu, objects
from jaxmocap.sensors import scenario as sc

G = imu.GRAVITY
T8 = 8  # one sequence length for most tests: one compilation of the jitted kernels
forward = eqx.filter_jit(jaxmocap.forward)


@pytest.fixture(scope="module")
def body():
    return jaxmocap.default_body("low").astype(jnp.float64)


@pytest.fixture(scope="module")
def sip6(body):
    return imu.imu_placement(body, "sip6")


@pytest.fixture(scope="module")
def xsens17(body):
    return imu.imu_placement(body, "xsens17")


def _synthesize(body, placement, poses, trans=None, sensor_to_bone=None):
    """`imu.synthesize_imu` with the zero translation and identity offsets spelled out: the
    tests' calls share one compiled program (None and an array compile apart)."""
    T, S = len(poses), placement.num_sensors
    trans = np.zeros((T, 3)) if trans is None else trans
    sensor_to_bone = np.broadcast_to(np.eye(3), (S, 3, 3)) if sensor_to_bone is None else sensor_to_bone
    return imu.synthesize_imu(
        body, placement, jnp.asarray(poses), trans=jnp.asarray(trans), sensor_to_bone=jnp.asarray(sensor_to_bone)
    )


def _fk_numpy(poses):
    """Independent forward kinematics of global rotations with SciPy: (T, 24, 3) -> (T, 24, 3, 3)."""
    local = Rotation.from_rotvec(poses.reshape(-1, 3)).as_matrix().reshape(*poses.shape, 3)
    G_ = np.zeros_like(local)
    for j, p in enumerate(SMPL_PARENTS):
        G_[:, j] = local[:, j] if p < 0 else G_[:, p] @ local[:, j]
    return G_


# --- placements ------------------------------------------------------------------------


def test_default_body_ids_follow_the_landmark_rule(body):
    for name, landmarks in imu.SENSOR_SETS.items():
        ids = tuple(imu.landmark_vertex(body, lm) for lm in landmarks)
        assert ids == imu.DEFAULT_BODY_IDS[(body.num_vertices, name)]
        assert imu.imu_placement(body, name).vertices == ids
    w = np.asarray(body.weights)
    p = imu.imu_placement(body, "xsens17")
    # Mostly skinned to its bone (the collar falls back to 'largest weight', see imu.py).
    assert all(w[v, b] >= 0.5 or w[v].argmax() == b for v, b in zip(p.vertices, p.bones))
    assert p.subset(["left_forearm", "head"]).bones == (18, 15)


def test_smpl_topology_uses_published_vertex_ids():
    from conftest import random_smpl_dict
    from jaxmocap.body import make_body

    d = random_smpl_dict(num_vertices=6890)
    smpl = make_body(d["v_template"], d["f"], d["shapedirs"], d["posedirs"], d["J_regressor"], d["weights"])
    p = imu.imu_placement(smpl, "sip6")
    assert p.vertices == (1961, 5424, 1176, 4662, 411, 3021)
    assert p.bones == (18, 19, 4, 5, 15, 0)


# --- closed-form IMU physics -------------------------------------------------------------


def test_constant_rate_rotation_measures_centripetal_acceleration(body, sip6):
    """Left arm swept about the vertical through the shoulder at ω: |a| = ω² r (radial)."""
    fps, omega, T = 120.0, 3.0, T8
    poses = np.zeros((T, 24, 3))
    poses[:, 16, 1] = omega * np.arange(T) / fps
    out = forward(body, jnp.asarray(poses))
    read = imu.imu_from_body_output(out, sip6, fps)
    s = sip6.index("left_forearm")
    centre = np.asarray(out.joints[0, 16])
    radial = np.asarray(read.position[:, s]) - centre
    radial[:, 1] = 0.0  # distance from the vertical axis
    r = np.linalg.norm(radial, axis=-1)
    a = np.asarray(read.free_acceleration[:, s])
    # Central differences on a circle give exactly ω_d² r with ω_d² = (2 - 2cos ωdt)/dt².
    discrete = (2 - 2 * np.cos(omega / fps)) * fps**2
    np.testing.assert_allclose(a[1:-1], -discrete * radial[1:-1], atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(a[1:-1], axis=-1), omega**2 * r[1:-1], rtol=(omega / fps) ** 2 / 10)
    # The one-sided end stencils are second order too.
    np.testing.assert_allclose(np.linalg.norm(a[[0, -1]], axis=-1), omega**2 * r[[0, -1]], rtol=2e-3)
    # Specific force: |a^s|² = (ω² r)² + g², and the gyro reads ω about the bone's y axis.
    np.testing.assert_allclose(
        np.linalg.norm(read.acceleration[1:-1, s], axis=-1), np.hypot(discrete * r[1:-1], G), rtol=1e-12
    )
    np.testing.assert_allclose(read.angular_velocity[:, s], np.tile([0.0, omega, 0.0], (T, 1)), atol=1e-9)


def test_resting_body_measures_only_gravity(body, xsens17):
    rng = np.random.default_rng(0)
    pose = rng.normal(scale=0.4, size=(24, 3))
    poses = np.repeat(pose[None], T8, 0)
    read = _synthesize(body, xsens17, poses, trans=np.tile([0.3, 0.9, -1.0], (T8, 1)))
    up = np.einsum("tsab,tsb->tsa", np.asarray(read.orientation), np.asarray(read.acceleration))
    np.testing.assert_allclose(up, np.broadcast_to([0.0, G, 0.0], up.shape), atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(read.acceleration, axis=-1), G, atol=1e-9)
    np.testing.assert_allclose(read.angular_velocity, 0.0, atol=1e-9)


def test_finite_difference_ends_are_exact_for_cubics():
    t = np.arange(7)[:, None, None] / 10.0
    p = jnp.asarray(1.0 + 2 * t + 3 * t**2 - 4 * t**3) * jnp.ones((1, 2, 3))
    a = imu.finite_difference_acceleration(p, 10.0)
    np.testing.assert_allclose(a, np.broadcast_to(6 - 24 * t, a.shape), atol=1e-9)
    assert np.all(np.asarray(imu.finite_difference_acceleration(p[:3], 10.0)) == 0)


def test_noise_off_orientations_equal_fk_times_offsets(body, xsens17):
    rng = np.random.default_rng(1)
    poses = rng.normal(scale=0.5, size=(T8, 24, 3))
    p = xsens17
    offsets = errors.random_rotations(rng, 1.0, (p.num_sensors,))
    read = _synthesize(body, p, poses, sensor_to_bone=offsets)
    expected = _fk_numpy(poses)[:, list(p.bones)] @ offsets
    np.testing.assert_allclose(read.orientation, expected, atol=1e-6)


# --- error models and calibration ------------------------------------------------------


def _static_readings(body, placement, T=T8):
    rng = np.random.default_rng(2)
    poses = np.repeat(rng.normal(scale=0.3, size=(1, 24, 3)), T, 0)
    return poses, _synthesize(body, placement, poses)


def test_heading_drift_rotates_orientations_by_exactly_gamma(body, xsens17):
    poses, read = _static_readings(body, xsens17)
    T, S = read.orientation.shape[:2]
    gamma = np.linspace(-2.5, 2.5, T * S).reshape(T, S)
    draw = errors.IMUErrors(
        misalignment=np.broadcast_to(np.eye(3), (S, 3, 3)), offset_bone=np.zeros((S, 3)),
        heading=gamma, acc_bias=np.zeros((T, S, 3)), gyro_bias=np.zeros((T, S, 3)),
        clock_offset=np.zeros(S), dropped=np.zeros((T, S), bool),
    )  # fmt: skip
    meas = errors.apply_imu_errors(read, draw, errors.IMUErrorModel(), 60.0, np.random.default_rng(0))
    delta = meas.orientation @ np.swapaxes(np.asarray(read.orientation), -1, -2)
    # One compiled program for the three library calls (eagerly, each of their operations compiled).
    R_gamma, heading, reset = jax.jit(
        lambda g, d, o: (imu.rotation_y(g), imu_calibration.heading_angle(d), imu_calibration.remove_heading(o, g))
    )(jnp.asarray(gamma), jnp.asarray(delta), jnp.asarray(meas.orientation))
    np.testing.assert_allclose(delta, np.asarray(R_gamma), atol=1e-12)
    np.testing.assert_allclose(heading, gamma, atol=1e-9)
    np.testing.assert_allclose(meas.acceleration, read.acceleration, atol=1e-12)  # a frame error only
    # Heading reset (eq. 2.71) undoes it.
    np.testing.assert_allclose(reset, read.orientation, atol=1e-12)


def test_error_switches_are_independent_and_deterministic(body, sip6, xsens17):
    poses, _ = _static_readings(body, xsens17)
    model = errors.IMUErrorModel(acc_noise=0.1, dropout_rate=0.05, dropout_length=2)
    run = lambda: errors.simulate_imu(body, sip6, poses, None, None, 60.0, model, np.random.default_rng(5))  # noqa: E731
    (ideal, m1, e1), (_, m2, _) = run(), run()
    np.testing.assert_array_equal(m1.acceleration, m2.acceleration)
    assert np.isnan(m1.orientation[e1.dropped]).all() and e1.dropped.any()
    ok = ~e1.dropped
    np.testing.assert_allclose(m1.orientation[ok], np.asarray(ideal.orientation)[ok], atol=1e-12)
    resid = m1.acceleration[ok] - np.asarray(ideal.acceleration)[ok]
    assert 0.085 < resid.std() < 0.115
    with pytest.raises(ValueError, match="acc_noise"):
        errors.IMUErrorModel(acc_noise=-1.0)


def test_calibration_recovers_planted_misalignment(body):
    p = imu.imu_placement(body, "xsens17")
    rng = np.random.default_rng(3)
    poses = rng.normal(scale=0.3, size=(T8, 24, 3))
    model = errors.IMUErrorModel(misalignment=0.3)
    ideal, meas, err = errors.simulate_imu(body, p, poses, None, None, 60.0, model, rng)
    R_bone0 = _fk_numpy(poses[:1])[0][list(p.bones)]  # the known initial pose x₀

    @jax.jit  # one compiled program for the calibration calls, not one per operation
    def calibrate(R_bone0, meas0, meas, head):
        recovered = imu_calibration.sensor_to_bone_offsets(R_bone0, meas0)
        bones = imu_calibration.virtual_bone_orientations(meas, recovered)
        return recovered, bones, imu_calibration.inertial_to_model_from_head(head)

    recovered, bones, R_ti = calibrate(
        jnp.asarray(R_bone0), jnp.asarray(meas.orientation[0]), jnp.asarray(meas.orientation),
        jnp.asarray(ideal.orientation[0, 0]),
    )  # fmt: skip
    np.testing.assert_allclose(recovered, err.misalignment, atol=1e-9)
    np.testing.assert_allclose(bones, _fk_numpy(poses)[:, list(p.bones)], atol=1e-9)
    # DIP eq. 6.4: a head sensor aligned with the model frame gives R^TI = R_head⁻¹.
    np.testing.assert_allclose(np.asarray(R_ti) @ ideal.orientation[0, 0], np.eye(3), atol=1e-12)
    # Heading reset: sensors in one known orientation read R_y(γ_s) R_ref.
    gamma = np.array([0.1, -0.7, 2.0])
    R_ref = Rotation.from_rotvec([0.2, 0.1, -0.3]).as_matrix()
    readings = np.asarray(jax.jit(imu.rotation_y)(jnp.asarray(gamma))) @ R_ref
    heading = jax.jit(imu_calibration.heading_reset)(jnp.asarray(readings), jnp.asarray(R_ref))
    np.testing.assert_allclose(heading, gamma, atol=1e-12)


# --- cameras, keypoints, rasteriser, depth, objects -----------------------------------


def test_known_point_projects_to_known_pixel():
    K = camera.intrinsics(640, 480, fov_y_degrees=90.0)  # f = 240
    R, t = camera.look_at([0.0, 0.0, 5.0], [0.0, 0.0, 0.0])
    uv, z = camera.project(jnp.asarray(K), jnp.asarray(R), jnp.asarray(t), jnp.asarray([[0.5, 0.2, 0.0]]))
    # The camera faces -z: world +x is image right, world +y image up (v decreases).
    np.testing.assert_allclose(uv[0], [320 + 240 * 0.5 / 5, 240 - 240 * 0.2 / 5], atol=1e-9)
    np.testing.assert_allclose(z[0], 5.0)
    np.testing.assert_allclose(camera.camera_centers(R, t), [0.0, 0.0, 5.0], atol=1e-12)


def test_rasterised_square_and_depth_points():
    """A 1 m square facing the camera at 4 m: pixel count = (f s / d)², depth exact."""
    W = H = 64
    K = camera.intrinsics(W, H, fov_y_degrees=60.0)
    f = K[0, 0]
    R, t = camera.look_at([0.0, 1.0, 4.0], [0.0, 1.0, 0.0])
    v = np.array([[-0.5, 0.5, 0.0], [0.5, 0.5, 0.0], [0.5, 1.5, 0.0], [-0.5, 1.5, 0.0]])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    d, lab = raster.rasterize_views(K, R[None], t[None], v[None], faces, np.array([0, 0]), W, H, floor=True)
    d, lab = np.asarray(d[0]), np.asarray(lab[0])
    side = f / 4.0
    assert abs((lab == 0).sum() - side**2) <= 4 * side + 4
    np.testing.assert_allclose(d[lab == 0], 4.0, atol=1e-9)
    assert (lab == raster.FLOOR).any() and (lab == raster.BACKGROUND).any()
    pts, labels, valid = depth.depth_point_cloud(
        K, R, t, d, lab, 100, np.random.default_rng(0), depth.DepthNoiseModel.off()
    )
    assert valid.all() and (labels == 0).all()
    np.testing.assert_allclose(pts[:, 2], 0.0, atol=1e-9)
    assert np.abs(pts[:, :2] - [0.0, 1.0]).max() <= 0.5 + 1e-9
    probe = jnp.asarray([[0.0, 1.0, 0.0], [0.0, 1.0, -1.0]])  # on the square; behind it
    vis = raster.visible_vertices(jnp.asarray(K), jnp.asarray(R), jnp.asarray(t), probe, jnp.asarray(d))
    assert list(np.asarray(vis)) == [True, False]


def test_keypoint_regressors_and_detector(body):
    for layout, names in keypoints.KEYPOINT_FORMATS.items():
        reg = keypoints.keypoint_regressor(body, layout)
        assert reg.shape == (len(names), body.num_vertices + 24)
        np.testing.assert_allclose(reg.sum(1), 1.0)
        kp = keypoints.rest_keypoints(body, layout)
        pairs = keypoints.flip_pairs(names)
        for a, b in pairs:  # left keypoints on +x, mirrored on the right
            assert kp[a, 0] > 0 > kp[b, 0]
        assert kp[names.index("nose"), 2] > kp[names.index("left_ear"), 2]
    uv = np.random.default_rng(0).uniform(10, 50, size=(2, 30, 18, 2))
    z = np.ones((2, 30, 18))
    clean = detector.detect(
        uv, z, 64, 64, keypoints.COCO18_NAMES, detector.DetectorErrorModel.off(), np.random.default_rng(1)
    )
    for p in range(2):
        slot = np.argmax(clean.person == p, axis=1)
        np.testing.assert_allclose(clean.keypoints[np.arange(30), slot, :, :2], uv[p])
    swap = detector.DetectorErrorModel(swap_rate=1.0, swap_length=100.0, confidence_mean=1.0, max_distractors=0)
    det = detector.detect(uv[:1], z[:1], 64, 64, keypoints.COCO18_NAMES, swap, np.random.default_rng(2))
    i, j = keypoints.COCO18_NAMES.index("left_wrist"), keypoints.COCO18_NAMES.index("right_wrist")
    np.testing.assert_allclose(det.keypoints[:, 0, i, :2], uv[0, :, j])
    assert det.swapped[:, 0, i].all()


def test_joint_keypoints_are_the_posed_joints_also_at_a_bent_elbow(body):
    """Eq. 4.3 projects R_θ(J_i(β)), the joints posed by forward kinematics; 𝒥 of the
    posed mesh would move a bent elbow into the arm (LBS collapses the skin there)."""
    pose = np.zeros((24, 3))
    pose[19, 1] = pose[18, 1] = 1.6  # elbows bent about 90 degrees
    pose[5, 0] = 1.2  # right knee
    out = forward(body, jnp.asarray(pose), jnp.asarray(np.linspace(-1, 1, 10)))
    names = keypoints.COCO18_NAMES
    kp = np.asarray(keypoints.regress_keypoints(keypoints.keypoint_regressor(body, "coco18"), out.vertices, out.joints))
    for name in ("left_elbow", "right_elbow", "right_knee", "left_wrist"):
        np.testing.assert_allclose(kp[names.index(name)], out.joints[SMPL_JOINT_NAMES.index(name)], atol=1e-6)
    neck = 0.5 * (out.joints[16] + out.joints[17])
    np.testing.assert_allclose(kp[names.index("neck")], neck, atol=1e-6)
    with pytest.raises(ValueError, match="pass both"):
        keypoints.regress_keypoints(keypoints.keypoint_regressor(body, "coco18"), out.vertices)


def test_object_follows_the_hand_during_contact(body):
    T = T8
    poses = np.zeros((T, 24, 3))
    poses[:, 17, 2] = np.linspace(0, 1.0, T)  # right arm swings down
    out = forward(body, jnp.asarray(poses), trans=jnp.asarray(np.tile([0, 0.9, 0], (T, 1))))
    obj = RigidObject.box((0.1, 0.1, 0.1))
    traj, contact = objects.contact_trajectory(
        obj, body, np.asarray(out.vertices), np.asarray(out.joints), np.asarray(out.joint_rotations), 2, 6
    )
    j = 21  # right wrist
    Rj, pj = np.asarray(out.joint_rotations[:, j]), np.asarray(out.joints[:, j])
    rel = np.einsum("tba,tb->ta", Rj, traj.translations - pj)
    np.testing.assert_allclose(rel[2:6], np.broadcast_to(rel[2], (4, 3)), atol=1e-9)
    np.testing.assert_allclose(traj.translations[:2], np.broadcast_to(traj.translations[2], (2, 3)))
    np.testing.assert_allclose(traj.translations[6:], np.broadcast_to(traj.translations[5], (2, 3)))
    assert contact.sum() == 4 and traj.vertices(obj)[..., 1].min() >= -1e-12


# --- library and scenarios ---------------------------------------------------------------


def test_new_library_motions(body):
    from jaxmocap.motion import library

    for fn in (library.leg_raises, library.sit_stand):
        m = fn(num_frames=40, body=body)
        assert m.poses.shape == (40, 24, 3) and fn.__name__ in library.MOTIONS
        v = np.asarray(forward(body, jnp.asarray(m.poses), trans=jnp.asarray(m.trans)).vertices)
        assert np.abs(v[..., 1].min(1)).max() < 0.02  # a foot on the ground in every frame


@pytest.fixture(scope="module")
def scene(body):
    # reach=False: no pick-up edit (tested in test_reach), whose IK solve compiled ~25 CPU-s
    config = sc.ScenarioConfig(
        fps=30.0, max_frames=16, people=2, imu_set="xsens17",
        imu_errors=errors.IMUErrorModel.xsens(),
        cameras=sc.CameraConfig(num_views=2, width=64, height=48, distance=3.0),
        keypoints="coco18", detector=detector.DetectorErrorModel.openpose(),
        silhouettes=True, depth_points=64, object="box", reach=False,
    )  # fmt: skip
    short = jaxmocap.motion.library.static_hold(num_frames=12, body=body)
    motions = ["walk", "run", short]  # person 1 of sequence 1 is short: lengths 16 and 12
    return sc.make_scenario(motions, config, seed=7, body=body, num_sequences=2), config, motions


def test_scenario_is_deterministic_and_padded(scene, body):
    s, config, motions = scene
    assert list(s["length"]) == [16, 12]
    assert s["mask"].shape == (2, 16) and s["mask"].sum() == s["length"].sum()
    assert s["imu_ori"].shape == (2, 2, 16, 17, 3, 3)
    assert s["labels"].shape == (2, 2, 16, 48, 64)
    assert s["det_keypoints"].shape[-2:] == (18, 3)
    assert set(np.unique(s["labels"])) <= {-2, -1, 0, 1, 2}
    seq = s.sequence(1)
    assert seq["poses"].shape[1] == s["length"][1]
    again = sc.make_scenario(motions, config, seed=7, body=body, num_sequences=2)
    for k in s.arrays:
        np.testing.assert_array_equal(s[k], again[k], err_msg=k)


def test_scenario_save_load_and_dip_layout(scene, tmp_path):
    s, _, _ = scene
    path = sc.save_scenario(s, tmp_path / "set")
    loaded = sc.load_scenario(path)
    assert loaded.meta == s.meta and loaded.config == s.config
    for k in s.arrays:
        np.testing.assert_array_equal(loaded[k], s[k])
    paths = sc.save_dip(s, tmp_path / "dip")
    d = load_dip(paths[0])
    n = int(s["length"][0])
    assert d["imu_ori"].shape == (n, 17, 3, 3) and d["imu_acc"].shape == (n, 17, 3) and d["gt"].shape == (n, 72)
    first = np.flatnonzero(np.isfinite(d["imu_ori"]).all((1, 2, 3)))[0]
    R0 = _fk_numpy(s.sequence(0)["poses"][0][first : first + 1])[0][s["imu_bones"]]
    np.testing.assert_allclose(d["imu_ori"][first], R0, atol=1e-5)  # calibrated at that frame
    with pytest.raises(ValueError, match="xsens17"):
        sc.save_dip(sc.Scenario(s.arrays, {**s.meta, "sensor_set": "sip6"}), tmp_path)
