"""Moved to `jaxmocap.geometry.camera` (pinhole geometry) and `jaxmocap.sensors.moving_camera`; this alias goes in the next release."""

from ..geometry.camera import Camera as Camera
from ..geometry.camera import camera_centers as camera_centers
from ..geometry.camera import distort_points as distort_points
from ..geometry.camera import intrinsics as intrinsics
from ..geometry.camera import look_at as look_at
from ..geometry.camera import pinhole_camera as pinhole_camera
from ..geometry.camera import project as project
from ..geometry.camera import project_points as project_points
from ..geometry.camera import ring_cameras as ring_cameras
from ..geometry.camera import to_pixels as to_pixels
from ..geometry.camera import undistort_pixels as undistort_pixels
from .moving_camera import camera_imu as camera_imu
from .moving_camera import handheld_trajectory as handheld_trajectory
