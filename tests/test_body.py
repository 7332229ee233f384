"""The SMPL forward pass: NumPy reference, gradients, batch shapes, dtypes, errors."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmocap
from jaxmocap.body import forward, forward_kinematics, make_body
from conftest import central_difference
from smpl_numpy import smpl_forward_numpy

rng = np.random.default_rng(2)
forward_jit = jax.jit(forward)


def test_matches_independent_numpy_smpl(smpl_dict, random_body):
    for seed in range(3):
        r = np.random.default_rng(seed)
        pose, betas, trans = r.normal(scale=0.6, size=(24, 3)), r.normal(size=10), r.normal(size=3)
        ref_v, ref_j, ref_r = smpl_forward_numpy(smpl_dict, pose, betas, trans)
        out = forward_jit(random_body, pose, betas, trans)
        np.testing.assert_allclose(out.vertices, ref_v, atol=1e-6)
        np.testing.assert_allclose(out.joints, ref_j, atol=1e-6)
        np.testing.assert_allclose(out.joint_rotations, ref_r, atol=1e-6)


def test_fewer_betas_than_components(smpl_dict, random_body):
    betas = rng.normal(size=4)
    ref_v, _, _ = smpl_forward_numpy(smpl_dict, np.zeros((24, 3)), betas, np.zeros(3))
    np.testing.assert_allclose(forward(random_body, np.zeros((24, 3)), betas).vertices, ref_v, atol=1e-9)


def test_no_shape_components_is_the_template_shape(random_body):
    """Motions without a shape (CMU clips: betas of shape (0,)) pose the template body."""
    pose = rng.normal(scale=0.3, size=(2, 24, 3))
    empty = forward(random_body, pose, np.zeros((0,)), np.zeros(3))
    none = forward(random_body, pose, None, np.zeros(3))
    np.testing.assert_allclose(empty.vertices, none.vertices, atol=1e-12)


@pytest.mark.parametrize("batch", [(), (1,), (3, 2)])
def test_batch_shapes_equal_per_sample(random_body, batch):
    pose = rng.normal(scale=0.5, size=(*batch, 24, 3))
    betas = rng.normal(size=(*batch, 10))
    trans = rng.normal(size=(*batch, 3))
    out = forward_jit(random_body, pose, betas, trans)
    V = random_body.num_vertices
    assert out.vertices.shape == (*batch, V, 3)
    assert out.joints.shape == (*batch, 24, 3)
    assert out.joint_rotations.shape == (*batch, 24, 3, 3)
    flat = jax.vmap(lambda p, b, t: forward(random_body, p, b, t))(
        pose.reshape(-1, 24, 3), betas.reshape(-1, 10), trans.reshape(-1, 3)
    )
    np.testing.assert_allclose(out.vertices.reshape(-1, V, 3), flat.vertices, atol=1e-12)


def test_broadcasting_shared_shape(random_body):
    out = forward_jit(random_body, rng.normal(size=(5, 24, 3)), rng.normal(size=10), np.zeros(3))
    assert out.vertices.shape == (5, random_body.num_vertices, 3)


@pytest.mark.parametrize("where", ["zero", "random", "near_pi"])
def test_skinning_gradients(random_body, where):
    """jacfwd == jacrev ≈ finite differences of vertices w.r.t. pose (a few joints)."""
    pose = {
        "zero": np.zeros((24, 3)),
        "random": rng.normal(scale=0.5, size=(24, 3)),
        "near_pi": np.tile([0.0, 0.0, np.pi - 1e-6], (24, 1)),
    }[where]
    joints = np.array([0, 4, 18])  # root, knee, elbow: all of skinning and FK are exercised

    def f(sub):
        p = jnp.asarray(pose).at[joints].set(sub.reshape(3, 3))
        out = forward(random_body, p, jnp.zeros(10), jnp.zeros(3))
        return jnp.concatenate([out.vertices[::7].ravel(), out.joints.ravel()])

    x = pose[joints].ravel()
    fwd = jax.jit(jax.jacfwd(f))(jnp.asarray(x))
    rev = jax.jit(jax.jacrev(f))(jnp.asarray(x))
    fd = central_difference(lambda y: f(jnp.asarray(y)), x, eps=1e-7 if where == "near_pi" else 1e-6)
    assert np.isfinite(fwd).all()
    np.testing.assert_allclose(fwd, rev, atol=1e-10)
    np.testing.assert_allclose(fwd, fd, atol=2e-6)


def test_shape_gradient_and_translation(random_body):
    f = lambda b: forward(random_body, jnp.zeros((24, 3)), b, jnp.zeros(3)).vertices  # noqa: E731
    jac = jax.jacfwd(f)(jnp.zeros(10))
    np.testing.assert_allclose(jac, np.moveaxis(random_body.shapedirs, 0, -1), atol=1e-12)  # linear in β at rest
    shift = forward_jit(random_body, np.zeros((24, 3)), np.zeros(10), np.array([1.0, 2.0, 3.0]))
    base = forward_jit(random_body, np.zeros((24, 3)), np.zeros(10), np.zeros(3))
    np.testing.assert_allclose(shift.vertices - base.vertices, np.broadcast_to([1.0, 2.0, 3.0], base.vertices.shape), atol=1e-12)


def test_forward_kinematics_closed_form():
    """A two-bone chain: rotate the root 90° about z, the child bone end lands on -x... +y."""
    parents = (-1, 0, 1)
    rest = jnp.array([[0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0]])
    local = jaxmocap.rotation.axis_angle_to_matrix(jnp.array([[0, 0, np.pi / 2], [0, 0, np.pi / 2], [0, 0, 0.0]]))
    R, p = forward_kinematics(parents, local, rest)
    np.testing.assert_allclose(p, [[0, 0, 0], [0, 1, 0], [-1, 1, 0]], atol=1e-12)
    np.testing.assert_allclose(R[2], jaxmocap.rotation.axis_angle_to_matrix(jnp.array([0, 0, np.pi])), atol=1e-12)


def test_float32_and_float64(random_body):
    pose = rng.normal(scale=0.5, size=(24, 3))
    v64 = forward_jit(random_body, pose).vertices
    v32 = forward_jit(random_body.astype(jnp.float32), pose.astype(np.float32)).vertices
    assert v64.dtype == jnp.float64 and v32.dtype == jnp.float32
    np.testing.assert_allclose(v32, v64, atol=1e-5)


def test_rest_pose_is_template(random_body):
    out = forward_jit(random_body, np.zeros((24, 3)), np.zeros(10), np.zeros(3))
    np.testing.assert_allclose(out.vertices, random_body.v_template, atol=1e-12)


def test_bad_shapes_are_named(random_body):
    with pytest.raises(ValueError, match=r"pose has shape \(72,\)"):
        forward(random_body, np.zeros(72))
    with pytest.raises(ValueError, match="betas has shape"):
        forward(random_body, np.zeros((24, 3)), np.zeros(11))
    with pytest.raises(ValueError, match="trans has shape"):
        forward(random_body, np.zeros((24, 3)), None, np.zeros(2))
    with pytest.raises(ValueError, match="do not broadcast"):
        forward(random_body, np.zeros((4, 24, 3)), np.zeros((3, 10)))
    with pytest.raises(ValueError, match="shapedirs has shape"):
        make_body(np.zeros((5, 3)), [[0, 1, 2]], np.zeros((4, 3, 2)), np.zeros((5, 3, 207)), np.zeros((24, 5)), np.zeros((5, 24)))


def test_body_is_a_pytree_with_static_topology(random_body):
    leaves = jax.tree_util.tree_leaves(random_body)
    assert len(leaves) == 5 and all(isinstance(x, jax.Array) for x in leaves)
    # Same topology -> same treedef, so jit caches are shared between bodies.
    other = jax.tree_util.tree_map(lambda x: x * 1.0, random_body)
    assert jax.tree_util.tree_structure(other) == jax.tree_util.tree_structure(random_body)
    vmapped = jax.vmap(lambda b: forward(b, jnp.zeros((24, 3))).vertices)(
        jax.tree_util.tree_map(lambda x: jnp.stack([x, x]), random_body)
    )
    assert vmapped.shape == (2, random_body.num_vertices, 3)
