"""The bundled open body: present, SMPL-shaped, in SMPL's rest-pose conventions."""

import jax
import numpy as np
import pytest

import jaxmocap
from jaxmocap.body import SMPL_JOINT_NAMES

forward_jit = jax.jit(jaxmocap.forward)


@pytest.fixture(scope="module")
def bodies():
    return {r: jaxmocap.default_body(r) for r in ("low", "full")}


def test_sizes_and_layout(bodies):
    low, full = bodies["low"], bodies["full"]
    assert 1000 <= low.num_vertices <= 2000 and 12000 <= full.num_vertices <= 16000
    for body in (low, full):
        assert body.joint_names == SMPL_JOINT_NAMES and body.num_betas >= 10
        np.testing.assert_allclose(body.weights.sum(1), 1.0, atol=1e-5)
        np.testing.assert_allclose(body.J_regressor.sum(1), 1.0, atol=1e-5)
        assert (np.asarray(body.J_regressor) >= 0).all()


def test_rest_pose_conventions(bodies):
    """SMPL's frame: y up, facing +z, the body's left at +x, arms horizontal (T-pose)."""
    j = np.asarray(forward_jit(bodies["low"], np.zeros((24, 3))).joints)
    name = {n: i for i, n in enumerate(SMPL_JOINT_NAMES)}
    assert np.linalg.norm(j[name["pelvis"]]) < 0.05
    assert j[name["head"], 1] > j[name["neck"], 1] > j[name["pelvis"], 1] > j[name["left_knee"], 1]
    assert j[name["left_hip"], 0] > 0 > j[name["right_hip"], 0]
    assert j[name["left_wrist"], 0] > 0.5 and j[name["right_wrist"], 0] < -0.5
    assert abs(j[name["left_wrist"], 1] - j[name["left_shoulder"], 1]) < 0.05  # arms level
    assert j[name["left_foot"], 2] > j[name["left_ankle"], 2]  # toes point forward (+z)


@pytest.mark.parametrize("beta", [0.0, 2.0, -2.0])
def test_low_and_full_give_the_same_joints(bodies, beta):
    betas = np.full(10, beta)
    low = forward_jit(bodies["low"], np.zeros((24, 3)), betas).joints
    full = forward_jit(bodies["full"], np.zeros((24, 3)), betas).joints
    # Measured: 0.03 mm at the mean shape, 0.52 mm at ±2 (the low body's regressor is fitted
    # to the full body's joints); 1 mm leaves room for rounding, not for a different body.
    np.testing.assert_allclose(low, full, atol=1e-3)


def test_first_shape_component_changes_height(bodies):
    def height(b0):
        v = forward_jit(bodies["low"], np.zeros((24, 3)), np.eye(10)[0] * b0).vertices
        return float(v[:, 1].max() - v[:, 1].min())

    assert 1.5 < height(0.0) < 1.85
    assert abs(height(2.0) - height(-2.0)) > 0.15
