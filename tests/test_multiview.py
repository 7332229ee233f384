"""Multi-view SMPLify (Huang ch. 4): energies against independent references, and the
two stages end to end on a short synthetic sequence with known truth."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.ndimage import distance_transform_edt, map_coordinates

from jaxmocap.body import default_body, forward
from jaxmocap.energies import camera as ec
from jaxmocap.geometry.camera import intrinsics, project, ring_cameras
from jaxmocap.geometry.keypoints import (
    KEYPOINT_FORMATS,
    flip_pairs,
    keypoint_regressor,
    regress_keypoints,
    rest_keypoints,
)
from jaxmocap.geometry.raster import rasterize_views
from jaxmocap.methods import multiview as mv
from jaxmocap.motion.library import walk
from jaxmocap.rotation import axis_angle_to_matrix
from jaxmocap.sensors.detector import person_track


def test_dct_basis_is_orthonormal_and_coefficients_reconstruct_its_span():
    B = ec.dct_basis(30, 10)
    np.testing.assert_allclose(B.T @ B, np.eye(10), atol=1e-12)
    # DCT-II: column k is cos(pi (n + 1/2) k / N), checked at one entry by hand.
    assert B[3, 2] == pytest.approx(np.sqrt(2 / 30) * np.cos(np.pi * 3.5 * 2 / 30))
    # The basis of E_T: 10 DCT vectors and a trend; a last window of 15 frames has a
    # 15-frame basis of the same bandwidth (5 vectors and the trend), 3 frames 1 and the
    # trend; all orthonormal, and a straight line costs nothing.
    full, short = ec.DCTBasis(30, 10)(30), ec.DCTBasis(30, 10)(15)
    assert full.shape == (30, 11) and short.shape == (15, 6) and ec.DCTBasis(30, 10)(3).shape == (3, 2)
    np.testing.assert_allclose(full[:, :10], B) and np.testing.assert_allclose(short[:, :5], ec.dct_basis(15, 5))
    for b in (full, short, ec.DCTBasis(30, 10)(3)):
        np.testing.assert_allclose(b.T @ b, np.eye(b.shape[1]), atol=1e-12)
        line = 0.3 + 0.05 * np.arange(len(b))
        np.testing.assert_allclose(b @ (b.T @ line), line, atol=1e-12)
    rng = np.random.default_rng(0)
    traj = np.concatenate([np.einsum("lk,kjd->ljd", full, rng.normal(size=(11, 24, 3))),
                           np.einsum("lk,kjd->ljd", short, rng.normal(size=(6, 24, 3)))])  # fmt: skip
    got = ec.dct_coefficients(traj, 30, 10)
    assert got.shape == (2, 11, 24, 3) and np.all(got[1, 6:] == 0.0)
    np.testing.assert_allclose(np.einsum("lk,kjd->ljd", full, got[0]), traj[:30], atol=1e-10)
    np.testing.assert_allclose(np.einsum("lk,kjd->ljd", short, got[1, :6]), traj[30:], atol=1e-10)


def test_bilinear_distance_matches_scipy_and_grows_outside_the_image():
    mask = np.zeros((20, 30), bool)
    mask[5:12, 8:20] = True
    dist = distance_transform_edt(~mask)
    uv = np.array([[3.3, 2.7], [25.1, 17.9], [10.5, 8.5]])
    got = np.asarray(ec._bilinear(jnp.asarray(dist), jnp.asarray(uv)))
    ref = map_coordinates(dist, [uv[:, 1] - 0.5, uv[:, 0] - 0.5], order=1)
    np.testing.assert_allclose(got, ref, rtol=1e-6)
    # 4 px left of the image: the border value plus the 4 px.
    out = float(ec._bilinear(jnp.asarray(dist), jnp.asarray([[-3.5, 8.5]]))[0])
    assert out == pytest.approx(dist[8, 0] + 4.0, rel=1e-6)
    g = jax.grad(lambda p: ec._bilinear(jnp.asarray(dist), p).sum())(jnp.asarray(uv))
    assert np.all(np.isfinite(np.asarray(g)))


@pytest.fixture(scope="module")
def scene():
    """6 frames of a body turning its arms and legs, 3 ring views, clean keypoints, masks."""
    body = default_body("low")
    T, V = 6, 3
    rng = np.random.default_rng(1)
    pose = np.zeros((T, 24, 3))
    s = np.linspace(0, 1, T)
    pose[:, 0, 1] = 0.4
    pose[:, 16, 2] = -1.0 + 0.5 * s  # left shoulder
    pose[:, 17, 2] = 1.0 - 0.3 * s
    pose[:, 1, 0] = -0.5 * s  # left hip flexion
    pose[:, 5, 0] = 0.6 * s  # right knee
    betas = np.zeros(10)
    betas[:3] = rng.normal(size=3)
    trans = np.stack([0.1 * s, np.full(T, 0.9), 0.05 * s], -1)
    out = forward(
        body, jnp.asarray(pose, jnp.float32), jnp.asarray(betas, jnp.float32), jnp.asarray(trans, jnp.float32)
    )
    K = intrinsics(256, 192, 55.0)
    R, t = ring_cameras(V, 4.0, 1.4, np.array([0.0, 0.9, 0.0]), 0.3)
    reg = keypoint_regressor(body, "body25")
    kp3 = regress_keypoints(reg, out.vertices, out.joints)
    uv, _ = project(jnp.asarray(K)[None, None], jnp.asarray(R)[None], jnp.asarray(t)[None], kp3[:, None])
    kp = np.concatenate([np.asarray(uv), np.full(uv.shape[:-1] + (1,), 0.9)], -1)  # (T, V, K, 3)
    Rb = np.repeat(R[None], T, 0).reshape(-1, 3, 3)
    tb = np.repeat(t[None], T, 0).reshape(-1, 3)
    vb = np.repeat(np.asarray(out.vertices)[:, None], V, 1).reshape(T * V, -1, 3)
    _, labels = rasterize_views(K, Rb, tb, vb, body.faces, np.zeros(len(body.faces), int), 256, 192)
    masks = np.asarray(labels).reshape(T, V, 192, 256) == 0
    return {"body": body, "K": np.repeat(K[None], V, 0), "R": R, "t": t, "kp": kp, "masks": masks,
            "joints": np.asarray(out.joints), "pose": pose, "betas": betas, "trans": trans}  # fmt: skip


def _mpjpe(body, p, betas, truth):
    b = np.broadcast_to(betas, (len(p["pose"]), betas.shape[-1])) if betas.ndim == 1 else betas
    j = forward(
        body, jnp.asarray(p["pose"], jnp.float32), jnp.asarray(b, jnp.float32), jnp.asarray(p["trans"], jnp.float32)
    ).joints
    return float(np.mean(np.linalg.norm(np.asarray(j) - truth, axis=-1))) * 1000


def test_keypoint_term_is_the_confidence_weighted_geman_mcclure_cost(scene):
    body = scene["body"]
    data = mv.camera_data(body, scene["K"], scene["R"], scene["t"], scene["kp"], "body25")
    params = {"pose": axis_angle_to_matrix(jnp.asarray(scene["pose"], jnp.float32)),
              "trans": jnp.asarray(scene["trans"], jnp.float32), "betas": jnp.asarray(np.broadcast_to(scene["betas"], (6, 10)), jnp.float32)}  # fmt: skip
    term = ec.keypoint_term(sigma=50.0)
    assert float(jnp.abs(term.fn(params, data)).max()) < 1e-2  # the truth reprojects exactly
    shifted = mv.dataclasses_replace(data, keypoints=data.keypoints + jnp.asarray([3.0, -4.0]))
    r = np.asarray(term.fn(params, shifted))
    s = 25.0  # |(3, -4)|^2
    expected = 0.9 * 50.0**2 * s / (50.0**2 + s)  # c · σ² s / (σ² + s)
    np.testing.assert_allclose((r**2).sum(-1), expected, rtol=2e-3)


def test_stage_one_and_two_recover_a_known_motion(scene):
    body = scene["body"]
    data = mv.camera_data(body, scene["K"], scene["R"], scene["t"], scene["kp"], "body25", masks=scene["masks"])
    w = mv.MuVSWeights(window=6)
    p0 = mv.initialise(data, w.num_betas)
    init = _mpjpe(body, p0, p0["betas"], scene["joints"])
    p1, _ = mv.stage_one(data, p0, w, silhouettes=True)
    e1 = _mpjpe(body, p1, p1["betas"], scene["joints"])
    assert np.all(np.isfinite(p1["pose"]))
    assert e1 < 0.5 * init and e1 < 40.0, (init, e1)
    p2, costs = mv.stage_two(data, p1, w)
    e2 = _mpjpe(body, p2, p2["betas"], scene["joints"])
    assert e2 < 40.0 and np.isfinite(costs["temporal"]), e2
    # A view that sees nothing (no detections, empty mask) leaves the fit finite.
    kp = scene["kp"].copy()
    kp[:, 2] = 0.0
    masks = scene["masks"].copy()
    masks[:, 2] = False
    blind = mv.camera_data(body, scene["K"], scene["R"], scene["t"], kp, "body25", masks=masks)
    p3, _ = mv.stage_one(blind, p0, w.replace(anneal=(1.0,)), silhouettes=True)
    assert np.all(np.isfinite(p3["pose"])) and _mpjpe(body, p3, p3["betas"], scene["joints"]) < 60.0


def test_resolve_left_right_flips_back_a_view_that_swapped_the_legs(scene):
    body = scene["body"]
    names = KEYPOINT_FORMATS["body25"]
    legs = [
        (a, b)
        for a, b in flip_pairs(names)
        if not any(k in names[a] for k in ("eye", "ear", "shoulder", "elbow", "wrist"))
    ]
    kp = scene["kp"].copy()
    for a, b in legs:  # view 1 swaps the legs in frames 3-5 (the hip is flexed: legs apart)
        kp[3:, 1, [a, b]] = kp[3:, 1, [b, a]]
    clean = mv.camera_data(body, scene["K"], scene["R"], scene["t"], scene["kp"], "body25")
    swapped = mv.camera_data(body, scene["K"], scene["R"], scene["t"], kp, "body25")
    fixed = mv.resolve_left_right(swapped)
    np.testing.assert_allclose(np.asarray(fixed.keypoints), np.asarray(clean.keypoints), atol=1e-4)
    np.testing.assert_array_equal(np.asarray(mv.resolve_left_right(clean).keypoints), np.asarray(clean.keypoints))
    # Frame by frame, one view cannot say which of its legs is which; over time the labels
    # of a swap in frames 3-4 jump in and out (the longer unswapped stretch wins).
    kp = scene["kp"].copy()
    for a, b in legs:
        kp[3:5, 1, [a, b]] = kp[3:5, 1, [b, a]]
    one = mv.mask_views(mv.camera_data(body, scene["K"], scene["R"], scene["t"], kp, "body25"), [1])
    np.testing.assert_array_equal(
        np.asarray(mv.resolve_left_right(one, temporal=0.0).keypoints), np.asarray(one.keypoints)
    )
    fixed = mv.resolve_left_right(one)
    np.testing.assert_allclose(np.asarray(fixed.keypoints), np.asarray(mv.mask_views(clean, [1]).keypoints), atol=1e-4)


def test_camera_data_refuses_wrong_shapes(scene):
    body = scene["body"]
    with pytest.raises(ValueError, match=r"\(T, V, 25, 3\)"):
        mv.camera_data(body, scene["K"], scene["R"], scene["t"], scene["kp"][..., :18, :], "body25")
    with pytest.raises(ValueError, match="V = 3 views"):
        mv.camera_data(body, scene["K"][:2], scene["R"][:2], scene["t"][:2], scene["kp"], "body25")
    with pytest.raises(ValueError, match="unknown keypoint layout"):
        mv.camera_data(body, scene["K"], scene["R"], scene["t"], scene["kp"], "body99")


def test_person_track_takes_each_views_slot_of_that_person():
    rng = np.random.default_rng(0)
    V, T, D, K = 3, 4, 3, 5
    kp = rng.normal(size=(V, T, D, K, 3))
    swapped = rng.random((V, T, D, K)) > 0.5
    who = np.full((V, T, D), -1)
    ref, ref_sw = np.zeros((T, V, K, 3)), np.zeros((T, V, K), bool)
    for v in range(V):
        for t in range(T):
            d = rng.integers(D + 1)  # D: not detected in this view and frame
            if d < D:
                who[v, t, d] = 0
                ref[t, v], ref_sw[t, v] = kp[v, t, d], swapped[v, t, d]
    got, got_sw = person_track(kp, who, 0, swapped)
    np.testing.assert_array_equal(got, ref)
    np.testing.assert_array_equal(got_sw, ref_sw)


def test_compact_body_gives_the_same_keypoints_joints_and_silhouette_terms(scene):
    """`compact` re-expresses the keypoints as rigidly skinned points per joint: exact."""
    body = scene["body"]
    data = mv.camera_data(body, scene["K"], scene["R"], scene["t"], scene["kp"], "body25", masks=scene["masks"])
    rng = np.random.default_rng(3)
    params = {"pose": jnp.asarray(rng.normal(size=(6, 24, 3)) * 0.4, jnp.float32),
              "trans": jnp.asarray(scene["trans"], jnp.float32), "betas": jnp.asarray(rng.normal(size=(6, 10)), jnp.float32)}  # fmt: skip
    w = mv.MuVSWeights()
    full = mv._weighted(mv._stage_one_problem(w.sigma, w.silhouette_stride, w.silhouette_slack, True), w, jnp.float32)
    joints = mv._weighted(
        mv._stage_one_problem(w.sigma, w.silhouette_stride, w.silhouette_slack, False), w, jnp.float32
    )
    costs = eqx.filter_jit(lambda problem, p, d: problem.costs(p, d))  # one program each, not op by op
    small = mv.compact(data, 0)
    assert small.body.num_vertices < 0.15 * body.num_vertices and not small.pose_blend
    compact_costs = costs(joints, params, small)
    for k, v in costs(joints, params, data).items():
        np.testing.assert_allclose(float(compact_costs[k]), float(v), rtol=1e-5, err_msg=k)
    strided = mv.compact(data, None, w.silhouette_stride)  # the full body's model points: E_S unchanged
    strided_costs = costs(full, params, strided)
    for k, v in costs(full, params, data).items():
        np.testing.assert_allclose(float(strided_costs[k]), float(v), rtol=1e-4, err_msg=k)
    want = forward(body, params["pose"], params["betas"], params["trans"]).joints

    @eqx.filter_jit
    def posed(p, d):
        return ec.posed_in_views({"pose": axis_angle_to_matrix(p["pose"]), "trans": p["trans"], "betas": p["betas"]}, d)

    got = posed(params, small).joints
    np.testing.assert_allclose(np.asarray(got), np.asarray(want), atol=1e-5)
    with pytest.raises(ValueError, match="already compact"):
        mv.compact(small)


@pytest.fixture(scope="module")
def walking():
    """39 frames of a walk at 30 fps (one 30-frame DCT window and a last one of 9 frames)
    in 3 ring views: the truth, clean keypoints and keypoints with 2 px noise, and both
    fitted by stage 1 (one compiled program for both, and one for stage 2)."""
    body = default_body("low")
    T = 39
    motion = walk(T, fps=30.0, body=body)
    trans = np.asarray(motion.trans) - np.array([0.0, 0.0, 0.6])  # through the ring's centre
    pose = np.asarray(motion.poses).reshape(T, 24, 3)
    out = forward(body, jnp.asarray(pose, jnp.float32), jnp.zeros(10, jnp.float32), jnp.asarray(trans, jnp.float32))
    K = np.repeat(intrinsics(256, 192, 55.0)[None], 3, 0)
    R, t = ring_cameras(3, 4.0, 1.4, np.array([0.0, 0.9, 0.0]), 0.3)
    uv, _ = project(jnp.asarray(K)[None], jnp.asarray(R)[None], jnp.asarray(t)[None],
                    regress_keypoints(keypoint_regressor(body, "body25"), out.vertices, out.joints)[:, None])  # fmt: skip
    rng = np.random.default_rng(5)
    w = mv.MuVSWeights()
    fits = {}
    for name, noise in (("clean", 0.0), ("noisy", 2.0)):
        kp = np.asarray(uv) + noise * rng.normal(size=uv.shape)
        data = mv.camera_data(body, K, R, t, np.concatenate([kp, np.full(kp.shape[:-1] + (1,), 0.9)], -1), "body25")
        p1, _ = mv.stage_one(data, mv.initialise(data, w.num_betas), w, silhouettes=False)
        fits[name] = (data, p1, kp)
    return {"body": body, "joints": np.asarray(out.joints), "fits": fits, "K": K, "R": R, "t": t}


def _reprojection(walking, name, p):
    """Median distance (px) of the fit's keypoints to the detections."""
    data, _, kp = walking["fits"][name]
    body = walking["body"]
    b = np.broadcast_to(p["betas"], (len(p["pose"]), 10))
    out = forward(body, jnp.asarray(p["pose"], jnp.float32), jnp.asarray(b, jnp.float32),
                  jnp.asarray(p["trans"], jnp.float32))  # fmt: skip
    K, R, t = (jnp.asarray(walking[k]) for k in "KRt")
    kp3 = regress_keypoints(keypoint_regressor(body, "body25"), out.vertices, out.joints)
    uv, _ = project(K[None], R[None], t[None], kp3[:, None])
    return float(np.median(np.linalg.norm(np.asarray(uv) - kp, axis=-1)))


