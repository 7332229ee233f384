"""Real-format input: multi-camera calibrations and OpenPose keypoints (issue 17, item 4).

The data layer: readers and writers of the files labs have, checked and converted to one
convention; nothing here imports from sensors, energies or methods.
"""

from . import calibration as calibration
from .calibration import FORMATS as FORMATS
from .calibration import CalibratedCamera as CalibratedCamera
from .calibration import CalibrationError as CalibrationError
from .calibration import load_calibration as load_calibration
from .calibration import save_calibration as save_calibration
