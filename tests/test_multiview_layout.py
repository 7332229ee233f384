"""BODY_25 or BODY_25B, told from the skeleton (issue 47, goal 2), in both directions.

The detections are the default body's keypoints of a walk in either layout, projected
into four cameras with 3 px noise and 10 % of points missed; no fitting. Margins measured
when this was written (score = median relative segment-length error, `app.layout`):
4 views, true layout 0.05 against 0.41-0.58 for the other; one view 0.13 against 0.57-0.60.
"""

import numpy as np
import pytest

from jaxmocap.app import layout as layout_module
from jaxmocap.app.layout import check_layout, layout_scores
from jaxmocap.body import posed_vertices
from jaxmocap.body.io import default_body
from jaxmocap.geometry.camera import ring_cameras
from jaxmocap.geometry.keypoints import keypoint_regressor, regress_keypoints
from jaxmocap.motion.library import walk


@pytest.fixture(scope="module")
def scene():
    body = default_body("low")
    verts, joints = posed_vertices(body, walk(20, fps=30.0, body=body))
    R, t = ring_cameras(4, 4.5, 1.6, [0.0, 0.9, 0.2], start_angle=0.4)
    K = np.array([[1000.0, 0.0, 640.0], [0.0, 1000.0, 360.0], [0.0, 0.0, 1.0]])
    P = np.stack([K @ np.concatenate([R[v], t[v][:, None]], 1) for v in range(4)])
    rng = np.random.default_rng(0)
    subjects = {}
    for layout in ("body25", "body25b"):
        X = regress_keypoints(keypoint_regressor(body, layout), *(np.asarray(a, np.float64) for a in (verts, joints)))
        x = np.einsum("vab,tkb->vtka", P[:, :, :3], X) + P[:, None, None, :, 3]
        uv = x[..., :2] / x[..., 2:] + rng.normal(scale=3.0, size=x[..., :2].shape)
        conf = np.where(rng.random(uv.shape[:-1]) < 0.1, 0.0, 0.8)
        subjects[layout] = np.concatenate([uv * (conf[..., None] > 0), conf[..., None]], -1)
    return body, P, subjects


@pytest.mark.parametrize("true, other", [("body25", "body25b"), ("body25b", "body25")])
@pytest.mark.parametrize("views", [4, 1])
def test_the_true_layout_has_the_consistent_skeleton(scene, true, other, views):
    body, P, subjects = scene
    scores = layout_scores(subjects[true][:views], P[:views], body, ["body25", "body25b"])
    assert scores[true] < (0.08 if views > 1 else 0.16), scores
    assert scores[other] > 3.0 * scores[true], scores
    check = check_layout(subjects[true][:views], P[:views], body, 25)
    assert (check.layout, check.verdict) == (true, "detected") and "detected from the skeleton" in check.message


def test_a_named_layout_is_confirmed_warned_about_or_refused(scene, monkeypatch):
    body, P, subjects = scene
    check = check_layout(subjects["body25b"], P, body, 25, "body25b", "Config.toml")
    assert (check.layout, check.verdict) == ("body25b", "confirmed") and "from Config.toml" in check.message
    # BODY_25B read as BODY_25: "left elbow" is the right shoulder; refused before any fit
    with pytest.raises(
        ValueError, match=r"--layout says the keypoints are body25, but.*% off.*pass --layout body25b\.$"
    ):
        check_layout(subjects["body25b"], P, body, 25, "body25", "--layout")
    # a milder misfit (here: the same data with the refusal threshold out of reach) is fitted
    # as named, with a warning
    monkeypatch.setattr(layout_module, "ABSURD_SCORE", 10.0)
    check = check_layout(subjects["body25b"], P, body, 25, "body25", "--layout")
    assert (check.layout, check.verdict) == ("body25", "warned") and check.message.startswith("warning: --layout")
    assert "body25b fits the skeleton clearly better" in check.message


def test_counts_that_do_not_match_the_named_layout_and_too_little_data_are_named(scene):
    body, P, subjects = scene
    with pytest.raises(
        ValueError, match=r"--layout names 'coco18' \(18 points\).*25 points per person: body25 or body25b"
    ):
        check_layout(subjects["body25"], P, body, 25, "coco18", "--layout")
    assert check_layout(np.zeros((2, 3, 18, 3)), P[:2], body, 18).verdict == "unchecked"
    with pytest.raises(ValueError, match="too few detections to tell body25 from body25b apart.*--layout"):
        check_layout(subjects["body25"][:, :1] * [1, 1, 0], P, body, 25)
    check = check_layout(subjects["body25"][:, :1] * [1, 1, 0], P, body, 25, "body25b")
    assert (check.layout, check.verdict) == ("body25b", "unchecked")
