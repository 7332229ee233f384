"""The SMPL forward pass: NumPy reference, gradients, batch shapes, dtypes, errors."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmocap
from jaxmocap.body import forward, forward_kinematics, kinematics, make_body
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
    np.testing.assert_allclose(forward_jit(random_body, np.zeros((24, 3)), betas).vertices, ref_v, atol=1e-9)


def test_no_shape_components_is_the_template_shape(random_body):
    """Motions without a shape (CMU clips: betas of shape (0,)) pose the template body."""
    pose = rng.normal(scale=0.3, size=(2, 24, 3))
    empty = forward_jit(random_body, pose, np.zeros((0,)), np.zeros(3))
    none = forward_jit(random_body, pose, None, np.zeros(3))
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
    flat = jax.jit(jax.vmap(forward, (None, 0, 0, 0)))(
        random_body, pose.reshape(-1, 24, 3), betas.reshape(-1, 10), trans.reshape(-1, 3)
    )
    np.testing.assert_allclose(out.vertices.reshape(-1, V, 3), flat.vertices, atol=1e-12)


def test_broadcasting_shared_shape(random_body):
    out = forward_jit(random_body, rng.normal(size=(5, 24, 3)), rng.normal(size=10), np.zeros(3))
    assert out.vertices.shape == (5, random_body.num_vertices, 3)


_GRADIENT_JOINTS = np.array([0, 4, 18])  # root, knee, elbow: all of skinning and FK are exercised


def _some_vertices_and_joints(sub, pose, body):
    """Every 7th vertex and the joints, with the pose of `_GRADIENT_JOINTS` set to `sub`."""
    p = pose.at[_GRADIENT_JOINTS].set(sub.reshape(3, 3))
    out = forward(body, p, jnp.zeros(10), jnp.zeros(3))
    return jnp.concatenate([out.vertices[::7].ravel(), out.joints.ravel()])


# The pose is an argument, not a constant: the three cases share these compiled programs.
_some_vertices_and_joints_jit = jax.jit(_some_vertices_and_joints)
_jacfwd_of_some = jax.jit(jax.jacfwd(_some_vertices_and_joints))
_jacrev_of_some = jax.jit(jax.jacrev(_some_vertices_and_joints))


@pytest.mark.parametrize("where", ["zero", "random", "near_pi"])
def test_skinning_gradients(random_body, where):
    """jacfwd == jacrev ≈ finite differences of vertices w.r.t. pose (a few joints)."""
    pose = {
        "zero": np.zeros((24, 3)),
        "random": rng.normal(scale=0.5, size=(24, 3)),
        "near_pi": np.tile([0.0, 0.0, np.pi - 1e-6], (24, 1)),
    }[where]
    pose = jnp.asarray(pose)
    x = np.asarray(pose[_GRADIENT_JOINTS]).ravel()
    fwd = _jacfwd_of_some(jnp.asarray(x), pose, random_body)
    rev = _jacrev_of_some(jnp.asarray(x), pose, random_body)
    fd = central_difference(
        lambda y: _some_vertices_and_joints_jit(jnp.asarray(y), pose, random_body),
        x,
        eps=1e-7 if where == "near_pi" else 1e-6,
    )
    assert np.isfinite(fwd).all()
    np.testing.assert_allclose(fwd, rev, atol=1e-10)
    np.testing.assert_allclose(fwd, fd, atol=2e-6)


def test_shape_gradient_and_translation(random_body):
    f = lambda b: forward(random_body, jnp.zeros((24, 3)), b, jnp.zeros(3)).vertices  # noqa: E731
    jac = jax.jit(jax.jacfwd(f))(jnp.zeros(10))
    np.testing.assert_allclose(jac, np.moveaxis(random_body.shapedirs, 0, -1), atol=1e-12)  # linear in β at rest
    shift = forward_jit(random_body, np.zeros((24, 3)), np.zeros(10), np.array([1.0, 2.0, 3.0]))
    base = forward_jit(random_body, np.zeros((24, 3)), np.zeros(10), np.zeros(3))
    np.testing.assert_allclose(
        shift.vertices - base.vertices, np.broadcast_to([1.0, 2.0, 3.0], base.vertices.shape), atol=1e-12
    )


def test_forward_kinematics_closed_form():
    """A two-bone chain: rotate the root 90° about z, the child bone end lands on -x... +y."""
    parents = (-1, 0, 1)
    rest = jnp.array([[0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0]])
    exp = jax.jit(jaxmocap.rotation.axis_angle_to_matrix)
    local = exp(jnp.array([[0, 0, np.pi / 2], [0, 0, np.pi / 2], [0, 0, 0.0]]))
    R, p = jax.jit(forward_kinematics, static_argnums=0)(parents, local, rest)
    np.testing.assert_allclose(p, [[0, 0, 0], [0, 1, 0], [-1, 1, 0]], atol=1e-12)
    np.testing.assert_allclose(R[2], exp(jnp.array([0, 0, np.pi])), atol=1e-12)


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
        make_body(
            np.zeros((5, 3)),
            [[0, 1, 2]],
            np.zeros((4, 3, 2)),
            np.zeros((5, 3, 207)),
            np.zeros((24, 5)),
            np.zeros((5, 24)),
        )


def test_body_is_a_pytree_with_static_topology(random_body):
    leaves = jax.tree_util.tree_leaves(random_body)
    assert len(leaves) == 5 and all(isinstance(x, jax.Array) for x in leaves)
    # Same topology -> same treedef, so jit caches are shared between bodies.
    other = jax.tree_util.tree_map(lambda x: x * 1.0, random_body)
    assert jax.tree_util.tree_structure(other) == jax.tree_util.tree_structure(random_body)
    vmapped = jax.jit(jax.vmap(lambda b: forward(b, jnp.zeros((24, 3))).vertices))(
        jax.tree_util.tree_map(lambda x: jnp.stack([x, x]), random_body)
    )
    assert vmapped.shape == (2, random_body.num_vertices, 3)


# Sparse skinning (the GPU path): each vertex's few non-zero weights instead of all joints.


def _sparsified_body(smpl_dict, per_vertex=4, seed=5):
    """The random test model with at most `per_vertex` non-zero weights per vertex."""
    d = smpl_dict
    r = np.random.default_rng(seed)
    weights = np.zeros_like(d["weights"])
    for _ in range(per_vertex):
        weights[np.arange(len(weights)), r.integers(0, 24, len(weights))] += r.random(len(weights))
    weights /= weights.sum(1, keepdims=True)
    return make_body(
        d["v_template"], d["f"], d["shapedirs"], d["posedirs"], d["J_regressor"], weights, dtype=np.float64
    )


def _skinning_inputs(body, n, seed):
    """Random (n, J, 3, 4) skinning transforms (rotation + offset) and (n, V, 3) rest vertices."""
    r = np.random.default_rng(seed)
    rot = jaxmocap.rotation.axis_angle_to_matrix(jnp.asarray(r.normal(size=(n, body.num_joints, 3)), body.dtype))
    transforms = jnp.concatenate([rot, jnp.asarray(r.normal(size=(n, body.num_joints, 3, 1)), body.dtype)], -1)
    return transforms, jnp.asarray(r.normal(scale=0.5, size=(n, body.num_vertices, 3)), body.dtype)


def test_max_influences_counts_non_zero_weights(smpl_dict, random_body):
    assert random_body.max_influences == 24  # random weights: every joint non-zero
    body = _sparsified_body(smpl_dict)
    assert body.max_influences == int(np.count_nonzero(np.asarray(body.weights), axis=1).max()) <= 4
    low = jaxmocap.default_body("low")
    assert low.max_influences == int(np.count_nonzero(np.asarray(low.weights), axis=1).max())
    assert low.astype(jnp.float64).max_influences == low.max_influences
    assert jaxmocap.body.mannequin_body(detail=0).max_influences == 1  # rigid parts
    with pytest.raises(ValueError, match="non-zero skinning weights"):
        dataclasses.replace(low, max_influences=1)


@pytest.mark.parametrize("which", ["sparsified", "random", "default_low"])
def test_sparse_skinning_equals_dense(smpl_dict, random_body, which):
    body = {
        "sparsified": lambda: _sparsified_body(smpl_dict),
        "random": lambda: random_body,  # 24 influences: top_k keeps them all
        "default_low": lambda: jaxmocap.default_body("low").astype(jnp.float64),
    }[which]()
    transforms, v_posed = _skinning_inputs(body, 3, seed=1)
    dense = jax.jit(kinematics._skin_dense)(body, transforms, v_posed)
    sparse = jax.jit(kinematics._skin_sparse)(body, transforms, v_posed)
    assert sparse.dtype == jnp.float64
    np.testing.assert_allclose(sparse, dense, atol=1e-12)
    # Whole forward pass, float32, explicit paths against each other.
    b32 = body.astype(jnp.float32)
    pose = rng.normal(scale=0.5, size=(4, 24, 3)).astype(np.float32)
    local = jaxmocap.rotation.axis_angle_to_matrix(jnp.asarray(pose))
    betas = rng.normal(size=(4, body.num_betas)).astype(np.float32)
    out = {
        s: jax.jit(lambda b, r, s_=s: kinematics.forward_rotations_unchecked(b, r, betas, skinning=s_).vertices)(
            b32, local
        )
        for s in ("dense", "sparse")
    }
    np.testing.assert_allclose(out["sparse"], out["dense"], atol=2e-6)


def test_automatic_skinning_is_dense_on_cpu(smpl_dict):
    """`forward` picks per platform; on the CPU it must stage out the dense product only."""
    body = _sparsified_body(smpl_dict)
    pose = rng.normal(scale=0.5, size=(2, 24, 3))
    hlo = jax.jit(forward).lower(body, pose).compile().as_text()
    dense = jax.jit(lambda b, r: kinematics.forward_rotations_unchecked(b, r, skinning="dense").vertices)
    if jax.default_backend() == "cpu":
        # The sparse path sorts and gathers per vertex; the kinematic chain's static joint
        # indices are gathers too, so compare against the explicitly dense program.
        dense_hlo = jax.jit(lambda b, p: kinematics.forward_rotations_unchecked(
            b, jaxmocap.rotation.axis_angle_to_matrix(p), skinning="dense")).lower(body, pose).compile().as_text()  # fmt: skip
        assert "sort" not in hlo and hlo.count("gather(") == dense_hlo.count("gather(")
    np.testing.assert_allclose(
        forward_jit(body, pose).vertices,
        dense(body, jaxmocap.rotation.axis_angle_to_matrix(jnp.asarray(pose))),
        atol=1e-12,
    )


@pytest.mark.parametrize("where", ["zero", "random"])
def test_sparse_skinning_gradients(smpl_dict, where):
    """Vertices' pose Jacobians through the sparse path: finite (zero pose included) and
    equal to the dense path's, forward and reverse mode."""
    body = _sparsified_body(smpl_dict)
    pose0 = np.zeros((24, 3)) if where == "zero" else rng.normal(scale=0.5, size=(24, 3))

    def vertices(skinning):
        def f(p):
            local = jaxmocap.rotation.axis_angle_to_matrix(p)
            return (
                kinematics.forward_rotations_unchecked(body, local, jnp.zeros(10), skinning=skinning)
                .vertices[::5]
                .ravel()
            )

        return f

    x = jnp.asarray(pose0)
    sparse_rev = jax.jit(jax.jacrev(vertices("sparse")))(x)
    sparse_fwd = jax.jit(jax.jacfwd(vertices("sparse")))(x)
    dense_fwd = jax.jit(jax.jacfwd(vertices("dense")))(x)
    assert np.isfinite(sparse_rev).all() and np.isfinite(sparse_fwd).all()
    np.testing.assert_allclose(sparse_rev, dense_fwd, atol=1e-10)
    np.testing.assert_allclose(sparse_fwd, dense_fwd, atol=1e-10)


