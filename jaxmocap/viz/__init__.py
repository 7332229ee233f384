"""Visualisation: posed meshes out through trimesh (.ply/.glb/.obj) and PNG pictures.

Coordinates stay in jaxmocap's world frame (metres, y up); glTF is y up as well.
"""

from .demo import export_motion as export_motion
from .demo import resolve_body as resolve_body
from .demo import run_demo as run_demo
from .mannequin import mannequin_body as mannequin_body
from .mesh import MeshExportError as MeshExportError
from .mesh import export_mesh as export_mesh
from .mesh import export_sequence as export_sequence
from .mesh import posed_vertices as posed_vertices
from .mesh import scalars_to_colors as scalars_to_colors
from .plot import plot_body as plot_body
from .plot import plot_pose as plot_pose
from .plot import plot_sequence as plot_sequence
