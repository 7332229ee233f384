"""Object symmetry (`RigidObject.symmetry`) and rotation errors modulo it
(`objects.rotation_error_deg`, `metrics.object_pose_errors`), against closed forms: a
pose composed with one of the object's own symmetries scores 0, a further turn θ about a
non-symmetric axis scores θ, a cylinder scores the angle between its axes."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from jaxmocap.metrics import object_pose_errors
from jaxmocap.objects import RigidObject, rotation_error_deg


def rot(axis, deg):
    return Rotation.from_rotvec(np.radians(deg) * np.asarray(axis, float)).as_matrix()


X, Y, Z = np.eye(3)


@pytest.fixture(scope="module")
def shapes():
    return {"box3": RigidObject.box((0.3, 0.2, 0.1)), "box2": RigidObject.box((0.3, 0.2, 0.2)),
            "bottle": RigidObject.cylinder(), "ball": RigidObject.ball(), "chair": RigidObject.chair()}  # fmt: skip


def test_group_sizes_follow_the_dimensions(shapes):
    # D2 (three 180° flips) for three distinct sides; D4 (8) when two sides are equal.
    assert len(shapes["box3"].symmetry.rotations) == 4
    assert len(shapes["box2"].symmetry.rotations) == 8
    bottle = shapes["bottle"].symmetry
    assert bottle.axis is not None and abs(bottle.axis @ Z) > 0.99 and len(bottle.rotations) == 2
    assert shapes["ball"].symmetry.spherical
    assert len(shapes["chair"].symmetry.rotations) == 1 and shapes["chair"].symmetry.axis is None


@pytest.mark.parametrize("flip", [X, Y, Z])
@pytest.mark.parametrize("theta", [0.0, 7.0, 30.0])
def test_box_flip_then_turn_scores_the_turn(shapes, flip, theta):
    true = Rotation.random(5, random_state=1).as_matrix()
    # A turn θ < 45° about an axis of the flip's own group stays θ from every group member.
    pred = true @ rot(flip, 180) @ rot(Y if flip is X else X, theta)
    sym = shapes["box3"].symmetry
    np.testing.assert_allclose(rotation_error_deg(pred, true, sym), theta, atol=1e-6)
    if theta == 0.0:
        np.testing.assert_allclose(rotation_error_deg(pred, true), 180.0, atol=1e-6)


def test_square_box_turns_a_quarter_about_its_long_axis(shapes):
    true = Rotation.random(4, random_state=2).as_matrix()
    sym = shapes["box2"].symmetry
    np.testing.assert_allclose(rotation_error_deg(true @ rot(X, 90), true, sym), 0.0, atol=1e-6)
    # not about a short axis: the closest member is 90° away (hand: Ry(90)ᵀ Rx(90) is 120°)
    np.testing.assert_allclose(rotation_error_deg(true @ rot(Y, 90), true, sym), 90.0, atol=1e-6)
    assert np.allclose(rotation_error_deg(true @ rot(X, 90), true, shapes["box3"].symmetry), 90.0)


@pytest.mark.parametrize("tilt", [0.0, 12.0, 60.0, 170.0])
def test_cylinder_scores_the_angle_between_its_axes(shapes, tilt):
    true = Rotation.random(3, random_state=3).as_matrix()
    pred = true @ rot(Z, 77.0) @ rot(X, tilt)  # any spin about the axis is free
    expect = min(tilt, 180.0 - tilt)  # the end-over-end flip maps the bottle onto itself
    np.testing.assert_allclose(rotation_error_deg(pred, true, shapes["bottle"].symmetry), expect, atol=1e-5)


def test_ball_is_always_right_and_chair_is_raw(shapes):
    a, b = Rotation.random(6, random_state=4).as_matrix(), Rotation.random(6, random_state=5).as_matrix()
    np.testing.assert_allclose(rotation_error_deg(a, b, shapes["ball"].symmetry), 0.0)
    np.testing.assert_allclose(rotation_error_deg(a, b, shapes["chair"].symmetry), rotation_error_deg(a, b))
    # raw against SciPy's geodesic
    np.testing.assert_allclose(rotation_error_deg(a, b), np.degrees((Rotation.from_matrix(a).inv() *
                               Rotation.from_matrix(b)).magnitude()), atol=1e-6)  # fmt: skip


def test_group_members_map_the_box_onto_itself(shapes):
    obj = shapes["box2"]
    for S in obj.symmetry.rotations:
        moved = (obj.vertices - obj.symmetry.centre) @ S.T + obj.symmetry.centre
        d = np.linalg.norm(moved[:, None] - obj.vertices[None], axis=-1).min(1)
        assert d.max() < 1e-9


def test_object_pose_errors_reports_a_flipped_box_modulo_its_symmetry(shapes):
    obj = shapes["box3"]
    T = 4
    true_R = Rotation.random(T, random_state=6).as_matrix()
    true_t = np.random.default_rng(0).normal(size=(T, 3))
    pred_R = true_R @ rot(Z, 180)  # box centred at the origin: the same shape, t unchanged
    err = object_pose_errors(pred_R, true_t, true_R, true_t, obj.vertices, symmetry=obj.symmetry)
    assert err["add_s_mm"] < 1e-9 and err["rotation_deg"] < 1e-6
    assert abs(err["rotation_raw_deg"] - 180.0) < 1e-6
