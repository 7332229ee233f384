"""Procedural reaches (`motion.reach`) and the pick-up / put-down scenes built on them
(`sensors.objects.pick_and_place` through `interaction_config`).

Everything is measured independently of the code under test: the edited motion is posed
again with `forward`, distances to the object come from trimesh's exact signed distance.
The low-res body walks 40 frames (the reach) or 24 (the scenes: contact frames 6-17).
"""

from types import SimpleNamespace

import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

from jaxmocap.body import default_body, forward
from jaxmocap.motion.library import walk
from jaxmocap.motion.reach import ReachError, contact_point, reach
from jaxmocap.objects import RigidObject
from jaxmocap.sensors.objects import pick_and_place
from jaxmocap.sensors.scenario import interaction_config, make_scenario

T, FRAME, BLEND = 40, 20, 10
FEET = [7, 8, 10, 11]  # ankles and toes


def _pose(body, poses, betas, trans):
    out = forward(
        body,
        jnp.asarray(poses, jnp.float64),
        jnp.asarray(betas, jnp.float64),
        jnp.asarray(trans, jnp.float64),
    )
    return np.asarray(out.vertices), np.asarray(out.joints), np.asarray(out.joint_rotations)


@pytest.fixture(scope="module")
def motion():
    body = default_body("low")
    m = walk(num_frames=T, body=body)
    betas = np.zeros(body.num_betas)
    V, J, G = _pose(body, m.poses, betas, m.trans)
    c, _, _ = contact_point(body, V[FRAME], J[FRAME], G[FRAME], "right_hand")
    # Down by 30 cm and 10 cm further out to the right (-x): a stoop, not an arm swing.
    target = c + np.array([-0.1, -0.3, 0.0])
    return SimpleNamespace(body=body, poses=m.poses, trans=m.trans, betas=betas, joints=J, target=target)


def test_reach_touches_the_target_with_the_feet_planted(motion):
    m = motion
    poses, trans, info = reach(
        m.body, m.poses, m.trans, m.betas, FRAME, "right_hand", m.target, BLEND, return_info=True
    )
    V, J, G = _pose(m.body, poses, m.betas, trans)
    c, _, vertex = contact_point(m.body, V[FRAME], J[FRAME], G[FRAME], "right_hand")
    gap = np.linalg.norm(c - m.target)
    assert gap < 0.01 and abs(gap - info.gap) < 1e-4 and vertex == info.vertex, (gap, info)
    drift = np.linalg.norm(J[FRAME, FEET] - m.joints[FRAME, FEET], axis=-1).max()
    assert drift < 0.01, drift
    # Outside the blend window nothing changes, bit for bit.
    outside = np.abs(np.arange(T) - FRAME) >= BLEND
    np.testing.assert_array_equal(poses[outside], m.poses[outside])
    np.testing.assert_array_equal(trans[outside], m.trans[outside])
    assert np.linalg.norm(J[FRAME] - m.joints[FRAME], axis=-1).max() > 0.25  # a real edit
    # Continuity: no frame-to-frame jump beyond the original's plus what a raised cosine
    # spreads the edit over (its slope is at most π / (2 BLEND) of the displacement).
    step = lambda j: np.linalg.norm(np.diff(j, axis=0), axis=-1).max()  # noqa: E731
    spread = np.pi / (2 * BLEND) * np.linalg.norm(J[FRAME] - m.joints[FRAME], axis=-1).max()
    assert step(J) <= step(m.joints) + spread + 0.005, (step(J), step(m.joints), spread)


def test_unreachable_target_reports_the_gap(motion):
    m = motion
    far = m.target + np.array([0.0, 0.0, 3.0])
    with pytest.raises(ReachError, match=r"cm away") as e:
        reach(m.body, m.poses, m.trans, m.betas, FRAME, "right_hand", far, BLEND)
    assert 1.0 < e.value.gap < 3.0 and e.value.poses.shape == m.poses.shape
    poses, _, info = reach(
        m.body,
        m.poses,
        m.trans,
        m.betas,
        FRAME,
        "right_hand",
        far,
        BLEND,
        tolerance=None,
        return_info=True,
    )
    assert info.gap == pytest.approx(e.value.gap) and np.isfinite(poses).all()


