"""The labelling rule (package docstring): per-frame classes from the true motion."""

from __future__ import annotations

import math

import equinox as eqx
import numpy as np

from ..._checks import check_rate
from ...body.model import SMPL_JOINT_NAMES, Body
from ...motion.sequence import Motion
from ._motion import body_or_default, posed_padded

__all__ = ["CLASSES", "SIGNALS", "LabelRule", "label_signals", "labels_from_signals", "activity_labels"]


#: The classes of the labelling rule, in label order.
CLASSES: tuple[str, ...] = (
    "still", "walk", "run", "jump", "bend", "turn_left", "turn_right", "arms", "arms_up",
)  # fmt: skip
#: The per-frame quantities of `label_signals`, in the order experiments store them.
SIGNALS: tuple[str, ...] = (
    "speed", "flight", "airborne", "tilt", "crouch", "turn", "arm_speed", "hand_height",
    "watch_arm_speed", "watch_hand_height",
)  # fmt: skip


_J = {n: i for i, n in enumerate(SMPL_JOINT_NAMES)}
_LEFT_FOOT = (_J["left_ankle"], _J["left_foot"])
_RIGHT_FOOT = (_J["right_ankle"], _J["right_foot"])
_WRISTS = (_J["left_wrist"], _J["right_wrist"])


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
    body = body_or_default(body)
    T, fps = motion.num_frames, motion.fps
    if T < 3:
        z = np.zeros(T)
        return dict(speed=z, flight=z, airborne=z, tilt=z, crouch=np.ones(T), turn=z, arm_speed=z,
                    hand_height=z - 1.0, watch_arm_speed=z, watch_hand_height=z - 1.0)  # fmt: skip
    joints = np.asarray(posed_padded(body, motion)[2].joints, np.float64)[:T]
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