def _jitter(body, p) -> np.ndarray:
    """Mean joint acceleration (m/s², 30 fps) at each inner frame (T-2,)."""
    b = np.broadcast_to(p["betas"], (len(p["pose"]), 10))
    j = np.asarray(forward(body, jnp.asarray(p["pose"], jnp.float32), jnp.asarray(b, jnp.float32),
                           jnp.asarray(p["trans"], jnp.float32)).joints, np.float64)  # fmt: skip
    return np.linalg.norm(j[2:] - 2 * j[1:-1] + j[:-2], axis=-1).mean(-1) * 30.0**2


def test_temporal_stage_keeps_the_reprojection_of_clean_data(walking):
    """Eq. 4.7-4.8 on clean keypoints: stage 2 may smooth, not fit worse (issue 49: the DCT
    vectors' zero slope at the window ends pulled a walking body to a stop there), with the
    default ("validated", λ_θ = 1), whose stage 1 is exact (0.07 px): E_T in full then
    pulled it to the DCT span, 0.17 px (`MuVSWeights.temporal_noise`); and with "thesis"
    (λ_θ = 20)."""
    data, p1, _ = walking["fits"]["clean"]
    thesis = mv.PRESETS["thesis"]
    loose, _ = mv.stage_one(data, mv.initialise(data, thesis.num_betas), thesis, silhouettes=False)
    assert mv.reprojection_px(data, p1) < 0.5 * mv.reprojection_px(data, loose)
    assert mv.reprojection_px(data, p1) == pytest.approx(_reprojection(walking, "clean", p1), rel=1e-3)
    for w, fit in ((mv.MuVSWeights(), p1), (thesis, loose)):
        p2, costs = mv.stage_two(data, fit, w)
        before, after = _reprojection(walking, "clean", fit), _reprojection(walking, "clean", p2)
        assert after <= 1.1 * before, (w.pose_prior, before, after)
        assert _mpjpe(walking["body"], p2, p2["betas"], walking["joints"]) <= 1.1 * _mpjpe(
            walking["body"], fit, fit["betas"], walking["joints"]
        )


