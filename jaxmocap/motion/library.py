"""Procedural motions (no data files needed): walk, run, jumping jacks, arm raises, squats,
leg raises, sit down / stand up, hold.

Every joint angle is a smooth closed-form periodic function of time (sums of cosines
and von Mises bumps exp((cos 2π(s−c) − 1)/w²) of the gait phase s). Angles follow
SMPL's frame (y up, facing +z, left = +x) with these signs (local rotations, parents
≈ upright):

    hip / spine flexion (segment toward +z)  rotation about x by −angle (legs) / +angle (spine)
    knee flexion (shank toward −z)          about x by +angle
    ankle dorsiflexion (toes up)             about x by −angle
    arms down from the T-pose                left shoulder about z by −angle, right by +angle
    elbow flexion (forearm forward)          left about y by −angle, right by +angle

Root translation: horizontal speed = stride length x stride frequency, the stride
length measured on the body's own legs at heel strike, so the stance foot barely slides;
height from forward kinematics so that the lowest ankle/foot joint (a smooth soft-min
with 5 mm temperature) sits at its rest height above the soles (y = 0), plus a flight
bump for running and hops for jumping jacks. The body's rest joints come from `body`
(default `jaxmocap.default_body()`, else approximate SMPL neutral joints,
`SMPL_APPROX_REST`). Gait: right heel strike at phase 0, left at 0.5; arms swing
opposite to the legs; the pelvis yaws toward the forward leg, the chest counter-rotates.
"""

from __future__ import annotations

import numpy as np

from ..body.model import SMPL_JOINT_NAMES, SMPL_PARENTS
from ..rotation import host_exp, host_log
from .sequence import Motion

__all__ = [
    "MOTIONS",
    "SMPL_APPROX_REST",
    "arm_raises",
    "jumping_jacks",
    "leg_raises",
    "run",
    "sit_stand",
    "squats",
    "static_hold",
    "walk",
]

#: Approximate SMPL neutral mean-shape rest joints (metres); soles at y ≈ −1.16.
SMPL_APPROX_REST = np.array([
    [-0.0018, -0.2233, 0.0282], [0.0695, -0.3139, 0.0154], [-0.0677, -0.3144, 0.0198],
    [-0.0043, -0.1144, -0.0015], [0.1024, -0.6890, 0.0169], [-0.1059, -0.6941, 0.0150],
    [0.0012, 0.0208, 0.0026], [0.0885, -1.0876, -0.0267], [-0.0920, -1.0948, -0.0272],
    [0.0026, 0.0737, 0.0280], [0.1148, -1.1437, 0.0925], [-0.1174, -1.1430, 0.0961],
    [-0.0002, 0.2876, -0.0148], [0.0781, 0.1976, -0.0060], [-0.0819, 0.1954, -0.0107],
    [0.0050, 0.3524, 0.0365], [0.1720, 0.2460, -0.0192], [-0.1752, 0.2461, -0.0224],
    [0.4344, 0.2317, -0.0387], [-0.4365, 0.2342, -0.0387], [0.6890, 0.2409, -0.0442],
    [-0.6911, 0.2440, -0.0452], [0.7715, 0.2335, -0.0581], [-0.7759, 0.2353, -0.0593],
])  # fmt: skip
_SMPL_APPROX_SOLE = -1.16

J = {n: i for i, n in enumerate(SMPL_JOINT_NAMES)}
_FEET = [J["left_ankle"], J["right_ankle"], J["left_foot"], J["right_foot"]]


def _rest(body):
    if body is None:
        try:
            from ..body.io import default_body

            body = default_body()
        except (OSError, ValueError):
            return SMPL_APPROX_REST, _SMPL_APPROX_SOLE
    from .retarget import smpl_rest

    return smpl_rest(body)


def _bump(s, center, width):
    """Periodic von Mises bump in phase s (period 1), peak 1 at `center`."""
    return np.exp((np.cos(2 * np.pi * (s - center)) - 1.0) / width**2)


def _axis(axis: str, degrees) -> np.ndarray:
    degrees = np.asarray(degrees, np.float64)
    vec = np.zeros((*degrees.shape, 3))
    vec[..., "xyz".index(axis)] = np.radians(degrees)
    return host_exp(vec)


