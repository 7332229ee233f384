"""Real-format input: multi-camera calibrations, OpenPose keypoints, Pose2Sim project folders,
videos (through MediaPipe Pose), DIP-IMU and 3DPW pickles.

The data layer: readers and writers of the files labs have, checked and converted to one
convention; nothing here imports from geometry, sensors, energies or methods.
"""

from . import calibration as calibration
from . import dip as dip
from . import openpose as openpose
from . import project as project
from . import threedpw as threedpw
from . import video as video
from .calibration import FORMATS as FORMATS
from .calibration import CalibratedCamera as CalibratedCamera
from .calibration import CalibrationError as CalibrationError
from .calibration import load_calibration as load_calibration
from .calibration import save_calibration as save_calibration
from .dip import load_dip as load_dip
from .openpose import KEYPOINT_COUNTS as KEYPOINT_COUNTS
from .openpose import KeypointFileError as KeypointFileError
from .openpose import KeypointRecording as KeypointRecording
from .openpose import align_views as align_views
from .openpose import normalise_view_name as normalise_view_name
from .openpose import read_openpose as read_openpose
from .openpose import write_openpose as write_openpose
from .project import ProjectError as ProjectError
from .project import read_config as read_config
from .project import read_project as read_project
from .threedpw import ThreeDPWSequence as ThreeDPWSequence
from .threedpw import load_threedpw as load_threedpw
