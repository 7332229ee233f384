"""Simulated sensors: virtual IMUs, error models, moving cameras, a 2D keypoint detector,
depth, segmentation candidates, rigid objects, and benchmark scenarios (issue 3).

The geometry they share with real-data methods (projection, triangulation, keypoint
regressors, rasteriser, calibration maths) is `jaxmocap.geometry`; the modules
`camera`, `keypoints`, `triangulation`, `calibration` and `silhouette` here are aliases of
it kept for one release.

Seeds: von Marcard §2.4 (IMU model), §3.2 (placement, calibration), §4.2 (camera, heading
drift); Huang §6.2-6.3 (synthetic IMU data, calibration) and ch. 4-5 (multi-view, RGB-D).
"""

from ..geometry.camera import look_at as look_at
from ..geometry.camera import project as project
from ..geometry.imu_calibration import heading_reset as heading_reset
from ..geometry.imu_calibration import remove_heading as remove_heading
from ..geometry.imu_calibration import sensor_to_bone_offsets as sensor_to_bone_offsets
from ..geometry.imu_calibration import virtual_bone_orientations as virtual_bone_orientations
from ..geometry.keypoints import keypoint_regressor as keypoint_regressor
from ..geometry.raster import rasterize_views as rasterize_views
from ..geometry.triangulation import select_person as select_person
from ..geometry.triangulation import triangulate as triangulate
from . import calibration as calibration
from . import camera as camera
from . import depth as depth
from . import detector as detector
from . import errors as errors
from . import imu as imu
from . import keypoints as keypoints
from . import moving_camera as moving_camera
from . import objects as objects
from . import scenario as scenario
from . import silhouette as silhouette
from . import threedpw as threedpw
from . import triangulation as triangulation
from .depth import DepthNoiseModel as DepthNoiseModel
from .detector import DetectorErrorModel as DetectorErrorModel
from .errors import IMUErrorModel as IMUErrorModel
from .errors import simulate_imu as simulate_imu
from .imu import IMUPlacement as IMUPlacement
from .imu import IMUReadings as IMUReadings
from .imu import imu_placement as imu_placement
from .imu import synthesize_imu as synthesize_imu
from .scenario import CameraConfig as CameraConfig
from .scenario import Scenario as Scenario
from .scenario import ScenarioConfig as ScenarioConfig
from .scenario import load_scenario as load_scenario
from .scenario import make_scenario as make_scenario
from .scenario import save_dip as save_dip
from .scenario import save_scenario as save_scenario