def test_a_short_last_window_is_smoothed_like_whole_ones(walking):
    """39 frames: a 30-frame window and one of 9 (its own 9-frame basis, `DCTBasis`). In the
    first 9 rows of the 30-frame basis that window was fitted exactly: not smoothed."""
    body = walking["body"]
    data, p1, _ = walking["fits"]["noisy"]
    p2, costs = mv.stage_two(data, p1, mv.MuVSWeights())
    assert costs["temporal_result"] == 0 or costs["temporal_steps"] == mv.MuVSWeights().steps[2]
    j1, j2 = _jitter(body, p1), _jitter(body, p2)
    whole, last = j2[:28].mean(), j2[30:].mean()  # accelerations inside each window
    assert last <= 1.5 * whole and j2.mean() < 0.5 * j1.mean(), (whole, last, j1.mean())
    assert _mpjpe(body, p2, p2["betas"], walking["joints"]) < _mpjpe(body, p1, p1["betas"], walking["joints"])


def test_weights_follow_the_image_resolution(scene):
    """The same views at twice the resolution (K and keypoints x 2) give the same fit:
    MuVSWeights are in pixels of its reference focal length; raw pixels would not."""
    body, R, t = scene["body"], scene["R"], scene["t"]
    K2, kp2 = scene["K"].copy(), scene["kp"].copy()
    K2[:, :2] *= 2.0
    kp2[..., :2] *= 2.0
    # With the masks (unread by these joint solves): the low-resolution solve is then the
    # compiled joint solve of `test_stage_one_and_two_recover_a_known_motion`.
    low = mv.camera_data(body, scene["K"], R, t, scene["kp"], "body25", masks=scene["masks"])
    high = mv.camera_data(body, K2, R, t, kp2, "body25", masks=scene["masks"].repeat(2, -2).repeat(2, -1))
    w = mv.MuVSWeights(anneal=(1.0,))
    p0 = mv.initialise(low, w.num_betas)
    a, _ = mv.stage_one(low, p0, w, silhouettes=False, max_steps=5)
    b, _ = mv.stage_one(high, p0, w, silhouettes=False, max_steps=5)
    np.testing.assert_allclose(b["pose"], a["pose"], atol=2e-3)
    np.testing.assert_allclose(b["trans"], a["trans"], atol=2e-4)
    raw, _ = mv.stage_one(high, p0, w.replace(reference_focal=None), silhouettes=False, max_steps=5)
    assert np.abs(raw["betas"] - a["betas"]).max() > 1e-2  # the keypoints weigh 4x more against the priors


