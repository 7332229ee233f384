"""Physical plausibility: MuJoCo/MJX scene of the body, batched contact checks, metrics,
physics-aware residuals (engine terms on rotation matrices, body and scene as
`PhysicsData`, composable with the IMU terms) and a report (ground penetration, floating,
foot skating, human-object penetration). World y up, as everywhere in jaxmocap."""

from .checker import ContactDistances as ContactDistances
from .checker import Scene as Scene
from .checker import check as check
from .checker import contact_distances as contact_distances
from .checker import contact_distances_posed as contact_distances_posed
from .checker import make_scene as make_scene
from .checker import pose_bones as pose_bones
from .energies import FootStationarityResidual as FootStationarityResidual
from .energies import GroundSupportResidual as GroundSupportResidual
from .energies import MJXGroundResidual as MJXGroundResidual
from .energies import ObjectPenetrationResidual as ObjectPenetrationResidual
from .energies import PhysicsData as PhysicsData
from .energies import detect_foot_contact as detect_foot_contact
from .energies import foot_stationarity as foot_stationarity
from .energies import foot_stationarity_term as foot_stationarity_term
from .energies import ground_support as ground_support
from .energies import ground_support_term as ground_support_term
from .energies import mjx_ground_term as mjx_ground_term
from .energies import object_penetration as object_penetration
from .energies import object_penetration_term as object_penetration_term
from .metrics import CONTACT_THRESHOLD as CONTACT_THRESHOLD
from .metrics import PENETRATION_THRESHOLDS as PENETRATION_THRESHOLDS
from .metrics import contact_heatmap as contact_heatmap
from .metrics import foot_contact as foot_contact
from .metrics import foot_skating as foot_skating
from .metrics import penetration_summary as penetration_summary
from .mjcf import BodyGeometry as BodyGeometry
from .mjcf import Ground as Ground
from .mjcf import capsule_plane_distance as capsule_plane_distance
from .mjcf import fit_body_geometry as fit_body_geometry
from .mjcf import scene_mjcf as scene_mjcf
from .report import PlausibilityReport as PlausibilityReport
from .report import format_report as format_report
from .report import plausibility_report as plausibility_report
from .report import plot_report as plot_report
