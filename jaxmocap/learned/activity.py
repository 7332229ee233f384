"""Activity recognition from one wrist IMU (Huang ch. 7): an MLP over 6 s windows plus a
linear-chain CRF.

Pipeline (Fig. 7.4, §7.3-7.4):

1. Readings. `watch_readings(motion, body, rng)`: the "left_forearm" sensor of the sip6 set
   (the watch, on the forearm near the wrist) simulated at the motion's own rate with an
   IMU error model (`jaxmocap.sensors.errors`, default `IMUErrorModel.xsens()`), then
   brought to 10 fps (the thesis downsamples "to rule out high-frequency details"): the
   reading at t_k = k / 10 s is the mean of the native samples in [t_k - 0.05, t_k + 0.05)
   (a box low-pass, so no aliasing of the 60-120 Hz signal; dropped samples are left out
   of the mean, a bin with none holds the previous bin's value). Each frame is
   (a (3), r (3)): specific force (gravity included, what a watch measures, m/s²) and
   angular rate (rad/s), both in the sensor frame.
2. Features. `window_features`: x_t = vec(a_{t-M+1}, ..., a_t, r_{t-M+1}, ..., r_t) with
   M = 60 frames (6 s at 10 fps, the current frame included): 360 values, all
   accelerations first, then all rates, each frame's 3 axes together. Frames before the
   start of a sequence repeat its first frame (a watch that was held still before the
   recording; the alternative, zeros, is far out of distribution for an accelerometer).
   Each of the 6 channels is standardised by mean and standard deviation of the training
   readings (`Standardiser`, stored with the model).
3. Per-frame class probabilities p_t = softmax(MLP(x_t)), MLP 360 → 1024 → 512 → 60 → C,
   each hidden layer followed by ReLU and Dropout 0.5 (Fig. 7.6).
4. Linear-chain CRF (eq. 7.2): the label sequence S maximises

       score(S) = Σ_t λ log p_{S_t}(t) + Σ_t A_{S_t, S_{t+1}}

   i.e. eq. 7.2 with the unary p replaced by λ log p (a log-linear CRF whose unary is the
   MLP's log-probability) and λT by the transition scores A (C, C). `viterbi` finds the
   maximiser (max-product recursion + backtracking, `lax.scan`), `crf_log_likelihood`
   computes log P(S) = score(S) - log Z with the exact forward algorithm (log-sum-exp
   recursion). A starts as the log transition frequencies of the training labels (the
   thesis computes T from training sequences, Fig. 7.5); A and λ are then learned by
   maximising the CRF log-likelihood with the MLP fixed (`train_crf`).

Labelling rule (`activity_labels` = `labels_from_signals(label_signals(...))`, thresholds
in `LabelRule`). Labels come from the true motion, frame by frame, so that classes occur
across subjects (a clip's own activity name is subject-specific in the CMU data: only
subject 2 punches, only subject 5 dances). With v the pelvis horizontal speed, everything
averaged over a centred 1 s window:

    jump        the lower foot is > 0.15 m above the ground (the lowest foot height
                within ±1 s), i.e. both feet clearly off it; padded by 0.25 s on each
                side (take-off and landing)
    run         v > 1.8 m/s and a flight phase: in > 25 % of the window neither foot is
                planted (each foot's ankle and toe joints both move faster than 1 m/s)
    turn_left   the pelvis heading changes by > 60° within the window, counter-clockwise
    turn_right  seen from above (y up) for turn_left, clockwise for turn_right
    bend        the trunk (pelvis → neck) tilts > 35° from vertical, or the pelvis is
                below 0.8 x its standing height above the soles (bend over, crouch, squat)
    walk        v > 0.5 m/s
    arms_up     a wrist above the head joint (window mean): reach up, arms held high
    arms        a wrist moves faster than 0.8 m/s relative to the pelvis (punch, wash,
                dribble, swordplay while standing)
    still       none of the above

The first matching line wins (jump before run before turn ...). `LabelRule.watch_arm = 1`
makes arms_up and arms look at the watch's (left) wrist alone. Then label flicker is
removed: every segment shorter than 0.5 s takes the label of its longer neighbour,
shortest first. Heights use the body's rest pose: a foot joint's height is its y minus its
rest height above the soles, so a flat foot reads 0.

Features beyond the thesis: `summary_features` (statistics of 1, 3 and 6 s windows of the
raw readings: forearm orientation from the mean specific force, shaking, angular rate, the
rate about the vertical) are what `experiments/har.py` feeds the MLP by default; on five
subjects' worth of motion they are less to learn than the 360 raw values.

Randomness: every function that draws takes a `numpy.random.Generator` or a JAX key.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array, lax

from .._checks import check_finite, check_rate
from ..body.model import SMPL_JOINT_NAMES, Body
from ..motion.sequence import Motion
from ._weights import fill_module, read_header, save_module

__all__ = [
    "CLASSES",
    "WATCH_RATE",
    "WINDOW",
    "WATCH_SENSOR",
    "LabelRule",
    "activity_labels",
    "label_signals",
    "labels_from_signals",
    "SIGNALS",
    "summary_features",
    "summary_feature_names",
    "SUMMARY_WINDOWS",
    "watch_readings",
    "resample_labels",
    "window_features",
    "Standardiser",
    "fit_standardiser",
    "ActivityMLP",
    "ActivityCRF",
    "ActivityClassifier",
    "init_crf",
    "transition_counts",
    "crf_score",
    "decode",
    "crf_log_partition",
    "crf_log_likelihood",
    "viterbi",
    "TrainingCurve",
    "train_mlp",
    "train_crf",
    "mlp_log_probs",
    "class_weights",
    "confusion_matrix",
    "classification_scores",
    "save_classifier",
    "load_classifier",
    "ActivityModelError",
]

#: The classes of the labelling rule, in label order.
CLASSES: tuple[str, ...] = (
    "still", "walk", "run", "jump", "bend", "turn_left", "turn_right", "arms", "arms_up",
)  # fmt: skip
#: The per-frame quantities of `label_signals`, in the order experiments store them.
SIGNALS: tuple[str, ...] = (
    "speed", "flight", "airborne", "tilt", "crouch", "turn", "arm_speed", "hand_height",
    "watch_arm_speed", "watch_hand_height",
)  # fmt: skip
#: Readings rate (fps) and window length (frames, current frame included) of §7.4.
WATCH_RATE = 10.0
WINDOW = 60
#: The sip6 sensor that plays the watch.
WATCH_SENSOR = "left_forearm"
NUM_CHANNELS = 6  # a (3) and r (3)

FORMAT = "jaxmocap-activity"
FORMAT_VERSION = 1

_J = {n: i for i, n in enumerate(SMPL_JOINT_NAMES)}
_LEFT_FOOT = (_J["left_ankle"], _J["left_foot"])
_RIGHT_FOOT = (_J["right_ankle"], _J["right_foot"])
_WRISTS = (_J["left_wrist"], _J["right_wrist"])


class ActivityModelError(ValueError):
    """A classifier file that cannot be read or does not match (names the file and the fix)."""


# --- labelling rule --------------------------------------------------------------------


class LabelRule(eqx.Module):
    """Thresholds of the labelling rule (module docstring); SI units, angles in degrees."""

    window: float = 1.0  # s, centred averaging window
    walk_speed: float = 0.5  # m/s
    run_speed: float = 1.8  # m/s
    run_flight: float = 0.25  # fraction of the window with no foot planted
    foot_moving: float = 1.0  # m/s: a foot is planted when ankle or toe is slower
    jump_height: float = 0.15  # m, lower foot above the ground
    jump_pad: float = 0.25  # s, added before and after each flight
    turn_degrees: float = 60.0  # heading change within the window
    bend_tilt: float = 35.0  # degrees of trunk tilt from vertical
    crouch_ratio: float = 0.8  # pelvis height / standing pelvis height
    arm_speed: float = 0.8  # m/s, wrist relative to the pelvis
    hand_above_head: float = 0.0  # m, a wrist this far above the head joint
    watch_arm: int = 0  # 1: "arms" / "arms_up" look at the watch arm only; 0: either arm
    min_segment: float = 0.5  # s, shorter segments are merged into a neighbour

    def __check_init__(self):
        for name in self.__dataclass_fields__:
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"LabelRule.{name} must be a finite number >= 0, got {value!r}.")
        if self.window <= 0:
            raise ValueError(f"LabelRule.window must be > 0 seconds, got {self.window}.")


def _extended(motion: Motion, frames: int) -> tuple[np.ndarray, np.ndarray]:
    """Poses and trans continued by `frames` frames past the end, by point reflection about
    the last frame (trans: 2 x_{T-1} - x_{T-1-k}; each joint: R_{T-1} R_{T-1-k}ᵀ R_{T-1}),
    so velocities carry on smoothly and the finite differences at the real last frame see no
    jump. Used to pad sequences to a few compiled lengths."""
    from ..rotation import host_compose

    T = motion.num_frames
    if frames <= 0:
        return motion.poses, motion.trans
    k = np.minimum(np.arange(1, frames + 1), T - 1)
    src = T - 1 - k
    trans = 2 * motion.trans[-1] - motion.trans[src]
    last = motion.poses[-1]  # (24, 3)
    poses = np.empty((frames, 24, 3))
    for i, s in enumerate(src):
        poses[i] = host_compose(last, -motion.poses[s], last)  # exp(-ω) = exp(ω)ᵀ
    return np.concatenate([motion.poses, poses]), np.concatenate([motion.trans, trans])


_BUCKET = 256


def _padded_length(T: int) -> int:
    return max(_BUCKET, -(-T // _BUCKET) * _BUCKET)


@eqx.filter_jit
def _forward(body: Body, poses: Array, trans: Array):
    from ..body.kinematics import forward

    return forward(body, poses, None, trans)


def _posed(body: Body, motion: Motion):
    """(padded poses, padded trans, forward output) with T padded to a multiple of 256
    frames (a handful of compiled shapes instead of one per clip length)."""
    T = motion.num_frames
    poses, trans = _extended(motion, _padded_length(T) - T)
    dtype = body.dtype
    poses, trans = jnp.asarray(poses, dtype), jnp.asarray(trans, dtype)
    return poses, trans, _forward(body, poses, trans)


def _default_body(body):
    if body is None:
        from ..body.io import default_body

        return default_body("low")
    return body


def _box(x: np.ndarray, n: int) -> np.ndarray:
    from scipy.ndimage import uniform_filter1d

    return uniform_filter1d(x, max(1, n), axis=0, mode="nearest")


def _merge_short_segments(labels: np.ndarray, min_length: int) -> np.ndarray:
    """Relabel every run shorter than `min_length` frames with its longer neighbour's
    label, shortest run first, until none is left (or one run covers everything)."""
    labels = np.asarray(labels).copy()
    if min_length <= 1 or labels.size == 0:
        return labels
    while True:
        change = np.flatnonzero(np.diff(labels)) + 1
        starts = np.concatenate([[0], change])
        ends = np.concatenate([change, [labels.size]])
        lengths = ends - starts
        if len(starts) == 1 or lengths.min() >= min_length:
            return labels
        i = int(np.argmin(lengths))  # first of the shortest
        left = lengths[i - 1] if i > 0 else -1
        right = lengths[i + 1] if i + 1 < len(starts) else -1
        j = i - 1 if left >= right else i + 1
        labels[starts[i] : ends[i]] = labels[starts[j]]


def label_signals(motion: Motion, body: Body | None = None, rule: LabelRule = LabelRule()) -> dict:
    """The per-frame kinematic quantities the labelling rule thresholds (module docstring),
    computed on the true motion at its own rate: a dict of (T,) float arrays

        speed        pelvis horizontal speed, m/s (centred `rule.window` average)
        flight       fraction of the window with no foot planted
        airborne     1 where the lower foot is > `rule.jump_height` above the ground
                     (padded by `rule.jump_pad`), else 0
        tilt         trunk (pelvis -> neck) angle from vertical, degrees
        crouch       pelvis height above the soles / its standing height
        turn         signed pelvis heading change across the window, degrees (+ = to the
                     left, counter-clockwise seen from above, y up)
        arm_speed    the faster wrist's speed relative to the pelvis, m/s (window average)
        hand_height  the higher wrist's height above the head joint, m (window average)
        watch_arm_speed, watch_hand_height   the same for the left wrist alone (the arm
                     that wears the watch, `WATCH_SENSOR`)

    `labels_from_signals` turns them into classes; `activity_labels` does both."""
    if not isinstance(motion, Motion):
        raise ValueError(f"activity_labels needs a jaxmocap Motion, got {type(motion).__name__}.")
    body = _default_body(body)
    T, fps = motion.num_frames, motion.fps
    if T < 3:
        z = np.zeros(T)
        return dict(speed=z, flight=z, airborne=z, tilt=z, crouch=np.ones(T), turn=z, arm_speed=z,
                    hand_height=z - 1.0, watch_arm_speed=z, watch_hand_height=z - 1.0)  # fmt: skip
    joints = np.asarray(_posed(body, motion)[2].joints, np.float64)[:T]
    rest = np.asarray(body.J_regressor, np.float64) @ np.asarray(body.v_template, np.float64)
    sole = float(np.asarray(body.v_template)[:, 1].min())
    w = max(1, int(round(rule.window * fps)))
    dt = 1.0 / fps
    vel = np.gradient(joints, dt, axis=0)  # (T, 24, 3)

    speed = np.linalg.norm(_box(vel[:, 0, [0, 2]], w), axis=-1)
    foot_speed = np.linalg.norm(vel, axis=-1)
    left = foot_speed[:, list(_LEFT_FOOT)].min(1)
    right = foot_speed[:, list(_RIGHT_FOOT)].min(1)
    flight = _box((np.minimum(left, right) > rule.foot_moving).astype(np.float64), w)

    feet = list(_LEFT_FOOT + _RIGHT_FOOT)
    foot_height = joints[:, feet, 1] - (rest[feet, 1] - sole)  # 0 for a flat foot on y = 0
    lower = np.minimum(foot_height[:, :2].min(1), foot_height[:, 2:].min(1))
    from scipy.ndimage import maximum_filter1d, minimum_filter1d

    ground = minimum_filter1d(lower, 2 * w + 1, mode="nearest")
    airborne = (lower - ground) > rule.jump_height
    pad = int(round(rule.jump_pad * fps))
    jump = maximum_filter1d(airborne.astype(np.int8), 2 * pad + 1, mode="constant") > 0

    trunk = joints[:, _J["neck"]] - joints[:, _J["pelvis"]]
    tilt = np.degrees(np.arccos(np.clip(trunk[:, 1] / np.linalg.norm(trunk, axis=1), -1.0, 1.0)))
    pelvis_height = joints[:, 0, 1] - lower  # above the soles (lower = the sole level, y)
    standing = rest[0, 1] - sole

    hips = joints[:, _J["left_hip"]] - joints[:, _J["right_hip"]]
    heading = np.unwrap(np.arctan2(hips[:, 2], hips[:, 0]))
    half = w // 2
    idx = np.arange(T)
    turned = heading[np.minimum(idx + half, T - 1)] - heading[np.maximum(idx - half, 0)]
    # arctan2(z, x) grows clockwise seen from above (y up): left turns are negative.
    turn = -np.degrees(turned) * max(w, 1) / max(2 * half, 1)

    wrist = joints[:, list(_WRISTS)] - joints[:, None, 0]
    arm_speed = _box(np.linalg.norm(np.gradient(wrist, dt, axis=0), axis=-1).max(1), w)
    wrist_speed = _box(np.linalg.norm(np.gradient(wrist, dt, axis=0), axis=-1), w)  # (T, 2)
    above_head = _box(joints[:, list(_WRISTS), 1] - joints[:, None, _J["head"], 1], w)  # (T, 2)
    return dict(
        hand_height=above_head.max(1),
        watch_arm_speed=wrist_speed[:, 0],
        watch_hand_height=above_head[:, 0],
        speed=speed,
        flight=flight,
        airborne=jump.astype(np.float64),
        tilt=tilt,
        crouch=pelvis_height / standing,
        turn=turn,
        arm_speed=arm_speed,
    )


def labels_from_signals(signals: dict, fps: float, rule: LabelRule = LabelRule()) -> np.ndarray:
    """The class of every frame from `label_signals` (first matching line of the rule
    wins), short segments merged into a neighbour."""
    check_rate("fps", fps)
    sig = {k: np.asarray(v, np.float64) for k, v in signals.items()}
    T = sig["speed"].shape[0]
    c = {n: i for i, n in enumerate(CLASSES)}
    labels = np.full(T, c["still"], np.int32)
    if T < 3:
        return labels
    bend = (sig["tilt"] > rule.bend_tilt) | (sig["crouch"] < rule.crouch_ratio)
    # Lowest priority first: later assignments win.
    arm = "watch_arm_speed" if rule.watch_arm and "watch_arm_speed" in sig else "arm_speed"
    hand = "watch_hand_height" if rule.watch_arm and "watch_hand_height" in sig else "hand_height"
    labels[sig[arm] > rule.arm_speed] = c["arms"]
    labels[sig[hand] > rule.hand_above_head] = c["arms_up"]
    labels[sig["speed"] > rule.walk_speed] = c["walk"]
    labels[bend] = c["bend"]
    labels[sig["turn"] > rule.turn_degrees] = c["turn_left"]
    labels[sig["turn"] < -rule.turn_degrees] = c["turn_right"]
    labels[(sig["speed"] > rule.run_speed) & (sig["flight"] > rule.run_flight)] = c["run"]
    labels[sig["airborne"] > 0] = c["jump"]
    return _merge_short_segments(labels, int(round(rule.min_segment * fps))).astype(np.int32)


def activity_labels(motion: Motion, body: Body | None = None, rule: LabelRule = LabelRule()) -> np.ndarray:
    """The class of every frame of `motion` by the labelling rule (module docstring).

    Args:
        motion: the true motion (any frame rate; y up, metres).
        body: the body the motion drives (default: `default_body("low")`); its rest pose
            gives the foot and pelvis heights.
        rule: the thresholds.
    Returns:
        (T,) int labels, indices into `CLASSES`.
    """
    if not isinstance(motion, Motion):
        raise ValueError(f"activity_labels needs a jaxmocap Motion, got {type(motion).__name__}.")
    if motion.num_frames < 3:
        return np.zeros(motion.num_frames, np.int32)
    return labels_from_signals(label_signals(motion, body, rule), motion.fps, rule)


def resample_labels(labels, fps: float, rate: float = WATCH_RATE) -> np.ndarray:
    """Labels at the watch frames t_k = k / rate (k = 0 .. floor(duration · rate)): the
    label of the nearest frame of the `fps` sequence."""
    check_rate("fps", fps)
    check_rate("rate", rate)
    labels = np.asarray(labels)
    if labels.ndim != 1 or labels.size == 0:
        raise ValueError(f"labels has shape {labels.shape}; expected (T,) with T >= 1.")
    n = _watch_frames(labels.size, fps, rate)
    src = np.minimum(np.round(np.arange(n) / rate * fps).astype(int), labels.size - 1)
    return labels[src]


def _watch_frames(T: int, fps: float, rate: float) -> int:
    return int(np.floor((T - 1) / fps * rate + 1e-6)) + 1


# --- watch readings ----------------------------------------------------------------------


def watch_readings(
    motion: Motion,
    body: Body | None = None,
    rng: np.random.Generator | None = None,
    error_model=None,
    rate: float = WATCH_RATE,
    sensor: str = WATCH_SENSOR,
) -> np.ndarray:
    """Simulated watch readings of `motion` at `rate` fps (module docstring, step 1).

    Args:
        motion: the motion; it must have at least `rate` fps (resample it up otherwise).
        body: the body (default `default_body("low")`); mean shape.
        rng: draws the sensor errors (default: seed 0).
        error_model: `IMUErrorModel` (default `IMUErrorModel.xsens()`).
        rate: output frame rate.
        sensor: a sensor of the "sip6" set ("left_forearm" is the watch).
    Returns:
        (N, 6) float32: specific force a (m/s²) and angular rate r (rad/s) in the sensor
        frame, N = floor(duration · rate) + 1 frames at t_k = k / rate.
    """
    from ..sensors.errors import IMUErrorModel, simulate_imu
    from ..sensors.imu import imu_placement

    if not isinstance(motion, Motion):
        raise ValueError(f"watch_readings needs a jaxmocap Motion, got {type(motion).__name__}.")
    check_rate("rate", rate)
    if motion.fps < rate:
        raise ValueError(
            f"the motion has {motion.fps:g} fps, fewer than the {rate:g} fps asked for; "
            f"resample it first (motion.resample({rate:g}) or more)."
        )
    if motion.num_frames < 4:
        raise ValueError(f"the motion has {motion.num_frames} frames; at least 4 are needed to differentiate twice.")
    body = _default_body(body)
    rng = np.random.default_rng(0) if rng is None else rng
    error_model = IMUErrorModel.xsens() if error_model is None else error_model
    placement = imu_placement(body, "sip6").subset([sensor])
    poses, trans, output = _posed(body, motion)
    _, measured, _ = simulate_imu(body, placement, poses, None, trans, motion.fps, error_model, rng, output=output)
    T = motion.num_frames
    signal = np.concatenate([measured.acceleration[:T, 0], measured.angular_velocity[:T, 0]], -1)
    n = _watch_frames(T, motion.fps, rate)
    # Box average over [t_k - 0.5/rate, t_k + 0.5/rate): bin of each native sample.
    bins = np.floor(np.arange(T) / motion.fps * rate + 0.5).astype(int)
    keep = bins < n
    ok = np.isfinite(signal).all(1) & keep
    sums = np.zeros((n, NUM_CHANNELS))
    counts = np.zeros(n)
    np.add.at(sums, bins[ok], signal[ok])
    np.add.at(counts, bins[ok], 1.0)
    out = np.full((n, NUM_CHANNELS), np.nan)
    has = counts > 0
    out[has] = sums[has] / counts[has, None]
    # Bins with every sample dropped hold the previous bin (the next one at the start).
    if not has.all():
        if not has.any():
            raise ValueError("every watch sample was dropped; use a lower dropout rate.")
        idx = np.where(has, np.arange(n), -1)
        idx = np.maximum.accumulate(idx)
        idx[idx < 0] = np.flatnonzero(has)[0]
        out = out[idx]
    return out.astype(np.float32)


# --- features -------------------------------------------------------------------------------


def _check_readings(name: str, readings) -> Array:
    shape = np.shape(readings)
    if len(shape) != 2 or shape[1] != NUM_CHANNELS:
        raise ValueError(
            f"{name} has shape {shape}; expected (N, 6) watch frames (acceleration x, y, z, "
            "angular rate x, y, z), as `watch_readings` returns."
        )
    if shape[0] < 1:
        raise ValueError(f"{name} has 0 frames; at least one is needed.")
    check_finite(name, readings)
    return jnp.asarray(readings, jnp.float32)


def window_features(readings, window: int = WINDOW) -> Array:
    """Input vectors x_t = vec(a_{t-M+1..t}, r_{t-M+1..t}) of every frame (§7.3, M = `window`).

    Args:
        readings: (N, 6) watch frames [a, r] (standardised or not).
        window: frames per window, the current one included.
    Returns:
        (N, 6 · window): per frame, the window's accelerations (frame-major, 3 axes each)
        then its angular rates. Frames before the first repeat the first frame.
    """
    x = _check_readings("readings", readings)
    if not (isinstance(window, int) and window >= 1):
        raise ValueError(f"window must be a whole number of frames >= 1, got {window!r}.")
    padded = jnp.concatenate([jnp.repeat(x[:1], window - 1, 0), x], 0)
    idx = jnp.arange(x.shape[0])[:, None] + jnp.arange(window)[None, :]  # (N, M)
    w = padded[idx]  # (N, M, 6)
    return jnp.concatenate([w[..., :3].reshape(x.shape[0], -1), w[..., 3:].reshape(x.shape[0], -1)], -1)


#: Window lengths (watch frames: 1 s, 3 s, 6 s) of `summary_features`.
SUMMARY_WINDOWS: tuple[int, ...] = (10, 30, 60)
#: Values per window of `summary_features` (names in `summary_feature_names`).
_SUMMARY_NAMES = (
    "up_x", "up_y", "up_z", "acc_mean_norm", "acc_dynamic", "acc_std_x", "acc_std_y", "acc_std_z",
    "acc_norm_std", "gyro_mean_x", "gyro_mean_y", "gyro_mean_z", "gyro_std_x", "gyro_std_y",
    "gyro_std_z", "gyro_rms", "yaw_rate", "yaw_rate_abs", "acc_norm_crossings",
)  # fmt: skip


def summary_feature_names(windows: Sequence[int] = SUMMARY_WINDOWS) -> list[str]:
    """Names of the columns of `summary_features`, window by window."""
    return [f"{n}@{w}" for w in windows for n in _SUMMARY_NAMES]


def _moving_mean(x: np.ndarray, length: int, centred: bool) -> np.ndarray:
    """Mean over a window of `length` frames ending at (or centred on) each frame; the
    sequence is continued by its first / last frame."""
    before = length // 2 if centred else length - 1
    after = length - 1 - before
    pad = [(before, after)] + [(0, 0)] * (x.ndim - 1)
    xp = np.pad(x, pad, mode="edge")
    cs = np.concatenate([np.zeros((1, *x.shape[1:])), np.cumsum(xp, 0)], 0)
    return (cs[length:] - cs[:-length]) / length


def summary_features(readings, windows: Sequence[int] = SUMMARY_WINDOWS, centred: bool = True) -> np.ndarray:
    """Window statistics of the raw watch readings, per frame (an alternative to the
    thesis's raw windows, `window_features`; compact enough for a few subjects of data).

    For every window length L in `windows` (frames), centred on the frame (or ending at it
    with `centred=False`), 19 values:

        up (3)            the mean specific force, normalised: the direction of "up" in
                          the watch frame, i.e. how the forearm is held
        acc_mean_norm     |mean specific force| (≈ g unless the wrist accelerates steadily)
        acc_dynamic       sqrt(mean |a - mean a|²): how much the wrist shakes
        acc_std (3), acc_norm_std   per-axis and magnitude standard deviations
        gyro_mean (3), gyro_std (3), gyro_rms   the angular rate's mean, spread, energy
        yaw_rate, |yaw_rate|   the angular rate about the vertical (r_t · up_t, up_t from a
                          1 s mean of a): turning of the whole body, signed (+ = left,
                          counter-clockwise seen from above)
        acc_norm_crossings   the rate of |a| crossing its window mean (per frame): the
                          step or swing frequency

    Args:
        readings: (N, 6) raw watch frames (a m/s², r rad/s), as `watch_readings` returns.
    Returns:
        (N, 19 · len(windows)) float32, columns named by `summary_feature_names`.
    """
    x = np.asarray(_check_readings("readings", readings), np.float64)
    if not windows or not all(isinstance(w, int) and w >= 2 for w in windows):
        raise ValueError(f"windows must be whole numbers of frames >= 2, got {windows!r}.")
    a, r = x[:, :3], x[:, 3:]
    up_local = _moving_mean(a, 10, centred)
    up_local /= np.maximum(np.linalg.norm(up_local, axis=1, keepdims=True), 1e-9)
    yaw = np.sum(r * up_local, 1, keepdims=True)
    anorm = np.linalg.norm(a, axis=1, keepdims=True)
    out = []
    for L in windows:
        ma = _moving_mean(a, L, centred)
        ma_norm = np.linalg.norm(ma, axis=1, keepdims=True)
        up = ma / np.maximum(ma_norm, 1e-9)
        a2 = _moving_mean(a**2, L, centred)
        a_var = np.maximum(a2 - ma**2, 0.0)
        dyn = np.sqrt(a_var.sum(1, keepdims=True))
        mn = _moving_mean(anorm, L, centred)
        n_std = np.sqrt(np.maximum(_moving_mean(anorm**2, L, centred) - mn**2, 0.0))
        mr = _moving_mean(r, L, centred)
        r2 = _moving_mean(r**2, L, centred)
        r_std = np.sqrt(np.maximum(r2 - mr**2, 0.0))
        r_rms = np.sqrt(r2.sum(1, keepdims=True))
        yaw_mean = _moving_mean(yaw, L, centred)
        yaw_abs = _moving_mean(np.abs(yaw), L, centred)
        above = (anorm > mn).astype(np.float64)
        crossings = _moving_mean(np.abs(np.diff(above, axis=0, prepend=above[:1])), L, centred)
        out += [up, ma_norm, dyn, np.sqrt(a_var), n_std, mr, r_std, r_rms, yaw_mean, yaw_abs, crossings]
    return np.concatenate(out, 1).astype(np.float32)


class Standardiser(eqx.Module):
    """Per-channel standardisation (x - mean) / std of the 6 watch channels."""

    mean: Array  # (6,)
    std: Array  # (6,)

    def __call__(self, readings) -> Array:
        x = _check_readings("readings", readings)
        return (x - self.mean) / self.std


def fit_standardiser(readings: Sequence) -> Standardiser:
    """Mean and standard deviation of each channel over a list of (N_i, 6) readings."""
    if len(readings) == 0:
        raise ValueError("fit_standardiser needs at least one (N, 6) readings array.")
    x = np.concatenate([np.asarray(_check_readings(f"readings[{i}]", r)) for i, r in enumerate(readings)])
    std = x.std(0)
    return Standardiser(jnp.asarray(x.mean(0), jnp.float32), jnp.asarray(np.maximum(std, 1e-6), jnp.float32))


# --- MLP ---------------------------------------------------------------------------------------


class ActivityMLP(eqx.Module):
    """The per-frame classifier of Fig. 7.6: 360 → 1024 → 512 → 60 → C; each hidden layer
    followed by ReLU and Dropout (rate 0.5)."""

    layers: tuple[eqx.nn.Linear, ...]
    dropout: float = eqx.field(static=True)

    def __init__(
        self,
        num_classes: int,
        key: Array,
        in_size: int = NUM_CHANNELS * WINDOW,
        hidden: Sequence[int] = (1024, 512, 60),
        dropout: float = 0.5,
    ):
        if not (isinstance(num_classes, int) and num_classes >= 2):
            raise ValueError(f"num_classes must be an int >= 2, got {num_classes!r}.")
        if not 0.0 <= dropout < 1.0:
            raise ValueError(f"dropout is a rate in [0, 1), got {dropout}.")
        sizes = (int(in_size), *(int(h) for h in hidden), num_classes)
        keys = jax.random.split(key, len(sizes) - 1)
        self.layers = tuple(eqx.nn.Linear(a, b, key=k) for a, b, k in zip(sizes[:-1], sizes[1:], keys))
        self.dropout = float(dropout)

    @property
    def in_size(self) -> int:
        return self.layers[0].in_features

    @property
    def num_classes(self) -> int:
        return self.layers[-1].out_features

    @property
    def hidden(self) -> tuple[int, ...]:
        return tuple(layer.out_features for layer in self.layers[:-1])

    def __call__(self, x: Array, key: Array | None = None) -> Array:
        """Logits (C,) of one input vector x (in_size,); dropout only when `key` is given."""
        keys = [None] * len(self.layers) if key is None else list(jax.random.split(key, len(self.layers)))
        for layer, k in zip(self.layers[:-1], keys[:-1]):
            x = jax.nn.relu(layer(x))
            if k is not None and self.dropout > 0:
                keep = jax.random.bernoulli(k, 1.0 - self.dropout, x.shape)
                x = jnp.where(keep, x / (1.0 - self.dropout), 0.0)
        return self.layers[-1](x)


@eqx.filter_jit
def _log_probs_batch(mlp: ActivityMLP, x: Array) -> Array:
    return jax.nn.log_softmax(jax.vmap(mlp)(x), -1)


def mlp_log_probs(mlp: ActivityMLP, features, chunk: int = 4096) -> Array:
    """log p_MLP (N, C) of (N, in_size) features, evaluated in fixed-size chunks."""
    x = jnp.asarray(features, jnp.float32)
    if x.ndim != 2 or x.shape[1] != mlp.in_size:
        raise ValueError(f"features has shape {x.shape}; this MLP needs (N, {mlp.in_size}).")
    check_finite("features", features)
    n = x.shape[0]
    size = min(chunk, max(256, -(-n // 256) * 256))
    out = []
    for s in range(0, n, size):
        part = x[s : s + size]
        pad = size - part.shape[0]
        if pad:
            part = jnp.concatenate([part, jnp.zeros((pad, x.shape[1]), x.dtype)])
        out.append(_log_probs_batch(mlp, part)[: size - pad])
    return jnp.concatenate(out, 0)


# --- linear-chain CRF ---------------------------------------------------------------------------


def _check_chain(unary, transitions, mask, labels=None):
    unary = jnp.asarray(unary)
    transitions = jnp.asarray(transitions)
    if unary.ndim != 2 or unary.shape[0] < 1:
        raise ValueError(f"unary has shape {unary.shape}; expected (T, C) with T >= 1.")
    C = unary.shape[1]
    if transitions.shape != (C, C):
        raise ValueError(f"transitions has shape {transitions.shape}; expected ({C}, {C}) for C = {C} classes.")
    check_finite("unary", unary)
    check_finite("transitions", transitions)
    mask = jnp.ones(unary.shape[0], bool) if mask is None else jnp.asarray(mask)
    if mask.shape != unary.shape[:1] or mask.dtype != jnp.bool_:
        raise ValueError(f"mask has shape {mask.shape} and dtype {mask.dtype}; expected ({unary.shape[0]},) bool.")
    if labels is not None:
        labels = jnp.asarray(labels)
        if labels.shape != unary.shape[:1] or not jnp.issubdtype(labels.dtype, jnp.integer):
            raise ValueError(
                f"labels has shape {labels.shape} and dtype {labels.dtype}; expected ({unary.shape[0]},) int."
            )
        v = np.asarray(labels) if not isinstance(labels, jax.core.Tracer) else None
        if v is not None and ((v < 0) | (v >= C))[np.asarray(mask)].any():
            raise ValueError(f"labels must lie in 0 .. {C - 1} at the unmasked frames; got {sorted(set(v.tolist()))}.")
    return unary, transitions, mask, labels


def crf_score(unary, transitions, labels, mask=None) -> Array:
    """score(S) = Σ_t u_t(S_t) + Σ_t A_{S_t, S_t'} over the unmasked frames, t' the next
    unmasked frame (masked frames are skipped: the chain links their neighbours)."""
    unary, transitions, mask, labels = _check_chain(unary, transitions, mask, labels)

    def step(carry, inp):
        prev, started = carry
        u, l, m = inp
        s = u[l] + jnp.where(started, transitions[prev, l], 0.0)
        return (jnp.where(m, l, prev), started | m), jnp.where(m, s, 0.0)

    _, s = lax.scan(step, (jnp.zeros((), labels.dtype), jnp.zeros((), bool)), (unary, labels, mask))
    return s.sum()


def crf_log_partition(unary, transitions, mask=None) -> Array:
    """log Z = log Σ_S exp score(S) by the forward algorithm:
    α_0 = u_0, α_t(j) = u_t(j) + logsumexp_i(α_{t-1}(i) + A_ij), log Z = logsumexp_j α_T(j).
    Masked frames are skipped (as in `crf_score`); 0 if every frame is masked."""
    unary, transitions, mask, _ = _check_chain(unary, transitions, mask)

    def step(carry, inp):
        alpha, started = carry
        u, m = inp
        new = jnp.where(started, jax.nn.logsumexp(alpha[:, None] + transitions, axis=0), 0.0) + u
        return (jnp.where(m, new, alpha), started | m), None

    C = unary.shape[1]
    (alpha, started), _ = lax.scan(step, (jnp.zeros(C, unary.dtype), jnp.zeros((), bool)), (unary, mask))
    return jnp.where(started, jax.nn.logsumexp(alpha), 0.0)


def crf_log_likelihood(unary, transitions, labels, mask=None) -> Array:
    """log P(labels) = score(labels) - log Z of the linear-chain CRF (exact).

    Args:
        unary: (T, C) per-frame scores u_t (here λ log p_MLP).
        transitions: (C, C) A_ij, the score of class i followed by class j.
        labels: (T,) int class per frame.
        mask: (T,) bool, frames to use (default all); masked frames are skipped.
    """
    return crf_score(unary, transitions, labels, mask) - crf_log_partition(unary, transitions, mask)


def viterbi(unary, transitions, mask=None) -> Array:
    """argmax_S score(S) (max-product recursion, then backtracking), (T,) int32.

    δ_t(j) = u_t(j) + max_i(δ_{t-1}(i) + A_ij), with back-pointers; masked frames are
    skipped and get the label of the previous unmasked frame (the first one's if none
    precedes), so padding at the end repeats the last label.
    """
    unary, transitions, mask, _ = _check_chain(unary, transitions, mask)
    C = unary.shape[1]
    identity = jnp.arange(C)

    def forward(carry, inp):
        delta, started = carry
        u, m = inp
        scores = delta[:, None] + transitions
        new = jnp.where(started, scores.max(0), 0.0) + u
        pointer = jnp.where(m & started, scores.argmax(0), identity)
        return (jnp.where(m, new, delta), started | m), pointer

    (delta, _), pointers = lax.scan(forward, (jnp.zeros(C, unary.dtype), jnp.zeros((), bool)), (unary, mask))

    def back(label, pointer):
        return pointer[label], label

    _, labels = lax.scan(back, jnp.argmax(delta), pointers, reverse=True)
    return labels.astype(jnp.int32)


class ActivityCRF(eqx.Module):
    """The CRF's parameters: transition scores A (C, C) and log λ (unary weight)."""

    transitions: Array
    log_weight: Array

    @property
    def weight(self) -> Array:
        return jnp.exp(self.log_weight)

    def unary(self, log_probs) -> Array:
        """u_t = λ log p_t, (T, C)."""
        return self.weight * jnp.asarray(log_probs)


def transition_counts(label_sequences: Sequence, num_classes: int) -> np.ndarray:
    """(C, C) counts of class i followed by class j over the sequences (negative labels
    are skipped, breaking the chain there)."""
    counts = np.zeros((num_classes, num_classes))
    for seq in label_sequences:
        seq = np.asarray(seq)
        a, b = seq[:-1], seq[1:]
        ok = (a >= 0) & (b >= 0)
        if (seq >= num_classes).any():
            raise ValueError(f"labels go up to {int(seq.max())}; expected < {num_classes} classes.")
        np.add.at(counts, (a[ok], b[ok]), 1.0)
    return counts


def init_crf(label_sequences: Sequence, num_classes: int, smoothing: float = 1.0, weight: float = 1.0) -> ActivityCRF:
    """A from the log transition frequencies of training labels, log P(j | i) with add-
    `smoothing` counts (the thesis's T, Fig. 7.5); λ = `weight`."""
    counts = transition_counts(label_sequences, num_classes) + smoothing
    A = np.log(counts / counts.sum(1, keepdims=True))
    return ActivityCRF(jnp.asarray(A, jnp.float32), jnp.asarray(np.log(weight), jnp.float32))


# --- the classifier -------------------------------------------------------------------------------


class ActivityClassifier(eqx.Module):
    """A trained recogniser: standardiser, MLP, CRF and the class names."""

    standardiser: Standardiser
    mlp: ActivityMLP
    crf: ActivityCRF
    classes: tuple[str, ...] = eqx.field(static=True)
    window: int = eqx.field(static=True, default=WINDOW)
    rate: float = eqx.field(static=True, default=WATCH_RATE)

    def __check_init__(self):
        C = len(self.classes)
        if self.mlp.num_classes != C or self.crf.transitions.shape != (C, C):
            raise ValueError(
                f"{C} class names, but the MLP has {self.mlp.num_classes} outputs and the CRF "
                f"{self.crf.transitions.shape} transitions."
            )
        if self.mlp.in_size != NUM_CHANNELS * self.window:
            raise ValueError(
                f"the MLP takes {self.mlp.in_size} inputs; a window of {self.window} frames gives {NUM_CHANNELS * self.window}."
            )

    def features(self, readings) -> Array:
        """Standardised window features (N, 6 · window) of (N, 6) raw readings."""
        return window_features(self.standardiser(readings), self.window)

    def log_probs(self, readings) -> Array:
        """Per-frame log p_MLP (N, C) of one sequence of (N, 6) raw readings."""
        return mlp_log_probs(self.mlp, self.features(readings))

    def predict(self, readings, use_crf: bool = True) -> np.ndarray:
        """(N,) class indices: Viterbi over the CRF (or the per-frame argmax)."""
        lp = self.log_probs(readings)
        if not use_crf:
            return np.asarray(jnp.argmax(lp, -1), np.int32)
        return decode(self.crf, [lp])[0]


def _bucket(n: int) -> int:
    return max(64, 1 << int(math.ceil(math.log2(max(n, 1)))))


@eqx.filter_jit
def _viterbi_batch(crf: ActivityCRF, log_probs: Array, mask: Array) -> Array:
    return jax.vmap(lambda lp, m: viterbi(crf.unary(lp), crf.transitions, m))(log_probs, mask)


def _pad_sequences(sequences: Sequence, length: int, fill=0.0):
    out = []
    for s in sequences:
        s = np.asarray(s)
        pad = [(0, length - s.shape[0])] + [(0, 0)] * (s.ndim - 1)
        out.append(np.pad(s, pad, constant_values=fill))
    return np.stack(out)


def decode(crf: ActivityCRF, log_probs: Sequence) -> list[np.ndarray]:
    """Viterbi labels of each (T_i, C) log-probability sequence (padded to a power-of-two
    length in one batch, so few shapes compile)."""
    if len(log_probs) == 0:
        return []
    lengths = [int(np.shape(lp)[0]) for lp in log_probs]
    L = _bucket(max(lengths))
    lp = _pad_sequences(log_probs, L)
    mask = np.arange(L)[None, :] < np.asarray(lengths)[:, None]
    out = np.asarray(_viterbi_batch(crf, jnp.asarray(lp, jnp.float32), jnp.asarray(mask)))
    return [o[:n] for o, n in zip(out, lengths)]


# --- training ---------------------------------------------------------------------------------------


class TrainingCurve(eqx.Module):
    """Per epoch (MLP) or per step (CRF): training loss, and validation loss, accuracy and
    macro F1 of the per-frame argmax (NaN without validation data)."""

    loss: np.ndarray
    val_loss: np.ndarray
    val_accuracy: np.ndarray
    val_macro_f1: np.ndarray


def class_weights(labels, num_classes: int, power: float = 1.0) -> np.ndarray:
    """w_c ∝ (1 / frequency_c)^power, normalised to mean 1 over the frames (classes with
    no frames get 0): balances the cross-entropy over classes."""
    labels = np.asarray(labels)
    counts = np.bincount(labels[labels >= 0], minlength=num_classes).astype(np.float64)
    w = np.where(counts > 0, 1.0 / np.maximum(counts, 1.0) ** power, 0.0)
    return (w * counts.sum() / max((w * counts).sum(), 1e-12)).astype(np.float32)


def _check_training(features, labels, num_inputs: int, num_classes: int, name: str = "features"):
    x = np.asarray(features, np.float32)
    y = np.asarray(labels)
    if x.ndim != 2 or x.shape[1] != num_inputs:
        raise ValueError(f"{name} has shape {x.shape}; expected (n, {num_inputs}).")
    if y.shape != (x.shape[0],) or not np.issubdtype(y.dtype, np.integer):
        raise ValueError(f"labels has shape {y.shape} and dtype {y.dtype}; expected ({x.shape[0]},) int.")
    if x.shape[0] == 0:
        raise ValueError(f"{name} has no samples.")
    if not np.isfinite(x).all():
        raise ValueError(f"{name} contains NaN or inf (sample {int(np.argmax(~np.isfinite(x).all(1)))}).")
    if (y < 0).any() or (y >= num_classes).any():
        raise ValueError(f"labels must lie in 0 .. {num_classes - 1}; got values {sorted(set(y.tolist()))[:10]}.")
    return x, y.astype(np.int32)


def _weighted_ce(mlp, x, y, w, key):
    keys = None if key is None else jax.random.split(key, x.shape[0])
    logits = jax.vmap(mlp)(x) if keys is None else jax.vmap(mlp)(x, keys)
    nll = -jnp.take_along_axis(jax.nn.log_softmax(logits, -1), y[:, None], 1)[:, 0]
    return jnp.sum(w[y] * nll) / jnp.sum(w[y])


def train_mlp(
    mlp: ActivityMLP,
    features,
    labels,
    key: Array,
    epochs: int = 20,
    batch_size: int = 256,
    learning_rate: float = 1e-3,
    weights=None,
    validation: tuple | None = None,
    on_epoch=None,
    verbose: bool = False,
) -> tuple[ActivityMLP, TrainingCurve]:
    """Adam on the (class-weighted) cross-entropy with dropout, `epochs` passes over the data.

    Args:
        mlp: the initial network.
        features: (n, in_size) standardised window features; labels (n,) int.
        key: JAX key (shuffling and dropout).
        weights: (C,) per-class loss weights (default 1; see `class_weights`).
        validation: optional (features, labels) scored after every epoch (no dropout).
        on_epoch: optional `on_epoch(epoch, mlp)` called after every epoch (1-based), e.g.
            to keep the held-out predictions of each epoch.
    Returns:
        (trained network, TrainingCurve per epoch).
    """
    import optax

    x, y = _check_training(features, labels, mlp.in_size, mlp.num_classes)
    if not (isinstance(epochs, int) and epochs >= 0) or not (isinstance(batch_size, int) and batch_size >= 1):
        raise ValueError(f"epochs must be an int >= 0 and batch_size an int >= 1; got {epochs!r}, {batch_size!r}.")
    C = mlp.num_classes
    w = jnp.ones(C, jnp.float32) if weights is None else jnp.asarray(weights, jnp.float32)
    if w.shape != (C,) or not bool(jnp.all(jnp.isfinite(w) & (w >= 0))):
        raise ValueError(f"weights must be ({C},) finite and >= 0, got shape {w.shape}.")
    if validation is not None:
        vx, vy = _check_training(*validation, mlp.in_size, C, name="validation features")
    optimiser = optax.adam(learning_rate)
    state = optimiser.init(eqx.filter(mlp, eqx.is_array))

    @eqx.filter_jit
    def step(mlp, state, xb, yb, k):
        loss, grads = eqx.filter_value_and_grad(_weighted_ce)(mlp, xb, yb, w, k)
        updates, state = optimiser.update(grads, state, eqx.filter(mlp, eqx.is_array))
        return eqx.apply_updates(mlp, updates), state, loss

    n = x.shape[0]
    bs = min(batch_size, n)
    per_epoch = max(1, n // bs)  # full batches only (one compiled shape); the rest reshuffles
    losses, val_losses, val_acc, val_f1 = [], [], [], []
    for epoch in range(epochs):
        key, shuffle_key = jax.random.split(key)
        order = np.asarray(jax.random.permutation(shuffle_key, n))
        total = 0.0
        for b in range(per_epoch):
            idx = order[b * bs : (b + 1) * bs]
            key, k = jax.random.split(key)
            mlp, state, loss = step(mlp, state, jnp.asarray(x[idx]), jnp.asarray(y[idx]), k)
            total += float(loss)
        losses.append(total / per_epoch)
        if validation is not None:
            lp = mlp_log_probs(mlp, vx)
            val_losses.append(float(-jnp.mean(jnp.take_along_axis(lp, jnp.asarray(vy)[:, None], 1))))
            scores = classification_scores(confusion_matrix(vy, np.asarray(jnp.argmax(lp, -1)), C))
            val_acc.append(scores["accuracy"])
            val_f1.append(scores["macro_f1"])
        if on_epoch is not None:
            on_epoch(epoch + 1, mlp)
        if verbose:
            extra = (
                f", validation loss {val_losses[-1]:.3f} accuracy {val_acc[-1]:.3f} macro F1 {val_f1[-1]:.3f}"
                if validation is not None
                else ""
            )
            print(f"  epoch {epoch + 1}/{epochs}: loss {losses[-1]:.3f}{extra}", flush=True)
    nan = np.full(len(losses), np.nan)
    val = [np.asarray(v) if v else nan for v in (val_losses, val_acc, val_f1)]
    return mlp, TrainingCurve(np.asarray(losses), *val)


def train_crf(
    crf: ActivityCRF,
    log_probs: Sequence,
    labels: Sequence,
    steps: int = 200,
    learning_rate: float = 0.05,
    prior_weight: float = 0.01,
    fit_transitions: bool = True,
) -> tuple[ActivityCRF, TrainingCurve]:
    """Maximise the CRF log-likelihood of labelled sequences with the MLP fixed.

    Loss: -Σ_i log P(S_i) / Σ_i T_i (mean per frame) + prior_weight · ||A - A_0||² / C,
    A_0 the initial transitions (the log transition frequencies), a Gaussian prior that
    keeps transitions seen rarely (or never) in these sequences near their frequency.

    Args:
        crf: initial parameters (`init_crf`).
        log_probs: list of (T_i, C) MLP log-probabilities of sequences the MLP was not
            trained on (otherwise λ learns the MLP's over-confidence on its training set).
        labels: list of (T_i,) int labels; negative labels are masked (skipped).
        fit_transitions: False learns λ only.
    Returns:
        (trained CRF, TrainingCurve per step).
    """
    import optax

    if len(log_probs) == 0 or len(log_probs) != len(labels):
        raise ValueError(
            f"train_crf needs as many label sequences as log-probability sequences (>= 1); got {len(log_probs)} and {len(labels)}."
        )
    C = crf.transitions.shape[0]
    lengths = []
    for i, (lp, lab) in enumerate(zip(log_probs, labels)):
        if np.shape(lp) != (np.shape(lab)[0], C) or np.ndim(lab) != 1:
            raise ValueError(
                f"sequence {i}: log_probs {np.shape(lp)} and labels {np.shape(lab)}; expected (T, {C}) and (T,)."
            )
        check_finite(f"log_probs[{i}]", lp)
        if (np.asarray(lab) >= C).any():
            raise ValueError(f"labels[{i}] go up to {int(np.max(lab))}; the CRF has {C} classes.")
        lengths.append(len(lab))
    L = _bucket(max(lengths))
    lp = jnp.asarray(_pad_sequences(log_probs, L), jnp.float32)
    lab_np = _pad_sequences(labels, L, fill=-1)
    mask = jnp.asarray(lab_np >= 0)
    lab = jnp.asarray(np.maximum(lab_np, 0), jnp.int32)
    frames = float(np.maximum(np.asarray(mask).sum(), 1))
    A0 = crf.transitions

    def loss_fn(params):
        A, log_w = params
        A = A if fit_transitions else lax.stop_gradient(A)
        ll = jax.vmap(lambda u, y, m: crf_log_likelihood(jnp.exp(log_w) * u, A, y, m))(lp, lab, mask)
        return -ll.sum() / frames + prior_weight * jnp.sum((A - A0) ** 2) / C

    optimiser = optax.adam(learning_rate)
    params = (crf.transitions, crf.log_weight)
    state = optimiser.init(params)

    @jax.jit
    def step(params, state):
        loss, grads = jax.value_and_grad(loss_fn)(params)
        updates, state = optimiser.update(grads, state, params)
        return optax.apply_updates(params, updates), state, loss

    losses = []
    for _ in range(steps):
        params, state, loss = step(params, state)
        losses.append(float(loss))
    nan = np.full(len(losses), np.nan)
    return ActivityCRF(*params), TrainingCurve(np.asarray(losses), nan, nan, nan)


# --- scores --------------------------------------------------------------------------------------------


def confusion_matrix(truth, predicted, num_classes: int) -> np.ndarray:
    """(C, C) counts, rows the true class, columns the predicted one (negative truth skipped)."""
    truth, predicted = np.asarray(truth), np.asarray(predicted)
    if truth.shape != predicted.shape:
        raise ValueError(f"truth {truth.shape} and predicted {predicted.shape} differ in shape.")
    ok = truth >= 0
    m = np.zeros((num_classes, num_classes), np.int64)
    np.add.at(m, (truth[ok], predicted[ok]), 1)
    return m


def classification_scores(confusion: np.ndarray) -> dict:
    """Accuracy, per-class precision / recall / F1 and macro F1 (mean over classes with
    any true frame) of a confusion matrix."""
    m = np.asarray(confusion, np.float64)
    tp = np.diag(m)
    support = m.sum(1)
    predicted = m.sum(0)
    precision = np.where(predicted > 0, tp / np.maximum(predicted, 1), 0.0)
    recall = np.where(support > 0, tp / np.maximum(support, 1), 0.0)
    f1 = np.where(precision + recall > 0, 2 * precision * recall / np.maximum(precision + recall, 1e-12), 0.0)
    present = support > 0
    return {
        "accuracy": float(tp.sum() / max(m.sum(), 1)),
        "macro_f1": float(f1[present].mean()) if present.any() else float("nan"),
        "precision": precision.tolist(),
        "recall": recall.tolist(),
        "f1": f1.tolist(),
        "support": support.astype(int).tolist(),
    }


# --- files ------------------------------------------------------------------------------------------------


def save_classifier(path, classifier: ActivityClassifier, meta: dict | None = None) -> Path:
    """Write the classifier (weights, standardisation, CRF, class names, `meta` as JSON)
    to an npz file, atomically."""
    path = Path(path)
    if path.suffix != ".npz":
        path = path.with_name(path.name + ".npz")
    header = {
        "format": FORMAT,
        "version": FORMAT_VERSION,
        "classes": list(classifier.classes),
        "window": classifier.window,
        "rate": classifier.rate,
        "hidden": list(classifier.mlp.hidden),
        "dropout": classifier.mlp.dropout,
        "meta": meta or {},
    }
    return save_module(path, classifier, header)


def load_classifier(path, classes: Sequence[str] | None = None) -> tuple[ActivityClassifier, dict]:
    """(classifier, meta) from a `save_classifier` file. With `classes`, the file's class
    names must equal them (in order). `ActivityModelError` names what does not match."""
    header, arrays = read_header(path, FORMAT, FORMAT_VERSION, ActivityModelError,
                                 "jaxmocap.learned.activity.save_classifier")  # fmt: skip
    names = tuple(header.get("classes", ()))
    if classes is not None and tuple(classes) != names:
        raise ActivityModelError(f"{path}: the classifier knows classes {list(names)}, not {list(classes)}.")
    try:
        window, C = int(header["window"]), len(names)
        skeleton = ActivityClassifier(
            Standardiser(jnp.zeros(NUM_CHANNELS), jnp.ones(NUM_CHANNELS)),
            ActivityMLP(C, jax.random.PRNGKey(0), NUM_CHANNELS * window, header["hidden"], header["dropout"]),
            ActivityCRF(jnp.zeros((C, C)), jnp.zeros(())),
            names,
            window,
            float(header["rate"]),
        )
    except (KeyError, TypeError, ValueError) as e:
        raise ActivityModelError(f"{path}: bad classifier configuration ({e}).") from None
    return fill_module(skeleton, header, arrays, path, ActivityModelError), header.get("meta", {})
