"""MPJPE / MPJAE (von Marcard §2.5.2, eq. 2.72-2.74) against closed-form cases."""

import jax.numpy as jnp
import numpy as np
import pytest

from conftest import assert_picture
from smpl_numpy import smpl_forward_numpy

from jaxmocap import metrics
from jaxmocap.rotation import axis_angle_to_matrix, matrix_to_axis_angle
from jaxmocap.viz.plot import plot_error_curves, plot_per_joint


def _random_joints(T=4, J=24, seed=0):
    return np.random.default_rng(seed).normal(scale=0.4, size=(T, J, 3))


def test_joint_sets_match_the_thesis():
    assert len(metrics.JOINT_SETS["totalcapture_mpjpe"]) == 14
    assert len(metrics.JOINT_SETS["totalcapture_mpjae"]) == 9
    assert len(metrics.JOINT_SETS["tnt15_mpjpe"]) == 13  # the 13 virtual markers of §3.4.2
    assert len(metrics.JOINT_SETS["tnt15_mpjae"]) == 4  # validation IMUs: thighs, upper arms
    with pytest.raises(ValueError, match="Unknown joint set"):
        metrics.joint_indices("nope")


def test_procrustes_removes_rigid_motion():
    p = _random_joints()
    R = np.asarray(axis_angle_to_matrix(jnp.array([0.3, -1.2, 0.7])))
    moved = p @ R.T + np.array([1.0, 2.0, -3.0])
    e = metrics.position_errors(moved, p, "all", align="procrustes")
    assert float(jnp.max(e)) < 1e-6
    assert float(metrics.mpjpe(moved, p, "all", align="none")) > 100.0
    # A per-joint offset of 1 cm along x with no alignment: exactly 10 mm.
    np.testing.assert_allclose(metrics.mpjpe(p + [0.01, 0, 0], p, align="none"), 10.0, rtol=1e-6)


def test_procrustes_never_increases_error():
    p, q = _random_joints(seed=1), _random_joints(seed=2)
    aligned = metrics.mpjpe(p, q, "all", align="procrustes")
    assert aligned <= metrics.mpjpe(p, q, "all", align="none")
    assert aligned <= metrics.mpjpe(p, q, "all", align="root") + 1e-9


def test_mpjae_is_the_geodesic_angle():
    rng = np.random.default_rng(3)
    R = np.asarray(axis_angle_to_matrix(jnp.asarray(rng.normal(size=(5, 24, 3)))))
    delta = np.asarray(axis_angle_to_matrix(jnp.array([0.0, 0.0, np.radians(30.0)])))
    e = metrics.angle_errors(delta @ R, R, "all")  # log(R̃ Rᵀ) = 30° about z
    np.testing.assert_allclose(e, 30.0, atol=1e-4)
    assert float(metrics.mpjae(R, R)) < 1e-3


def test_masked_mean_uses_selected_frames_only():
    p = _random_joints(T=3)
    q = p.copy()
    q[2] += 1.0  # a bad frame, masked out
    assert float(metrics.mpjpe(q, p, "all", align="none", mask=np.array([True, True, False]))) < 1e-9


def test_non_finite_frames_are_nan_on_that_frame_and_masked_exactly():
    """The documented behaviour: NaN stays on its frame (per-frame Procrustes) and a mask drops it."""
    p = _random_joints(T=3)
    q = p + 0.01
    q[1, 4] = np.nan
    e = np.asarray(metrics.position_errors(q, p, "all"))
    assert np.isnan(e[1]).all() and np.isfinite(e[[0, 2]]).all()
    assert np.isnan(float(metrics.mpjpe(q, p, "all")))
    keep = np.array([True, False, True])
    np.testing.assert_allclose(metrics.mpjpe(q, p, "all", mask=keep), metrics.mpjpe(q[keep], p[keep], "all"), rtol=1e-6)
    R = np.broadcast_to(np.eye(3), (3, 24, 3, 3)).copy()
    Rn = R.copy()
    Rn[2, 1] = np.nan
    a = np.asarray(metrics.angle_errors(Rn, R, "all"))
    assert np.isnan(a[2, 1]) and np.isfinite(np.delete(a.reshape(-1), 2 * 24 + 1)).all()
    assert float(metrics.mpjae(Rn, R, "all", mask=np.array([True, True, False]))) < 1e-3


