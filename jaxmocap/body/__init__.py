"""Body models: the SMPL-layout pytree, its forward pass, and model files."""

from .io import BODY_CHOICES as BODY_CHOICES
from .io import BodyFileError as BodyFileError
from .io import default_body as default_body
from .io import load_body as load_body
from .io import resolve_body as resolve_body
from .io import save_body as save_body
from .kinematics import BodyOutput as BodyOutput
from .kinematics import forward as forward
from .kinematics import forward_kinematics as forward_kinematics
from .kinematics import forward_rotations as forward_rotations
from .kinematics import shaped_joints as shaped_joints
from .mannequin import mannequin_body as mannequin_body
from .model import SMPL_FEET as SMPL_FEET
from .model import SMPL_JOINT_NAMES as SMPL_JOINT_NAMES
from .model import SMPL_PARENTS as SMPL_PARENTS
from .model import Body as Body
from .model import make_body as make_body
from .model import scaled_body as scaled_body
from .posed import posed_arrays as posed_arrays
from .posed import posed_vertices as posed_vertices
