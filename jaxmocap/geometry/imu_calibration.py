"""IMU calibration as the seeds do it: heading reset, frame alignment, sensor-to-bone offsets.

- Heading reset (von Marcard eq. 2.71; DIP §6.3.5): with all sensors held in one known
  orientation R_ref, sensor s reads R_y(γ_s) R_ref; its heading γ_s is the twist of
  R̃_s R_refᵀ about the vertical, and R_s(t) ← R_y(-γ_s) R̃_s(t) removes it.
- Inertial-to-model frame (eq. 3.2; DIP eq. 6.4): M_i^g constant; DIP takes
  R^TI = R_Head⁻¹ from a head sensor mounted aligned with the SMPL frame.
- Sensor-to-bone offsets from a known initial pose x₀ (eq. 3.3, 4.7; DIP eq. 6.5):
  R_s^b = R_b^g(x₀)ᵀ R_i^g R_s^i(0).
- Virtual bone orientations (DIP eq. 6.6): R_b^g(t) = R_s^g(t) (R_s^b)ᵀ, and the
  root-relative normalisation (DIP eq. 6.7-6.8).

All functions are plain jnp maps with leading batch axes.
"""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array

from ..rotation import matrix_to_quaternion, rotation_y

__all__ = [
    "heading_angle",
    "heading_reset",
    "remove_heading",
    "inertial_to_model_from_head",
    "sensor_to_bone_offsets",
    "virtual_bone_orientations",
    "normalize_to_root",
]


def heading_angle(rotation: Array) -> Array:
    """Twist angle of R about the vertical y axis (swing-twist split): (..., 3, 3) -> (...,).

    For R = R_y(γ) it returns γ exactly (in (-π, π]).
    """
    q = matrix_to_quaternion(rotation)
    return 2.0 * jnp.arctan2(q[..., 2], q[..., 0])


def heading_reset(reset_orientations: Array, reference: Array | None = None) -> Array:
    """Per-sensor heading γ_s from readings taken with all sensors in one known orientation.

    Args:
        reset_orientations: (..., S, 3, 3) readings R̃_s during the reset.
        reference: (3, 3) or (..., S, 3, 3) the known common orientation (default I).
    Returns:
        (..., S) heading angles γ_s; correct with `remove_heading` (eq. 2.71).
    """
    R = reset_orientations
    if reference is not None:
        R = R @ jnp.swapaxes(jnp.asarray(reference, R.dtype), -1, -2)
    return heading_angle(R)


def remove_heading(orientations: Array, heading: Array) -> Array:
    """R_s(t) = R_y(-γ_s) R̃_s(t) (eq. 2.71). orientations (..., S, 3, 3), heading (..., S)."""
    return rotation_y(-jnp.asarray(heading, orientations.dtype)) @ orientations


def inertial_to_model_from_head(head_orientation: Array) -> Array:
    """R^TI = R_Head⁻¹ (DIP eq. 6.4): the head sensor is mounted aligned with the model frame."""
    return jnp.swapaxes(head_orientation, -1, -2)


def sensor_to_bone_offsets(
    bone_orientations: Array, sensor_orientations: Array, inertial_to_model: Array | None = None
) -> Array:
    """R_s^b = R_b^g(x₀)ᵀ · R_i^g · R_s^i(0)  (von Marcard eq. 3.3 / 4.7; DIP eq. 6.5).

    Args:
        bone_orientations: (..., S, 3, 3) R_b^g of each sensor's bone in the known pose x₀.
        sensor_orientations: (..., S, 3, 3) the sensors' readings at that frame.
        inertial_to_model: (3, 3) R_i^g (default identity: readings already in model frame).
    Returns:
        (..., S, 3, 3) sensor-to-bone rotations.
    """
    R = sensor_orientations
    if inertial_to_model is not None:
        R = jnp.asarray(inertial_to_model, R.dtype) @ R
    return jnp.swapaxes(bone_orientations, -1, -2) @ R


def virtual_bone_orientations(sensor_orientations: Array, sensor_to_bone: Array) -> Array:
    """R_b^g(t) = R_s^g(t) (R_s^b)ᵀ (DIP eq. 6.6): the bone orientation the IMU measures."""
    return sensor_orientations @ jnp.swapaxes(sensor_to_bone, -1, -2)


def normalize_to_root(orientations: Array, accelerations: Array, root: int) -> tuple[Array, Array]:
    """DIP eq. 6.7-6.8: R̄_s = R_root⁻¹ R_s, ā_s = R_root⁻¹ (a_s - a_root).

    orientations (..., S, 3, 3) and global accelerations (..., S, 3); `root` is the
    index of the root (pelvis) sensor.
    """
    R_root_T = jnp.swapaxes(orientations[..., root, :, :], -1, -2)[..., None, :, :]
    a = accelerations - accelerations[..., root : root + 1, :]
    return R_root_T @ orientations, jnp.einsum("...ab,...b->...a", R_root_T, a)