class _Pose:
    """Local rotation matrices (T, 24, 3, 3), built by left-multiplying axis rotations."""

    def __init__(self, T):
        self.R = np.broadcast_to(np.eye(3), (T, 24, 3, 3)).copy()

    def rot(self, joint: str, axis: str, degrees):
        j = J[joint]
        self.R[:, j] = _axis(axis, np.broadcast_to(degrees, self.R.shape[:1])) @ self.R[:, j]
        return self

    def globals(self):
        G = self.R.copy()
        for j in range(1, 24):
            G[:, j] = G[:, SMPL_PARENTS[j]] @ self.R[:, j]
        return G

    def axis_angle(self):
        return host_log(self.R)


def _ground_height(pose: _Pose, rest, sole, tau=0.005):
    """Per-frame trans_y putting the lowest foot joint (soft-min) at its rest clearance."""
    from .retarget import smpl_joint_positions

    T = pose.R.shape[0]
    joints = smpl_joint_positions(pose.globals(), rest, np.zeros((T, 3)))
    clearance = rest[_FEET, 1] - sole
    h = joints[:, _FEET, 1] - clearance  # height of each joint's "sole" above y=0 at trans 0
    m = h.min(1, keepdims=True)
    softmin = m[:, 0] - tau * np.log(np.exp(-(h - m) / tau).sum(1))
    return -softmin


def _arms_down(p: _Pose, down=70.0, swing_left=0.0, swing_right=0.0, elbow_left=10.0, elbow_right=10.0):
    # First lower the arms about z, then swing them about x (forward = +z).
    p.rot("left_shoulder", "z", -down).rot("right_shoulder", "z", down)
    p.rot("left_shoulder", "x", -np.asarray(swing_left)).rot("right_shoulder", "x", -np.asarray(swing_right))
    p.rot("left_elbow", "y", -np.asarray(elbow_left)).rot("right_elbow", "y", np.asarray(elbow_right))
    return p


def _gait(s, run: bool):
    """Closed-form gait angles (degrees) for the right leg at phase s (left: s + 0.5)."""
    if run:
        hip = 15 + 30 * np.cos(2 * np.pi * (s - 0.02))
        knee = 20 + 20 * _bump(s, 0.15, 0.25) + 75 * _bump(s, 0.68, 0.45)
        ankle = 8 * _bump(s, 0.2, 0.3) - 20 * _bump(s, 0.42, 0.2) + 5 * _bump(s, 0.8, 0.4)
    else:
        hip = 10 + 20 * np.cos(2 * np.pi * s)
        knee = 5 + 15 * _bump(s, 0.15, 0.3) + 55 * _bump(s, 0.72, 0.52)
        ankle = (
            -5 * _bump(s, 0.05, 0.2) + 10 * _bump(s, 0.42, 0.35) - 18 * _bump(s, 0.63, 0.25) + 3 * _bump(s, 0.85, 0.35)
        )
    return hip, knee, ankle


def _locomotion(num_frames, fps, frequency, run, body, name):
    rest, sole = _rest(body)
    t = np.arange(num_frames) / fps

    def pose_at(s):
        p = _Pose(len(s))
        for side, phase in (("right", s), ("left", s + 0.5)):
            hip, knee, ankle = _gait(phase, run)
            p.rot(f"{side}_hip", "x", -hip).rot(f"{side}_knee", "x", knee).rot(f"{side}_ankle", "x", -ankle)
        c = np.cos(2 * np.pi * s)  # +1 when the right leg is forward
        swing = (30.0 if run else 15.0) * c
        _arms_down(
            p,
            down=65.0 if run else 72.0,
            swing_left=swing,
            swing_right=-swing,
            elbow_left=(80.0 if run else 15.0) + 0.5 * swing,
            elbow_right=(80.0 if run else 15.0) - 0.5 * swing,
        )
        lean = 8.0 if run else 3.0
        p.rot("pelvis", "y", 5.0 * c).rot("spine3", "y", -6.0 * c)
        p.rot("spine1", "x", lean).rot("neck", "x", -lean)
        p.rot("pelvis", "z", 2.0 * np.cos(4 * np.pi * s))
        return p

    # Speed matched to the stride on this body: the mean backward velocity (relative to
    # the pelvis) of whichever ankle is lower, over one cycle, so the stance foot
    # stays put on average.
    from .retarget import smpl_joint_positions

    n = 240
    cycle = pose_at(np.arange(n) / n)
    joints = smpl_joint_positions(cycle.globals(), rest, np.zeros((n, 3)))
    ankles = joints[:, [J["left_ankle"], J["right_ankle"]]]
    stance = np.argmin(ankles[:, :, 1], axis=1)
    dz = (np.roll(ankles[:, :, 2], -1, axis=0) - np.roll(ankles[:, :, 2], 1, axis=0)) * n / 2 * frequency
    speed = -float(np.mean(dz[np.arange(n), stance]))

    s = frequency * t
    p = pose_at(s)
    y = _ground_height(p, rest, sole)
    if run:
        y = y + 0.04 * _bump(2 * s, 0.45, 0.35)  # flight phase after each push-off
    trans = np.stack([np.zeros_like(t), y, speed * t], -1)
    return Motion(poses=p.axis_angle(), trans=trans, fps=fps, name=name)


