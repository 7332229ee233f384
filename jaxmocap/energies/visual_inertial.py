"""Energies of the Video Inertial Poser (von Marcard ch. 4, eq. 4.7-4.9, 4.19-4.30).

Unknowns (`jaxmocap.solve` kinds; terms see rotations as matrices):

| key | kind | what |
| --- | --- | --- |
| "pose" | frame so3 (T, 24, 3) | body pose x_t |
| "trans" | frame vector (T, 3) | body translation |
| "cam" | frame se3 (T, 6) | camera-to-world pose [R_c^g | c] of the hand-held camera |
| "heading" | sequence angle (S,) | γ_s, heading correction per body sensor (§4.2.4) |
| "x0" | sequence so3 (24, 3) | the initial pose that defines the sensor-to-bone offsets |

Each residual is an equinox module with static configuration (bones, fps, which unknowns
are free), wrapped in a `Term` by the `*_term` constructors below (as `energies.imu`).

A variant that keeps heading or x₀ fixed (VIP-vanilla, VIP-noHeadParam) reads them from
`VIPData.heading` / `VIPData.x0` instead (`free_heading` / `free_x0` below).

Sensor model (eq. 4.7-4.9 as we write them):
- measured R̃_s(t) = R_y(-γ_s) R_s(t): a heading error rotates the sensor's world frame
  about the vertical, so the corrected orientation is R_y(γ_s) R̃_s(t) and the corrected
  world acceleration R_y(γ_s) ã^g (gravity is vertical, so eq. 3.9 commutes with R_y);
- sensor-to-bone offset R_s^b(x₀, γ_s) = R_b^g(x₀)ᵀ R_y(γ_s) R̃_s(0) (eq. 3.3 with the
  initial pose and the heading unknown);
- E_ori row: log(R_b^g(x_t) R_s^b (R_y(γ_s) R̃_s(t))ᵀ)^∨; E_acc row: the model sensor
  point's central-difference acceleration minus R_y(γ_s) ã^g(t) (eq. 3.10-3.13).
  Our choice: the sensor point p^b in its bone frame is taken from calibration and not
  re-derived from x₀ (the sensor vertex moves rigidly with its bone up to skinning).
- The camera IMU's axes are the camera's axes (`sensors.moving_camera.camera_imu`; a rigid,
  calibrated mount). Our choice: its heading is not an unknown, it defines the world's
  heading; without that, turning the whole scene about the vertical together with every
  γ_s would leave all energies unchanged (a gauge freedom).

E_img (eq. 4.27-4.28): confidence-weighted reprojection of the COCO-18 keypoints,
through `geometry.camera.project`, in pixels scaled by 1080 / image height (our choice:
w_img = 1e-4 is the thesis's weight for 1080-pixel video; the scaling keeps its meaning
for our smaller synthetic images), with a Geman-McClure loss of σ = 100 px at that scale
(our choice: the detector's left/right swaps and outliers must not drag the body).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jax import Array

from ..body.kinematics import ancestors, chain_transforms, mat3_apply, mat3_mul
from ..body.model import SMPL_PARENTS, Body
from ..geometry.camera import project
from ..geometry.keypoints import regress_keypoints
from ..priors.pose_prior import PosePrior
from ..rotation import matrix_to_axis_angle, rotation_y
from ..solve import GemanMcClure, Term, nan_mask
from ..timeseries import second_difference
from .camera import detected
from .posed import PosedBody

__all__ = [
    "REFERENCE_IMAGE_HEIGHT",
    "VIPData",
    "heading_orientation_term",
    "heading_acceleration_term",
    "camera_orientation_term",
    "camera_acceleration_term",
    "image_term",
    "initial_pose_term",
    "world_to_camera",
    "HeadingOrientationResidual",
    "HeadingAccelerationResidual",
    "CameraOrientationResidual",
    "CameraAccelerationResidual",
    "ImageResidual",
    "InitialPoseResidual",
]

#: E_img is measured in pixels of an image this high (the thesis's 1080p video).
REFERENCE_IMAGE_HEIGHT = 1080.0


class VIPData(eqx.Module):
    """Everything the VIP energies read for one sequence (T frames, S body sensors).

    orientation: (T, S, 3, 3) measured R̃_s^g, NaN = dropped; orientation0: (S, 3, 3)
    R̃_s^g at frame 0 (the calibration frame). acceleration: (T, S, 3) ã^g (eq. 3.9
    applied with the measured orientation), NaN = dropped. sensor_point: (S, 3) p^b.
    rest_joints: (24, 3) J(β); prior: the pose prior; body, betas: the actor's model.
    cam_orientation: (T, 3, 3) camera IMU R̃_c^g; cam_acceleration: (T, 3) its ã^g.
    K: (3, 3) intrinsics (undistorted pixels); regressor: (18, N) COCO-18 regressor.
    keypoints: (T, 18, 2) detections; confidence: (T, 18), 0 = missing.
    pixel_scale: REFERENCE_IMAGE_HEIGHT / image height.
    heading: (S,) γ_s used when heading is not an unknown; x0: (24, 3, 3) the initial
    pose's local rotations used when x₀ is not an unknown. camera: (T, 4, 4)
    camera-to-world poses used when the camera is not an unknown (VIP-Cam). fps: static.
    """

    orientation: Array
    orientation0: Array
    acceleration: Array
    sensor_point: Array
    rest_joints: Array
    prior: PosePrior
    body: Body
    betas: Array
    cam_orientation: Array
    cam_acceleration: Array
    K: Array
    regressor: Array
    keypoints: Array
    confidence: Array
    pixel_scale: Array
    heading: Array
    x0: Array
    camera: Array
    fps: float = eqx.field(static=True)

    @property
    def num_frames(self) -> int:
        return self.orientation.shape[0]


def _heading(params, data: VIPData, free: bool) -> Array:
    return params["heading"] if free else data.heading


def _x0(params, data: VIPData, free: bool) -> Array:
    return params["x0"] if free else data.x0


def _extra_reads(free_heading: bool, free_x0: bool) -> tuple:
    return (("heading", None),) * free_heading + (("x0", None),) * free_x0


class HeadingOrientationResidual(eqx.Module):
    """E_ori with heading and initial pose (eq. 4.7-4.9, 4.20): log(R_b^g(x_t) R_s^b
    (R_y(γ_s) R̃_s(t))ᵀ)^∨ per frame and body sensor, (T, S, 3)."""

    bones: tuple[int, ...] = eqx.field(static=True)
    free_heading: bool = eqx.field(static=True, default=True)
    free_x0: bool = eqx.field(static=True, default=True)

    def __call__(self, params, data: VIPData) -> Array:
        bones = self.bones
        R, _ = chain_transforms(SMPL_PARENTS, params["pose"], data.rest_joints, bones)
        R0, _ = chain_transforms(SMPL_PARENTS, _x0(params, data, self.free_x0)[None], data.rest_joints, bones)
        Ry = rotation_y(_heading(params, data, self.free_heading))  # (S, 3, 3)
        R_bone = jnp.stack([R[b] for b in bones], 1)  # (T, S, 3, 3)
        R_bone0 = jnp.stack([R0[b][0] for b in bones], 0)  # (S, 3, 3)
        offset = mat3_mul(jnp.swapaxes(R_bone0, -1, -2), mat3_mul(Ry, data.orientation0))  # eq. 4.9
        measured = mat3_mul(Ry[None], data.orientation)
        return matrix_to_axis_angle(mat3_mul(mat3_mul(R_bone, offset[None]), jnp.swapaxes(measured, -1, -2)))


def orientation_present(data: VIPData) -> Array:
    """Body-sensor orientation samples that were not dropped, (T, S)."""
    return nan_mask(data.orientation, (-2, -1))


def heading_orientation_term(bones, weight, free_heading: bool = True, free_x0: bool = True) -> Term:
    """w_ori E_ori over the body sensors with heading and initial pose (eq. 4.7-4.9, 4.20)."""
    fn = HeadingOrientationResidual(tuple(int(b) for b in bones), bool(free_heading), bool(free_x0))
    reads = (("pose", ancestors(SMPL_PARENTS, fn.bones)),) + _extra_reads(free_heading, free_x0)
    return Term("ori", fn, weight, 0, None, orientation_present, reads)


class HeadingAccelerationResidual(eqx.Module):
    """E_acc with the measurements turned by R_y(γ_s) (eq. 4.21-4.22): the model sensor
    point's central-difference acceleration minus R_y(γ_s) ã^g(t), (T, S, 3)."""

    bones: tuple[int, ...] = eqx.field(static=True)
    fps: float = eqx.field(static=True)
    free_heading: bool = eqx.field(static=True, default=True)

    def __call__(self, params, data: VIPData) -> Array:
        bones = self.bones
        R, J = chain_transforms(SMPL_PARENTS, params["pose"], data.rest_joints, bones)
        R_bone = jnp.stack([R[b] for b in bones], 1)
        p = mat3_apply(R_bone, data.sensor_point) + jnp.stack([J[b] for b in bones], 1)
        p = p + params["trans"][:, None, :]
        a_model = second_difference(p) * self.fps**2
        Ry = rotation_y(_heading(params, data, self.free_heading))
        return a_model - jnp.einsum("sab,tsb->tsa", Ry, data.acceleration)


