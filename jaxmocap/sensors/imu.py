"""Virtual IMUs: named sensor placements on the body mesh and noise-free synthesis.

A sensor s rides on one bone b (an SMPL joint whose global rotation moves it) at one mesh
vertex. Its readings, in the notation of von Marcard §2.4 and §3.2.3:

    orientation   R_s^g(t) = R_b^g(x_t) R_s^b                       (eq. 3.2-3.3, 4.8)
    free accel.   a^g(t)   = (p_{t-1} - 2 p_t + p_{t+1}) / dt²      (Huang eq. 6.1)
    specific f.   a^s(t)   = R_s^g(t)ᵀ (a^g(t) + g)                 (eq. 2.62, 2.65)
    gyroscope     ω^s(t)   = log(R_s^g(t-1)ᵀ R_s^g(t+1))^∨ / (2 dt)  (eq. 2.61, earth rate 0)

with g = (0, +9.81, 0) the gravity *reaction* in our y-up world: a sensor at rest reads
+9.81 m/s² along its own view of "up" (eq. 2.65 with a^i = 0).

Sequence ends: the central differences need frames t ± 1. At t = 0 and t = T-1 we use
the one-sided second-order stencils (2p₀ - 5p₁ + 4p₂ - p₃)/dt² (exact for cubics, like
the central one) and the one-sided rate log(R₀ᵀR₁)/dt; with T < 4 frames accelerations
are returned as zeros (too short to differentiate twice). DIP's own code instead drops the
two end frames; `synthesize_imu(..., trim_ends=True)` does not exist on purpose: callers
slice `[1:-1]` if they want exactly that.

Placements. For SMPL's topology (6890 vertices) the six-sensor set uses the vertex ids
of public code: TransPose / PIP (Yi et al. 2021-22, `preprocess.py`:
``vi_mask = [1961, 5424, 1176, 4662, 411, 3021]`` with bones ``[18, 19, 4, 5, 15, 0]``);
DIP's `data_synthesis/genSynData.py` uses the neighbouring ids [1962, 5431, 1096, 4583,
412, 3021]. For every other body and every other set (TotalCapture 13, Xsens 17) the
vertex is chosen by one landmark rule applied to the body's rest mesh (β = 0):

    p  = J_a + f (J_b - J_a)     a point on the bone axis (rest joints J = 𝒥 T̄)
    d  = unit outward direction  (front +z, back -z, up +y, lateral ±x)
    candidates = vertices with skinning weight w_vb ≥ 0.5 for the bone b
                 (fallback: argmax_j w_vj = b), lying in the half space (v - p)·d > 0
    vertex = argmin over candidates of the distance from v to the ray p + s d.

That is the skin point straight out from the bone in direction d. Where no vertex has
w ≥ 0.5 for the bone (the collars of the default body), the fallbacks apply.

The synthesis functions are `equinox.filter_jit`-compiled (placement and fps static). The ids of the default
bodies are stored below (`DEFAULT_BODY_IDS`) and reproduced by a test.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jax import Array

from .._checks import check_finite, check_frames, check_rate
from ..body.kinematics import BodyOutput, forward
from ..body.model import SMPL_JOINT_NAMES, Body
from ..geometry.surface import ray_vertex, rest_joints  # also re-exported: they lived here
from ..rotation import matrix_to_axis_angle, rotation_y  # rotation_y: re-exported where it used to live

__all__ = [
    "GRAVITY",
    "SENSOR_SETS",
    "SMPL_SIP6_VERTICES",
    "IMUPlacement",
    "IMUReadings",
    "imu_placement",
    "landmark_vertex",
    "ray_vertex",
    "rest_joints",
    "synthesize_imu",
    "imu_from_body_output",
    "imu_from_trajectory",
    "finite_difference_acceleration",
    "angular_velocity",
    "rotation_y",
    "DEFAULT_BODY_IDS",
]

#: Gravity reaction in the y-up world (m/s²): what a resting accelerometer measures.
GRAVITY = 9.81

_J = {n: i for i, n in enumerate(SMPL_JOINT_NAMES)}


@dataclasses.dataclass(frozen=True)
class _Landmark:
    """One sensor: its bone, the axis segment (a → b, fraction f) and outward direction."""

    name: str
    bone: str
    a: str
    b: str | None
    f: float
    d: tuple[float, float, float]


def _lr(name, bone, a, b, f, d):
    """The left sensor and its mirror image (x negated) on the right."""
    mirror = (-d[0], d[1], d[2])
    r = lambda s: s.replace("left", "right") if s else s  # noqa: E731
    return [
        _Landmark(f"left_{name}", bone, a, b, f, d),
        _Landmark(f"right_{name}", r(bone), r(a), r(b), f, mirror),
    ]


_HEAD = _Landmark("head", "head", "head", None, 0.0, (0.0, 1.0, 0.0))
_STERNUM = _Landmark("sternum", "spine3", "spine3", "neck", 0.3, (0.0, 0.0, 1.0))
_PELVIS = _Landmark("pelvis", "pelvis", "pelvis", "spine1", 0.3, (0.0, 0.0, -1.0))
_FOREARM = _lr("forearm", "left_elbow", "left_elbow", "left_wrist", 0.85, (0.0, 1.0, 0.0))
_SHANK = _lr("lower_leg", "left_knee", "left_knee", "left_ankle", 0.2, (0.0, 0.0, 1.0))
_UPPERARM = _lr("upper_arm", "left_shoulder", "left_shoulder", "left_elbow", 0.5, (0.0, 1.0, 0.0))
_THIGH = _lr("upper_leg", "left_hip", "left_hip", "left_knee", 0.5, (1.0, 0.0, 0.0))
_FOOT = _lr("foot", "left_ankle", "left_ankle", "left_foot", 0.5, (0.0, 1.0, 0.0))
_HAND = _lr("hand", "left_wrist", "left_wrist", "left_hand", 0.5, (0.0, 1.0, 0.0))
_SHOULDER = _lr("shoulder", "left_collar", "left_collar", "left_shoulder", 0.6, (0.0, 1.0, 0.0))

#: Sensor sets, each an ordered tuple of landmarks.
#:   sip6: von Marcard §3.2.2 / DIP / TransPose order (left, right forearm; left, right
#:         lower leg; head; pelvis). DIP-IMU's 17 → 6 subset is [7, 8, 11, 12, 0, 2].
#:   totalcapture13: TotalCapture's Xsens suit as read by DIP's `read_TC_data.py`
#:         (head, sternum, pelvis, upper arms, forearms, thighs, shanks, feet).
#:   xsens17: DIP-IMU's pickle order (head, sternum, pelvis, shoulders, upper arms,
#:         lower arms, upper legs, lower legs, hands, feet).
SENSOR_SETS: dict[str, tuple[_Landmark, ...]] = {
    "sip6": (*_FOREARM, *_SHANK, _HEAD, _PELVIS),
    "totalcapture13": (
        _HEAD, _STERNUM, _PELVIS, *_UPPERARM, *_FOREARM, *_THIGH, *_SHANK, *_FOOT,
    ),
    "xsens17": (
        _HEAD, _STERNUM, _PELVIS, *_SHOULDER, *_UPPERARM, *_FOREARM, *_THIGH, *_SHANK,
        *_HAND, *_FOOT,
    ),
}  # fmt: skip

#: TransPose / PIP `vi_mask` on SMPL's 6890-vertex mesh, in the sip6 order.
SMPL_SIP6_VERTICES = (1961, 5424, 1176, 4662, 411, 3021)

#: Landmark-rule ids on the default bodies, keyed by (vertex count, set); filled at the end.
DEFAULT_BODY_IDS: dict[tuple[int, str], tuple[int, ...]] = {}


class IMUPlacement(eqx.Module):
    """Where each virtual IMU sits: a mesh vertex and the bone (joint) that carries it.

    Static (hashed) so that it can be closed over by jitted functions.
    """

    names: tuple[str, ...] = eqx.field(static=True)
    vertices: tuple[int, ...] = eqx.field(static=True)
    bones: tuple[int, ...] = eqx.field(static=True)
    set_name: str = eqx.field(static=True, default="custom")

    def __check_init__(self):
        if not (len(self.names) == len(self.vertices) == len(self.bones)):
            raise ValueError(
                f"IMUPlacement needs one vertex and one bone per name; got {len(self.names)} "
                f"names, {len(self.vertices)} vertices, {len(self.bones)} bones."
            )

    @property
    def num_sensors(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise ValueError(f"No sensor {name!r}; this placement has {list(self.names)}.") from None

    def subset(self, names: Sequence[str]) -> IMUPlacement:
        """The placement restricted to `names`, in that order."""
        idx = [self.index(n) for n in names]
        return IMUPlacement(
            tuple(self.names[i] for i in idx),
            tuple(self.vertices[i] for i in idx),
            tuple(self.bones[i] for i in idx),
            f"{self.set_name}[{len(idx)}]",
        )


def landmark_vertex(body: Body, landmark: _Landmark) -> int:
    """The vertex picked by the landmark rule of the module docstring on `body`'s rest mesh."""
    joints = rest_joints(body)
    p = joints[_J[landmark.a]]
    if landmark.b is not None:
        p = p + landmark.f * (joints[_J[landmark.b]] - p)
    return ray_vertex(body, p, landmark.d, _J[landmark.bone])