def walk(num_frames: int = 120, fps: float = 30.0, frequency: float = 0.9, body=None) -> Motion:
    """A straight walk along +z: `frequency` strides (two steps) per second, ~1.1 m/s."""
    return _locomotion(num_frames, fps, frequency, False, body, f"walk({frequency} Hz)")


def run(num_frames: int = 120, fps: float = 30.0, frequency: float = 1.4, body=None) -> Motion:
    """A straight jog along +z with a flight phase, `frequency` strides per second."""
    return _locomotion(num_frames, fps, frequency, True, body, f"run({frequency} Hz)")


def _cycle(num_frames, fps, period):
    t = np.arange(num_frames) / fps
    return t, 0.5 * (1.0 - np.cos(2 * np.pi * t / period))  # 0 → 1 → 0 each period


def jumping_jacks(num_frames: int = 120, fps: float = 30.0, period: float = 1.0, body=None) -> Motion:
    """Jumping jacks: arms from the sides to overhead while the legs spread, with hops."""
    rest, sole = _rest(body)
    t, a = _cycle(num_frames, fps, period)
    p = _Pose(len(t))
    p.rot("left_hip", "z", 14 * a).rot("right_hip", "z", -14 * a)
    p.rot("left_ankle", "z", -10 * a).rot("right_ankle", "z", 10 * a)
    p.rot("left_knee", "x", 8 + 10 * np.sin(2 * np.pi * t / period) ** 2)
    p.rot("right_knee", "x", 8 + 10 * np.sin(2 * np.pi * t / period) ** 2)
    p.rot("left_shoulder", "z", -75 + 160 * a).rot("right_shoulder", "z", 75 - 160 * a)
    p.rot("left_elbow", "y", -10.0).rot("right_elbow", "y", 10.0)
    y = _ground_height(p, rest, sole) + 0.06 * np.sin(2 * np.pi * t / period) ** 2
    trans = np.stack([np.zeros_like(t), y, np.zeros_like(t)], -1)
    return Motion(poses=p.axis_angle(), trans=trans, fps=fps, name="jumping_jacks")


def arm_raises(num_frames: int = 120, fps: float = 30.0, period: float = 2.0, body=None) -> Motion:
    """Standing front arm raises: both arms from the sides to shoulder height and back."""
    rest, sole = _rest(body)
    t, a = _cycle(num_frames, fps, period)
    p = _Pose(len(t))
    _arms_down(p, down=75.0, swing_left=95 * a, swing_right=95 * a, elbow_left=5.0, elbow_right=5.0)
    y = _ground_height(p, rest, sole)
    trans = np.stack([np.zeros_like(t), y, np.zeros_like(t)], -1)
    return Motion(poses=p.axis_angle(), trans=trans, fps=fps, name="arm_raises")


def squats(num_frames: int = 120, fps: float = 30.0, period: float = 2.5, depth: float = 1.0, body=None) -> Motion:
    """Squats: hips, knees and ankles flex together (depth 1: thighs near horizontal)."""
    rest, sole = _rest(body)
    t, a = _cycle(num_frames, fps, period)
    a = depth * a
    p = _Pose(len(t))
    for side in ("left", "right"):
        p.rot(f"{side}_hip", "x", -95 * a).rot(f"{side}_knee", "x", 110 * a).rot(f"{side}_ankle", "x", -25 * a)
    p.rot("spine1", "x", 25 * a).rot("spine2", "x", 10 * a).rot("neck", "x", -20 * a)
    _arms_down(p, down=75.0, swing_left=85 * a, swing_right=85 * a, elbow_left=5.0, elbow_right=5.0)
    y = _ground_height(p, rest, sole)
    # Keep the feet (not the pelvis) in place: shift back by the ankles' forward drift.
    from .retarget import smpl_joint_positions

    z = smpl_joint_positions(p.globals(), rest, np.zeros((len(t), 3)))[:, [J["left_ankle"], J["right_ankle"]], 2].mean(
        1
    )
    trans = np.stack([np.zeros_like(t), y, -(z - z[0])], -1)
    return Motion(poses=p.axis_angle(), trans=trans, fps=fps, name="squats")


