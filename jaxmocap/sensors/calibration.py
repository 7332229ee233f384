"""Moved to `jaxmocap.geometry.imu_calibration`; this alias goes in the next release."""

from ..geometry.imu_calibration import heading_angle as heading_angle
from ..geometry.imu_calibration import heading_reset as heading_reset
from ..geometry.imu_calibration import inertial_to_model_from_head as inertial_to_model_from_head
from ..geometry.imu_calibration import normalize_to_root as normalize_to_root
from ..geometry.imu_calibration import remove_heading as remove_heading
from ..geometry.imu_calibration import sensor_to_bone_offsets as sensor_to_bone_offsets
from ..geometry.imu_calibration import virtual_bone_orientations as virtual_bone_orientations
