"""Rigid objects with 6-DoF trajectories and hand/foot contact over marked frame ranges.

For human-object scenes (InterCap, Huang ch. 5). An object is a `jaxmocap.objects.RigidObject`
(a mesh in its own frame); its trajectory is (R_o(t), t_o(t)) with world vertices
R_o v + t_o. `contact_trajectory` makes the object physically tied to the body:

  - before the contact range it rests where it will be touched (as if on a support);
  - at the first contact frame s it is placed against the body part: the part's
    contact point c (the part vertex furthest along the part's contact normal n, e.g. the
    palm for a hand) touches the object's extreme point along -n;
  - during contact it moves rigidly with the part's joint: X_o(t) = G_j(t) G_j(s)⁻¹ X_o(s);
  - after release it stays where it was released;
  - at every frame it is lifted if needed so that nothing is below the ground plane.

Contact parts, their joints and contact normals in the joint's rest frame (T-pose: palms
down, feet flat facing +z; the grips along the fingers) are in `CONTACT_PARTS`; the body contact vertices are those
skinned mostly to the part's bones (InterCap's annotated contact vertices).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..body.model import SMPL_JOINT_NAMES
from ..objects import RigidObject

__all__ = ["ObjectTrajectory", "CONTACT_PARTS", "contact_vertices", "contact_trajectory"]

_J = {n: i for i, n in enumerate(SMPL_JOINT_NAMES)}

#: part: (carrying joint, bones of its skin region, contact normal in the rest frame)
CONTACT_PARTS = {
    "left_hand": ("left_wrist", ("left_wrist", "left_hand"), (0.0, -1.0, 0.0)),
    "right_hand": ("right_wrist", ("right_wrist", "right_hand"), (0.0, -1.0, 0.0)),
    # Carrying by the fingers (a bag, a box by its handle): the object hangs beyond the
    # fingertips, so a hanging arm carries it beside the thigh, not into it.
    "left_grip": ("left_wrist", ("left_wrist", "left_hand"), (1.0, 0.0, 0.0)),
    "right_grip": ("right_wrist", ("right_wrist", "right_hand"), (-1.0, 0.0, 0.0)),
    "left_foot": ("left_ankle", ("left_ankle", "left_foot"), (0.0, 0.0, 1.0)),
    "right_foot": ("right_ankle", ("right_ankle", "right_foot"), (0.0, 0.0, 1.0)),
}


@dataclasses.dataclass(frozen=True)
class ObjectTrajectory:
    """Object pose per frame: rotations (T, 3, 3) and translations (T, 3) (object → world)."""

    rotations: np.ndarray
    translations: np.ndarray

    def vertices(self, obj: RigidObject) -> np.ndarray:
        """(T, N, 3) world vertices."""
        return np.einsum("tab,nb->tna", self.rotations, obj.vertices) + self.translations[:, None]


def contact_vertices(body, part: str) -> np.ndarray:
    """Indices of the body vertices skinned mostly (≥ 0.5) to the part's bones."""
    if part not in CONTACT_PARTS:
        raise ValueError(f"Unknown contact part {part!r}; choose from {sorted(CONTACT_PARTS)}.")
    w = np.asarray(body.weights)
    bones = [_J[b] for b in CONTACT_PARTS[part][1]]
    return np.flatnonzero(w[:, bones].sum(1) >= 0.5)


def contact_trajectory(
    obj: RigidObject,
    body,
    vertices: np.ndarray,
    joints: np.ndarray,
    joint_rotations: np.ndarray,
    start: int,
    end: int,
    part: str = "right_hand",
    ground: float = 0.0,
) -> tuple[ObjectTrajectory, np.ndarray]:
    """Object trajectory in hand/foot contact over frames [start, end).

    Args:
        obj: the object; body: the body model (for the contact region).
        vertices (T, V, 3), joints (T, J, 3), joint_rotations (T, J, 3, 3): the posed body.
        start, end: contact frame range; part: a key of CONTACT_PARTS; ground: floor height.
    Returns:
        (trajectory, contact (T,) bool).
    """
    T = len(vertices)
    if not 0 <= start < end <= T:
        raise ValueError(f"Contact range [{start}, {end}) must lie inside the {T} frames.")
    joint_name, _, normal_rest = CONTACT_PARTS[part]
    j = _J[joint_name]
    region = contact_vertices(body, part)
    R_j, p_j = np.asarray(joint_rotations[:, j], np.float64), np.asarray(joints[:, j], np.float64)
    n = R_j[start] @ np.asarray(normal_rest)
    pts = np.asarray(vertices[start, region], np.float64)
    c = pts[np.argmax((pts - p_j[start]) @ n)]
    # Object at identity rotation; its extreme point along -n (a vertex) touches c.
    t0 = c - obj.vertices[np.argmin(obj.vertices @ n)]
    Rs = np.broadcast_to(np.eye(3), (T, 3, 3)).copy()
    ts = np.broadcast_to(t0, (T, 3)).copy()
    rel_R = R_j[start].T  # G_j(s)⁻¹ applied to X_o(s) = (I, t0)
    rel_t = R_j[start].T @ (t0 - p_j[start])
    Rs[start:end] = R_j[start:end] @ rel_R
    ts[start:end] = np.einsum("tab,b->ta", R_j[start:end], rel_t) + p_j[start:end]
    Rs[end:], ts[end:] = Rs[end - 1], ts[end - 1]
    lowest = np.einsum("tab,nb->tna", Rs, obj.vertices)[..., 1].min(1) + ts[:, 1]
    ts[:, 1] += np.maximum(ground - lowest, 0.0)
    contact = np.zeros(T, bool)
    contact[start:end] = True
    return ObjectTrajectory(Rs, ts), contact
