"""Camera and body geometry that real-data methods and the simulator share.

Pinhole projection and lens distortion (`camera`), triangulation and person selection
across calibrated views (`triangulation`), 2D keypoint layouts and their regressors on the
body (`keypoints`, `surface`), the z-buffer rasteriser and visibility (`raster`), the
object-mask selection rule (`masks`), and the IMU frame maths of calibration
(`imu_calibration`). Nothing here adds noise or synthesises data: that is
`jaxmocap.sensors`.

Seeds: von Marcard §3.2 (calibration), §4.2 (camera); Huang ch. 4-6 (multi-view, RGB-D,
DIP calibration).
"""

from . import camera as camera
from . import imu_calibration as imu_calibration
from . import keypoints as keypoints
from . import masks as masks
from . import raster as raster
from . import surface as surface
from . import triangulation as triangulation
from .camera import Camera as Camera
from .camera import distort_points as distort_points
from .camera import intrinsics as intrinsics
from .camera import look_at as look_at
from .camera import pinhole_camera as pinhole_camera
from .camera import project as project
from .camera import project_points as project_points
from .camera import ring_cameras as ring_cameras
from .camera import undistort_pixels as undistort_pixels
from .imu_calibration import sensor_to_bone_offsets as sensor_to_bone_offsets
from .imu_calibration import virtual_bone_orientations as virtual_bone_orientations
from .keypoints import KEYPOINT_FORMATS as KEYPOINT_FORMATS
from .keypoints import keypoint_regressor as keypoint_regressor
from .keypoints import regress_keypoints as regress_keypoints
from .keypoints import rest_keypoints as rest_keypoints
from .raster import rasterize_views as rasterize_views
from .triangulation import projection_matrices as projection_matrices
from .triangulation import select_person as select_person
from .triangulation import triangulate as triangulate