#: The monocular tests' weights: one annealing round, and σ₁ for one view at the several views'
#: value, so that the one-view solves are the compiled programs of the several-view ones.
MONOCULAR = mv.MuVSWeights(anneal=(1.0,), sigma_monocular=10.0)


@pytest.fixture(scope="module")
def floor(scene):
    """The floor the true feet stand on (their lowest point over the frames): one value for
    the monocular tests, whose floor solves are then one compiled program (the floor's
    height is a static setting of the term)."""
    out = forward(scene["body"], jnp.asarray(scene["pose"], jnp.float32), jnp.asarray(scene["betas"], jnp.float32),
                  jnp.asarray(scene["trans"], jnp.float32))  # fmt: skip
    return ((0.0, 1.0, 0.0), float(np.asarray(out.vertices)[..., 1].min()))


def test_one_view_says_it_is_monocular_and_how_uncertain_its_depth_is(scene, floor):
    """One view measures size in pixels, not depth: the result says so, with a 1σ depth
    that holds the truth; the floor (where the true feet stand) narrows it. Several views:
    not monocular. (The joint-only solve of `test_weights_follow_the_image_resolution`.)"""
    body = scene["body"]
    w = MONOCULAR
    # masks unread (no silhouettes): the joint solves of the stage tests' compiled programs
    data = mv.camera_data(body, scene["K"], scene["R"], scene["t"], scene["kp"], "body25", masks=scene["masks"])
    one = mv.mask_views(data, [0])
    R, t = scene["R"][0], scene["t"][0]
    true_depth = float(np.median((scene["joints"][:, 0] @ R.T + t)[:, 2]))
    alone = mv.multiview_smplify(one, w, silhouettes=False, temporal=False)
    ground = mv.multiview_smplify(one, w, silhouettes=False, temporal=False, floor=floor)
    for r in (alone, ground):
        d = r.depth
        assert r.monocular and d["view"] == 0 and d["depth_uncertainty_m"] > 0
        assert abs(d["depth_m"] - true_depth) < 2.5 * d["depth_uncertainty_m"], (d, true_depth)
    assert alone.depth["ground"] is None and ground.depth["ground"] is not None
    assert ground.depth["depth_uncertainty_m"] < alone.depth["depth_uncertainty_m"]
    assert abs(ground.depth["depth_m"] - true_depth) < abs(alone.depth["depth_m"] - true_depth)
    both = mv.multiview_smplify(data, w, silhouettes=False, temporal=False)
    assert not both.monocular and both.depth is None
    assert set(both.solution) == {f"joints_{i}" for i in range(len(w.anneal))}  # one Solution per stage solve
    assert both.params["betas"] is both.betas and np.shape(both.converged) == ()


