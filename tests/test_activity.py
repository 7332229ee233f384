"""Watch activity recognition (jaxmocap.learned.activity): CRF against brute force, the
labelling rule on procedural motions, features, training steps, files and errors.

Everything is tiny (a few frames, a narrow MLP, a few optimisation steps); the full
leave-one-subject-out training is `experiments/har.py`.
"""

from __future__ import annotations

import itertools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxmocap.learned import activity as A
from jaxmocap.motion import library

C_IDX = {c: i for i, c in enumerate(A.CLASSES)}


@pytest.fixture
def x64():
    """float64 for the exact comparisons (conftest turns it on for the suite; restored after)."""
    before = jax.config.jax_enable_x64
    jax.config.update("jax_enable_x64", True)
    yield
    jax.config.update("jax_enable_x64", before)


def _chain(seed, T=4, C=3, dtype=np.float64):
    rng = np.random.default_rng(seed)
    return rng.normal(size=(T, C)).astype(dtype), rng.normal(size=(C, C)).astype(dtype)


def _brute_scores(unary, transitions, mask=None):
    """score(S) of every label sequence over the unmasked frames, by enumeration."""
    T, C = unary.shape
    mask = np.ones(T, bool) if mask is None else np.asarray(mask)
    frames = np.flatnonzero(mask)
    out = {}
    for seq in itertools.product(range(C), repeat=len(frames)):
        s = sum(unary[t, l] for t, l in zip(frames, seq))
        s += sum(transitions[a, b] for a, b in zip(seq[:-1], seq[1:]))
        out[seq] = s
    return frames, out


