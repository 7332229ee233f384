"""InterCap benchmark data (Huang ch. 5): the chair, the interaction preset, segmentation
candidates and the temporal selection rule.

One tiny scene (low-res body carrying the chair, unedited walk: no pick-up, 3 views of
96 x 72 px, 256 depth points, 10 frames: test_interaction's shapes, so the suite's
compiled programs serve both) is shared by the module; mask errors are checked on synthetic label images, where the
object is large enough for them to show (in the tiny scene it spans a few dozen pixels,
so the size-limited boundary error is mostly zero).
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

from jaxmocap.geometry.masks import select_candidate
from jaxmocap.objects import RigidObject
from jaxmocap.sensors import DepthNoiseModel, make_scenario
from jaxmocap.sensors.scenario import interaction_config
from jaxmocap.sensors.segmentation import object_candidates

V, T, W, H, M = 3, 10, 96, 72, 256


# A signed distance field's lookup as one compiled program (eagerly, each of its operations compiled).
_sdf_at = jax.jit(lambda sdf, points: sdf(points))


def _iou(a, b):
    return np.count_nonzero(a & b) / max(np.count_nonzero(a | b), 1)


@pytest.fixture(scope="module")
def chair():
    return RigidObject.chair()


@pytest.fixture(scope="module")
def scene():
    # reach=False: no pick-up edit (tested in test_reach), whose IK solve compiled ~25 CPU-s
    cfg = interaction_config(object="chair", num_views=V, max_frames=T, width=W, height=H, depth_points=M, reach=False)
    return make_scenario(["walk"], cfg, seed=0)


# --- the chair ---------------------------------------------------------------------------


def test_chair_parts_are_disjoint_and_its_sdf_has_the_right_sign(chair):
    assert chair.mesh.is_watertight and not chair.mesh.is_convex and len(chair.parts) == 6
    boxes = [(v.min(0), v.max(0)) for v, _ in chair.parts]
    for i in range(len(boxes)):
        for j in range(i):
            gap = np.max(np.maximum(boxes[j][0] - boxes[i][1], boxes[i][0] - boxes[j][1]))
            assert gap >= 0.002 - 1e-12, (i, j, gap)  # apart along some axis
    lo, hi = chair.mesh.bounds
    assert np.allclose(lo + hi, 0) and 0.75 < hi[1] - lo[1] < 0.85
    sdf = chair.sdf()
    leg = np.array([0.18, -0.2, 0.18])  # centre of a front leg
    seat = np.array([0.0, 0.03, 0.0])  # centre of the seat
    under = np.array([0.0, -0.2, 0.0])  # between the legs, inside the convex hull
    d = np.asarray(_sdf_at(sdf, jnp.asarray(np.stack([leg, seat, under]))))
    assert d[0] < -0.005 and d[1] < -0.005 and d[2] > 0.15, d
    # Outside points further than one grid cell diagonal from the surface: never negative.
    pts = np.random.default_rng(0).uniform(lo - 0.1, hi + 0.1, (4000, 3))
    exact = -trimesh.proximity.signed_distance(chair.mesh, pts)
    np.testing.assert_array_equal(exact > 0, ~chair.mesh.contains(pts))
    far = exact > np.linalg.norm(np.asarray(sdf.spacing))
    assert far.sum() > 2000 and np.all(np.asarray(_sdf_at(sdf, jnp.asarray(pts[far]))) > 0)
    with pytest.raises(ValueError, match="gap"):
        RigidObject.chair(gap=0.001)


# --- the interaction preset --------------------------------------------------------------


def test_interaction_config_rejects_bad_arguments():
    with pytest.raises(ValueError, match=r"'table'.*\['ball', 'bottle', 'box', 'chair'\]"):
        interaction_config(object="table")
    with pytest.raises(ValueError, match="num_views"):
        interaction_config(num_views=0)
    with pytest.raises(ValueError, match="depth_points"):
        interaction_config(depth_points=-1)
    with pytest.raises(ValueError, match="fps"):
        interaction_config(fps=0.0)
    with pytest.raises(ValueError, match="contact part"):
        interaction_config(contact_part="nose")
    with pytest.raises(ValueError, match="detector"):
        interaction_config(detector="openpose")
    cfg = interaction_config(depth_noise=DepthNoiseModel.off())
    assert cfg.depth_noise.missing_rate == 0 and cfg.cameras.num_views == 4 and cfg.imu_set is None


def test_scene_has_the_documented_arrays(scene, chair):
    a = scene.arrays
    shapes = {
        "labels": (1, V, T, H, W), "depth_points": (1, V, T, M, 3), "depth_labels": (1, V, T, M),
        "depth_valid": (1, V, T, M), "det_keypoints": (1, V, T, 1, 25, 3), "det_person": (1, V, T, 1),
        "kp_true": (1, 1, V, T, 25, 2), "cam_R": (1, V, T, 3, 3), "cam_t": (1, V, T, 3),
        "obj_R": (1, T, 3, 3), "obj_t": (1, T, 3), "contact": (1, T), "poses": (1, 1, T, 24, 3),
    }  # fmt: skip
    for k, shape in shapes.items():
        assert a[k].shape == shape, (k, a[k].shape)
    assert a["visible"].shape[:4] == (1, V, T, 1) and "imu_ori" not in a
    assert a["labels"].dtype == np.int8 and set(np.unique(a["labels"])) <= {-2, -1, 0, 1}
    assert (a["labels"] == 1).sum((-1, -2)).min() > 0  # the chair (label P = 1) in every view and frame
    assert not a["det_swapped"].any() and set(np.unique(a["det_person"])) <= {-2, 0}
    np.testing.assert_array_equal(a["obj_vertices"], chair.vertices)
    assert 0 < a["contact"].sum() < T


def test_object_depth_points_lie_on_the_object(scene, chair):
    s = scene.sequence(0)
    on = (s["depth_labels"] == 1) & s["depth_valid"]  # (V, T, M)
    assert on.sum(-1).min() >= 5
    t = np.nonzero(on)[1]
    local = np.einsum("nba,nb->na", s["obj_R"][t], s["depth_points"][on] - s["obj_t"][t])  # Rᵀ (p - t)
    d = np.abs(np.asarray(_sdf_at(chair.sdf(), jnp.asarray(local))))
    # Kinect-like axial noise at ~4.5 m is σ_z ≈ 3 cm, so the bound is statistical.
    assert np.median(d) < 0.02 and np.percentile(d, 95) < 0.06, (np.median(d), np.percentile(d, 95))


# --- segmentation candidates -------------------------------------------------------------


def test_candidates_hold_the_object_at_true_index(scene):
    labels = scene.sequence(0)["labels"]
    cand, idx = object_candidates(labels, 1, np.random.default_rng(0))
    assert cand.shape == (T, V, 3, H, W) and cand.dtype == bool and idx.shape == (T, V)
    clean = np.swapaxes(labels == 1, 0, 1)  # (T, V, H, W)
    for t in range(T):
        for v in range(V):
            for k in range(3):
                iou = _iou(cand[t, v, k], clean[t, v])
                if k == idx[t, v]:
                    assert iou > 0.6, (t, v, iou)
                else:
                    assert iou < 0.1, (t, v, k, iou)
            if idx[t, v] < 0:
                assert sum(not cand[t, v, k].any() for k in range(3)) == 1  # the missed object's slot
    again = object_candidates(labels, 1, np.random.default_rng(0))
    np.testing.assert_array_equal(cand, again[0])
    np.testing.assert_array_equal(idx, again[1])


def test_mask_errors_misses_and_invisible_views():
    # A 24 x 32 px object moving across view 0; view 1 never sees it.
    labels = np.full((2, 30, H, W), -1, np.int8)
    for t in range(30):
        labels[0, t, 20:44, t : t + 32] = 1
    cand, idx = object_candidates(labels, 1, np.random.default_rng(1), num_distractors=3, miss_rate=0.2)
    assert cand.shape == (30, 2, 4, H, W)
    assert np.all(idx[:, 1] == -1) and np.all(cand[:, 1].any((-1, -2)).sum(-1) == 3)
    hit = np.flatnonzero(idx[:, 0] >= 0)
    assert 15 <= len(hit) <= 29  # ~ 20 % missed
    ious = np.array([_iou(cand[t, 0, idx[t, 0]], labels[0, t] == 1) for t in hit])
    assert ious.min() > 0.6 and (ious < 0.99).sum() >= 5, ious  # corrupted, not replaced
    area = (labels[0] == 1).sum((-1, -2))[0]
    sizes = cand[:, 0].sum((-1, -2))
    assert np.all(sizes[idx[:, 0] < 0].min(-1) == 0)  # a miss leaves an empty slot
    assert 0.3 * area < np.median(sizes) < 2.0 * area  # distractors of similar area


def test_select_candidate_follows_the_previous_frame(scene):
    labels = scene.sequence(0)["labels"]
    cand, idx = object_candidates(labels, 1, np.random.default_rng(2))
    clean = labels == 1  # (V, T, H, W)
    right = total = 0
    for t in range(1, T):
        pick = select_candidate(cand[t], clean[:, t - 1])
        assert pick.shape == (V,)
        ok = idx[t] >= 0
        right += int((pick[ok] == idx[t][ok]).sum())
        total += int(ok.sum())
    assert total >= 15 and right / total >= 0.9, (right, total)
    # No overlap, or an empty reference: -1.
    c = np.zeros((1, 2, 8, 8), bool)
    c[0, 0, :2, :2] = c[0, 1, 5:, 5:] = True
    ref = np.zeros((1, 8, 8), bool)
    assert select_candidate(c, ref)[0] == -1
    ref[0, 3, 3] = True
    assert select_candidate(c, ref)[0] == -1
    ref[0, 4:7, 4:7] = True
    assert select_candidate(c, ref)[0] == 1


def test_segmentation_rejects_bad_inputs():
    labels = np.zeros((2, 3, 8, 8), np.int8)
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match=r"\(V, T, H, W\)"):
        object_candidates(labels[0], 1, rng)
    with pytest.raises(ValueError, match="integer"):
        object_candidates(labels.astype(float), 1, rng)
    with pytest.raises(ValueError, match="miss_rate"):
        object_candidates(labels, 1, rng, miss_rate=1.5)
    with pytest.raises(ValueError, match="num_distractors"):
        object_candidates(labels, 1, rng, num_distractors=-1)
    with pytest.raises(ValueError, match="object_label"):
        object_candidates(labels, -2, rng)
    c = np.zeros((2, 3, 8, 8), bool)
    with pytest.raises(ValueError, match=r"reference must be \(V, H, W\)"):
        select_candidate(c, np.zeros((2, 8, 9), bool))
    with pytest.raises(ValueError, match="bool"):
        select_candidate(c.astype(np.uint8), np.zeros((2, 8, 8), bool))