def test_the_floor_puts_a_body_of_the_wrong_size_back_at_its_depth(scene):
    """A body 10 % too small and too close looks the same to one camera (`rescale_about_camera`);
    where its feet meet the floor says how far it is (`place_monocular`). No solve."""
    body = scene["body"]
    data = mv.camera_data(body, scene["K"], scene["R"], scene["t"], scene["kp"], "body25")
    one = mv.mask_views(data, [0])
    truth = {"pose": scene["pose"], "trans": scene["trans"], "betas": np.broadcast_to(scene["betas"], (6, 10))}
    small = mv.rescale_about_camera(one, truth, 1 / 1.1, 0)
    assert mv.reprojection_px(one, small) < 0.5 and mv.reprojection_px(one, truth) < 0.05
    depth = lambda p: np.median((mv._full_pose(one, p)[1][:, 0] @ scene["R"][0].T + scene["t"][0])[:, 2])  # noqa: E731
    assert depth(small) == pytest.approx(depth(truth) / 1.1, rel=1e-3)
    verts, _ = mv._full_pose(one, truth)
    floor = ((0.0, 1.0, 0.0), float(verts[0, :, 1].min()))  # the feet of the first frame stand on it
    placed, d = mv.place_monocular(one, small, floor)
    assert d["ground"] is not None and d["scale"] > 1.0
    assert abs(depth(placed) - depth(truth)) < 0.5 * abs(depth(small) - depth(truth))
    assert abs(d["depth_m"] - depth(truth)) < 2 * d["depth_uncertainty_m"]
    same, none = mv.place_monocular(data, small, floor)
    assert none is None and same is small