def imu_placement(body: Body, set_name: str = "sip6") -> IMUPlacement:
    """The named sensor set ("sip6", "totalcapture13", "xsens17") on `body`.

    SMPL-topology bodies (6890 vertices) get the published ids for "sip6"; every other
    case uses the landmark rule (module docstring).
    """
    if not hasattr(body, "num_vertices") or not hasattr(body, "v_template"):
        raise ValueError(
            f"imu_placement: body must be a jaxmocap Body (e.g. default_body()), got {type(body).__name__}."
        )
    if set_name not in SENSOR_SETS:
        raise ValueError(f"Unknown sensor set {set_name!r}; choose from {sorted(SENSOR_SETS)}.")
    landmarks = SENSOR_SETS[set_name]
    names = tuple(lm.name for lm in landmarks)
    bones = tuple(_J[lm.bone] for lm in landmarks)
    if body.num_vertices == 6890 and set_name == "sip6":
        vertices = SMPL_SIP6_VERTICES
    else:
        key = (body.num_vertices, set_name)
        stored = DEFAULT_BODY_IDS.get(key) if body.kind == "default" else None
        vertices = stored or tuple(landmark_vertex(body, lm) for lm in landmarks)
    return IMUPlacement(names, tuple(int(i) for i in vertices), bones, set_name)


