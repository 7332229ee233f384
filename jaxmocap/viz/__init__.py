"""Visualisation: meshes out through trimesh (.ply/.glb/.obj) and PNG pictures.

Draws arrays it is given and nothing else (the demo pipeline lives in `jaxmocap.app`).

Coordinates stay in jaxmocap's world frame (metres, y up); glTF is y up as well.
"""

from . import vip as vip
from .mesh import MeshExportError as MeshExportError
from .mesh import export_mesh as export_mesh
from .mesh import export_sequence as export_sequence
from .mesh import scalars_to_colors as scalars_to_colors
from .plot import plot_body as plot_body
from .plot import plot_error_curves as plot_error_curves
from .plot import plot_per_joint as plot_per_joint
from .plot import plot_pose as plot_pose
from .plot import plot_sequence as plot_sequence