def test_floor_contact_term_is_the_robust_height_of_the_lowest_sole(scene):
    """The floor term (eq. 5.6-5.7 with the floor as the surface) by hand: per frame, the
    lowest foot keypoint's height less its rest height above the sole, through ρ_GM."""
    body = scene["body"]
    data = mv.camera_data(body, scene["K"], scene["R"], scene["t"], scene["kp"], "body25")
    names = KEYPOINT_FORMATS["body25"]
    feet = [names.index(n) for n in ("left_big_toe", "left_small_toe", "left_heel",
                                     "right_big_toe", "right_small_toe", "right_heel")]  # fmt: skip
    up, height, points, offsets, sigma = mv._floor_spec(data, ((0.0, 2.0, 0.0), 0.05), 0.1)
    assert up == (0.0, 1.0, 0.0) and height == 0.05 and points == tuple(feet) and sigma == 0.1
    rest = np.asarray(body.v_template, np.float64)
    kp = rest_keypoints(body, "body25")
    np.testing.assert_allclose(offsets, kp[feet, 1] - rest[:, 1].min(), atol=1e-6)
    assert 0.0 < min(offsets) and max(offsets) < 0.08  # toes and heels a few cm above the sole
    params = {"pose": axis_angle_to_matrix(jnp.asarray(scene["pose"], jnp.float32)),
              "trans": jnp.asarray(scene["trans"], jnp.float32), "betas": jnp.asarray(np.broadcast_to(scene["betas"], (6, 10)), jnp.float32)}  # fmt: skip
    out = forward(body, jnp.asarray(scene["pose"], jnp.float32), jnp.asarray(scene["betas"], jnp.float32),
                  jnp.asarray(scene["trans"], jnp.float32))  # fmt: skip
    reg = keypoint_regressor(body, "body25")[feet]
    kp = regress_keypoints(reg, *(np.asarray(a, np.float64) for a in (out.vertices, out.joints)))
    sole = (kp[..., 1] - np.asarray(offsets)).min(-1) - 0.05  # (T,)
    r = np.asarray(ec_floor(up, height, points, offsets, sigma).fn(params, data))
    assert r.shape == (6, 1, 1)
    np.testing.assert_allclose(r[:, 0, 0] ** 2, 0.1**2 * sole**2 / (0.1**2 + sole**2), rtol=1e-4)
    assert np.all(np.sign(r[:, 0, 0]) == np.sign(sole))  # above the floor: pulled down; below: pushed up
    quadratic = np.asarray(ec_floor(up, height, points, offsets, None).fn(params, data))[:, 0, 0]
    np.testing.assert_allclose(quadratic, sole, atol=1e-5)
    # the compact body of the solves gives the same residual
    np.testing.assert_allclose(np.asarray(ec_floor(up, height, points, offsets, None).fn(params, mv.compact(data, 0)))[:, 0, 0],
                               sole, atol=1e-5)  # fmt: skip
    with pytest.raises(ValueError, match="floor must be"):
        mv._floor_spec(data, ((0.0, 0.0, 0.0), 0.0), 0.1)


