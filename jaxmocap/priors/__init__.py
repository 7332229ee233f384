"""Priors learnt from motion data: the Gaussian pose prior and joint limits of SIP (von Marcard §3.3.3),
and SMPLify's mixture of Gaussians (`MixturePosePrior`)."""

from .pose_prior import DEFAULT_PRIOR_PATH as DEFAULT_PRIOR_PATH
from .pose_prior import JOINT_LIMITS_DEG as JOINT_LIMITS_DEG
from .pose_prior import PosePrior as PosePrior
from .pose_prior import default_pose_prior as default_pose_prior
from .pose_prior import joint_limits as joint_limits
from .pose_prior import MixturePosePrior as MixturePosePrior
from .pose_prior import load_pose_prior as load_pose_prior
