"""Moved to `jaxmocap.geometry.triangulation`; this alias goes in the next release."""

from ..geometry.triangulation import projection_matrices as projection_matrices
from ..geometry.triangulation import select_person as select_person
from ..geometry.triangulation import triangulate as triangulate
from ..geometry.triangulation import undistort_recording as undistort_recording
