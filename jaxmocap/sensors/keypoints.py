"""Moved to `jaxmocap.geometry.keypoints` (layouts, regressors) and `jaxmocap.sensors.detector`; this alias goes in the next release."""

from ..geometry.keypoints import BODY25_NAMES as BODY25_NAMES
from ..geometry.keypoints import BODY25B_NAMES as BODY25B_NAMES
from ..geometry.keypoints import COCO18_NAMES as COCO18_NAMES
from ..geometry.keypoints import HALPE26_NAMES as HALPE26_NAMES
from ..geometry.keypoints import KEYPOINT_FORMATS as KEYPOINT_FORMATS
from ..geometry.keypoints import MEDIAPIPE33_NAMES as MEDIAPIPE33_NAMES
from ..geometry.keypoints import flip_pairs as flip_pairs
from ..geometry.keypoints import keypoint_regressor as keypoint_regressor
from ..geometry.keypoints import regress_keypoints as regress_keypoints
from .detector import Detections as Detections
from .detector import DetectorErrorModel as DetectorErrorModel
from .detector import detect as detect
from .detector import person_track as person_track
