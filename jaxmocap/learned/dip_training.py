"""Training data and training of the Deep Inertial Poser (Huang §6.2.2-6.2.3, §6.3.1).

Synthesis (eq. 6.1): motions are cut into windows of `window` frames, each window made
into a scenario by `jaxmocap.sensors.make_scenario` (virtual sensors on the mesh, finite-
difference accelerations, a random body shape, a sensor-error preset), calibrated on its
first frame's true pose (eq. 6.5, as at test time) and turned into network inputs
(`dip.dip_inputs`). Windows shorter than `window` (short clips) hold their last frame and
are masked there. Augmentations, all optional: mirrored motions (`Motion.mirrored`),
speed changes (`Motion.time_scaled`), shapes β ~ N(0, betas_std²), error presets.

Training (§6.3.1): Adam, learning rate 1e-3 decayed by 0.96 every 2000 steps, gradients
clipped to global norm 1, early stopping on the validation loss. Several networks (e.g.
the folds of a leave-one-subject-out split) train at once, vmapped: one compiled step
advances them all, each on its own data.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax

from ..motion.sequence import Motion
from .dip import NUM_INPUTS, DIPConfig, DIPNetwork, dip_loss, dip_targets

__all__ = ["DIPDataset", "TrainConfig", "augmented", "windows", "synthesize", "train_dip"]


@dataclasses.dataclass(frozen=True)
class DIPDataset:
    """N windows of W frames: inputs (N, W, 60) float32, poses (N, W, 24, 3) float32 (the
    targets), mask (N, W) real frames, group (N,) e.g. the CMU subject, source (N,) clip name."""

    inputs: np.ndarray
    poses: np.ndarray
    mask: np.ndarray
    group: np.ndarray
    source: np.ndarray

    def __len__(self) -> int:
        return len(self.inputs)

    def take(self, keep) -> DIPDataset:
        keep = np.asarray(keep)
        return DIPDataset(*(getattr(self, f.name)[keep] for f in dataclasses.fields(self)))

    def save(self, path) -> Path:
        path = Path(path)
        tmp = path.with_name(path.name + ".tmp.npz")
        np.savez(tmp, **{f.name: getattr(self, f.name) for f in dataclasses.fields(self)})
        tmp.replace(path)
        return path

    @classmethod
    def load(cls, path) -> DIPDataset:
        with np.load(path) as f:
            return cls(*(f[fl.name] for fl in dataclasses.fields(cls)))

    @classmethod
    def concatenate(cls, parts: Sequence[DIPDataset]) -> DIPDataset:
        return cls(*(np.concatenate([getattr(p, f.name) for p in parts]) for f in dataclasses.fields(cls)))


def augmented(motion: Motion, mirror: bool = True, speeds: Sequence[float] = (1.0,)) -> list[Motion]:
    """The motion at every speed in `speeds`, and mirrored too when `mirror`."""
    base = [motion, motion.mirrored()] if mirror else [motion]
    return [m.time_scaled(s) for m in base for s in speeds]


def windows(motion: Motion, window: int, stride: int) -> list[tuple[Motion, int]]:
    """(window motion, number of real frames): windows every `stride` frames, the last one
    ending at the motion's end; a motion shorter than `window` gives one window holding its
    last frame."""
    T = motion.num_frames
    if T <= window:
        pad = window - T
        hold = lambda x: np.concatenate([x, np.repeat(x[-1:], pad, 0)])  # noqa: E731
        return [(motion.replace(poses=hold(motion.poses), trans=hold(motion.trans)), T)]
    starts = list(range(0, T - window + 1, stride))
    if starts[-1] != T - window:
        starts.append(T - window)
    return [(motion[s : s + window], window) for s in starts]


@jax.jit
def _calibrated_inputs(body, poses0, betas, trans0, orientation, acceleration):
    """Calibrate on the first frame's true pose (eq. 6.5) and build the inputs, one window."""
    from ..body.kinematics import forward
    from ..geometry.imu_calibration import sensor_to_bone_offsets
    from .dip import SIP6_BONES, dip_inputs, hold_dropped

    first = hold_dropped(orientation)[0]  # a dropout at frame 0 reads the first later sample
    R_b0 = forward(body, poses0, betas, trans0).joint_rotations[np.asarray(SIP6_BONES)]
    return dip_inputs(orientation, acceleration, sensor_to_bone_offsets(R_b0, first))