def static_hold(num_frames: int = 60, fps: float = 30.0, body=None) -> Motion:
    """Standing still in a relaxed A-pose with a slight breathing sway (±1°, 0.25 Hz)."""
    rest, sole = _rest(body)
    t = np.arange(num_frames) / fps
    p = _Pose(len(t))
    _arms_down(p, down=60.0, elbow_left=10.0, elbow_right=10.0)
    p.rot("spine2", "x", np.sin(2 * np.pi * 0.25 * t)).rot("pelvis", "z", 0.5 * np.sin(2 * np.pi * 0.1 * t))
    y = _ground_height(p, rest, sole)
    trans = np.stack([np.zeros_like(t), y, np.zeros_like(t)], -1)
    return Motion(poses=p.axis_angle(), trans=trans, fps=fps, name="static_hold")


def leg_raises(num_frames: int = 120, fps: float = 30.0, period: float = 2.0, body=None) -> Motion:
    """Standing front leg raises, alternating legs each period (hip flexion up to 60°).

    The raised leg stays nearly straight (knee 10°), the foot relaxed; the stance side
    keeps its sole on the ground (root height from the lowest foot joint) and the trunk
    counter-leans slightly backwards. Arms hang at the sides.
    """
    rest, sole = _rest(body)
    t = np.arange(num_frames) / fps
    bump = np.sin(np.pi * (t / period % 1.0)) ** 2  # 0 → 1 → 0 within each period
    left = (np.floor(t / period) % 2 == 0).astype(float)  # left leg on even periods
    p = _Pose(len(t))
    for side, on in (("left", left), ("right", 1.0 - left)):
        a = on * bump
        p.rot(f"{side}_hip", "x", -60 * a).rot(f"{side}_knee", "x", 10 * a).rot(f"{side}_ankle", "x", 10 * a)
    p.rot("spine1", "x", -5 * bump)
    _arms_down(p, down=75.0, elbow_left=10.0, elbow_right=10.0)
    y = _ground_height(p, rest, sole)
    trans = np.stack([np.zeros_like(t), y, np.zeros_like(t)], -1)
    return Motion(poses=p.axis_angle(), trans=trans, fps=fps, name="leg_raises")


def _smoothstep(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3 - 2 * x)


def sit_stand(num_frames: int = 150, fps: float = 30.0, period: float = 5.0, body=None) -> Motion:
    """Sit down on a (not modelled) seat of knee height and stand up again, every `period` s.

    Each period: stand 10 %, sit down over 30 %, stay seated 20 %, stand up over 30 %,
    stand 10 % (smoothstep transitions). Seated: hips 85°, knees 90°; the trunk leans
    forward by up to 35° in the middle of each transition (the usual sit-to-stand
    strategy). Feet stay planted: the root moves back and down with the hips.
    """
    rest, sole = _rest(body)
    t = np.arange(num_frames) / fps
    s = t / period % 1.0
    a = _smoothstep((s - 0.1) / 0.3) - _smoothstep((s - 0.6) / 0.3)  # 0 → 1 (seated) → 0
    lean = np.sin(np.pi * a) ** 2
    p = _Pose(len(t))
    for side in ("left", "right"):
        # The pelvis tilt below swings the legs backwards; the hips undo it.
        p.rot(f"{side}_hip", "x", -85 * a - 20 * lean).rot(f"{side}_knee", "x", 90 * a).rot(
            f"{side}_ankle", "x", -5 * a
        )
    p.rot("pelvis", "x", 20 * lean).rot("spine1", "x", 15 * lean).rot("neck", "x", -15 * lean)
    _arms_down(p, down=75.0, swing_left=30 * lean, swing_right=30 * lean, elbow_left=20.0,
               elbow_right=20.0)  # fmt: skip
    y = _ground_height(p, rest, sole)
    from .retarget import smpl_joint_positions

    z = smpl_joint_positions(p.globals(), rest, np.zeros((len(t), 3)))[:, [J["left_ankle"], J["right_ankle"]], 2].mean(
        1
    )
    trans = np.stack([np.zeros_like(t), y, -(z - z[0])], -1)
    return Motion(poses=p.axis_angle(), trans=trans, fps=fps, name="sit_stand")


MOTIONS = {
    "walk": walk,
    "run": run,
    "jumping_jacks": jumping_jacks,
    "arm_raises": arm_raises,
    "squats": squats,
    "leg_raises": leg_raises,
    "sit_stand": sit_stand,
    "static_hold": static_hold,
}
