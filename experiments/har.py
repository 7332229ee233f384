"""Watch activity recognition (Huang ch. 7) on simulated watch readings of the CMU clips:
leave-one-subject-out, MLP alone vs MLP + linear-chain CRF.

    python experiments/har.py [--seed 0] [--max-epochs 15] [--out experiments/results] [--fresh]
    python experiments/har.py --folds 02,131      # development folds only: prints, writes nothing
    python experiments/har.py --features raw --hidden 1024,512,60   # the thesis's input and MLP

Data. Every clip of `jaxmocap.motion.corpus()` (CMU subjects 02, 05, 06, 07, 131; the 46
cmu_cc clips and the 9 of ../shared/data/cmu), loaded at 60 fps on the default body
(low), mean shape. Clips 007_03 .. 007_12 start with one bogus frame (a rest pose metres
away: the root jumps by > 2 m into the first real frame); leading frames before a root
jump of > 0.3 m are dropped. Readings: `watch_readings` (left forearm of sip6,
`IMUErrorModel.xsens()` errors, box-averaged to 10 fps), one noise draw per sequence from
`SeedSequence([seed, role, clip, variant])`, so training and test draws differ.

Labels. The clips' own descriptions (index.csv) give one activity per subject besides
"walk" (dance is subject 05's alone, basketball 06's), so no clip-level class but walk can
be trained on some subjects and tested on another. Labels are therefore the frame-level
kinematic rule of `jaxmocap.learned.activity` (`label_signals` → `labels_from_signals`,
thresholds in `LabelRule`), computed on the true motion (each augmented copy on its own
motion; mirroring swaps turn_left and turn_right) and taken at the 10 fps watch frames.
The signals are cached with the readings, so a change of thresholds needs no new
simulation.

Classes. A class of the rule is dropped when it has fewer than `min_test_frames` frames
(5 s) pooled over the held-out test sets, or fewer than that outside the subject that
holds most of its frames (the fold testing that subject could then train it on almost
nothing real). This is a count of labels, decided before any training. A dropped class's
frames stay in the sequences (the watch sees them, the chain runs through them) but are
left out of every loss and every score. With the default rule that keeps still, walk,
turn_left, turn_right, arms, arms_up and drops run (all in 02), jump (25 of 159 frames
outside subject 05) and bend (5 of 153 outside subject 02).

Features and model. `--features summary` (default): `summary_features`, statistics of
1, 3 and 6 s windows centred on the frame (57 values: how the forearm is held, how much
it shakes, angular rate, the rate about the vertical, i.e. the body's turning), an MLP
57 → 256 → 128 → C (ReLU, dropout 0.5), class-weighted cross-entropy (weights ∝
1/frequency). `--features raw`: the thesis's 360 raw values of a 6 s window ending at the
frame into 1024 → 512 → 60. These design choices were made looking only at the
development subjects' folds (02 and 131, `jaxmocap.motion.splits.DEVELOPMENT`).

Split (subject-disjoint, as everywhere in this project; `split` in har.json). For each
test subject s:
  - training subjects: the other four, with augmentation (mirrored x speeds 0.8, 1, 1.2),
    plus the procedural motions of `jaxmocap.motion.library` (training only, same
    augmentation);
  - hyper-parameters (number of epochs, the CRF's transitions and λ) are chosen on the
    training subjects only, by an inner leave-one-subject-out over them, the locked
    subject 07 excepted (it trains but is never held out to choose anything): an MLP is
    trained on the others (+ procedural) and scored on the held-out one's un-augmented
    clips after every epoch. The epoch count with the best macro F1 of the MLP's argmax
    over all inner held-out frames is kept; the CRF's transitions A start from the
    training labels' log transition frequencies and are fitted with λ by maximum
    likelihood (`train_crf`) on the held-out MLP outputs of that epoch (outputs of MLPs
    that never saw those subjects); then λ is picked from a grid by the held-out macro F1
    of Viterbi decoding with that A (the thesis set its λ by hand). The likelihood's own
    λ is kept as a diagnostic (`crf_likelihood_lambda`): the held-out MLP is poorly
    calibrated, and the likelihood shrinks λ to ≈ 0.03, where the chain ignores the MLP;
  - the final MLP trains on all four subjects for that many epochs; the test subject's
    un-augmented clips are classified frame by frame (argmax: "MLP") and by Viterbi
    ("MLP + CRF").
Predictions are pooled over the five folds: accuracy, macro F1 (over the kept classes),
per-class F1, per-subject scores, and the same over the evaluation subjects 05, 06, 07
alone; confusion matrices (row-normalised) in `har_confusion.png`.

Outputs (atomic writes): `har.json` (keys `classes`, `accuracy_crf`, `macro_f1_crf`,
`macro_f1_mlp`, `accuracy_mlp`, `split`, ...), `har.md`, `har_confusion.png`; the simulated
data and each finished fold are cached in `--cache` (default `out/har_cache`; resumable,
`--fresh` ignores it).
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import os
import platform
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _provenance  # noqa: E402,F401  (its commit is taken now, at the start of the run, not when it writes)

from jaxmocap.body import default_body  # noqa: E402
from jaxmocap.learned import activity as A
from jaxmocap.motion import library
from jaxmocap.motion.corpus import corpus
from jaxmocap.motion.io import load_motion
from jaxmocap.motion.splits import DEVELOPMENT, LOCKED, LEAVE_SUBJECT_OUT, Split

#: Thesis, Table 7.2 (DRIHI data, 15 classes, 6 training / 5 test subjects).
THESIS = {
    "num_classes": 15,
    "accuracy_mlp_top1": 0.61,
    "accuracy_mlp_top2": 0.74,
    "accuracy_mlp_top3": 0.81,
    "accuracy_mlp_crf": 0.74,
    "source": "Huang thesis Table 7.2, raw signal, MLP (+ CRF: 'Final')",
}
ROLE_TEST, ROLE_TRAIN, ROLE_PROCEDURAL = 0, 1, 2
#: What the design was chosen on: the development folds (test subjects 02 and 131, pooled,
#: 630 frames of the 6 classes), measured while building this version (seed 0).
DESIGN_NOTES = {
    "summary features, MLP 256-128, dropout 0.5, Adam 1e-4, class weights 1/sqrt(frequency)": {
        "macro_f1_mlp": 0.263, "macro_f1_crf_likelihood_lambda": 0.133, "macro_f1_crf": 0.248},
    "the same, Adam 1e-3, dropout 0.2": {"macro_f1_mlp": 0.180, "macro_f1_crf": 0.204},
    "the same as the first, class weights 1/frequency (kept)": {
        "macro_f1_mlp": 0.336, "macro_f1_crf_likelihood_lambda": 0.133, "macro_f1_crf": 0.238},
    "labels of the watch arm alone (LabelRule.watch_arm = 1)": "not trained: arms_up keeps 21 frames outside "
    "subject 05, so only 5 classes would pass the class rule",
}  # fmt: skip


@dataclasses.dataclass(frozen=True)
class Config:
    seed: int = 0
    fps: float = 60.0
    speeds: tuple[float, ...] = (0.8, 1.0, 1.2)
    mirror: bool = True
    procedural_seconds: float = 12.0
    max_epochs: int = 15
    batch_size: int = 256
    learning_rate: float = 1e-4
    class_weight_power: float = 1.0
    crf_steps: int = 300
    crf_learning_rate: float = 0.05
    crf_prior: float = 0.01
    crf_lambda_grid: tuple[float, ...] = (0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0)
    min_test_frames: int = 50
    features: str = "summary"  # "raw": the thesis's 6 s windows; "summary": A.summary_features
    centred: bool = True  # summary windows centred on the frame (False: ending at it)
    hidden: tuple[int, ...] = (256, 128)
    dropout: float = 0.5

    def key(self, fields=None) -> str:
        d = dataclasses.asdict(self)
        d = d if fields is None else {k: d[k] for k in fields}
        return hashlib.sha1(json.dumps(d, sort_keys=True).encode()).hexdigest()[:10]

    def data_key(self) -> str:
        """What the simulated data depends on (+ the layout version of the cached file)."""
        return self.key(("seed", "fps", "speeds", "mirror", "procedural_seconds")) + "v2"


def save_npz_atomic(path: Path, **arrays) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez_compressed(tmp, **arrays)
    os.replace(tmp, path)


def strip_leading_jump(motion, limit: float = 0.3):
    """Drop frames before a root jump of more than `limit` metres within the first 5 frames."""
    step = np.linalg.norm(np.diff(motion.trans[:6], axis=0), axis=1)
    bad = np.flatnonzero(step > limit)
    return motion[int(bad[-1]) + 1 :] if bad.size else motion


# --- data ----------------------------------------------------------------------------------


def simulate(config: Config, body, log) -> dict:
    """Readings and labels of every sequence: test copies of the clips, augmented training
    copies, augmented procedural motions. Returns flat arrays with offsets."""
    clips = corpus()
    if not clips:
        raise SystemExit("no CMU clips found (set JAXMOCAP_CMU / JAXMOCAP_CMU_CC, or put them in ../shared/data).")
    variants = [(m, s) for m in ((False, True) if config.mirror else (False,)) for s in config.speeds]
    seqs = []

    def add(motion, role, index, variant, subject, name, mirror, speed, activity):
        rng = np.random.default_rng(np.random.SeedSequence([config.seed, role, index, variant]))
        readings = A.watch_readings(motion, body, rng)
        signals = A.label_signals(motion, body)
        seqs.append(
            dict(
                readings=readings,
                signals=np.stack([signals[k] for k in A.SIGNALS], 1),
                fps=motion.fps,
                role=role,
                subject=subject,
                name=name,
                mirror=mirror,
                speed=speed,
                activity=activity,
            )
        )

    t0 = time.time()
    for i, clip in enumerate(clips):
        motion = strip_leading_jump(load_motion(clip.path, fps=config.fps))
        add(motion, ROLE_TEST, i, 0, clip.subject, clip.path.stem, False, 1.0, clip.activity)
        for v, (mirror, speed) in enumerate(variants):
            m = motion.mirrored() if mirror else motion
            add(m.time_scaled(speed), ROLE_TRAIN, i, v, clip.subject, clip.path.stem, mirror, speed, clip.activity)
        log(f"  simulated {clip.path.stem} ({clip.subject}, {motion.duration:.1f} s) [{time.time() - t0:.0f} s]")
    frames = int(round(config.procedural_seconds * config.fps))
    for i, (name, make) in enumerate(library.MOTIONS.items()):
        motion = make(num_frames=frames, fps=config.fps)
        for v, (mirror, speed) in enumerate(variants):
            m = motion.mirrored() if mirror else motion
            add(m.time_scaled(speed), ROLE_PROCEDURAL, i, v, "procedural", name, mirror, speed, name)
    log(f"  simulated {len(library.MOTIONS)} procedural motions [{time.time() - t0:.0f} s]")
    lengths = np.array([len(s["readings"]) for s in seqs])
    signal_lengths = np.array([len(s["signals"]) for s in seqs])
    return dict(
        signal_names=np.array(A.SIGNALS),
        readings=np.concatenate([s["readings"] for s in seqs]),
        signals=np.concatenate([s["signals"] for s in seqs]),
        signal_offsets=np.concatenate([[0], np.cumsum(signal_lengths)]),
        fps=np.array([s["fps"] for s in seqs]),
        offsets=np.concatenate([[0], np.cumsum(lengths)]),
        role=np.array([s["role"] for s in seqs]),
        subject=np.array([s["subject"] for s in seqs]),
        name=np.array([s["name"] for s in seqs]),
        mirror=np.array([s["mirror"] for s in seqs]),
        speed=np.array([s["speed"] for s in seqs]),
        activity=np.array([s["activity"] for s in seqs]),
    )


def label_arrays(arrays: dict, rule: A.LabelRule = A.LabelRule()) -> np.ndarray:
    """Labels of every sequence at its watch frames: the rule applied to the stored
    kinematic signals (at the motion's own rate), then resampled to 10 fps."""
    names = [str(n) for n in arrays["signal_names"]]
    out = []
    for i in range(len(arrays["role"])):
        s, e = arrays["signal_offsets"][i], arrays["signal_offsets"][i + 1]
        fps = float(arrays["fps"][i])
        signals = dict(zip(names, arrays["signals"][s:e].T))
        labels = A.resample_labels(A.labels_from_signals(signals, fps, rule), fps)
        n = arrays["offsets"][i + 1] - arrays["offsets"][i]
        if len(labels) != n:
            raise RuntimeError(f"sequence {i}: {len(labels)} labels for {n} watch frames")
        out.append(labels)
    return np.concatenate(out).astype(np.int32)


class Data:
    """The simulated sequences, with labels remapped to the kept classes (-1 = left out),
    and each sequence's (unstandardised) features, computed once."""

    def __init__(self, arrays: dict, keep: list[int], config: "Config"):
        self.a = arrays
        remap = np.full(len(A.CLASSES), -1, np.int32)
        remap[keep] = np.arange(len(keep))
        self.labels_all = arrays["labels"]
        self.labels = remap[arrays["labels"]]
        self.n = len(arrays["role"])
        self.kept = [A.CLASSES[k] for k in keep]
        self.config = config
        self._features = {}

    def seq(self, i):
        s, e = self.a["offsets"][i], self.a["offsets"][i + 1]
        return self.a["readings"][s:e], self.labels[s:e]

    def features(self, i) -> np.ndarray:
        """(N, F) features of sequence i: the thesis's raw windows or the window statistics."""
        if i not in self._features:
            r = self.seq(i)[0]
            if self.config.features == "raw":
                f = np.asarray(A.window_features(r, A.WINDOW))
            else:
                f = A.summary_features(r, centred=self.config.centred)
            self._features[i] = f
        return self._features[i]

    def select(self, roles, subjects=None):
        out = []
        for i in range(self.n):
            if self.a["role"][i] in roles and (subjects is None or self.a["subject"][i] in subjects):
                out.append(i)
        return out


def class_frames_per_subject(arrays) -> dict:
    out = {}
    for subject in sorted(set(arrays["subject"][arrays["role"] == ROLE_TEST].tolist())):
        counts = np.zeros(len(A.CLASSES), int)
        for i in np.flatnonzero((arrays["role"] == ROLE_TEST) & (arrays["subject"] == subject)):
            s, e = arrays["offsets"][i], arrays["offsets"][i + 1]
            counts += np.bincount(arrays["labels"][s:e], minlength=len(A.CLASSES))
        out[subject] = dict(zip(A.CLASSES, counts.tolist()))
    return out


# --- training ----------------------------------------------------------------------------------


class ColumnStandardiser:
    """(x - mean) / std per feature column, fitted on the training rows."""

    def __init__(self, x: np.ndarray):
        self.mean = x.mean(0)
        self.std = np.maximum(x.std(0), 1e-6)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        return ((x - self.mean) / self.std).astype(np.float32)


def features_of(data: Data, indices, standardiser=None):
    x = np.concatenate([data.features(i) for i in indices])
    y = np.concatenate([data.seq(i)[1] for i in indices])
    return (x if standardiser is None else standardiser(x)), y


def train_network(data, train_idx, key, config, num_classes, epochs, validation=None, on_epoch=None, log=print):
    x, y = features_of(data, train_idx)
    ok = y >= 0
    standardiser = ColumnStandardiser(x[ok])
    x, y = standardiser(x[ok]), y[ok]
    weights = A.class_weights(y, num_classes, config.class_weight_power)
    k_init, k_train = jax.random.split(key)
    mlp = A.ActivityMLP(num_classes, k_init, x.shape[1], config.hidden, config.dropout)
    val = None
    if validation is not None:
        vx, vy = features_of(data, validation, standardiser)
        val = (vx[vy >= 0], vy[vy >= 0])
    callback = None if on_epoch is None else (lambda e, m: on_epoch(e, m, standardiser))
    log(f"    {len(y)} training windows, {x.shape[1]} features, {epochs} epochs")
    mlp, curve = A.train_mlp(
        mlp,
        x,
        y,
        k_train,
        epochs=epochs,
        batch_size=config.batch_size,
        learning_rate=config.learning_rate,
        weights=weights,
        validation=val,
        on_epoch=callback,
    )
    return standardiser, mlp, curve


def log_probs_of(data, i, mlp, standardiser) -> np.ndarray:
    return np.asarray(A.mlp_log_probs(mlp, standardiser(data.features(i))))


def macro_f1(truth, pred, C) -> float:
    return A.classification_scores(A.confusion_matrix(truth, pred, C))["macro_f1"]


def run_fold(test, subjects, data, config, num_classes, log) -> dict:
    train_subjects = [s for s in subjects if s != test]
    procedural = data.select([ROLE_PROCEDURAL])
    key = jax.random.fold_in(jax.random.PRNGKey(config.seed), subjects.index(test))
    # Inner leave-one-subject-out over the training subjects; the locked subject trains
    # but is never held out to choose anything (jaxmocap.motion.splits.LOCKED).
    groups = [[s] for s in train_subjects if s not in LOCKED]
    held = {}  # epoch -> list of (log_probs, labels)
    inner_curves, inner_frames = [], []
    for g, group in enumerate(groups):
        fit_subjects = [s for s in train_subjects if s not in group]
        val_idx = data.select([ROLE_TRAIN], group)
        val_idx = [i for i in val_idx if not data.a["mirror"][i] and data.a["speed"][i] == 1.0]

        def keep(epoch, mlp, standardiser, val_idx=val_idx):
            for i in val_idx:
                held.setdefault(epoch, []).append((log_probs_of(data, i, mlp, standardiser), data.seq(i)[1]))

        log(f"  inner fold {g + 1}/{len(groups)}: train {fit_subjects} + procedural, validate {group}")
        _, _, curve = train_network(
            data,
            data.select([ROLE_TRAIN], fit_subjects) + procedural,
            jax.random.fold_in(key, g + 1),
            config,
            num_classes,
            config.max_epochs,
            validation=val_idx,
            on_epoch=keep,
            log=log,
        )
        inner_curves.append(curve)
        inner_frames.append(sum(int((data.seq(i)[1] >= 0).sum()) for i in val_idx))
        log(f"    held-out macro F1 per epoch: {np.round(curve.val_macro_f1, 3).tolist()}")
    # The epoch count maximises the macro F1 of the MLP's argmax pooled over every inner
    # held-out frame (calibration is left to the CRF's λ).
    pooled_f1 = []
    for e in range(1, config.max_epochs + 1):
        truth_e = np.concatenate([y for _, y in held[e]])
        pred_e = np.concatenate([p.argmax(1) for p, _ in held[e]])
        pooled_f1.append(macro_f1(truth_e, pred_e, num_classes))
    w = np.asarray(inner_frames, np.float64) / max(sum(inner_frames), 1)
    mean_loss = np.sum([wi * c.val_loss for wi, c in zip(w, inner_curves)], 0)
    epochs = int(np.argmax(pooled_f1)) + 1
    log(f"    pooled held-out macro F1 per epoch: {np.round(pooled_f1, 3).tolist()}")
    # CRF on the held-out outputs at that epoch.
    lp, lab = zip(*held[epochs])
    train_labels = [
        data.seq(i)[1]
        for i in data.select([ROLE_TRAIN], train_subjects)
        if not data.a["mirror"][i] and data.a["speed"][i] == 1.0
    ]
    crf0 = A.init_crf(train_labels, num_classes)
    crf_ml, crf_curve = A.train_crf(
        crf0,
        list(lp),
        list(lab),
        steps=config.crf_steps,
        learning_rate=config.crf_learning_rate,
        prior_weight=config.crf_prior,
    )
    truth_held = np.concatenate(lab)

    def held_f1(c):
        return macro_f1(truth_held, np.concatenate(A.decode(c, list(lp))), num_classes)

    # λ for decoding: the held-out macro F1 of Viterbi on the inner held-out clips picks it
    # from a grid, A as fitted (the thesis set its λ by hand). The λ of the likelihood fit
    # stays as a diagnostic: on held-out subjects the MLP is poorly calibrated and the
    # likelihood shrinks λ until the chain ignores it (λ ≈ 0.03, every frame one class).
    grid = [
        (lam, held_f1(A.ActivityCRF(crf_ml.transitions, jnp.asarray(np.log(lam), jnp.float32))))
        for lam in config.crf_lambda_grid
    ]
    lam_best = max(grid, key=lambda t: t[1])[0]
    crf = A.ActivityCRF(crf_ml.transitions, jnp.asarray(np.log(lam_best), jnp.float32))
    held_mlp_f1 = macro_f1(truth_held, np.concatenate([p.argmax(1) for p in lp]), num_classes)
    log(
        f"  held-out macro F1: MLP {held_mlp_f1:.3f}, CRF (likelihood λ) {held_f1(crf_ml):.3f}, "
        f"CRF by λ: {[(lam, round(f, 3)) for lam, f in grid]}"
    )
    log(
        f"  epochs {epochs} (pooled held-out macro F1 {pooled_f1[epochs - 1]:.3f}, log-loss {mean_loss[epochs - 1]:.3f}); CRF λ = {lam_best:g} (likelihood {float(crf_ml.weight):.3f}), "
        f"loss {crf_curve.loss[0]:.3f} -> {crf_curve.loss[-1]:.3f}"
    )
    # Final network on all training subjects.
    log(f"  final: train {train_subjects} + procedural")
    standardiser, mlp, curve = train_network(
        data,
        data.select([ROLE_TRAIN], train_subjects) + procedural,
        jax.random.fold_in(key, 0),
        config,
        num_classes,
        epochs,
        log=log,
    )
    train_y = np.concatenate([data.seq(i)[1] for i in data.select([ROLE_TRAIN], train_subjects) + procedural])
    majority = int(np.argmax(np.bincount(train_y[train_y >= 0], minlength=num_classes)))
    test_idx = data.select([ROLE_TEST], [test])
    log_probs = [log_probs_of(data, i, mlp, standardiser) for i in test_idx]
    decoded = A.decode(crf, log_probs)
    decoded_ml = A.decode(crf_ml, log_probs)
    return dict(
        names=np.array([data.a["name"][i] for i in test_idx]),
        lengths=np.array([len(p) for p in log_probs]),
        log_probs=np.concatenate(log_probs),
        labels=np.concatenate([data.seq(i)[1] for i in test_idx]),
        mlp=np.concatenate([p.argmax(1) for p in log_probs]).astype(np.int32),
        crf=np.concatenate(decoded).astype(np.int32),
        crf_likelihood_lambda=np.concatenate(decoded_ml).astype(np.int32),
        info=np.asarray(
            json.dumps(
                {
                    "epochs": epochs,
                    "majority_class": majority,
                    "trained_on": train_subjects + ["procedural"],
                    "inner_groups": groups,
                    "inner_val_log_loss": [c.val_loss.tolist() for c in inner_curves],
                    "inner_pooled_macro_f1": pooled_f1,
                    "inner_val_macro_f1": [c.val_macro_f1.tolist() for c in inner_curves],
                    "inner_val_accuracy": [c.val_accuracy.tolist() for c in inner_curves],
                    "final_train_loss": curve.loss.tolist(),
                    "crf_weight": lam_best,
                    "crf_weight_likelihood": float(crf_ml.weight),
                    "heldout_macro_f1_by_lambda": grid,
                    "heldout_macro_f1_mlp": held_mlp_f1,
                    "heldout_macro_f1_crf": held_f1(crf),
                    "heldout_macro_f1_crf_likelihood_lambda": held_f1(crf_ml),
                    "crf_transitions": np.asarray(crf.transitions).round(3).tolist(),
                    "crf_transitions_init": np.asarray(crf0.transitions).round(3).tolist(),
                    "crf_loss": [float(crf_curve.loss[0]), float(crf_curve.loss[-1])],
                }
            )
        ),
    )


# --- report ------------------------------------------------------------------------------------------


def plot_confusions(conf_mlp, conf_crf, classes, scores, path: Path):
    from matplotlib.figure import Figure

    from jaxmocap.viz.plot import save_figure

    fig = Figure(figsize=(12, 5.2), layout="constrained")
    axes = fig.subplots(1, 2)
    for ax, conf, title in ((axes[0], conf_mlp, "MLP"), (axes[1], conf_crf, "MLP + CRF")):
        rows = conf.sum(1, keepdims=True)
        norm = np.where(rows > 0, conf / np.maximum(rows, 1), 0.0)
        im = ax.imshow(norm, vmin=0, vmax=1, cmap="Blues")
        C = len(classes)
        for i in range(C):
            for j in range(C):
                ax.text(
                    j,
                    i,
                    f"{norm[i, j]:.2f}",
                    ha="center",
                    va="center",
                    fontsize=7,
                    color="white" if norm[i, j] > 0.6 else "black",
                )
        ax.set_xticks(range(C), classes, rotation=45, ha="right")
        ax.set_yticks(range(C), [f"{c} ({int(rows[k, 0])})" for k, c in enumerate(classes)])
        ax.set_xlabel("predicted")
        ax.set_ylabel("true (frames)")
        s = scores[title]
        ax.set_title(f"{title}: accuracy {s['accuracy']:.3f}, macro F1 {s['macro_f1']:.3f}", fontsize=10)
    fig.colorbar(im, ax=axes, shrink=0.8, label="fraction of the true class")
    fig.suptitle("Watch HAR, leave-one-subject-out over 5 CMU subjects (rows normalised)", fontsize=10)
    fig.set_dpi(110)
    tmp = path.with_name(path.stem + ".tmp.png")
    save_figure(fig, tmp)
    os.replace(tmp, path)


def markdown(result: dict) -> str:
    classes = result["classes"]
    ev = result["evaluation_subjects_only"]
    base = result["baseline_constant_most_frequent_test_class"]
    lines = [
        "# Watch activity recognition (Huang ch. 7), leave-one-subject-out",
        "",
        f"{result['num_classes']} classes ({', '.join(classes)}); dropped: {result['protocol']['dropped_classes'] or 'none'}. "
        f"Test frames (10 fps), pooled over the 5 held-out CMU subjects: {result['test_frames']}. "
        f"Features: {result['protocol']['features']}",
        "",
        "| | accuracy | macro F1 | macro F1, evaluation subjects " + "/".join(ev["subjects"]) + " |",
        "| --- | --- | --- | --- |",
        f"| MLP | {result['accuracy_mlp']:.3f} | {result['macro_f1_mlp']:.3f} | {ev['macro_f1_mlp']:.3f} |",
        f"| MLP + CRF (A by likelihood, λ chosen on the training subjects) | {result['accuracy_crf']:.3f} | {result['macro_f1_crf']:.3f} | {ev['macro_f1_crf']:.3f} |",
        f"| MLP + CRF, λ by likelihood too (diagnostic) | {result['crf_likelihood_lambda']['accuracy']:.3f} | {result['crf_likelihood_lambda']['macro_f1']:.3f} | – |",
        f"| majority class of the training labels | {result['baseline_majority_class']['accuracy']:.3f} | {result['baseline_majority_class']['macro_f1']:.3f} | – |",
        f"| constant '{base['class']}' (most frequent test class; reference, reads the test labels) "
        f"| {base['accuracy']:.3f} | {base['macro_f1']:.3f} | – |",
        f"| thesis (15 classes, real watch data) | {THESIS['accuracy_mlp_top1']:.2f} → {THESIS['accuracy_mlp_crf']:.2f} with CRF | – | – |",
    ]
    if "comparison" in result:
        o = result["comparison"]
        lines += [
            f"| the thesis's input and MLP ({o['features']}): MLP | {o['accuracy_mlp']:.3f} | {o['macro_f1_mlp']:.3f} | {o['evaluation_subjects_only']['macro_f1_mlp']:.3f} |",
            f"| the thesis's input and MLP: MLP + CRF | {o['accuracy_crf']:.3f} | {o['macro_f1_crf']:.3f} | {o['evaluation_subjects_only']['macro_f1_crf']:.3f} |",
        ]
    lines += [
        "",
        "Per-class F1 (frames):",
        "",
        "| class | frames | MLP | MLP + CRF | CRF, likelihood λ |",
        "| --- | --- | --- | --- | --- |",
    ]
    for c in classes:
        lines.append(
            f"| {c} | {result['support'][c]} | {result['per_class_f1']['mlp'][c]:.3f} | {result['per_class_f1']['mlp_crf'][c]:.3f} "
            f"| {result['crf_likelihood_lambda']['per_class_f1'][c]:.3f} |"
        )
    lines += [
        "",
        "Per held-out subject (λ chosen / by likelihood):",
        "",
        "| subject | frames | epochs | CRF λ | accuracy MLP | accuracy MLP + CRF | macro F1 MLP | macro F1 MLP + CRF |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for s, v in result["per_subject_accuracy"].items():
        lines.append(
            f"| {s} | {v['frames']} | {v['epochs']} | {v['crf_weight']:g} / {v['crf_weight_likelihood']:.3f} | {v['mlp']:.3f} "
            f"| {v['mlp_crf']:.3f} | {v['macro_f1_mlp']:.3f} | {v['macro_f1_crf']:.3f} |"
        )
    lines += [
        "",
        "Label frames per subject (10 fps, all classes of the rule):",
        "",
        "| subject | " + " | ".join(A.CLASSES) + " |",
        "| --- |" + " --- |" * len(A.CLASSES),
    ]
    for s, v in result["class_frames_per_subject"].items():
        lines.append(f"| {s} | " + " | ".join(str(v[c]) for c in A.CLASSES) + " |")
    compute = sum(v for v in result["seconds_compute"].values() if v == v)
    lines += [
        "",
        f"Runtime {result['seconds']:.0f} s (this invocation; {compute:.0f} s of simulation and training, caches included). Protocol and configuration: `har.json`; confusion matrices: `har_confusion.png`.",
        "",
    ]
    return "\n".join(lines)


def rule_dict(rule: A.LabelRule) -> dict:
    return {k: getattr(rule, k) for k in A.LabelRule.__dataclass_fields__}


def versions() -> dict:
    import equinox
    import optax

    return {
        "python": platform.python_version(),
        "jax": jax.__version__,
        "equinox": equinox.__version__,
        "optax": optax.__version__,
        "numpy": np.__version__,
        "platform": platform.platform(),
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--max-epochs", type=int, default=Config.max_epochs)
    p.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "results")
    p.add_argument(
        "--cache",
        type=Path,
        default=Path(__file__).resolve().parents[1] / "out" / "har_cache",
        help="the simulated data and finished folds (resumable)",
    )
    p.add_argument("--fresh", action="store_true", help="ignore the cache")
    p.add_argument(
        "--folds",
        default=None,
        help="comma-separated test subjects to run (default all); a partial run prints its scores and writes nothing",
    )
    p.add_argument("--features", choices=("summary", "raw"), default=Config.features)
    p.add_argument("--hidden", default=None, help="hidden layer sizes, e.g. 1024,512,60")
    p.add_argument("--trailing", action="store_true", help="summary windows end at the frame (causal)")
    p.add_argument("--learning-rate", type=float, default=Config.learning_rate)
    p.add_argument("--dropout", type=float, default=Config.dropout)
    p.add_argument("--class-weight-power", type=float, default=Config.class_weight_power)
    p.add_argument(
        "--compare",
        type=Path,
        default=None,
        help="a har.json of another run (e.g. --features raw) whose headline numbers are copied in",
    )
    args = p.parse_args(argv)
    hidden = Config.hidden if args.hidden is None else tuple(int(h) for h in args.hidden.split(","))
    config = Config(seed=args.seed, max_epochs=args.max_epochs, features=args.features,
                    hidden=hidden, centred=not args.trailing, learning_rate=args.learning_rate,
                    dropout=args.dropout, class_weight_power=args.class_weight_power)  # fmt: skip
    t0 = time.time()

    def log(msg):
        print(f"[{time.time() - t0:6.0f} s] {msg}", flush=True)

    cache = args.cache
    body = default_body("low")
    split = Split("har", tuning=DEVELOPMENT, training=LEAVE_SUBJECT_OUT)
    data_path = cache / f"data_{config.data_key()}.npz"
    if data_path.is_file() and not args.fresh:
        with np.load(data_path) as f:
            arrays = {k: f[k] for k in f.files}
        log(f"simulated data from {data_path}")
    else:
        log("simulating watch readings and labels")
        t_sim = time.time()
        arrays = simulate(config, body, log)
        arrays["seconds"] = np.asarray(time.time() - t_sim)
        save_npz_atomic(data_path, **arrays)
    rule = A.LabelRule()
    arrays["labels"] = label_arrays(arrays, rule)
    frames = class_frames_per_subject(arrays)
    pooled = {c: sum(v[c] for v in frames.values()) for c in A.CLASSES}
    # Outside its largest subject: what the fold testing that subject can train on.
    elsewhere = {c: pooled[c] - max(v[c] for v in frames.values()) for c in A.CLASSES}
    keep = [k for k, c in enumerate(A.CLASSES) if min(pooled[c], elsewhere[c]) >= config.min_test_frames]
    dropped = [c for c in A.CLASSES if min(pooled[c], elsewhere[c]) < config.min_test_frames]
    data = Data(arrays, keep, config)
    C = len(keep)
    log(
        f"classes {data.kept} (dropped {dropped}: fewer than {config.min_test_frames} frames pooled, or outside "
        f"the subject holding most of them; frames pooled {pooled}, outside the largest subject {elsewhere})"
    )
    subjects = sorted(frames)
    run_subjects = subjects if args.folds is None else [s for s in subjects if s in args.folds.split(",")]
    rule_key = hashlib.sha1(json.dumps(rule_dict(rule), sort_keys=True).encode()).hexdigest()[:6]
    folds = {}
    for test in run_subjects:
        path = cache / f"fold_{test}_{config.key()}_{rule_key}.npz"
        if path.is_file() and not args.fresh:
            with np.load(path) as f:
                folds[test] = {k: f[k] for k in f.files}
            log(f"fold {test}: from cache")
            continue
        log(f"fold: test subject {test}")
        t_fold = time.time()
        folds[test] = run_fold(test, subjects, data, config, C, log)
        folds[test]["seconds"] = np.asarray(time.time() - t_fold)
        save_npz_atomic(path, **folds[test])
        f = folds[test]
        ok = f["labels"] >= 0
        log(
            f"fold {test}: accuracy MLP {np.mean(f['mlp'][ok] == f['labels'][ok]):.3f}, "
            f"MLP + CRF {np.mean(f['crf'][ok] == f['labels'][ok]):.3f}"
        )

    if args.folds is not None:  # a partial run (development): scores only
        for name in ("mlp", "crf", "crf_likelihood_lambda"):
            t = np.concatenate([folds[s]["labels"] for s in run_subjects])
            q = np.concatenate([folds[s][name] for s in run_subjects])
            sc = A.classification_scores(A.confusion_matrix(t, q, C))
            log(
                f"{run_subjects} {name}: accuracy {sc['accuracy']:.3f} macro F1 {sc['macro_f1']:.3f} "
                f"per class {dict(zip(data.kept, np.round(sc['f1'], 2).tolist()))}"
            )
        return 0
    truth = np.concatenate([folds[s]["labels"] for s in subjects])
    pred = {
        "MLP": np.concatenate([folds[s]["mlp"] for s in subjects]),
        "MLP + CRF": np.concatenate([folds[s]["crf"] for s in subjects]),
        "likelihood λ": np.concatenate([folds[s]["crf_likelihood_lambda"] for s in subjects]),
    }
    conf = {k: A.confusion_matrix(truth, v, C) for k, v in pred.items()}
    scores = {k: A.classification_scores(m) for k, m in conf.items()}
    lp = np.concatenate([folds[s]["log_probs"] for s in subjects])
    ok = truth >= 0
    rank = (lp[ok] > np.take_along_axis(lp[ok], truth[ok][:, None], 1)).sum(1)
    majority = np.concatenate(
        [np.full(len(folds[s]["labels"]), json.loads(str(folds[s]["info"]))["majority_class"]) for s in subjects]
    )
    per_subject = {}
    for s in subjects:
        f = folds[s]
        m = f["labels"] >= 0
        info = json.loads(str(f["info"]))
        per_subject[s] = {
            "frames": int(m.sum()),
            "mlp": float(np.mean(f["mlp"][m] == f["labels"][m])),
            "mlp_crf": float(np.mean(f["crf"][m] == f["labels"][m])),
            "mlp_crf_likelihood_lambda": float(np.mean(f["crf_likelihood_lambda"][m] == f["labels"][m])),
            "macro_f1_mlp": macro_f1(f["labels"], f["mlp"], C),
            "macro_f1_crf": macro_f1(f["labels"], f["crf"], C),
            "epochs": info["epochs"],
            "crf_weight": info["crf_weight"],
            "crf_weight_likelihood": info["crf_weight_likelihood"],
        }
    # The evaluation subjects alone (jaxmocap.motion.splits: 05, 06, 07; nothing was
    # chosen on them, not even the design of features and model).
    ev = [s for s in subjects if s in split.evaluation]
    t_ev = np.concatenate([folds[s]["labels"] for s in ev])
    evaluation_only = {"subjects": ev}
    for key, name in (("mlp", "mlp"), ("crf", "crf")):
        sc = A.classification_scores(A.confusion_matrix(t_ev, np.concatenate([folds[s][name] for s in ev]), C))
        evaluation_only[f"accuracy_{key}"] = sc["accuracy"]
        evaluation_only[f"macro_f1_{key}"] = sc["macro_f1"]
        evaluation_only[f"per_class_f1_{key}"] = dict(zip(data.kept, sc["f1"]))
        evaluation_only["support"] = dict(zip(data.kept, sc["support"]))
    result = {
        "classes": data.kept,
        "num_classes": C,
        "accuracy_mlp": scores["MLP"]["accuracy"],
        "accuracy_crf": scores["MLP + CRF"]["accuracy"],
        "macro_f1_mlp": scores["MLP"]["macro_f1"],
        "macro_f1_crf": scores["MLP + CRF"]["macro_f1"],
        "crf_gain_macro_f1": scores["MLP + CRF"]["macro_f1"] - scores["MLP"]["macro_f1"],
        "accuracy_mlp_crf": scores["MLP + CRF"]["accuracy"],
        "macro_f1_mlp_crf": scores["MLP + CRF"]["macro_f1"],
        "evaluation_subjects_only": evaluation_only,
        "split": {
            **split.record(),
            "folds": {
                s: {
                    "evaluated": [s],
                    "trained_on": [t for t in subjects if t != s] + ["procedural motions"],
                    "tuned_on": [t for t in subjects if t != s and t not in LOCKED],
                    "tuned": "epochs, CRF transitions and λ, by inner leave-one-subject-out over tuned_on",
                }
                for s in subjects
            },
            "design": "label rule, class set, features and network size were chosen looking only at the "
            "development subjects' folds (02, 131) and at label counts; the thresholds of the rule by label counts alone",
        },
        "crf_likelihood_lambda": {
            "note": "diagnostic: the same CRF transitions with λ fitted by maximum likelihood on the inner "
            "held-out MLP outputs (the previous default) instead of chosen from "
            + str(list(config.crf_lambda_grid))
            + " by the inner held-out macro F1 of Viterbi",
            "accuracy": scores["likelihood λ"]["accuracy"],
            "macro_f1": scores["likelihood λ"]["macro_f1"],
            "per_class_f1": dict(zip(data.kept, scores["likelihood λ"]["f1"])),
        },
        "top_k_accuracy_mlp": {f"top{k}": float(np.mean(rank < k)) for k in (1, 2, 3)},
        "baseline_constant_most_frequent_test_class": {
            "class": data.kept[int(np.argmax(np.bincount(truth[ok], minlength=C)))],
            "accuracy": float(np.bincount(truth[ok], minlength=C).max() / ok.sum()),
            "macro_f1": A.classification_scores(
                A.confusion_matrix(
                    truth,
                    np.full_like(truth, int(np.argmax(np.bincount(truth[ok], minlength=C)))),
                    C,
                )
            )["macro_f1"],
            "note": "reference only (it reads the test labels): every frame labelled with the most frequent class of the pooled test frames",
        },
        "baseline_majority_class": {
            "accuracy": float(np.mean(majority[ok] == truth[ok])),
            "macro_f1": A.classification_scores(A.confusion_matrix(truth, majority, C))["macro_f1"],
            "note": "every frame labelled with the most frequent class of the fold's training labels",
        },
        "per_class_f1": {
            "mlp": dict(zip(data.kept, scores["MLP"]["f1"])),
            "mlp_crf": dict(zip(data.kept, scores["MLP + CRF"]["f1"])),
        },
        "per_class_recall": {
            "mlp": dict(zip(data.kept, scores["MLP"]["recall"])),
            "mlp_crf": dict(zip(data.kept, scores["MLP + CRF"]["recall"])),
        },
        "support": dict(zip(data.kept, scores["MLP"]["support"])),
        "test_frames": int(ok.sum()),
        "confusion": {k: m.tolist() for k, m in conf.items()},
        "per_subject_accuracy": per_subject,
        "class_frames_per_subject": frames,
        "folds": {s: json.loads(str(folds[s]["info"])) for s in subjects},
        "protocol": {
            "split": "leave-one-subject-out over the CMU subjects "
            + ", ".join(subjects)
            + "; predictions pooled over the 5 folds",
            "selection": "epochs and CRF (λ, transitions) chosen on the training subjects only, by an inner "
            "leave-one-subject-out over the training subjects but the locked one (07 trains, never validates); the best "
            "macro F1 over all inner held-out frames picks the epoch count (Adam, learning rate "
            + f"{config.learning_rate:g}, 1 .. {config.max_epochs} epochs); the CRF's transitions are fitted by likelihood on "
            "the held-out MLP outputs at that epoch, its λ picked from a grid by their Viterbi macro F1",
            "labelling": "frame-level kinematic rule of jaxmocap.learned.activity (LabelRule defaults: "
            + json.dumps(rule_dict(rule))
            + "), first match of jump > run > turn_left / turn_right > bend > walk > arms_up > arms > still, "
            "segments < 0.5 s merged into a neighbour. The clips' own activity names (index.csv) are not used as "
            "labels: walk is the only one shared by two subjects (dance is subject 05's alone, basketball 06's), "
            "so no other clip-level class can be trained and tested on different subjects",
            "features": (
                "the thesis's raw windows (60 frames, 360 values)"
                if config.features == "raw"
                else "summary_features: statistics of 1, 3 and 6 s windows "
                + ("centred on the frame" if config.centred else "ending at the frame")
                + " (57 values); MLP hidden sizes "
                + str(list(config.hidden))
            ),
            "design_choices_on_development_folds": DESIGN_NOTES,
            "dropped_classes": dropped,
            "dropped_rule": f"a class is dropped when it has fewer than {config.min_test_frames} frames (5 s) pooled over "
            "the held-out test sets, or fewer than that outside the subject holding most of its frames (then the "
            "fold testing that subject has almost nothing real to train it on); its frames stay in the sequences "
            "(the watch sees them, the chain runs through them) but out of every loss and score",
            "class_frames_pooled": pooled,
            "class_frames_outside_largest_subject": elsewhere,
            "readings": "left_forearm sensor of sip6 on the default body (low), IMUErrorModel.xsens(), simulated at 60 fps, "
            "box-averaged to 10 fps; windows of 60 frames (6 s), 360 values, start padded with the first frame",
            "augmentation": "training only: mirrored x speeds " + str(list(config.speeds)) + "; procedural motions "
            f"({', '.join(library.MOTIONS)}, {config.procedural_seconds:g} s each) in every training set",
            "test_data": "the held-out subject's clips, unaugmented, with their own sensor-noise draws",
            "data_fixes": "leading frames before a root jump > 0.3 m dropped (007_03 .. 007_12 start with a bogus frame)",
            "seeds": f"noise: SeedSequence([{config.seed}, role, clip, variant]); networks: PRNGKey({config.seed}) folded with the fold and inner fold",
        },
        "config": dataclasses.asdict(config),
        "thesis": THESIS,
        "seconds": time.time() - t0,
        "seconds_compute": {
            "simulation": float(arrays.get("seconds", np.nan)),
            **{f"fold_{s}": float(folds[s].get("seconds", np.nan)) for s in subjects},
        },
        "versions": versions(),
    }
    if args.compare is not None:
        other = json.loads(args.compare.read_text())
        result["comparison"] = {
            "features": other["protocol"].get("features"),
            "config": {
                k: other["config"][k] for k in ("features", "hidden", "dropout", "learning_rate", "class_weight_power")
            },
            **{k: other[k] for k in ("classes", "accuracy_mlp", "accuracy_crf", "macro_f1_mlp", "macro_f1_crf")},
            "evaluation_subjects_only": {
                k: other["evaluation_subjects_only"][k] for k in ("macro_f1_mlp", "macro_f1_crf")
            },
            "note": "the same protocol, labels and folds with another input/network (python experiments/har.py "
            + ("--features raw --hidden 1024,512,60" if other["config"]["features"] == "raw" else "...")
            + " --out DIR)",
        }
    args.out.mkdir(parents=True, exist_ok=True)
    from _provenance import record, write_json, write_text

    # The split record with its folds (who trained and tuned what) is the provenance's too.
    used = {"subjects": sorted(run_subjects), "procedural_motions": "jaxmocap.motion.library (training only)"}
    write_json(
        args.out / "har.json", {k: v for k, v in result.items() if k != "split"}, split=result["split"], data=used
    )
    write_text(args.out / "har.md", markdown(result), split=result["split"], data=used)
    plot_confusions(conf["MLP"], conf["MLP + CRF"], data.kept, scores, args.out / "har_confusion.png")
    record(args.out / "har_confusion.png", split=result["split"], data=used)
    log(
        f"accuracy MLP {result['accuracy_mlp']:.3f} -> MLP + CRF {result['accuracy_mlp_crf']:.3f}; "
        f"macro F1 {result['macro_f1_mlp']:.3f} -> {result['macro_f1_mlp_crf']:.3f} ({C} classes)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
