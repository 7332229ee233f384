"""The Deep Inertial Poser: inputs (eq. 6.5-6.8), the LSTM against a NumPy derivation, the loss
(eq. 6.2-6.3), training on tiny data, weight files, the shipped network and SIP's BiRNN start."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import norm

from jaxmocap import default_body
from jaxmocap.app.scenarios import inertial_setup
from jaxmocap.learned import dip
from jaxmocap.learned import dip_training as dt
from jaxmocap.methods import inertial as I
from jaxmocap.motion import library
from jaxmocap.rotation import nearest_rotation
from jaxmocap.sensors import IMUErrorModel, ScenarioConfig, make_scenario


@pytest.fixture(scope="module")
def body():
    return default_body("low")


@pytest.fixture(scope="module")
def setup6(body):
    # 45 frames of 6 IMUs at 30 Hz: SIP's compiled solve is test_inertial.py's (one compile per suite run).
    sc = make_scenario(["walk"], ScenarioConfig(fps=30.0, max_frames=45, betas_std=0.0), seed=0, body=body)
    return sc, inertial_setup(sc, 0, body)


def _numpy_inputs(ori, acc, s2b):
    """Eq. 6.6-6.8 written out per frame and sensor."""
    T = len(ori)
    out = np.zeros((T, 60))
    for t in range(T):
        bone = [ori[t, s] @ s2b[s].T for s in range(6)]
        Rr = bone[5]
        rots = [Rr.T @ bone[s] for s in range(5)]
        accs = [Rr.T @ (acc[t, s] - acc[t, 5]) for s in range(5)]
        out[t] = np.concatenate([np.concatenate([r.ravel() for r in rots]), np.concatenate(accs)])
    return out


def test_inputs_match_a_numpy_derivation_and_ignore_heading():
    rng = np.random.default_rng(0)
    ori = Rotation.random(5 * 6, random_state=1).as_matrix().reshape(5, 6, 3, 3)
    acc = rng.normal(size=(5, 6, 3)) * 3
    s2b = Rotation.random(6, random_state=2).as_matrix()
    x = np.asarray(dip.dip_inputs(ori, acc, s2b))
    np.testing.assert_allclose(x, _numpy_inputs(ori, acc, s2b), atol=1e-9)
    # Facing another way (a rotation of the whole world about the vertical) changes nothing (§6.3.3).
    Q = Rotation.from_rotvec([0.0, 2.1, 0.0]).as_matrix()
    x_turned = np.asarray(dip.dip_inputs(Q @ ori, acc @ Q.T, s2b))
    np.testing.assert_allclose(x_turned, x, atol=1e-9)


def test_dropped_samples_hold_the_last_reading():
    rng = np.random.default_rng(3)
    ori = Rotation.random(4 * 6, random_state=4).as_matrix().reshape(4, 6, 3, 3)
    acc = rng.normal(size=(4, 6, 3))
    s2b = np.broadcast_to(np.eye(3), (6, 3, 3))
    held_ori, held_acc = ori.copy(), acc.copy()
    ori[2, 1] = np.nan  # frame 2 of sensor 1 holds frame 1's sample
    acc[0, 3] = np.nan  # frame 0 of sensor 3 reads the first later sample
    held_ori[2, 1] = held_ori[1, 1]
    held_acc[0, 3] = held_acc[1, 3]
    x = np.asarray(dip.dip_inputs(ori, acc, s2b))
    assert np.isfinite(x).all()
    np.testing.assert_allclose(x, _numpy_inputs(held_ori, held_acc, s2b), atol=1e-9)
    with pytest.raises(ValueError, match="sip6"):
        dip.dip_inputs(ori[:, :5], acc[:, :5], s2b[:5])


def _numpy_lstm(x, Wih, Whh, b, reverse=False):
    T, H = len(x), Whh.shape[1]
    h, c = np.zeros(H), np.zeros(H)
    out = np.zeros((T, H))
    sig = lambda z: 1 / (1 + np.exp(-z))  # noqa: E731
    for t in range(T - 1, -1, -1) if reverse else range(T):
        g = Wih @ x[t] + Whh @ h + b
        i, f, z, o = np.split(g, 4)
        c = sig(f) * c + sig(i) * np.tanh(z)
        h = sig(o) * np.tanh(c)
        out[t] = h
    return out


@pytest.mark.parametrize("reverse", [False, True])
def test_lstm_matches_numpy_and_padding_does_not_leak(reverse):
    lstm = dip.LSTM(4, 3, reverse, jax.random.PRNGKey(0))
    x = np.random.default_rng(0).normal(size=(7, 4))
    ref = _numpy_lstm(x, *(np.asarray(a, np.float64) for a in (lstm.weight_ih, lstm.weight_hh, lstm.bias)), reverse)
    np.testing.assert_allclose(lstm(jnp.asarray(x), jnp.ones(7, bool)), ref, atol=1e-5)
    # Frames after the real ones (padding) change nothing on the real frames, in either direction.
    padded = np.concatenate([x, 50 * np.ones((3, 4))])
    mask = jnp.arange(10) < 7
    np.testing.assert_allclose(lstm(jnp.asarray(padded), mask)[:7], ref, atol=1e-5)


def test_loss_is_the_gaussian_negative_log_likelihood():
    rng = np.random.default_rng(1)
    mu, y = rng.normal(size=(2, 5, 4)), rng.normal(size=(2, 5, 4))
    sigma = rng.uniform(0.2, 2.0, size=(2, 5, 4))
    mask = np.ones((2, 5), bool)
    mask[1, 3:] = False
    got = float(dip._gaussian_nll(mu, sigma, y, jnp.asarray(mask)))
    ref = -(norm.logpdf(y, mu, sigma) + 0.5 * np.log(2 * np.pi))[mask].mean()
    np.testing.assert_allclose(got, ref, rtol=1e-6)


@pytest.fixture(scope="module")
def tiny_data(body):
    items = [(m, g) for g, name in (("a", "walk"), ("b", "squats"))
             for m in dt.augmented(library.MOTIONS[name](num_frames=40, fps=30.0, body=body))]  # fmt: skip
    return dt.synthesize(items, body, [IMUErrorModel.xsens()], window=16, stride=8)


def test_synthesis_windows_and_masks(tiny_data):
    d = tiny_data
    assert d.inputs.shape[1:] == (16, 60) and d.poses.shape[1:] == (16, 24, 3)
    assert np.isfinite(d.inputs).all() and d.mask.all()  # 40 frames give full windows
    assert set(d.group) == {"a", "b"} and any("mirrored" in s for s in d.source)
    short = dt.windows(library.walk(num_frames=10, fps=30.0), 16, 8)
    assert len(short) == 1 and short[0][1] == 10 and short[0][0].num_frames == 16
    with pytest.raises(ValueError, match="one frame rate"):
        dt.synthesize([(library.walk(20, 30.0), "a"), (library.walk(20, 60.0), "a")], None, [IMUErrorModel()])


def test_training_lowers_both_losses_and_files_round_trip(tiny_data, tmp_path):
    even = np.arange(len(tiny_data)) % 2 == 0
    train, val = tiny_data.take(even), tiny_data.take(~even)
    config = dip.DIPConfig(hidden=8)
    nets, curves = dt.train_dip([train, train], [val, val], config,
                                dt.TrainConfig(steps=40, batch=4, eval_every=20, learning_rate=1e-2), progress=False)  # fmt: skip
    c = curves[0]
    assert c["train_loss"][-1] < c["train_loss"][0] and min(c["val_loss"]) < c["val_loss"][0]
    path = dip.save_dip_model(tmp_path / "m.npz", nets[0], {"fold": "test"})
    net, meta = dip.load_dip_model(path)
    assert meta == {"fold": "test"} and net.config == config
    # float16 storage moves the poses by far less than a degree.
    x, root = jnp.asarray(val.inputs[0]), jnp.broadcast_to(jnp.eye(3), (16, 3, 3))
    a = Rotation.from_rotvec(np.array(dip.network_poses(nets[0], x, root)).reshape(-1, 3))
    b = Rotation.from_rotvec(np.array(dip.network_poses(net, x, root)).reshape(-1, 3))
    assert np.degrees((a.inv() * b).magnitude()).max() < 0.1


def test_bad_weight_files_fail_clearly(tmp_path):
    with pytest.raises(dip.DIPModelError, match="no jaxmocap_dip_model file"):
        dip.load_dip_model(tmp_path / "missing.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(dip.DIPModelError, match="not a jaxmocap_dip_model file"):
        dip.load_dip_model(tmp_path / "junk.npz")
    net = dip.DIPNetwork(dip.DIPConfig(hidden=4))
    path = dip.save_dip_model(tmp_path / "m.npz", net)
    with np.load(path) as f:
        arrays = dict(f)
    arrays["w3"] = np.zeros((2, 2), np.float16)  # a parameter of the wrong shape
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(dip.DIPModelError, match="has shape"):
        dip.load_dip_model(tmp_path / "bad.npz")


def test_shipped_network_poses_a_sequence_and_starts_sip(body, setup6):
    sc, setup = setup6
    net, meta = dip.load_dip_model(dip.DEFAULT_MODEL_PATH)
    assert meta["held_apart_subject"] is None and "02_01" in meta["training_clips"]
    poses = np.array(dip.birnn_poses(setup))
    assert poses.shape == (setup.num_frames, 24, 3) and np.isfinite(poses).all()
    # The root is the pelvis sensor's bone orientation; joints DIP does not predict stay at rest.
    d = setup.data
    root = np.asarray(d.orientation[:, 5] @ d.sensor_to_bone[5].T)
    np.testing.assert_allclose(Rotation.from_rotvec(poses[:, 0]).as_matrix(), root, atol=1e-4)
    assert np.all(poses[:, [7, 8, 10, 11, 20, 21, 22, 23]] == 0)
    # A clip the network has seen (library walk): its poses are close to the truth.
    truth = Rotation.from_rotvec(sc["poses"][0, 0][:, list(dip.MAJOR_JOINTS)].reshape(-1, 3))
    err = np.degrees((truth.inv() * Rotation.from_rotvec(poses[:, list(dip.MAJOR_JOINTS)].reshape(-1, 3))).magnitude())
    assert np.median(err) < 15.0
    res = I.sparse_inertial_poser(setup, init="birnn", max_steps=2)
    np.testing.assert_allclose(res.init, poses, atol=1e-5)
    with pytest.raises(ValueError, match="'sop', 'birnn'"):
        I.sparse_inertial_poser(setup, init="dip")
    with pytest.raises(ValueError, match="sip6"):
        dip.birnn_poses(setup.subset([0, 1, 2, 3, 5, 4]))


def test_nearest_rotation_and_mirrored_motion(body):
    R = Rotation.random(4, random_state=5).as_matrix()
    M = R + 0.05 * np.random.default_rng(0).normal(size=R.shape)
    nearest = jax.jit(nearest_rotation)  # one program, not dozens of eager ones
    Q = np.asarray(nearest(jnp.asarray(M)))
    np.testing.assert_allclose(np.linalg.det(Q), 1.0, atol=1e-6)
    # The orthogonal Procrustes solution: U Vᵀ from the SVD (no reflection at this noise).
    u, _, vt = np.linalg.svd(M)
    np.testing.assert_allclose(Q, u @ vt, atol=1e-6)
    assert np.linalg.det(np.asarray(nearest(-jnp.eye(3)))) > 0
    from jaxmocap import forward
    from jaxmocap.body.model import SMPL_JOINT_NAMES

    m = library.walk(num_frames=20, fps=30.0, body=body)
    mm = m.mirrored()
    np.testing.assert_allclose(mm.mirrored().poses, m.poses)
    joints = jax.jit(lambda b, p, t: forward(b, p, None, t).joints)
    j = np.asarray(joints(body, jnp.asarray(m.poses), jnp.asarray(m.trans)))
    jm = np.asarray(joints(body, jnp.asarray(mm.poses), jnp.asarray(mm.trans)))
    index = {n: i for i, n in enumerate(SMPL_JOINT_NAMES)}
    swap = [index[n.replace("left", "@").replace("right", "left").replace("@", "right")] for n in SMPL_JOINT_NAMES]
    np.testing.assert_allclose(jm[:, swap] * [-1, 1, 1], j, atol=2e-4)  # the default body is symmetric to 0.1 mm
    assert m.time_scaled(2.0).num_frames == 10
    with pytest.raises(ValueError, match="speed"):
        m.time_scaled(0.0)