class IMUReadings(eqx.Module):
    """Noise-free IMU signals of S sensors over T frames (leading batch axes allowed).

    orientation: (..., T, S, 3, 3) R_s^g, sensor-to-world.
    acceleration: (..., T, S, 3) specific force a^s in the sensor frame (m/s²).
    free_acceleration: (..., T, S, 3) a^g in the world frame, gravity excluded (m/s²).
    angular_velocity: (..., T, S, 3) ω^s in the sensor frame (rad/s).
    position: (..., T, S, 3) sensor position in the world frame (m).
    """

    orientation: Array
    acceleration: Array
    free_acceleration: Array
    angular_velocity: Array
    position: Array


def finite_difference_acceleration(positions: Array, fps: float) -> Array:
    """a_t = (p_{t-1} - 2 p_t + p_{t+1}) / dt² along axis -3 of (..., T, S, 3).

    Huang eq. 6.1 / von Marcard eq. 3.10. Ends: one-sided 4-point stencils (see module
    docstring); zeros when T < 4.
    """
    T = positions.shape[-3]
    if T < 4:
        return jnp.zeros_like(positions)
    p = positions
    inv = jnp.asarray(fps, p.dtype) ** 2
    mid = (p[..., :-2, :, :] - 2 * p[..., 1:-1, :, :] + p[..., 2:, :, :]) * inv
    first = (2 * p[..., 0, :, :] - 5 * p[..., 1, :, :] + 4 * p[..., 2, :, :] - p[..., 3, :, :]) * inv
    last = (2 * p[..., -1, :, :] - 5 * p[..., -2, :, :] + 4 * p[..., -3, :, :] - p[..., -4, :, :]) * inv
    return jnp.concatenate([first[..., None, :, :], mid, last[..., None, :, :]], -3)


def angular_velocity(rotations: Array, fps: float) -> Array:
    """Body-frame rate ω^s from (..., T, S, 3, 3) rotations: central log differences."""
    T = rotations.shape[-4]
    if T < 2:
        return jnp.zeros(rotations.shape[:-1], rotations.dtype)
    Rt = jnp.swapaxes(rotations, -1, -2)
    fps = jnp.asarray(fps, rotations.dtype)
    one_sided = lambda a, b: matrix_to_axis_angle(Rt[..., a, :, :, :] @ rotations[..., b, :, :, :]) * fps  # noqa: E731
    if T == 2:
        w = one_sided(0, 1)
        return jnp.stack([w, w], -3)
    mid = matrix_to_axis_angle(Rt[..., :-2, :, :, :] @ rotations[..., 2:, :, :, :]) * (fps / 2)
    return jnp.concatenate([one_sided(0, 1)[..., None, :, :], mid, one_sided(-2, -1)[..., None, :, :]], -3)