def test_one_and_two_blend_products_agree(random_body):
    """Shape and pose blend shapes as one product against the stacked bases or as two."""
    pose = jaxmocap.rotation.axis_angle_to_matrix(jnp.asarray(rng.normal(scale=0.5, size=(3, 24, 3))))
    betas = rng.normal(size=(3, 10))

    def run(joint):
        return jax.jit(lambda b: kinematics.forward_rotations_unchecked(b, pose, betas, joint_blend=joint).vertices)(
            random_body
        )

    np.testing.assert_allclose(run(True), run(False), atol=1e-12)


def test_sparse_skinning_derivatives_match_dense(smpl_dict):
    """Sparse skinning differentiates as the dense product: the same gradient with respect
    to every leaf of the body (weights included, all joints) and the same second
    derivatives."""
    body = _sparsified_body(smpl_dict)
    transforms, v_posed = _skinning_inputs(body, 2, seed=3)
    probe = jnp.asarray(rng.normal(size=(2, body.num_vertices, 3)))

    def loss(skin):
        return lambda b, t, v: jnp.sum(probe * skin(b, t, v) ** 2)

    grads = {
        name: jax.jit(jax.grad(loss(skin), argnums=(0, 1, 2)))(body, transforms, v_posed)
        for name, skin in (("dense", kinematics._skin_dense), ("sparse", kinematics._skin_sparse))
    }
    for d, s in zip(jax.tree_util.tree_leaves(grads["dense"]), jax.tree_util.tree_leaves(grads["sparse"])):
        np.testing.assert_allclose(s, d, atol=1e-10)
    t1, v1, p1 = transforms[:1], v_posed[:1], probe[:1]

    def second(skin):
        return jax.jit(jax.hessian(lambda t: jnp.sum(p1 * skin(body, t, v1) ** 2)))(t1)

    np.testing.assert_allclose(second(kinematics._skin_sparse), second(kinematics._skin_dense), atol=1e-9)