def acceleration_present(data: VIPData) -> Array:
    """Body-sensor acceleration samples that were not dropped, (T, S)."""
    return nan_mask(data.acceleration, -1)


def heading_acceleration_term(bones, fps: float, weight, free_heading: bool = True) -> Term:
    """w_acc E_acc over the body sensors, measurements turned by R_y(γ_s) (eq. 4.21-4.22)."""
    fn = HeadingAccelerationResidual(tuple(int(b) for b in bones), float(fps), bool(free_heading))
    reads = (("pose", ancestors(SMPL_PARENTS, fn.bones)), ("trans", None)) + _extra_reads(free_heading, False)
    return Term("acc", fn, weight, 1, None, acceleration_present, reads)


class CameraOrientationResidual(eqx.Module):
    """The camera IMU's orientation against the camera pose's rotation (eq. 4.20), (T, 1, 3)."""

    def __call__(self, params, data: VIPData) -> Array:
        Rc = params["cam"][:, :3, :3]
        return matrix_to_axis_angle(mat3_mul(Rc, jnp.swapaxes(data.cam_orientation, -1, -2)))[:, None]


def camera_orientation_present(data: VIPData) -> Array:
    """Camera-IMU orientation samples that were not dropped, (T, 1)."""
    return nan_mask(data.cam_orientation, (-2, -1))[:, None]