def synthesize(
    items: Sequence[tuple[Motion, str]],
    body,
    error_models: Sequence,
    window: int = 240,
    stride: int = 120,
    betas_std: float = 1.0,
    seed: int = 0,
    progress: bool = False,
) -> DIPDataset:
    """Windows of every (motion, group) item under every sensor-error preset.

    Motions must share one frame rate (that of the sensors). Each preset draws its own
    shapes and sensor errors (seed + preset index).
    """
    from ..sensors import ScenarioConfig, make_scenario
    from ..sensors.errors import global_free_acceleration

    rates = {m.fps for m, _ in items}
    if len(rates) != 1:
        raise ValueError(f"synthesize needs one frame rate for all motions (resample them); got {sorted(rates)}.")
    fps = rates.pop()
    cut = [(w, n, g, m.name) for m, g in items for w, n in windows(m, window, stride)]
    parts = []
    for k, errors in enumerate(error_models):
        config = ScenarioConfig(fps=fps, max_frames=window, imu_set="sip6", imu_errors=errors, betas_std=betas_std)
        sc = make_scenario([w for w, *_ in cut], config, seed=seed + k, body=body, progress=progress)
        acc = global_free_acceleration(sc["imu_ori"][:, 0], sc["imu_acc"][:, 0])
        f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
        inputs = jax.vmap(_calibrated_inputs, in_axes=(None, 0, 0, 0, 0, 0))(
            body, f32(sc["poses"][:, 0, 0]), f32(sc["betas"][:, 0]), f32(sc["trans"][:, 0, 0]),
            f32(sc["imu_ori"][:, 0]), f32(acc),
        )  # fmt: skip
        mask = np.arange(window)[None] < np.asarray([n for _, n, *_ in cut])[:, None]
        parts.append(DIPDataset(np.asarray(inputs, np.float32), np.asarray(sc["poses"][:, 0], np.float32), mask,
                                np.asarray([g for *_, g, _ in cut]), np.asarray([s for *_, s in cut])))  # fmt: skip
    return DIPDataset.concatenate(parts)


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Optimisation settings (defaults: §6.3.1 where the thesis gives them)."""

    steps: int = 4000
    batch: int = 32
    learning_rate: float = 1e-3
    decay_rate: float = 0.96
    decay_steps: int = 2000
    clip_norm: float = 1.0
    acc_weight: float = 1.0
    eval_every: int = 100
    seed: int = 0


def _optimizer(c: TrainConfig):
    schedule = optax.exponential_decay(c.learning_rate, c.decay_steps, c.decay_rate)
    return optax.chain(optax.clip_by_global_norm(c.clip_norm), optax.adam(schedule))


def _standardisation(d: DIPDataset) -> tuple[np.ndarray, np.ndarray]:
    x = d.inputs[d.mask].astype(np.float64)
    return x.mean(0).astype(np.float32), np.maximum(x.std(0), 1e-3).astype(np.float32)


def train_dip(
    train_sets: Sequence[DIPDataset],
    val_sets: Sequence[DIPDataset],
    config: DIPConfig = DIPConfig(),
    train: TrainConfig = TrainConfig(),
    progress: bool = True,
) -> tuple[list[DIPNetwork], list[dict]]:
    """Train one network per training set, all at once; keep each at its best validation loss.

    Returns (networks, curves); a curve holds the step, training loss (mean since the last
    evaluation) and validation loss of every evaluation, and the best step.
    """
    M = len(train_sets)
    if M == 0 or len(val_sets) != M:
        raise ValueError(f"train_dip needs one validation set per training set, got {M} and {len(val_sets)}.")
    empty = [i for i, (a, b) in enumerate(zip(train_sets, val_sets)) if len(a) == 0 or len(b) == 0]
    if empty:
        raise ValueError(f"training/validation sets {empty} are empty.")
    W = train_sets[0].inputs.shape[1]
    if any(d.inputs.shape[1:] != (W, NUM_INPUTS) for d in (*train_sets, *val_sets)):
        raise ValueError("every dataset must hold windows of one length W with 60 inputs (N, W, 60).")
    rng = np.random.default_rng(train.seed)
    key = jax.random.PRNGKey(train.seed)

    # All windows on the device once; each network draws its batches by index.
    data = DIPDataset.concatenate([*train_sets, *val_sets])
    X, P, Mk = jnp.asarray(data.inputs), jnp.asarray(data.poses), jnp.asarray(data.mask)
    offsets = np.cumsum([0] + [len(d) for d in (*train_sets, *val_sets)])
    train_idx = [np.arange(offsets[i], offsets[i + 1]) for i in range(M)]
    val_idx = [np.arange(offsets[M + i], offsets[M + i + 1]) for i in range(M)]
    Nv = max(len(v) for v in val_idx)
    val_pad = np.stack([np.pad(v, (0, Nv - len(v)), constant_values=v[0]) for v in val_idx])
    val_real = np.stack([np.arange(Nv) < len(v) for v in val_idx])

    stats = [_standardisation(d) for d in train_sets]
    mean, std = (jnp.asarray(np.stack(s)) for s in zip(*stats))
    keys = jax.random.split(key, M + 1)
    key = keys[0]
    nets = eqx.filter_vmap(lambda k, m, s: DIPNetwork(config, k, m, s))(keys[1:], mean, std)
    opt = _optimizer(train)
    opt_state = eqx.filter_vmap(opt.init)(nets)

    def batch_of(idx):
        return X[idx], jax.vmap(dip_targets)(P[idx]), Mk[idx]

    @eqx.filter_jit
    def step(nets, opt_state, idx, key):
        def one(net, state, idx, key):
            x, y, m = batch_of(idx)
            (loss, _), g = eqx.filter_value_and_grad(dip_loss, has_aux=True)(net, x, y, m, key, train.acc_weight)
            updates, state = opt.update(g, state, net)
            return eqx.apply_updates(net, updates), state, loss

        return eqx.filter_vmap(one)(nets, opt_state, idx, jax.random.split(key, M))

    @eqx.filter_jit
    def validate(nets, idx, real):
        def one(net, idx, real):
            x, y, m = batch_of(idx)
            return dip_loss(net, x, y, m & real[:, None], None, train.acc_weight)[0]

        return eqx.filter_vmap(one)(nets, idx, real)

    best = nets
    best_loss = np.full(M, np.inf)
    curves = [{"step": [], "train_loss": [], "val_loss": [], "best_step": 0} for _ in range(M)]
    running, t0 = [], time.perf_counter()
    for s in range(1, train.steps + 1):
        idx = np.stack([rng.choice(t, train.batch) for t in train_idx])
        key, sub = jax.random.split(key)
        nets, opt_state, loss = step(nets, opt_state, jnp.asarray(idx), sub)
        running.append(loss)
        if s % train.eval_every == 0 or s == train.steps:
            val = np.asarray(validate(nets, jnp.asarray(val_pad), jnp.asarray(val_real)))
            tr = np.asarray(jnp.stack(running)).mean(0)
            running = []
            better = val < best_loss
            best_loss = np.where(better, val, best_loss)
            pick = jnp.asarray(better)
            best = jax.tree_util.tree_map(
                lambda b, n, pick=pick: jnp.where(pick.reshape((M,) + (1,) * (n.ndim - 1)), n, b) if eqx.is_array(n) else n,
                best, nets,
            )  # fmt: skip
            for i, c in enumerate(curves):
                c["step"].append(s)
                c["train_loss"].append(float(tr[i]))
                c["val_loss"].append(float(val[i]))
                if better[i]:
                    c["best_step"] = s
            if progress:
                rate = s / (time.perf_counter() - t0)
                print(f"step {s}/{train.steps}  train {np.round(tr, 3)}  val {np.round(val, 3)}  "
                      f"{rate:.1f} steps/s, ETA {(train.steps - s) / rate:.0f} s", flush=True)  # fmt: skip
    networks = [jax.tree_util.tree_map(lambda x, i=i: x[i] if eqx.is_array(x) else x, best) for i in range(M)]
    return networks, curves