def test_pose_errors_and_plots(tmp_path, random_body):
    rng = np.random.default_rng(4)
    poses = rng.normal(scale=0.2, size=(6, 24, 3))
    err = metrics.pose_errors(random_body, poses, poses)
    assert err["mpjpe"].shape == (6, 14) and err["mpjae"].shape == (6, 9)
    assert max(float(v.max()) for v in err.values()) < 1e-3
    s = metrics.summary({"a": np.ones((3, 2))})
    assert s["a"] == {"mean": 1.0, "std": 0.0}
    a = plot_error_curves({"SOP": err["mpjae"] + 2, "SIP": err["mpjae"]}, tmp_path / "c.png")
    b = plot_per_joint({"SOP": err["mpjae"] + 1}, metrics.JOINT_SETS["totalcapture_mpjae"], tmp_path / "j.png")
    assert_picture(a, min_colour_fraction=0.002)  # two coloured lines
    assert_picture(b, min_colour_fraction=0.01)  # nine bars


def test_jitter_of_a_cubic_is_its_constant_jerk():
    fps = 60.0
    t = np.arange(20) / fps
    p = np.zeros((20, 2, 3))
    p[:, 0, 1] = 2.0 * t**3  # jerk 12 m/s³
    p[:, 1, 0] = 5.0 * t**2 - t  # jerk 0
    np.testing.assert_allclose(float(metrics.jitter(p, fps)), (12.0 + 0.0) / 2 / 1000, rtol=1e-4)
    with pytest.raises(ValueError, match="T >= 4"):
        metrics.jitter(p[:3], fps)


def test_literature_metrics_against_a_known_error(random_body, smpl_dict):
    # One bone turned by a known angle, and a global shift: the root-aligned errors ignore
    # the shift, the angular errors see the bone and its descendants only.
    rng = np.random.default_rng(5)
    true = rng.normal(scale=0.2, size=(6, 24, 3))
    pred = true.copy()
    j = metrics.SMPL_JOINT_NAMES.index("left_shoulder")
    R = np.asarray(axis_angle_to_matrix(jnp.asarray(true[:, j])))
    turn = np.asarray(axis_angle_to_matrix(jnp.asarray([0.0, 0.0, np.radians(10.0)])))
    pred[:, j] = np.asarray(matrix_to_axis_angle(jnp.asarray(R @ turn)))
    shift = np.tile([0.3, 0.0, -0.2], (6, 1))
    m = metrics.literature_metrics(random_body, pred, true, 30.0, pred_trans=shift, true_trans=np.zeros((6, 3)))
    # Global orientations: the shoulder and its 3 descendants (elbow, wrist, hand) turn by 10°.
    assert m["sip_error_deg"] == pytest.approx(10.0 / 4, rel=1e-3)  # 1 of the 4 bones
    assert m["angular_error_deg"] == pytest.approx(10.0 * 4 / 24, rel=1e-3)
    # Positions and vertices, root-aligned, against the independent NumPy SMPL (tests/smpl_numpy.py).
    betas = np.zeros(random_body.num_betas)
    ref = [[smpl_forward_numpy(smpl_dict, p, betas, np.zeros(3))[:2] for p in poses] for poses in (pred, true)]
    rel = lambda i, k: np.stack([r[k] - r[1][:1] for r in ref[i]])  # noqa: E731  (T, N, 3) minus the pelvis
    expect = {
        k: 100 * np.linalg.norm(rel(0, i) - rel(1, i), axis=-1).mean()
        for k, i in (("position_error_cm", 1), ("mesh_error_cm", 0))
    }
    assert expect["position_error_cm"] > 0.1 and expect["mesh_error_cm"] > 0.1  # the turn is visible
    for key, value in expect.items():
        assert m[key] == pytest.approx(value, rel=1e-6), key
    same = metrics.literature_metrics(random_body, true, true, 30.0, pred_trans=shift, true_trans=np.zeros((6, 3)))
    assert same["position_error_cm"] < 1e-4 and same["mesh_error_cm"] < 1e-4 and same["angular_error_deg"] < 1e-2


def test_literature_metrics_of_a_padded_trajectory_with_its_mask(random_body):
    """Padding to a common length (any values) with a frame mask gives the unpadded numbers."""
    rng = np.random.default_rng(6)
    # 6 frames: the unpadded call is the known-error test's program (same shapes)
    true, pred = rng.normal(scale=0.2, size=(2, 6, 24, 3))
    trans = np.cumsum(rng.normal(scale=0.01, size=(2, 6, 3)), axis=1)
    plain = metrics.literature_metrics(random_body, pred, true, 30.0, pred_trans=trans[0], true_trans=trans[1])
    pad = lambda x: np.concatenate([x, rng.normal(size=(5,) + x.shape[1:])])  # noqa: E731
    mask = np.arange(11) < 6
    padded = metrics.literature_metrics(random_body, pad(pred), pad(true), 30.0, pred_trans=pad(trans[0]),
                                        true_trans=pad(trans[1]), mask=mask)  # fmt: skip
    assert padded == pytest.approx(plain, rel=1e-5)
    with pytest.raises(ValueError, match="mask has shape"):
        metrics.literature_metrics(random_body, pred, true, 30.0, mask=np.ones(4, bool))