def camera_orientation_term(weight) -> Term:
    """The camera IMU's orientation against the camera pose's rotation (eq. 4.20): (T, 1, 3)."""
    return Term("cam_ori", CameraOrientationResidual(), weight, 0, None, camera_orientation_present, (("cam", None),))


class CameraAccelerationResidual(eqx.Module):
    """The camera centre's central-difference acceleration against its IMU (eq. 4.22), (T, 1, 3)."""

    fps: float = eqx.field(static=True)

    def __call__(self, params, data: VIPData) -> Array:
        centre = params["cam"][:, :3, 3]
        return (second_difference(centre) * self.fps**2 - data.cam_acceleration)[:, None]


def camera_acceleration_present(data: VIPData) -> Array:
    """Camera-IMU acceleration samples that were not dropped, (T, 1)."""
    return nan_mask(data.cam_acceleration, -1)[:, None]


def camera_acceleration_term(fps: float, weight) -> Term:
    """The camera centre's central-difference acceleration against its IMU (eq. 4.22): (T, 1, 3)."""
    fn = CameraAccelerationResidual(float(fps))
    return Term("cam_acc", fn, weight, 1, None, camera_acceleration_present, (("cam", None),))


def world_to_camera(cam: Array) -> tuple[Array, Array]:
    """(R, t) world-to-camera of camera-to-world 4x4 poses (..., 4, 4)."""
    R = jnp.swapaxes(cam[..., :3, :3], -1, -2)
    return R, -jnp.einsum("...ab,...b->...a", R, cam[..., :3, 3])


class ImageResidual(eqx.Module):
    """E_img (eq. 4.27-4.28): √c ρ_σ(π(K, camera, keypoint) - detection) in reference pixels, (T, 18, 2)."""

    sigma: float = eqx.field(static=True, default=100.0)
    free_camera: bool = eqx.field(static=True, default=True)

    def __call__(self, params, data: VIPData, posed=None) -> Array:
        body = PosedBody()(params, data) if posed is None else posed  # posed: the problem's (Term.posed)
        kp = regress_keypoints(data.regressor, body.vertices, body.joints)  # (T, 18, 3)
        R, t = world_to_camera(params["cam"] if self.free_camera else data.camera)
        uv, _ = project(data.K[None], R, t, kp)
        e = (uv - data.keypoints) * data.pixel_scale
        return jnp.sqrt(data.confidence)[..., None] * GemanMcClure(self.sigma)(e)


def image_term(weight, sigma: float = 100.0, free_camera: bool = True) -> Term:
    """w_img E_img (eq. 4.27-4.28): √c (π(K, camera, keypoint) - detection), (T, 18, 2)."""
    reads = (("pose", None), ("trans", None)) + ((("cam", None),) if free_camera else ())
    return Term(
        "img", ImageResidual(float(sigma), bool(free_camera)), weight, 0, None, detected, reads, posed=PosedBody()
    )


class InitialPoseResidual(eqx.Module):
    """log(R_j(x₀) R̂_jᵀ) per joint on row 0, zero elsewhere, (T, 24, 3) (`initial_pose_term`)."""

    def __call__(self, params, data: VIPData) -> Array:
        e = matrix_to_axis_angle(mat3_mul(params["x0"], jnp.swapaxes(data.x0, -1, -2)))  # (24, 3)
        first = (jnp.arange(data.num_frames) == 0).astype(e.dtype)
        return first[:, None, None] * e[None]


def initial_pose_term(weight) -> Term:
    """Keeps x₀ near its given value, log(R_j(x₀) R̂_jᵀ) per joint, on row 0 only (our
    choice: joints that carry no sensor are otherwise not seen by any energy)."""
    return Term("x0", InitialPoseResidual(), weight, 0, None, None, (("x0", None),))