def test_reach_rejects_bad_input(motion):
    m = motion
    args = (m.body, m.poses, m.trans, m.betas)
    for frame in (T, -1, 2.0, True):
        with pytest.raises(ValueError, match=r"outside the motion's 40 frames"):
            reach(*args, frame, "right_hand", m.target)
    with pytest.raises(ValueError, match=r"Unknown contact part 'nose'.*right_grip"):
        reach(*args, FRAME, "nose", m.target)
    for target in ([0.0, 1.0], [np.nan, 0.0, 0.0]):
        with pytest.raises(ValueError, match="finite world point"):
            reach(*args, FRAME, "right_hand", target)
    with pytest.raises(ValueError, match="blend must be an int >= 1"):
        reach(*args, FRAME, "right_hand", m.target, blend=0)
    with pytest.raises(ValueError, match=r"poses \(T, 24, 3\)"):
        reach(m.body, m.poses[:, :22], m.trans, m.betas, FRAME, "right_hand", m.target)
    with pytest.raises(ValueError, match="reach must be True or False"):
        interaction_config(reach="yes")
    box = RigidObject.box()
    with pytest.raises(ValueError, match=r"Contact range \[30, 30\) must lie inside the 40 frames"):
        pick_and_place(box, *args, 30, 30)
    with pytest.raises(ValueError, match="Unknown contact part 'nose'"):
        pick_and_place(box, *args, 5, 30, part="nose")


# --- pick-up and put-down scenes ------------------------------------------------------------


@pytest.fixture(scope="module")
def body():
    return default_body("low")


def _scene(body, name, reach=True):
    cfg = interaction_config(object=name, num_views=1, max_frames=24, width=48, height=36, depth_points=0, reach=reach)
    sc = make_scenario(["walk"], cfg, seed=0, body=body)
    return sc, sc.sequence(0), RigidObject(sc["obj_vertices"].astype(np.float64), sc["obj_faces"])


@pytest.mark.parametrize("name", ["box", "bottle", "chair"])
def test_object_is_picked_up_from_and_put_down_on_the_floor(body, name):
    sc, s, obj = _scene(body, name)
    R, t = s["obj_R"].astype(np.float64), s["obj_t"].astype(np.float64)
    start, end = np.flatnonzero(s["contact"])[[0, -1]] + [0, 1]
    assert (start, end) == (6, 18)
    low = np.einsum("tab,nb->tna", R, obj.vertices)[..., 1].min(1) + t[:, 1]
    rest = np.r_[0:start, end:24]
    assert np.abs(low[rest]).max() < 0.005, low  # on the floor, not floating
    for frames in (slice(0, start + 1), slice(end, 24)):  # at rest
        np.testing.assert_allclose(R[frames], np.broadcast_to(R[frames][0], R[frames].shape), atol=1e-6)
        np.testing.assert_allclose(t[frames], np.broadcast_to(t[frames][0], t[frames].shape), atol=1e-6)
    if name == "chair":  # dragged, tilted on a corner: it travels, its lowest point stays on the floor
        assert np.linalg.norm(t[end - 1, [0, 2]] - t[start, [0, 2]]) > 0.3 and low[start:end].min() > -0.005, (t, low)
    else:  # carried, lifted
        assert low[start:end].max() > low[start] + 0.1, low
    V, J, G = _pose(body, s["poses"][0], s["betas"][0][: body.num_betas], s["trans"][0])
    np.testing.assert_allclose(J, s["joints"][0], atol=1e-4)  # derived arrays follow the edit
    for f in (start, end - 1):  # pick-up and put-down
        c, _, _ = contact_point(body, V[f], J[f], G[f], "right_grip")
        local = (np.vstack([c, V[f]]) - t[f]) @ R[f]  # object frame
        sd = trimesh.proximity.signed_distance(obj.mesh, local)  # > 0 inside
        gap, depth = abs(sd[0]), sd[1:].max()
        assert gap < 0.01 and depth < 0.01, (f, gap, depth)
    if name == "box":  # a deep stoop for a 20 cm box; the old behaviour on request
        _, s0, _ = _scene(body, name, reach=False)
        assert J[start, 0, 1] < s0["joints"][0, start, 0, 1] - 0.08
        R0, t0 = s0["obj_R"].astype(np.float64), s0["obj_t"].astype(np.float64)
        low0 = np.einsum("tab,nb->tna", R0, obj.vertices)[..., 1].min(1) + t0[:, 1]
        assert low0[:start].min() > 0.3 and np.abs(s0["poses"] - s["poses"]).max() > 0.1