def ec_floor(*spec):
    from jaxmocap.energies.interaction import floor_contact_term

    return floor_contact_term(*spec)


def test_the_floor_term_moves_a_body_too_close_to_the_camera_back(scene, floor):
    """One view cannot tell a body 10 % too close (and small) from the truth
    (`rescale_about_camera`): started there, stage 1 stays too close without the floor; with
    it (the true feet stand on it) the feet pull the body back, and the depth error and the
    unaligned MPJPE shrink. Several views: the pipeline gives the stages no floor."""
    body = scene["body"]
    data = mv.camera_data(body, scene["K"], scene["R"], scene["t"], scene["kp"], "body25", masks=scene["masks"])
    one = mv.mask_views(data, [0])
    truth = {"pose": scene["pose"], "trans": scene["trans"], "betas": np.broadcast_to(scene["betas"], (6, 10)).copy()}
    close = mv.rescale_about_camera(one, truth, 1 / 1.1, 0)
    _, joints = mv._full_pose(one, truth)
    depth = lambda p: np.median((mv._full_pose(one, p)[1][:, 0] @ scene["R"][0].T + scene["t"][0])[:, 2])  # noqa: E731
    w = MONOCULAR  # the floor (the true feet's lowest point) and σ₁ of the one-view test: its compiled solves
    alone, _ = mv.stage_one(one, close, w, silhouettes=False, max_steps=15)
    ground, costs = mv.stage_one(one, close, w, silhouettes=False, max_steps=15, floor=floor)
    err_alone, err_ground = abs(depth(alone) - depth(truth)), abs(depth(ground) - depth(truth))
    # nothing in the image says it is too close (the shape prior, pulling β to the mean body,
    # moves it part of the way: 0.36 -> 0.09 m)
    assert err_alone > 0.02 * depth(truth), err_alone
    assert err_ground < 0.6 * err_alone, (err_alone, err_ground)  # 0.046 against 0.087 m; no floor: 1x
    mpjpe = lambda p: float(np.linalg.norm(mv._full_pose(one, p)[1] - joints, axis=-1).mean())  # noqa: E731
    assert mpjpe(ground) < 0.6 * mpjpe(alone), (mpjpe(alone), mpjpe(ground))  # 88 against 178 mm
    assert (
        mv._floor_for(one, floor) is floor and mv._floor_for(data, floor) is None and mv._floor_for(one, None) is None
    )
    assert mv._floor_for(mv.stack([one, one]), floor) is floor and mv._floor_for(mv.stack([one, data]), floor) is None
