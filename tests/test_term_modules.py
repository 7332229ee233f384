"""Terms are equinox modules with static configuration (issue 49): a problem built twice
with the same settings is the same static pytree, so `solve`'s jit reuses one program
without the methods caching their problems; other settings give another program."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import pytest

from jaxmocap.energies import camera as ec
from jaxmocap.energies import interaction as ei
from jaxmocap.energies import visual_inertial as ev
from jaxmocap.methods import interaction as mi
from jaxmocap.methods import multiview as mv
from jaxmocap.methods import visual_inertial as vip

FLOOR = ((0.0, 1.0, 0.0), 0.1, (11, 14), (0.02, 0.03), 0.05)


def _static(problem):
    """What `eqx.filter_jit` compiles against: the tree structure with every non-array leaf."""
    return jax.tree_util.tree_structure(eqx.partition(problem, eqx.is_array)[1]), eqx.partition(problem, eqx.is_array)[
        1
    ]


BUILDERS = {
    "muvs_stage_one": lambda s: mv._weighted(
        mv._stage_one_problem(s, 2, 2.0, True, 1.0, FLOOR), mv.MuVSWeights(), jnp.float32
    ),
    "muvs_stage_two": lambda s: mv._stage_two_problem(s, 2, 2.0, True, 30, 10, 0.05, 1.0, FLOOR),
    "intercap_joint": lambda s: mi._weighted(mi._JOINT_TERMS, mi.InterCapWeights(sigma=s), jnp.float32),
    "vip": lambda s: vip._vip_problem((1, 2, 4, 5), 30.0, True, True, True, s),
    "vip_tracker": lambda s: vip._tracker_problem((1, 2, 4) if s == 100.0 else (1, 2, 5)),
}


@pytest.mark.parametrize("name", sorted(BUILDERS))
def test_equal_settings_build_equal_problems_and_others_do_not(name):
    build = BUILDERS[name]
    (tree_a, leaves_a), (tree_b, leaves_b) = _static(build(100.0)), _static(build(100.0))
    assert tree_a == tree_b and hash(tree_a) == hash(tree_b) and leaves_a == leaves_b
    tree_c, _ = _static(build(50.0))
    assert tree_c != tree_a


def test_every_term_function_and_mask_is_a_module_or_a_module_level_function():
    terms = [
        ec.keypoint_term(), *ec.silhouette_terms(), ec.shape_term(), ec.pose_prior_term(), ec.temporal_term(),
        ei.object_mask_term(), ei.object_depth_term(), ei.body_depth_term(), ei.bend_term(),
        ei.self_penetration_term(), ei.smoothness_term(), ei.object_smoothness_term(), ei.penetration_term(),
        ei.ground_term(), ei.object_ground_term(), ei.contact_term(), ei.floor_contact_term(*FLOOR),
        ev.heading_orientation_term((1, 2), 1.0), ev.heading_acceleration_term((1, 2), 30.0, 1.0),
        ev.camera_orientation_term(1.0), ev.camera_acceleration_term(30.0, 1.0), ev.image_term(1.0),
        ev.initial_pose_term(1.0),
    ]  # fmt: skip
    for t in terms:
        for f in (t.fn, t.mask, t.jacobian, t.basis and t.basis.features):
            if f is None or isinstance(f, eqx.Module):
                continue
            # A closure would be a new function per problem, and a new compile.
            assert "<locals>" not in f.__qualname__ and f.__name__ != "<lambda>", (t.name, f)


def test_the_old_posed_body_helper_warns_and_poses_the_body(random_body):
    """`posed_body` is kept for one release: it warns and equals the forward pass."""
    import jax.numpy as jnp
    import pytest

    from jaxmocap.body.kinematics import forward_rotations
    from jaxmocap.energies.posed import posed_body

    params = {"pose": jnp.broadcast_to(jnp.eye(3), (2, random_body.num_joints, 3, 3)), "trans": jnp.ones((2, 3))}
    with pytest.warns(DeprecationWarning, match="PosedBody"):
        out = posed_body(params, random_body)
    want = forward_rotations(random_body, params["pose"], None, params["trans"])
    assert jnp.array_equal(out.vertices, want.vertices) and jnp.array_equal(out.joints, want.joints)