# --- CRF -------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_forward_algorithm_equals_enumeration(x64, seed):
    unary, transitions = _chain(seed)
    _, scores = _brute_scores(unary, transitions)
    brute = np.logaddexp.reduce(np.array(list(scores.values())))
    got = A.crf_log_partition(jnp.asarray(unary), jnp.asarray(transitions))
    assert got.dtype == jnp.float64
    np.testing.assert_allclose(float(got), brute, rtol=1e-12)
    # log-likelihood of every sequence = score - log Z, and the probabilities sum to 1
    seqs = jnp.asarray(list(scores))
    ll = jax.jit(jax.vmap(lambda s: A.crf_log_likelihood(unary, transitions, s)))(seqs)
    np.testing.assert_allclose(np.asarray(ll), np.array(list(scores.values())) - brute, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(np.exp(np.asarray(ll)).sum(), 1.0, rtol=1e-10)


def test_masked_frames_are_skipped(x64):
    unary, transitions = _chain(3, T=5)
    mask = np.array([True, False, True, True, False])
    frames, scores = _brute_scores(unary, transitions, mask)
    brute = np.logaddexp.reduce(np.array(list(scores.values())))
    np.testing.assert_allclose(float(A.crf_log_partition(unary, transitions, jnp.asarray(mask))), brute, rtol=1e-12)
    best = max(scores, key=scores.get)
    path = np.asarray(A.viterbi(unary, transitions, jnp.asarray(mask)))
    np.testing.assert_array_equal(path[frames], best)
    assert path[1] == path[0] and path[4] == path[3]  # masked frames repeat the previous label
    labels = np.zeros(5, np.int32)
    labels[frames] = best
    labels[[1, 4]] = [2, 0]  # whatever sits at masked frames is ignored
    np.testing.assert_allclose(
        float(A.crf_log_likelihood(unary, transitions, labels, jnp.asarray(mask))),
        scores[best] - brute,
        rtol=1e-10,
    )


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_viterbi_equals_brute_force_argmax(seed):
    unary, transitions = _chain(seed, T=4, C=3, dtype=np.float32)
    _, scores = _brute_scores(unary.astype(np.float64), transitions.astype(np.float64))
    best = max(scores, key=scores.get)
    np.testing.assert_array_equal(np.asarray(A.viterbi(unary, transitions)), best)


def test_viterbi_without_transitions_is_the_argmax_and_decode_pads():
    rng = np.random.default_rng(4)
    seqs = [rng.normal(size=(n, 4)).astype(np.float32) for n in (5, 17, 1)]
    crf = A.ActivityCRF(jnp.zeros((4, 4)), jnp.zeros(()))
    for lp, got in zip(seqs, A.decode(crf, seqs)):
        np.testing.assert_array_equal(got, lp.argmax(1))
    # strong self-transitions smooth a flickering sequence into one label
    sticky = A.ActivityCRF(jnp.asarray(10.0 * np.eye(4), jnp.float32), jnp.zeros(()))
    flicker = np.log(np.full((6, 4), 0.1) + 0.6 * np.eye(4)[[0, 1, 0, 0, 1, 0]]).astype(np.float32)
    np.testing.assert_array_equal(A.decode(sticky, [flicker])[0], np.zeros(6))


def test_init_crf_uses_log_transition_frequencies():
    crf = A.init_crf([np.array([0, 0, 0, 1, 1]), np.array([1, 0, -1, 0])], 2, smoothing=0.0)
    # 0->0: 2, 0->1: 1, 1->1: 1, 1->0: 1 (the -1 breaks the chain)
    np.testing.assert_allclose(np.exp(crf.transitions), [[2 / 3, 1 / 3], [0.5, 0.5]], rtol=1e-6)
    assert float(crf.weight) == pytest.approx(1.0)


def test_train_crf_increases_the_likelihood():
    rng = np.random.default_rng(5)
    labels = [np.repeat(rng.integers(0, 3, 4), 5) for _ in range(3)]  # 20 frames, 4 segments
    noisy = [np.eye(3)[np.where(rng.random(20) < 0.3, rng.integers(0, 3, 20), y)] for y in labels]
    log_probs = [np.log(0.05 + 0.9 * p).astype(np.float32) for p in noisy]
    crf0 = A.init_crf([np.zeros(2, int)], 3)  # a poor start
    crf, curve = A.train_crf(crf0, log_probs, labels, steps=40, learning_rate=0.1, prior_weight=0.0)
    assert curve.loss[-1] < curve.loss[0] - 0.05
    assert float(crf.transitions[0, 0] - crf.transitions[0, 1]) > float(crf0.transitions[0, 0] - crf0.transitions[0, 1])


# --- labelling rule ---------------------------------------------------------------------


def _fractions(labels):
    return np.bincount(labels, minlength=len(A.CLASSES)) / len(labels)


@pytest.mark.parametrize(
    "name, expected, share",
    [
        ("walk", "walk", 0.9),
        ("run", "run", 0.9),
        ("static_hold", "still", 1.0),
        ("leg_raises", "still", 0.9),
    ],
)
def test_labelling_rule_on_procedural_motions(name, expected, share):
    motion = library.MOTIONS[name](num_frames=180, fps=30.0)
    labels = A.activity_labels(motion)
    assert labels.shape == (180,) and labels.dtype == np.int32
    assert _fractions(labels)[C_IDX[expected]] >= share


def test_labelling_rule_squats_bend_and_segments_are_long_enough():
    motion = library.squats(num_frames=150, fps=30.0)
    labels = A.activity_labels(motion)
    assert set(np.unique(labels)) <= {C_IDX["still"], C_IDX["bend"]} and (labels == C_IDX["bend"]).any()
    change = np.flatnonzero(np.diff(labels)) + 1
    runs = np.diff(np.concatenate([[0], change, [len(labels)]]))
    assert runs.min() >= int(round(A.LabelRule().min_segment * motion.fps))


def test_merge_short_segments():
    labels = np.array([0] * 6 + [1] * 2 + [0] * 5 + [2] * 8 + [3])
    out = A.labels._merge_short_segments(labels, 3)
    np.testing.assert_array_equal(out, [0] * 13 + [2] * 9)


def test_label_rule_rejects_bad_thresholds():
    with pytest.raises(ValueError, match="walk_speed"):
        A.LabelRule(walk_speed=-1.0)
    with pytest.raises(ValueError, match="window"):
        A.LabelRule(window=0.0)
    with pytest.raises(ValueError, match="Motion"):
        A.activity_labels(np.zeros((10, 24, 3)))


# --- readings and features --------------------------------------------------------------


def test_watch_readings_rate_and_resampled_labels():
    motion = library.static_hold(num_frames=61, fps=60.0)  # 1 s
    r = A.watch_readings(motion, error_model=None, rng=np.random.default_rng(0))
    assert r.shape == (11, 6) and r.dtype == np.float32 and np.isfinite(r).all()
    # a still watch reads gravity (≈ 9.81 m/s²) and no rotation
    np.testing.assert_allclose(np.linalg.norm(r[:, :3], axis=1), 9.81, atol=0.3)
    assert np.abs(r[:, 3:]).max() < 0.1
    labels = A.resample_labels(A.activity_labels(motion), motion.fps)
    assert labels.shape == (11,)
    with pytest.raises(ValueError, match="resample"):
        A.watch_readings(library.static_hold(num_frames=20, fps=5.0))


def test_window_features_layout_and_start_padding():
    readings = np.arange(4 * 6, dtype=np.float32).reshape(4, 6)
    x = np.asarray(A.window_features(readings, window=3))
    assert x.shape == (4, 18)
    # frame 1: window frames (0, 0, 1): accelerations first, then rates
    np.testing.assert_array_equal(x[1, :9], np.concatenate([readings[0, :3], readings[0, :3], readings[1, :3]]))
    np.testing.assert_array_equal(x[1, 9:], np.concatenate([readings[0, 3:], readings[0, 3:], readings[1, 3:]]))
    np.testing.assert_array_equal(x[3, :9], readings[1:4, :3].reshape(-1))
    assert A.window_features(np.zeros((5, 6))).shape == (5, 360)


def test_bad_readings_are_rejected():
    with pytest.raises(ValueError, match=r"\(N, 6\)"):
        A.window_features(np.zeros((10, 3)))
    bad = np.zeros((10, 6))
    bad[3, 4] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        A.window_features(bad)
    with pytest.raises(ValueError, match="NaN"):
        A.fit_standardiser([bad])
    with pytest.raises(ValueError, match="transitions"):
        A.viterbi(np.zeros((4, 3)), np.zeros((2, 2)))
    with pytest.raises(ValueError, match="NaN"):
        A.crf_log_partition(np.full((4, 3), np.nan), np.zeros((3, 3)))
    with pytest.raises(ValueError, match="labels"):
        A.crf_log_likelihood(np.zeros((4, 3)), np.zeros((3, 3)), np.array([0, 1, 3, 0]))


# --- MLP training, classifier files --------------------------------------------------------


def _tiny_problem(seed=0, n=64, window=4, C=3):
    rng = np.random.default_rng(seed)
    y = rng.integers(0, C, n).astype(np.int32)
    x = rng.normal(size=(n, 6 * window)).astype(np.float32) + 2.0 * np.eye(C, 6 * window, dtype=np.float32)[y]
    return x, y


def test_mlp_shapes_and_dropout():
    mlp = A.ActivityMLP(5, jax.random.PRNGKey(0))
    assert mlp.in_size == 360 and mlp.hidden == (1024, 512, 60) and mlp.num_classes == 5
    small = A.ActivityMLP(3, jax.random.PRNGKey(0), in_size=24, hidden=(16, 8))
    x = jnp.ones(24)
    assert small(x).shape == (3,)
    np.testing.assert_array_equal(small(x), small(x))  # no key: deterministic
    assert not np.allclose(small(x, jax.random.PRNGKey(1)), small(x, jax.random.PRNGKey(2)))
    with pytest.raises(ValueError, match="num_classes"):
        A.ActivityMLP(1, jax.random.PRNGKey(0))


def test_a_few_adam_steps_reduce_the_loss():
    x, y = _tiny_problem()
    mlp = A.ActivityMLP(3, jax.random.PRNGKey(0), in_size=24, hidden=(32, 16), dropout=0.0)
    trained, curve = A.train_mlp(
        mlp,
        x,
        y,
        jax.random.PRNGKey(1),
        epochs=8,
        batch_size=16,
        learning_rate=1e-2,
        weights=A.class_weights(y, 3),
        validation=(x, y),
    )
    assert curve.loss.shape == (8,) and np.isfinite(curve.loss).all()
    assert curve.loss[-1] < 0.5 * curve.loss[0]
    assert curve.val_accuracy[-1] > 0.8
    with pytest.raises(ValueError, match="labels"):
        A.train_mlp(mlp, x, y + 3, jax.random.PRNGKey(1), epochs=1)
    x_bad = x.copy()
    x_bad[0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        A.train_mlp(mlp, x_bad, y, jax.random.PRNGKey(1), epochs=1)
    with pytest.raises(ValueError, match=r"\(n, 24\)"):
        A.train_mlp(mlp, x[:, :10], y, jax.random.PRNGKey(1), epochs=1)


def _tiny_classifier(seed=0):
    window, C = 4, 3
    standardiser = A.fit_standardiser([np.random.default_rng(seed).normal(size=(20, 6))])
    mlp = A.ActivityMLP(C, jax.random.PRNGKey(seed), in_size=6 * window, hidden=(8, 4))
    crf = A.init_crf([np.array([0, 0, 1, 1, 2])], C, weight=0.5)
    return A.ActivityClassifier(standardiser, mlp, crf, ("still", "walk", "arms"), window=window)


def test_save_load_round_trip(tmp_path):
    clf = _tiny_classifier()
    path = A.save_classifier(tmp_path / "har", clf, meta={"fold": "02"})
    assert path.suffix == ".npz"
    loaded, meta = A.load_classifier(path, classes=("still", "walk", "arms"))
    assert meta == {"fold": "02"} and loaded.classes == clf.classes and loaded.window == 4
    for a, b in zip(
        jax.tree_util.tree_leaves(eqx.filter(clf, eqx.is_array)),
        jax.tree_util.tree_leaves(eqx.filter(loaded, eqx.is_array)),
    ):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-6)  # stored as float32
    readings = np.random.default_rng(1).normal(size=(9, 6)).astype(np.float32)
    np.testing.assert_array_equal(clf.predict(readings), loaded.predict(readings))
    np.testing.assert_array_equal(clf.predict(readings, use_crf=False), np.asarray(clf.log_probs(readings)).argmax(1))


def test_mismatched_files_fail_clearly(tmp_path):
    path = A.save_classifier(tmp_path / "har.npz", _tiny_classifier())
    with pytest.raises(A.ActivityModelError, match="classes"):
        A.load_classifier(path, classes=("still", "walk", "run"))
    with pytest.raises(A.ActivityModelError, match="no jaxmocap-activity file"):
        A.load_classifier(tmp_path / "missing.npz")
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    with pytest.raises(A.ActivityModelError, match="not a jaxmocap-activity file"):
        A.load_classifier(tmp_path / "other.npz")
    # a file whose weights do not fit its declared configuration
    with np.load(path) as f:
        arrays = {k: f[k] for k in f.files}
    arrays["w2"] = np.zeros((3, 3), np.float32)
    np.savez(tmp_path / "broken.npz", **arrays)
    with pytest.raises(A.ActivityModelError, match="shape"):
        A.load_classifier(tmp_path / "broken.npz")
    with pytest.raises(ValueError, match="class names"):
        c = _tiny_classifier()
        A.ActivityClassifier(c.standardiser, c.mlp, c.crf, ("still", "walk"), window=4)


def test_scores_from_a_confusion_matrix():
    m = A.confusion_matrix(np.array([0, 0, 1, 1, 2, -1]), np.array([0, 1, 1, 1, 0, 2]), 3)
    np.testing.assert_array_equal(m, [[1, 1, 0], [0, 2, 0], [1, 0, 0]])
    s = A.classification_scores(m)
    assert s["accuracy"] == pytest.approx(3 / 5)
    assert s["f1"][1] == pytest.approx(0.8) and s["f1"][2] == 0.0
    assert s["macro_f1"] == pytest.approx((0.5 + 0.8 + 0.0) / 3)


# --- turning: labels and the watch's yaw rate ------------------------------------------------


def _turning(degrees_per_second: float, seconds: float = 3.0, fps: float = 60.0):
    """Standing still while spinning about the vertical at a constant rate (+ = to the left,
    counter-clockwise seen from above)."""
    from scipy.spatial.transform import Rotation

    from jaxmocap.motion.sequence import Motion

    base = library.static_hold(num_frames=int(seconds * fps), fps=fps)
    t = np.arange(base.num_frames) / fps
    yaw = Rotation.from_rotvec(np.radians(degrees_per_second * t)[:, None] * np.array([0.0, 1.0, 0.0]))
    poses = base.poses.copy()
    poses[:, 0] = (yaw * Rotation.from_rotvec(base.poses[:, 0])).as_rotvec()
    return Motion(poses, base.trans, fps)


@pytest.mark.parametrize("rate, name", [(120.0, "turn_left"), (-120.0, "turn_right"), (20.0, "still")])
def test_turn_direction_in_labels_and_watch_yaw_rate(rate, name):
    motion = _turning(rate)
    labels = A.activity_labels(motion)
    assert _fractions(labels)[C_IDX[name]] >= 0.9
    readings = A.watch_readings(motion, error_model=None)
    features = A.summary_features(readings)
    yaw = features[:, A.summary_feature_names().index("yaw_rate@10")]
    # the watch reads the body's rotation about the vertical, sign included
    np.testing.assert_allclose(np.median(yaw), np.radians(rate), rtol=0.05)
    # mirroring swaps the direction of the turn
    mirrored = A.activity_labels(motion.mirrored())
    swap = {"turn_left": "turn_right", "turn_right": "turn_left", "still": "still"}[name]
    assert _fractions(mirrored)[C_IDX[swap]] >= 0.9


def test_summary_features_layout_windows_and_a_still_watch():
    readings = np.zeros((40, 6), np.float32)
    readings[:, 1] = 9.81  # held still, y axis up
    x = A.summary_features(readings)
    names = A.summary_feature_names()
    assert x.shape == (40, len(names)) and len(names) == 19 * len(A.SUMMARY_WINDOWS)
    col = {n: x[:, i] for i, n in enumerate(names)}
    np.testing.assert_allclose(col["up_y@30"], 1.0, atol=1e-6)
    np.testing.assert_allclose(col["acc_dynamic@60"], 0.0, atol=1e-4)
    np.testing.assert_allclose(col["yaw_rate@10"], 0.0, atol=1e-6)
    # a burst of shaking at frames 20..24: a centred window sees it before frame 20, a
    # trailing one does not
    shaken = readings.copy()
    shaken[20:25, 0] = np.array([5.0, -5.0, 5.0, -5.0, 5.0])
    c = A.summary_features(shaken, windows=(10,))
    t = A.summary_features(shaken, windows=(10,), centred=False)
    dyn = A.summary_feature_names((10,)).index("acc_dynamic@10")
    assert c[17, dyn] > 1.0 and t[17, dyn] == pytest.approx(0.0, abs=1e-5) and t[22, dyn] > 1.0
    with pytest.raises(ValueError, match="windows"):
        A.summary_features(readings, windows=(1,))


def test_labels_from_signals_equal_activity_labels():
    motion = library.MOTIONS["walk"](num_frames=120, fps=30.0)
    signals = A.label_signals(motion)
    assert set(signals) == set(A.SIGNALS)
    np.testing.assert_array_equal(A.labels_from_signals(signals, 30.0), A.activity_labels(motion))
    raised = dict(signals, hand_height=np.full(120, 0.2))  # walking wins over a raised hand
    assert (A.labels_from_signals(raised, 30.0) == C_IDX["walk"]).all()
    slow = dict(raised, speed=np.zeros(120))
    assert (A.labels_from_signals(slow, 30.0) == C_IDX["arms_up"]).all()
