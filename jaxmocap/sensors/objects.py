"""Rigid objects with 6-DoF trajectories and hand/foot contact over marked frame ranges.

For human-object scenes (InterCap, Huang ch. 5). An object is a `jaxmocap.objects.RigidObject`
(a mesh in its own frame); its trajectory is (R_o(t), t_o(t)) with world vertices
R_o v + t_o. `contact_trajectory` makes the object physically tied to the body:

  - before the contact range it rests where it will be touched: on the floor where
    `pick_and_place` put it (`rest=`), or else where the hand is at the first contact frame
    (as if on a support);
  - at the first contact frame s the part's contact point c (the part vertex furthest
    along the part's contact normal n, e.g. the palm for a hand) touches the object's
    extreme point along -n: the object is put there, or (`rest=`) the pick-up reach
    brought the hand there;
  - during contact it moves rigidly with the part's joint: X_o(t) = G_j(t) G_j(s)⁻¹ X_o(s);
  - after release it stays where it was released (set down onto the floor with `rest=`);
  - at every frame it is lifted if needed so that nothing is below the ground plane.

`pick_and_place` edits the motion to fit (`motion.reach`): a pick-up reach at s to the
object resting on the floor beside the hand, a put-down reach at the last contact frame
that lowers the carried object onto the floor.

Contact parts (`CONTACT_PARTS`) and their body vertices (`contact_vertices`) are defined in
`jaxmocap.motion.reach` and re-exported here.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

from ..body.kinematics import forward
from ..motion.reach import CONTACT_PARTS, contact_joint, contact_point, contact_vertices, reach
from ..objects import RigidObject

__all__ = [
    "ObjectTrajectory",
    "CONTACT_PARTS",
    "Handling",
    "contact_vertices",
    "contact_trajectory",
    "pick_and_place",
]


@dataclasses.dataclass(frozen=True)
class ObjectTrajectory:
    """Object pose per frame: rotations (T, 3, 3) and translations (T, 3) (object → world)."""

    rotations: np.ndarray
    translations: np.ndarray

    def vertices(self, obj: RigidObject) -> np.ndarray:
        """(T, N, 3) world vertices."""
        return np.einsum("tab,nb->tna", self.rotations, obj.vertices) + self.translations[:, None]


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
    rest: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[ObjectTrajectory, np.ndarray]:
    """Object trajectory in hand/foot contact over frames [start, end).

    Args:
        obj: the object; body: the body model (for the contact region).
        vertices (T, V, 3), joints (T, J, 3), joint_rotations (T, J, 3, 3): the posed body.
        start, end: contact frame range; part: a key of CONTACT_PARTS; ground: floor height.
        rest: the object's pose (R (3, 3), t (3,)) before `start`, where the motion picks it
            up (`pick_and_place`); after `end` it is then set down onto the ground (its lowest
            vertex at `ground`). None: it rests where the contact point is at `start`.
    Returns:
        (trajectory, contact (T,) bool).
    """
    T = len(vertices)
    if not 0 <= start < end <= T:
        raise ValueError(f"Contact range [{start}, {end}) must lie inside the {T} frames.")
    j = contact_joint(part)
    R_j, p_j = np.asarray(joint_rotations[:, j], np.float64), np.asarray(joints[:, j], np.float64)
    if rest is None:
        # Object at identity rotation; its extreme point along -n (a vertex) touches c.
        c, n, _ = contact_point(body, vertices[start], joints[start], joint_rotations[start], part)
        R0, t0 = np.eye(3), c - obj.vertices[np.argmin(obj.vertices @ n)]
    else:
        R0, t0 = np.asarray(rest[0], np.float64), np.asarray(rest[1], np.float64)
    Rs = np.broadcast_to(R0, (T, 3, 3)).copy()
    ts = np.broadcast_to(t0, (T, 3)).copy()
    rel_R = R_j[start].T @ R0  # G_j(s)⁻¹ X_o(s)
    rel_t = R_j[start].T @ (t0 - p_j[start])
    Rs[start:end] = R_j[start:end] @ rel_R
    ts[start:end] = np.einsum("tab,b->ta", R_j[start:end], rel_t) + p_j[start:end]
    Rs[end:], ts[end:] = Rs[end - 1], ts[end - 1]
    lowest = np.einsum("tab,nb->tna", Rs, obj.vertices)[..., 1].min(1) + ts[:, 1]
    if rest is not None:
        ts[end:, 1] += ground - lowest[end:]  # set down: the put-down reach left it within mm
        lowest[end:] = ground
    ts[:, 1] += np.maximum(ground - lowest, 0.0)
    contact = np.zeros(T, bool)
    contact[start:end] = True
    return ObjectTrajectory(Rs, ts), contact


@dataclasses.dataclass(frozen=True)
class Handling:
    """`pick_and_place`'s result: the edited motion, the object's resting pose before the
    pick-up (`rest` = (R (3, 3), t (3,)) for `contact_trajectory`) and measured numbers:
    `pick_gap` (m, contact point to the grasp point), `put_gap` (m, the carried object's
    lowest point above the ground at the put-down), `penetration` (m, the deepest body
    vertex inside the object at pick-up and at put-down) and `crouch` (m, how far the
    pelvis was lowered at the pick-up)."""

    poses: np.ndarray
    trans: np.ndarray
    rest: tuple[np.ndarray, np.ndarray]
    pick_gap: float
    put_gap: float
    penetration: tuple[float, float]
    crouch: float


def _penetration(obj: RigidObject, R, t, vertices) -> float:
    """Depth (m, >= 0) of the deepest of `vertices` (N, 3) inside the object posed at (R, t)."""
    import trimesh

    local = (np.asarray(vertices, np.float64) - t) @ R
    lo, hi = obj.vertices.min(0), obj.vertices.max(0)
    near = local[np.all((local > lo) & (local < hi), -1)]  # only these can be inside
    if not len(near):
        return 0.0
    return max(0.0, float(np.max(trimesh.proximity.signed_distance(obj.mesh, near))))  # > 0 inside


def _horizontal(v, fallback) -> np.ndarray:
    h = np.array([v[0], 0.0, v[2]])
    norm = np.linalg.norm(h)
    return h / norm if norm > 1e-6 else np.asarray(fallback, np.float64)


def pick_and_place(
    obj: RigidObject,
    body,
    poses,
    trans,
    betas,
    start: int,
    end: int,
    part: str = "right_hand",
    ground: float = 0.0,
    blend: int = 15,
    clearance: float = 0.03,
) -> Handling:
    """Edit a motion to pick `obj` up from the floor at `start` and put it down at `end - 1`.

    Before `start` the object rests on the floor (unrotated, lowest vertex at `ground`) beside
    the part's contact point, pushed horizontally away from the pelvis until its near side is
    `clearance` beyond it (and further if the reaching body would enter it). A `motion.reach`
    at `start` brings the contact point to the object's grasp point (its extreme vertex
    along -n, `contact_trajectory`'s rule), and one at `end - 1` lowers the hand until the
    object, carried rigidly by the part's joint, touches the ground (iterated, as turning
    the wrist moves the object's lowest point). Blend windows are at most half the carrying
    time, so the two reaches do not overlap; frames of the blend where a foot would dip below
    the ground are raised onto it. `ReachError` if a target is out of reach.

    Returns:
        a `Handling`; pass `rest` to `contact_trajectory` with the posed edited motion.
    """
    poses, trans = np.asarray(poses, np.float64), np.asarray(trans, np.float64)
    T = len(poses)
    if not 0 <= start < end <= T:
        raise ValueError(f"Contact range [{start}, {end}) must lie inside the {T} frames.")
    j = contact_joint(part)
    put, v = end - 1, obj.vertices
    blend = max(1, min(blend, (put - start) // 2))
    betas = np.asarray(betas)[: body.num_betas]

    def posed(p, t, f):  # vertices, joints, joint rotations of frame(s) f
        out = forward(body, jnp.asarray(p[f]), jnp.asarray(betas), jnp.asarray(t[f]))
        return tuple(np.asarray(x, np.float64) for x in (out.vertices, out.joints, out.joint_rotations))

    # Pick-up: rest pose beside the hand, grasp vertex by the normal the reach ends with.
    V0, J0, G0 = posed(poses, trans, start)
    c, n, _ = contact_point(body, V0, J0, G0, part)
    u = _horizontal(c - J0[0], (1.0, 0.0, 0.0))
    R0 = np.eye(3)
    t0 = c * [1.0, 0.0, 1.0] + u * (clearance - np.min(v @ u))
    t0[1] = ground - v[:, 1].min()
    for _ in range(3):
        for _ in range(3):
            k = int(np.argmin(v @ n))
            p1, tr1, info = reach(body, poses, trans, betas, start, part, t0 + v[k], blend, return_info=True)
            V1, J1, G1 = posed(p1, tr1, start)
            _, n, _ = contact_point(body, V1, J1, G1, part)
            if int(np.argmin(v @ n)) == k:
                break
        pick_depth = _penetration(obj, R0, t0, V1)
        if pick_depth <= 0.005:
            break
        t0 = t0 + u * (pick_depth + clearance)
    # Put-down: the object as carried from the pick-up pose, lowered onto the ground.
    rel_R, rel_t = G1[j].T @ R0, G1[j].T @ (t0 - J1[j])
    p2, tr2, low, put_depth = p1, tr1, ground, pick_depth
    for it in range(6 if put > start else 0):
        V2, J2, G2 = posed(p2, tr2, put)
        R_o, t_o = G2[j] @ rel_R, G2[j] @ rel_t + J2[j]
        low, put_depth = float(np.min(v @ R_o[1]) + t_o[1]), _penetration(obj, R_o, t_o, V2)
        if (abs(low - ground) < 1e-3 and put_depth <= 0.005) or it == 5:
            break
        c2, _, _ = contact_point(body, V2, J2, G2, part)
        push = 0.0 if put_depth <= 0.005 else put_depth + clearance
        target = c2 + [0.0, ground - low, 0.0] + push * _horizontal(c2 - J2[0], u)
        p2, tr2 = reach(body, p1, tr1, betas, put, part, target, blend)
    # Blending between the planted reach pose and the original one can dip a foot below the
    # ground; raise those frames (not the reach frames themselves, whose feet are planted).
    lowest = posed(p2, tr2, slice(None))[0][..., 1].min(-1)
    lift = np.maximum(ground - lowest, 0.0)
    lift[[start, put]] = 0.0
    tr2 = tr2 + lift[:, None] * [0.0, 1.0, 0.0]
    return Handling(
        p2,
        tr2,
        (R0, t0),
        info.gap,
        low - ground,
        (pick_depth, put_depth),
        float(J0[0, 1] - J1[0, 1]),
    )