@eqx.filter_jit
def imu_from_trajectory(rotations: Array, positions: Array, fps: float) -> IMUReadings:
    """IMU signals of rigid sensors from their world trajectories.

    Args:
        rotations: (..., T, S, 3, 3) sensor-to-world rotations R_s^g.
        positions: (..., T, S, 3) sensor positions, metres.
        fps: frames per second.
    Returns:
        IMUReadings (eq. 2.62 / 6.1): works for body sensors, a camera or an object.
    """
    check_rate("fps", fps)  # a negative rate flips the gyroscope, zero silences it
    if rotations.ndim < 4 or rotations.shape[-2:] != (3, 3) or positions.shape[:-1] != rotations.shape[:-2]:
        raise ValueError(
            f"rotations {rotations.shape} and positions {positions.shape} must be (..., T, S, 3, 3) "
            "and (..., T, S, 3) with the same T and S."
        )
    check_frames("the sensor trajectory", rotations.shape[-4])
    free = finite_difference_acceleration(positions, fps)
    up = jnp.zeros(3, positions.dtype).at[1].set(GRAVITY)
    specific = jnp.einsum("...ba,...b->...a", rotations, free + up)
    return IMUReadings(
        orientation=rotations,
        acceleration=specific,
        free_acceleration=free,
        angular_velocity=angular_velocity(rotations, fps),
        position=positions,
    )


def synthesize_imu(
    body: Body,
    placement: IMUPlacement,
    poses: Array,
    betas: Array | None = None,
    trans: Array | None = None,
    fps: float = 60.0,
    sensor_to_bone: Array | None = None,
    offset_bone: Array | None = None,
) -> IMUReadings:
    """Virtual IMU readings of one motion (T frames).

    Args:
        body: the body model.
        placement: the sensors (vertices + bones).
        poses: (T, 24, 3) axis-angle poses; batch axes in front are vmapped by the caller.
        betas: (B,) shape; trans: (T, 3) root translation.
        fps: frame rate (dt = 1 / fps).
        sensor_to_bone: (S, 3, 3) R_s^b, the sensor frame in its bone frame (identity:
            the sensor axes are the bone's axes).
        offset_bone: (S, 3) displacement of the sensor from its vertex, in the bone frame
            (placement error along the limb; metres).
    Returns:
        IMUReadings with (T, S, ...) arrays.
    """
    check_rate("fps", fps)
    shape = jnp.shape(poses)
    if len(shape) < 3 or shape[-2:] != (body.num_joints, 3):
        raise ValueError(f"poses has shape {shape}; expected (T, {body.num_joints}, 3) axis-angle.")
    check_frames("poses", shape[-3])
    # Here, not in the compiled function: its inputs are traced there (nothing to check).
    for name, x in (("poses", poses), ("betas", betas), ("trans", trans)):
        if x is not None:
            check_finite(name, x)
    return _synthesize_imu(body, placement, poses, betas, trans, fps, sensor_to_bone, offset_bone)


@eqx.filter_jit
def _synthesize_imu(body, placement, poses, betas, trans, fps, sensor_to_bone, offset_bone) -> IMUReadings:
    return imu_from_body_output(forward(body, poses, betas, trans), placement, fps, sensor_to_bone, offset_bone)


@eqx.filter_jit
def imu_from_body_output(
    output: BodyOutput,
    placement: IMUPlacement,
    fps: float,
    sensor_to_bone: Array | None = None,
    offset_bone: Array | None = None,
) -> IMUReadings:
    """`synthesize_imu` from an already computed `forward` output with (T, ...) arrays."""
    bones, verts = np.asarray(placement.bones), np.asarray(placement.vertices)
    R_bone = output.joint_rotations[..., bones, :, :]  # R_b^g
    pos = output.vertices[..., verts, :]
    if offset_bone is not None:
        pos = pos + jnp.einsum("...sab,sb->...sa", R_bone, jnp.asarray(offset_bone, pos.dtype))
    R = R_bone if sensor_to_bone is None else R_bone @ jnp.asarray(sensor_to_bone, R_bone.dtype)
    return imu_from_trajectory(R, pos, fps)


# Computed with `landmark_vertex` on default_body("low") / ("full") and frozen here so that
# the ids cannot change silently if the rule or the body files are edited; the test suite
# re-derives them from the rule.
DEFAULT_BODY_IDS.update({
    (1229, "sip6"): (954, 342, 1096, 513, 101, 409),
    (1229, "totalcapture13"): (101, 151, 409, 771, 159, 954, 342, 1064, 470, 1096, 513, 1188, 597),
    (1229, "xsens17"): (
        101, 151, 409, 763, 150, 771, 159, 954, 342, 1064, 470, 1096, 513, 963, 324, 1188, 597,
    ),
    (13380, "sip6"): (10176, 3508, 11299, 4681, 881, 4205),
    (13380, "totalcapture13"): (
        881, 1399, 4205, 8376, 1704, 10176, 3508, 13344, 6748, 11299, 4681, 12827, 6230,
    ),
    (13380, "xsens17"): (
        881, 1399, 4205, 8168, 1482, 8376, 1704, 10176, 3508, 13344, 6748, 11299, 4681, 10339,
        3671, 12827, 6230,
    ),
})  # fmt: skip
