"""Rotation maps: values against SciPy, gradients (jacfwd == jacrev ≈ finite differences)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from conftest import central_difference
from jaxmocap import rotation as rot

rng = np.random.default_rng(1)
AXIS = np.array([0.48, -0.6, 0.64])
AXIS /= np.linalg.norm(AXIS)
# Run op by op, each map was dozens of tiny compiled programs per shape; jitted, one each.
exp = jax.jit(rot.axis_angle_to_matrix)
log = jax.jit(rot.matrix_to_axis_angle)
roundtrip = jax.jit(lambda x: rot.matrix_to_axis_angle(rot.axis_angle_to_matrix(x)))
exp_fwd, exp_rev = jax.jit(jax.jacfwd(exp)), jax.jit(jax.jacrev(exp))
roundtrip_fwd, roundtrip_rev = jax.jit(jax.jacfwd(roundtrip)), jax.jit(jax.jacrev(roundtrip))
log_fwd, log_rev = jax.jit(jax.jacfwd(log)), jax.jit(jax.jacrev(log))
# Zero, tiny, generic, large and near-π rotations.
CASES = {
    "zero": np.zeros(3),
    "tiny": 1e-9 * AXIS,
    "small": 1e-3 * AXIS,
    "generic": np.array([0.3, -0.7, 0.2]),
    "large": 2.5 * AXIS,
    "near_pi": (np.pi - 1e-6) * AXIS,
}


@pytest.mark.parametrize("name", CASES)
def test_axis_angle_to_matrix_matches_scipy_and_is_orthonormal(name):
    w = CASES[name]
    R = np.asarray(exp(jnp.asarray(w)))
    np.testing.assert_allclose(R, Rotation.from_rotvec(w).as_matrix(), atol=1e-14)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-14)


@pytest.mark.parametrize("name", CASES)
def test_exp_gradients(name):
    w = jnp.asarray(CASES[name])
    fwd = exp_fwd(w)
    rev = exp_rev(w)
    fd = central_difference(lambda x: exp(jnp.asarray(x)), w)
    assert np.isfinite(fwd).all()
    np.testing.assert_allclose(fwd, rev, atol=1e-12)
    np.testing.assert_allclose(fwd, fd, atol=1e-7)


@pytest.mark.parametrize("name", CASES)
def test_log_inverts_exp_with_identity_jacobian(name):
    w = jnp.asarray(CASES[name])
    np.testing.assert_allclose(roundtrip(w), w, atol=1e-9)
    fwd = roundtrip_fwd(w)
    rev = roundtrip_rev(w)
    # Near π, finite steps must not cross π (where the log wraps): keep them tiny.
    fd = central_difference(lambda x: roundtrip(jnp.asarray(x)), w, eps=1e-8)
    np.testing.assert_allclose(fwd, np.eye(3), atol=1e-6)
    np.testing.assert_allclose(fwd, rev, atol=1e-10)
    np.testing.assert_allclose(fd, np.eye(3), atol=1e-5)


@pytest.mark.parametrize("name", CASES)
def test_log_gradient_wrt_matrix_matches_finite_differences(name):
    R = Rotation.from_rotvec(CASES[name]).as_matrix()
    f = log
    fwd = log_fwd(jnp.asarray(R))
    rev = log_rev(jnp.asarray(R))
    assert np.isfinite(fwd).all() and np.isfinite(rev).all()
    np.testing.assert_allclose(fwd, rev, atol=1e-9)
    if name != "near_pi":  # off-manifold steps of 1e-7 would cross π there
        fd = central_difference(lambda x: f(jnp.asarray(x)), R, eps=1e-7)
        np.testing.assert_allclose(np.asarray(fwd).reshape(3, 9), fd, atol=1e-6)


@jax.jit
def _round_trips(w):
    R = rot.axis_angle_to_matrix(w)
    q = rot.matrix_to_quaternion(R)
    p = rot.matrix_to_quaternion(R[::-1])
    return dict(R=R, q=q, R_of_q=rot.quaternion_to_matrix(q), q_of_w=rot.axis_angle_to_quaternion(w),
                w_of_q=rot.quaternion_to_axis_angle(q), R_of_6d=rot.sixd_to_matrix(rot.matrix_to_6d(R)),
                pq=rot.quaternion_to_matrix(rot.quaternion_multiply(p, q)))  # fmt: skip


def test_quaternion_and_6d_round_trips():
    w = rng.normal(size=(50, 3))
    w *= (rng.random((50, 1)) * np.pi) / np.linalg.norm(w, axis=1, keepdims=True)
    out = _round_trips(jnp.asarray(w))
    R, q = out["R"], out["q"]
    ref = Rotation.from_rotvec(w).as_quat(scalar_first=True)
    ref *= np.sign(ref[:, :1])
    np.testing.assert_allclose(q, ref, atol=1e-12)
    np.testing.assert_allclose(out["R_of_q"], R, atol=1e-12)
    np.testing.assert_allclose(out["q_of_w"], ref, atol=1e-12)
    np.testing.assert_allclose(out["w_of_q"], w, atol=1e-10)
    np.testing.assert_allclose(out["R_of_6d"], R, atol=1e-12)
    np.testing.assert_allclose(out["pq"], R[::-1] @ R, atol=1e-12)


def test_float32_accuracy_and_zero_gradient():
    w = jnp.asarray(CASES["small"], jnp.float32)
    R = exp(w)
    assert R.dtype == jnp.float32
    np.testing.assert_allclose(R, Rotation.from_rotvec(CASES["small"]).as_matrix(), atol=1e-7)
    g = jax.jit(jax.grad(lambda x: roundtrip(x).sum()))(jnp.zeros(3, jnp.float32))
    np.testing.assert_allclose(g, np.ones(3), atol=1e-6)


@jax.jit
def _maps(w):
    R = rot.axis_angle_to_matrix(w)
    return R, rot.matrix_to_axis_angle(R), rot.geodesic_angle(R, R)


@pytest.mark.parametrize("batch", [(), (1,), (3, 2)])
def test_batch_shapes(batch):
    w = jnp.asarray(rng.normal(size=(*batch, 3)))
    R, w_back, angle = _maps(w)
    assert R.shape == (*batch, 3, 3)
    assert w_back.shape == (*batch, 3)
    assert angle.shape == batch
    np.testing.assert_allclose(angle, 0.0, atol=1e-7)


@jax.jit
def _left_jacobian_inverse_and_reference(w):
    def composed(d):
        return rot.matrix_to_axis_angle(rot.axis_angle_to_matrix(d) @ rot.axis_angle_to_matrix(w))

    reference = jax.jacfwd(composed)(jnp.zeros(3, w.dtype))
    grad = jax.grad(lambda v: jnp.sum(rot.left_jacobian_inverse(v)))(w)
    return reference, rot.left_jacobian_inverse(w), rot.left_jacobian_inverse(w.astype(jnp.float32)), grad


@pytest.mark.parametrize("name", ["zero", "tiny", "small", "generic", "large"])
def test_left_jacobian_inverse_is_the_derivative_of_log(name):
    """log(exp(δ^) exp(ω^))^∨ = ω + J_l⁻¹(ω) δ + O(δ²), by forward-mode AD, float64 and float32."""
    reference, inverse64, inverse32, g = _left_jacobian_inverse_and_reference(jnp.asarray(CASES[name]))
    np.testing.assert_allclose(inverse64, reference, atol=1e-9)
    assert inverse32.dtype == jnp.float32
    np.testing.assert_allclose(inverse32, reference, atol=2e-6)
    assert bool(jnp.all(jnp.isfinite(g)))
