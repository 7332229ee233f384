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


def _rodrigues(w):
    """exp(ω^) in NumPy, one rotation vector: an independent reference for the host twins."""
    theta = np.linalg.norm(w)
    K = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]]) / theta
    return np.eye(3) + np.sin(theta) * K + (1 - np.cos(theta)) * K @ K


def _elementary(axis, angle):
    c, s = np.cos(angle), np.sin(angle)
    i, j = [(1, 2), (2, 0), (0, 1)]["xyz".index(axis)]
    R = np.eye(3)
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


def test_host_twins_match_numpy_references():
    rng = np.random.default_rng(3)
    a, b, c = rng.normal(size=(3, 5, 3))
    R = rot.host_exp(a)
    assert R.shape == (5, 3, 3)
    np.testing.assert_allclose(R, [_rodrigues(w) for w in a], atol=1e-12)
    np.testing.assert_allclose(rot.host_exp(rot.host_log(R)), R, atol=1e-12)
    product = rot.host_compose(a, b, c)  # exp(a) exp(b) exp(c), frame by frame
    np.testing.assert_allclose(rot.host_exp(product), R @ rot.host_exp(b) @ rot.host_exp(c), atol=1e-12)
    np.testing.assert_allclose(rot.host_exp(rot.host_compose(a[0], b)), R[0] @ rot.host_exp(b), atol=1e-12)  # broadcast
    np.testing.assert_allclose(rot.host_exp(rot.host_rotate(R[1], b)), R[1] @ rot.host_exp(b), atol=1e-12)
    with pytest.raises(ValueError, match=r"matrix has shape \(5, 3, 3\); expected one \(3, 3\)"):
        rot.host_rotate(R, b)
    angles = rng.uniform(-3, 3, (4, 3))
    # Lower case: fixed axes, the first applied first; upper case: intrinsic, the first outermost.
    fixed = [_elementary("y", z) @ _elementary("x", y) @ _elementary("z", x) for x, y, z in angles]
    intrinsic = [_elementary("z", x) @ _elementary("x", y) @ _elementary("y", z) for x, y, z in angles]
    np.testing.assert_allclose(rot.host_euler("zxy", angles), fixed, atol=1e-12)
    np.testing.assert_allclose(rot.host_euler("ZXY", np.degrees(angles), degrees=True), intrinsic, atol=1e-12)
    assert rot.host_euler("xz", angles[0, :2]).shape == (3, 3)


def test_host_slerp_moves_at_constant_angular_speed():
    w = np.array([[0.1, 0.2, 0.3], [0.5, -1.0, 0.8]])
    out = rot.host_slerp([0.0, 2.0], w, [0.0, 0.5, 2.0])
    R0, R1 = rot.host_exp(w)
    step = rot.host_log(R0.T @ R1)  # the relative rotation, a quarter of it by t = 0.5
    np.testing.assert_allclose(rot.host_exp(out), [R0, R0 @ rot.host_exp(step / 4), R1], atol=1e-12)
