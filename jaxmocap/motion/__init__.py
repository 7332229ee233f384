"""Motion sequences and motion files (AMASS npz, CMU ASF/AMC, BVH), retargeted to SMPL's tree,
and procedural edits of them (`reach`: a body part touching a point at one frame).

World frame everywhere: metres, y up, SMPL facing +z, left side +x (see `sequence`).
"""

from . import library as library
from .amass import load_amass as load_amass
from .amass import save_amass as save_amass
from .asf_amc import load_asf_amc as load_asf_amc
from .asf_amc import read_amc as read_amc
from .asf_amc import read_asf as read_asf
from .bvh import load_bvh as load_bvh
from .bvh import read_bvh as read_bvh
from .io import load_motion as load_motion
from .io import save_motion as save_motion
from .reach import ReachError as ReachError
from .reach import reach as reach
from .retarget import retarget as retarget
from .sequence import Motion as Motion
from .skeleton import MotionFileError as MotionFileError
from .skeleton import SkeletonMotion as SkeletonMotion
