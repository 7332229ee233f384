"""IMU error models in physical units, each a separate switch (von Marcard §2.4.2-2.4.4, §4.2.4).

Measured signals of a sensor s at frame t (all errors default to off):

    R̃_s(t) = exp(n_R) · R_y(γ_s(t)) · R_b^g(t) R_s^b R_mis,s          orientation
    ã^s(t) = R_misᵀ a^s(t; p + δ_s) + b_a(t) + n_a                      eq. 2.65
    ω̃^s(t) = R_misᵀ ω^s(t) + b_ω(t) + n_ω                               eq. 2.66

    γ_s(t) = γ_s,0 + random walk   heading drift about the vertical (eq. 2.71, §4.2.4);
                                    the accelerometer is not affected (it is a frame error)
    b(t)   = b_0 + random walk     constant and random-walk bias (eq. 2.64, 2.66)
    R_mis                          sensor-to-bone misalignment (the mounting error that
                                    calibration, eq. 3.3 / 4.7 / 6.5, has to absorb)
    δ_s                            placement offset along the limb (bone frame)
    clock offset                   each sensor samples at t + τ_s (signals resampled)
    dropout                        runs of lost samples, returned as NaN (as in DIP-IMU)

Randomness: every function takes a `numpy.random.Generator`; the scenario code derives
one per sequence and component from `numpy.random.SeedSequence(seed)`, so results are
deterministic given the seed and independent of the order things are generated in.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import numpy as np

from ..body.kinematics import forward
from ..rotation import host_exp, host_log
from .imu import GRAVITY, IMUPlacement, IMUReadings, imu_from_body_output

__all__ = [
    "IMUErrorModel",
    "IMUErrors",
    "MeasuredIMU",
    "sample_imu_errors",
    "apply_imu_errors",
    "simulate_imu",
    "global_free_acceleration",
    "random_rotations",
]


@dataclasses.dataclass(frozen=True)
class IMUErrorModel:
    """Standard deviations of each IMU error, in SI units; 0 switches an error off.

    acc_noise (m/s²), gyro_noise (rad/s), orientation_noise (rad): white noise per sample.
    acc_bias (m/s²), gyro_bias (rad/s): constant bias per sensor and axis.
    acc_bias_walk (m/s²/√s), gyro_bias_walk (rad/s/√s): bias random walk.
    heading_offset (rad): constant heading error γ_s,0 per sensor.
    heading_walk (rad/√s): slowly varying heading drift (random walk of γ_s).
    misalignment (rad): sensor-to-bone mounting error, a random rotation per sensor.
    placement_offset (m): sensor displaced along its limb's axis.
    dropout_rate: probability per sample that a dropout run starts; dropout_length (frames):
        mean run length (geometric).
    clock_offset (s): per-sensor sampling time offset.
    """

    acc_noise: float = 0.0
    gyro_noise: float = 0.0
    orientation_noise: float = 0.0
    acc_bias: float = 0.0
    acc_bias_walk: float = 0.0
    gyro_bias: float = 0.0
    gyro_bias_walk: float = 0.0
    heading_offset: float = 0.0
    heading_walk: float = 0.0
    misalignment: float = 0.0
    placement_offset: float = 0.0
    dropout_rate: float = 0.0
    dropout_length: float = 1.0
    clock_offset: float = 0.0

    def __post_init__(self):
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if not (np.isfinite(value) and value >= 0):
                raise ValueError(f"IMUErrorModel.{f.name} must be finite and >= 0, got {value}.")
        if self.dropout_rate > 1:
            raise ValueError(f"dropout_rate is a probability, got {self.dropout_rate}.")
        if self.dropout_length < 1:
            raise ValueError(f"dropout_length is in frames and must be >= 1, got {self.dropout_length}.")

    @classmethod
    def off(cls) -> IMUErrorModel:
        return cls()

    @classmethod
    def xsens(cls) -> IMUErrorModel:
        """Plausible values for body-worn MEMS IMUs (Xsens MTw class), not a datasheet.

        Orientation ≲ 1° in inclination (von Marcard §2.4.3), a few degrees of heading
        offset per sensor plus slow drift (§4.2.4), ~5° mounting error, 2 cm placement.
        """
        return cls(
            acc_noise=0.05,
            gyro_noise=0.01,
            orientation_noise=np.radians(0.5),
            acc_bias=0.05,
            acc_bias_walk=0.002,
            gyro_bias=0.005,
            gyro_bias_walk=0.0005,
            heading_offset=np.radians(3.0),
            heading_walk=np.radians(1.0) / np.sqrt(60.0),  # ~1° per minute (1σ)
            misalignment=np.radians(5.0),
            placement_offset=0.02,
            dropout_rate=0.0005,
            dropout_length=5.0,
            clock_offset=0.002,
        )


@dataclasses.dataclass(frozen=True)
class IMUErrors:
    """One draw of the error model for S sensors over T frames (NumPy arrays)."""

    misalignment: np.ndarray  # (S, 3, 3) R_mis
    offset_bone: np.ndarray  # (S, 3) placement offset δ_s in the bone frame
    heading: np.ndarray  # (T, S) γ_s(t), radians
    acc_bias: np.ndarray  # (T, S, 3)
    gyro_bias: np.ndarray  # (T, S, 3)
    clock_offset: np.ndarray  # (S,) seconds
    dropped: np.ndarray  # (T, S) bool


@dataclasses.dataclass(frozen=True)
class MeasuredIMU:
    """What the sensors report: NaN where samples were dropped.

    orientation (T, S, 3, 3) R̃_s^g; acceleration (T, S, 3) specific force in the sensor
    frame; angular_velocity (T, S, 3) in the sensor frame.
    """

    orientation: np.ndarray
    acceleration: np.ndarray
    angular_velocity: np.ndarray


def random_rotations(rng: np.random.Generator, std: float, shape=()) -> np.ndarray:
    """Rotations exp(n^) with n ~ N(0, std² I): (*shape, 3, 3)."""
    n = rng.normal(scale=std, size=(*shape, 3)) if std > 0 else np.zeros((*shape, 3))
    return host_exp(n)


def _walk(rng, T, shape, std0, walk, fps):
    """Constant N(0, std0²) plus a Gaussian random walk with `walk`/√s increments."""
    value = rng.normal(scale=std0, size=shape) if std0 > 0 else np.zeros(shape)
    out = np.broadcast_to(value, (T, *shape)).copy()
    if walk > 0 and T > 1:
        steps = rng.normal(scale=walk / np.sqrt(fps), size=(T - 1, *shape))
        out[1:] += np.cumsum(steps, axis=0)
    return out


def _dropouts(rng, T, S, rate, length):
    dropped = np.zeros((T, S), bool)
    if rate <= 0:
        return dropped
    starts = rng.random((T, S)) < rate
    lengths = rng.geometric(1.0 / length, size=(T, S))
    for t, s in zip(*np.nonzero(starts)):
        dropped[t : t + lengths[t, s], s] = True
    return dropped


def sample_imu_errors(
    model: IMUErrorModel,
    placement: IMUPlacement,
    num_frames: int,
    fps: float,
    rng: np.random.Generator,
    bone_directions: np.ndarray | None = None,
) -> IMUErrors:
    """Draw every error of `model` for one sequence (the draw order is fixed).

    bone_directions: (S, 3) unit limb axes in the bone frame (rest pose) along which the
    placement offset moves the sensor; default: the bone's y axis.
    """
    T, S = num_frames, placement.num_sensors
    misalignment = random_rotations(rng, model.misalignment, (S,))
    if bone_directions is None:
        bone_directions = np.tile([0.0, 1.0, 0.0], (S, 1))
    along = rng.normal(scale=model.placement_offset, size=S) if model.placement_offset > 0 else np.zeros(S)
    heading = _walk(rng, T, (S,), model.heading_offset, model.heading_walk, fps)
    acc_bias = _walk(rng, T, (S, 3), model.acc_bias, model.acc_bias_walk, fps)
    gyro_bias = _walk(rng, T, (S, 3), model.gyro_bias, model.gyro_bias_walk, fps)
    clock = rng.normal(scale=model.clock_offset, size=S) if model.clock_offset > 0 else np.zeros(S)
    dropped = _dropouts(rng, T, S, model.dropout_rate, model.dropout_length)
    return IMUErrors(
        misalignment=misalignment,
        offset_bone=along[:, None] * np.asarray(bone_directions, np.float64),
        heading=heading,
        acc_bias=acc_bias,
        gyro_bias=gyro_bias,
        clock_offset=clock,
        dropped=dropped,
    )


def _resample(readings: IMUReadings, shift_frames: np.ndarray) -> tuple[np.ndarray, ...]:
    """Signals of each sensor at fractional frame t + shift_s (clamped at the ends)."""
    R = np.asarray(readings.orientation)
    T = R.shape[0]
    f = np.clip(np.arange(T)[:, None] + shift_frames[None, :], 0, T - 1)
    k = np.minimum(np.floor(f).astype(int), T - 2) if T > 1 else np.zeros_like(f, int)
    s = (f - k)[..., None]
    k1 = np.minimum(k + 1, T - 1)
    cols = np.arange(R.shape[1])[None, :]
    R0, R1 = R[k, cols], R[k1, cols]
    R_t = R0 @ host_exp(s * host_log(np.swapaxes(R0, -1, -2) @ R1))
    lerp = lambda x: (1 - s) * x[k, cols] + s * x[k1, cols]  # noqa: E731
    return R_t, lerp(np.asarray(readings.acceleration)), lerp(np.asarray(readings.angular_velocity))


def apply_imu_errors(
    readings: IMUReadings,
    errors: IMUErrors,
    model: IMUErrorModel,
    fps: float,
    rng: np.random.Generator,
) -> MeasuredIMU:
    """Measured signals from readings already synthesised with the misalignment and offsets.

    (Misalignment and placement offsets change the physics, so `simulate_imu` passes
    them to `synthesize_imu`; this adds timing, heading, bias, noise and dropouts.)
    """
    if np.any(errors.clock_offset != 0):
        R, acc, gyro = _resample(readings, errors.clock_offset * fps)
    else:
        R = np.asarray(readings.orientation)
        acc, gyro = np.asarray(readings.acceleration), np.asarray(readings.angular_velocity)
    heading = np.asarray(errors.heading, np.float64)  # R_y(heading) (`rotation.rotation_y`) on the host, in float64
    R = host_exp(np.stack([np.zeros_like(heading), heading, np.zeros_like(heading)], -1)) @ R
    T, S = R.shape[:2]
    if model.orientation_noise > 0:
        R = random_rotations(rng, model.orientation_noise, (T, S)) @ R
    acc = acc + errors.acc_bias
    gyro = gyro + errors.gyro_bias
    if model.acc_noise > 0:
        acc = acc + rng.normal(scale=model.acc_noise, size=acc.shape)
    if model.gyro_noise > 0:
        gyro = gyro + rng.normal(scale=model.gyro_noise, size=gyro.shape)
    d = errors.dropped
    R, acc, gyro = R.copy(), acc.copy(), gyro.copy()
    R[d], acc[d], gyro[d] = np.nan, np.nan, np.nan
    return MeasuredIMU(orientation=R, acceleration=acc, angular_velocity=gyro)


def simulate_imu(
    body,
    placement: IMUPlacement,
    poses,
    betas,
    trans,
    fps: float,
    model: IMUErrorModel,
    rng: np.random.Generator,
    output=None,
) -> tuple[IMUReadings, MeasuredIMU, IMUErrors]:
    """Ideal readings, measured readings and the drawn errors of one sequence.

    The ideal readings use the nominal sensor (identity sensor-to-bone offset, the
    placement vertex); the measured ones the misaligned, displaced, drifting sensor.
    `output`: an already computed `forward(body, poses, betas, trans)` (saves a pass).
    """
    T = np.shape(poses)[0]
    rest = np.asarray(body.J_regressor) @ np.asarray(body.v_template)
    children = _child_directions(rest, placement)
    errors = sample_imu_errors(model, placement, T, fps, rng, children)
    if output is None:
        output = _forward(body, poses, betas, trans)
    if model.misalignment > 0 or model.placement_offset > 0:
        ideal, actual = _nominal_and_displaced(output, placement, fps, errors.misalignment, errors.offset_bone)
    else:
        ideal = actual = imu_from_body_output(output, placement, fps)
    return ideal, apply_imu_errors(actual, errors, model, fps, rng), errors


@eqx.filter_jit
def _nominal_and_displaced(output, placement, fps, sensor_to_bone, offset_bone):
    """The nominal and the misaligned, displaced sensor's readings as one compiled program
    per sequence length: two programs compiled ~7 CPU-s each, for the same trajectory."""
    ideal = imu_from_body_output(output, placement, fps)
    return ideal, imu_from_body_output(output, placement, fps, sensor_to_bone=sensor_to_bone, offset_bone=offset_bone)


_forward = eqx.filter_jit(forward)


def _child_directions(rest_joints: np.ndarray, placement: IMUPlacement) -> np.ndarray:
    """Unit rest direction from each sensor's joint to its child (or up for leaves).

    Global rotations are identity in the rest pose, so world and bone frames agree there.
    """
    from ..body.model import SMPL_PARENTS

    out = []
    for b in placement.bones:
        kids = [j for j, p in enumerate(SMPL_PARENTS) if p == b]
        # Torso joints have several children: take the one on the midline (the spine).
        kids.sort(key=lambda j: abs(rest_joints[j, 0] - rest_joints[b, 0]))
        d = rest_joints[kids[0]] - rest_joints[b] if kids else np.array([0.0, 1.0, 0.0])
        out.append(d / max(np.linalg.norm(d), 1e-9))
    return np.stack(out)


def global_free_acceleration(orientation, acceleration) -> np.ndarray:
    """R̃_s^g ã^s - g: the accelerometer in the world frame with gravity removed (DIP's imu_acc)."""
    acc = np.einsum("...ab,...b->...a", np.asarray(orientation), np.asarray(acceleration))
    return acc - np.array([0.0, GRAVITY, 0.0])