def test_compact_body_poses_exactly_like_the_mesh():
    """`compact_body`: joints, joint rotations, keypoints and kept vertices of the full body."""
    from jaxmocap.body.compact import compact_body
    from jaxmocap.geometry.keypoints import keypoint_regressor, regress_keypoints

    body = jaxmocap.default_body("low").astype(jnp.float64)
    reg = keypoint_regressor(body, "coco18")
    keep = np.array([0, 100, 700])
    small, small_reg, _ = compact_body(body, reg, keep)
    rng = np.random.default_rng(0)
    pose, betas, trans = rng.normal(0, 0.4, (3, 24, 3)), rng.normal(0, 1, (3, 10)), rng.normal(0, 1, (3, 3))
    full, cut = (forward(b, jnp.asarray(pose), jnp.asarray(betas), jnp.asarray(trans))
                 for b in (body, small))  # fmt: skip
    np.testing.assert_allclose(cut.joints, full.joints, atol=1e-9)
    np.testing.assert_allclose(cut.joint_rotations, full.joint_rotations, atol=1e-9)
    np.testing.assert_allclose(cut.vertices[:, :3], full.vertices[:, keep], atol=1e-9)
    np.testing.assert_allclose(
        regress_keypoints(small_reg, cut.vertices, cut.joints),
        regress_keypoints(reg, full.vertices, full.joints),
        atol=1e-9,
    )
    on_mesh = np.asarray(reg)[:, : body.num_vertices]
    assert small.num_vertices == 3 + int((np.abs(on_mesh @ np.asarray(body.weights)) > 1e-12).sum()) + 24


@pytest.mark.parametrize("columns", [0, 66])
def test_padded_blend_product_is_the_same(random_body, columns):
    """Accelerators widen the stacked blend product with zero columns (`_stacked_blend`):
    the padded vertices are sliced off and the rest are unchanged."""
    V = random_body.num_vertices
    coeffs = jnp.asarray(rng.normal(size=(5, 32)))
    bases = jnp.asarray(rng.normal(size=(32, 3 * V)))
    template = random_body.v_template.reshape(-1)
    out = kinematics._stacked_blend(coeffs, bases, template, columns)
    assert out.shape == (5, V, 3)
    np.testing.assert_allclose(out, (template + coeffs @ bases).reshape(5, V, 3), atol=1e-12)
