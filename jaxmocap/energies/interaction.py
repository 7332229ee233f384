"""Energies of InterCap (Huang ch. 5): a person and a rigid object they handle.

Unknowns: body `pose` (T, 24, 3, 3) and `trans` (T, 3) as in every body term, and the
object's world-from-object pose `object` (T, 4, 4) (an SE(3) unknown per frame,
`solve.frame("se3")`). Each term reads `InteractionData` (object geometry, selected masks,
labelled point clouds, contact flags, floor) and, for the keypoints and the body, the
`CameraData` of `energies.camera`; a problem gets both through
`CombinedData((camera_data, interaction_data))`. As in `energies.camera`, each residual
is an equinox module with static configuration (`VertexAcceleration(stride)`, ...), built
into a `Term` by the constructor named in the table.

| term | equation | residual (per frame) |
| --- | --- | --- |
| `object_mask` | 5.1, λ_segm | observed object-mask points against the projected object (`camera.mask_to_model`) |
| `object_depth` | 5.1, λ_depth | signed distance of observed object points to the posed object surface |
| `body_depth` | 5.4, E_D | observed body points minus their visible-vertex correspondences |
| `bend` | 5.2, E_α | exp(±θ/2) of elbow and knee bending (squared: SMPLify's exp(±θ)) |
| `self_penetration` | 5.5, E_P | overlap of body spheres of non-adjacent segments |
| `smooth` | 5.6, E_A | vertex accelerations v_{t-1} - 2 v_t + v_{t+1} |
| `object_smooth` | 5.6, E_B (object acceleration) | accelerations of the object's box corners |
| `penetration` | 5.6, body-object term of PROX | max(0, -sdf) of body vertices in the posed object |
| `ground`, `object_ground` | 5.6, E_G, E_G' | max(0, h - y) of body vertices and object points |
| `contact` | 5.7, E_C | Q_t · distance of the closest body contact vertex to the object surface |
| `floor` | 5.6-5.7, E_G and E_C with the floor as the surface | signed height of the lowest sole point above a known floor (one camera's depth, `methods.multiview`) |

Choices where the thesis leaves one (each noted at its function too):
- eq. 5.1 compares rendered and observed masks/depth inside the observed mask only (the
  `* S_v`); here the mask part is the point form of that product (every observed object
  pixel must be covered by the projected object, the mask-to-model sum of eq. 4.5) and the
  depth part is the point-to-surface distance of the observed object points, read from
  the object's signed distance field: both need no renderer, and neither penalises object
  parts hidden by the body (which is why the thesis masks with S_v).
- eq. 5.4 (min over visible vertices of ‖v - p‖, not squared): correspondences are fixed
  per outer round (ICP: `methods.interaction` re-finds them between solves, with the
  visibility of the current fit); Huber with δ = 1 cm gives the un-squared norm's tails.
- eq. 5.7: the closest object point of a body contact vertex x is x - sdf(x)∇sdf(x), so
  the Chamfer distance of the contact vertices to their closest points is |sdf| at them.
  It is re-found at every evaluation (ICP within the solve) and is exact where the grid
  resolves the surface. Only the closest contact vertex enters (Q_t: a hand touches the
  object; which vertex touches is left to the fit; see `contact_term`).
- E_A (a learnt motion prior in the thesis, Zhang et al. 2021a) is a second-difference
  prior on vertices here: it penalises jitter without pulling towards rest.
- E_P (PROX's triangle-level self-penetration) is a sphere model as in SMPLify: spheres
  along each segment's bone, penalised where spheres of segments at least three links
  apart overlap (pairs already overlapping in the rest pose are left out).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..body.kinematics import shaped_joints
from ..body.model import SMPL_JOINT_NAMES, Body
from ..geometry.keypoints import regress_keypoints
from ..objects import ObjectSDF
from ..solve import GemanMcClure, Huber, Term
from .camera import PosedInViews, Silhouettes, mask_to_model, posed_in_views, project_to_views

__all__ = [
    "InteractionData",
    "body_spheres",
    "object_world",
    "object_mask_term",
    "object_depth_term",
    "body_depth_term",
    "bend_term",
    "self_penetration_term",
    "smoothness_term",
    "object_smoothness_term",
    "penetration_term",
    "ground_term",
    "object_ground_term",
    "contact_term",
    "floor_contact_term",
    "BEND_JOINTS",
    "ObjectMaskResidual",
    "ObjectDepthResidual",
    "BodyDepthResidual",
    "BendResidual",
    "SelfPenetrationResidual",
    "VertexAcceleration",
    "CornerAcceleration",
    "PenetrationResidual",
    "GroundResidual",
    "ObjectGroundResidual",
    "ContactResidual",
    "FloorContactResidual",
]


class InteractionData(eqx.Module):
    """What the InterCap terms read besides the `CameraData` (shapes: T frames, V views).

    surface: (S, 3) points on the object surface (object frame).
    corners: (8, 3) the object's bounding-box corners (object frame; E_B).
    sdf: the object's `ObjectSDF`.
    object_masks: the selected object masks as `Silhouettes` (T, V, ...) or None.
    object_points, object_valid: (T, V, M, 3) world points labelled object, (T, V, M).
    body_points, body_valid: (T, V, Mb, 3) world points labelled body, (T, V, Mb).
    body_match: (T, V, Mb) int, the visible vertex each body point is matched to.
    contact: (T,) Q_t in [0, 1] (eq. 5.6); contact_vertices: (Nc,) int body vertices.
    floor: () ground height (y up).
    sphere_weights: (S, J), sphere_radius (S,), sphere_pairs (P, 2) int: the
        self-penetration spheres (`body_spheres`).
    """

    surface: Array
    corners: Array
    sdf: ObjectSDF
    object_masks: Silhouettes | None
    object_points: Array
    object_valid: Array
    body_points: Array
    body_valid: Array
    body_match: Array
    contact: Array
    contact_vertices: Array
    floor: Array
    sphere_weights: Array
    sphere_radius: Array
    sphere_pairs: Array


def object_world(pose: Array, points: Array) -> Array:
    """Object-frame points (N, 3) under poses (T, 4, 4) -> world points (T, N, 3)."""
    return jnp.einsum("tab,nb->tna", pose[:, :3, :3], points.astype(pose.dtype)) + pose[:, None, :3, 3]


def _object_local(pose: Array, points: Array) -> Array:
    """World points (T, ..., N, 3) -> the object frame of poses (T, 4, 4): Rᵀ(x - t)."""
    extra = points.ndim - 3
    R = pose[:, :3, :3].reshape(pose.shape[:1] + (1,) * extra + (3, 3))
    t = pose[:, :3, 3].reshape(pose.shape[:1] + (1,) * extra + (1, 3))
    return jnp.einsum("...ba,...nb->...na", R, points - t)


# --- object fitting (eq. 5.1) ------------------------------------------------------------


class ObjectMaskResidual(eqx.Module):
    """λ_segm part of E_O (eq. 5.1): observed object-mask points against the projected object
    surface samples (`camera.mask_to_model`), (T, V, M, 2)."""

    slack: float = eqx.field(static=True, default=1.0)

    def __call__(self, params, data) -> Array:
        uv, _ = project_to_views(data, object_world(params["object"], data.surface))
        return mask_to_model(uv, data.object_masks, self.slack)


def object_mask_valid(data) -> Array:
    """The sampled object-mask points that exist, (T, V, M)."""
    return data.object_masks.valid


def object_mask_term(weight: float = 1.0, slack: float = 1.0) -> Term:
    """λ_segm part of E_O (eq. 5.1): every observed object-mask point lies within `slack`
    px of the projected object surface samples (mask-to-model, Huber tails), (T, V, M, 2)."""
    fn = ObjectMaskResidual(float(slack))
    return Term("object_mask", fn, weight, mask=object_mask_valid, reads=(("object", None),))


class ObjectDepthResidual(eqx.Module):
    """λ_depth part of E_O (eq. 5.1): signed distance (m) of each observed object point to the
    posed object's surface, (T, V, M, 1)."""

    def __call__(self, params, data) -> Array:
        local = _object_local(params["object"], data.object_points.astype(params["object"].dtype))
        return data.sdf(local)[..., None]


def object_point_valid(data) -> Array:
    """The observed object points that exist, (T, V, M)."""
    return data.object_valid


def object_depth_term(weight: float = 1.0, sigma: float = 0.02) -> Term:
    """λ_depth part of E_O (eq. 5.1): signed distance (m) of each observed object point to
    the posed object's surface, Geman-McClure ρ_σ (mislabelled points), (T, V, M, 1)."""
    return Term("object_depth", ObjectDepthResidual(), weight, loss=GemanMcClure(sigma), mask=object_point_valid,
                reads=(("object", None),))  # fmt: skip


# --- human fitting (eq. 5.2-5.5) -----------------------------------------------------------


class BodyDepthResidual(eqx.Module):
    """E_D (eq. 5.4): observed body points minus their matched visible vertices
    (`data.body_match`), (T, V, Mb, 3)."""

    def __call__(self, params, data, posed=None) -> Array:
        verts = posed_in_views(params, data, posed).vertices  # (T, N, 3)
        T, V, M = data.body_match.shape
        matched = jnp.take_along_axis(verts, data.body_match.reshape(T, V * M)[..., None], axis=1)
        return data.body_points.astype(verts.dtype) - matched.reshape(T, V, M, 3)


def body_point_valid(data) -> Array:
    """The observed body points that exist, (T, V, Mb)."""
    return data.body_valid


def body_depth_term(weight: float = 1.0, delta: float = 0.01) -> Term:
    """E_D (eq. 5.4): observed body points minus their matched visible vertices
    (`data.body_match`, re-found between solves), Huber δ (m), (T, V, Mb, 3)."""
    return Term("body_depth", BodyDepthResidual(), weight, loss=Huber(delta), mask=body_point_valid,
                posed=PosedInViews())  # fmt: skip


#: (joint, rotation axis, sign s): E_α penalises exp(s θ), θ the bending angle about the
#: axis (SMPLify's elbow and knee signs on SMPL's axes: s θ > 0 is the unnatural way).
BEND_JOINTS = (("left_elbow", 1, 1.0), ("right_elbow", 1, -1.0), ("left_knee", 0, -1.0), ("right_knee", 0, -1.0))


def _axis_angle_about(R: Array, axis: int) -> Array:
    """Angle of the rotation about coordinate `axis` (exact for rotations about it)."""
    i, j = (axis + 1) % 3, (axis + 2) % 3
    return jnp.arctan2(R[..., j, i], R[..., i, i])


#: The joints E_α reads (`BEND_JOINTS`).
_BEND_IDS = tuple(SMPL_JOINT_NAMES.index(n) for n, _, _ in BEND_JOINTS)


class BendResidual(eqx.Module):
    """E_α (eq. 5.2): exp(s θ / 2) of each joint of `BEND_JOINTS`, (T, 4, 1)."""

    def __call__(self, params, data) -> Array:
        R = params["pose"][:, np.asarray(_BEND_IDS)]  # (T, 4, 3, 3)
        theta = jnp.stack([_axis_angle_about(R[:, k], a) for k, (_, a, _) in enumerate(BEND_JOINTS)], -1)
        signs = jnp.asarray([s for _, _, s in BEND_JOINTS], theta.dtype)
        return jnp.exp(0.5 * signs * theta)[..., None]


def bend_term(weight: float = 1.0) -> Term:
    """E_α (eq. 5.2): Σ exp(s θ) over elbows and knees (SMPLify), as residuals exp(s θ / 2)."""
    return Term("bend", BendResidual(), weight, reads=(("pose", _BEND_IDS),))


def body_spheres(body: Body, betas=None, per_bone: int = 2, min_links: int = 3) -> dict:
    """Self-penetration spheres of `body` at shape `betas` (E_P, eq. 5.5; SMPLify's model).

    Each joint with children and vertices (skinned mostly to it) carries `per_bone`
    spheres on the segment from it towards the mean of its children, radius the median
    distance of its vertices to that segment. Pairs of spheres whose joints are at least
    `min_links` apart in the kinematic tree and do not overlap in the rest pose are
    penalised. Returns arrays for `InteractionData`: sphere_weights (S, J) (centre =
    weights @ posed joints), sphere_radius (S,), sphere_pairs (P, 2).
    """
    full = np.zeros(body.num_betas)
    if betas is not None:
        b = np.asarray(betas, np.float64).reshape(-1)[: body.num_betas]
        full[: len(b)] = b
    rest = np.asarray(shaped_joints(body, jnp.asarray(full[None], body.dtype)))[0].astype(np.float64)
    verts = np.asarray(body.v_template, np.float64) + np.einsum(
        "k,kvc->vc", full, np.asarray(body.shapedirs, np.float64)
    )
    owner = np.argmax(np.asarray(body.weights), 1)
    parents = np.asarray(body.parents)
    weights, radii, joint_of = [], [], []
    for j in range(len(parents)):
        kids = np.flatnonzero(parents == j)
        if not len(kids) or not np.any(owner == j):
            continue
        a, ab = rest[j], rest[kids].mean(0) - rest[j]
        pts = verts[owner == j]
        s = np.clip((pts - a) @ ab / max(ab @ ab, 1e-12), 0.0, 1.0)
        r = float(np.median(np.linalg.norm(pts - (a + s[:, None] * ab), axis=-1)))
        for k in range(per_bone):
            alpha = (k + 0.5) / per_bone
            w = np.zeros(len(parents))
            w[j] += 1 - alpha
            w[kids] += alpha / len(kids)
            weights.append(w)
            radii.append(r)
            joint_of.append(j)
    weights, radii = np.stack(weights), np.array(radii)
    centres = weights @ rest
    links = _tree_distance(parents)
    pairs = [(i, k) for i in range(len(radii)) for k in range(i + 1, len(radii))
             if links[joint_of[i], joint_of[k]] >= min_links
             and np.linalg.norm(centres[i] - centres[k]) > radii[i] + radii[k]]  # fmt: skip
    return {"sphere_weights": weights, "sphere_radius": radii, "sphere_pairs": np.array(pairs, np.int64).reshape(-1, 2)}


def _tree_distance(parents) -> np.ndarray:
    """Links between every two joints of a kinematic tree."""
    n = len(parents)
    chains = []
    for j in range(n):
        chain, k = [], j
        while k >= 0:
            chain.append(k)
            k = int(parents[k])
        chains.append(chain)
    out = np.zeros((n, n), int)
    for a in range(n):
        for b in range(n):
            common = set(chains[a]) & set(chains[b])
            out[a, b] = min(chains[a].index(c) + chains[b].index(c) for c in common)
    return out


class SelfPenetrationResidual(eqx.Module):
    """E_P (eq. 5.5): max(0, r_i + r_j - ‖c_i - c_j‖) for the sphere pairs, (T, P, 1)."""

    def __call__(self, params, data, posed=None) -> Array:
        joints = posed_in_views(params, data, posed).joints  # (T, J, 3)
        centres = jnp.einsum("sj,tjc->tsc", data.sphere_weights.astype(joints.dtype), joints)
        i, k = data.sphere_pairs[:, 0], data.sphere_pairs[:, 1]
        d2 = jnp.sum((centres[:, i] - centres[:, k]) ** 2, -1)
        d = jnp.sqrt(d2 + 1e-12)
        r = (data.sphere_radius[i] + data.sphere_radius[k]).astype(joints.dtype)
        return jax.nn.relu(r - d)[..., None]


def self_penetration_term(weight: float = 1.0) -> Term:
    """E_P (eq. 5.5): max(0, r_i + r_j - ‖c_i - c_j‖) for the sphere pairs, (T, P, 1);
    centres from the posed joints (`body_spheres`)."""
    return Term("self_penetration", SelfPenetrationResidual(), weight, posed=PosedInViews())


# --- joint fit over all frames (eq. 5.6-5.7) -----------------------------------------------


def _second_difference(points: Array) -> Array:
    """Row t: x_{t-1} - 2 x_t + x_{t+1} (T, ..., 3); edge rows are zero (dropped by bandwidth 1)."""
    inner = points[:-2] - 2 * points[1:-1] + points[2:]
    zero = jnp.zeros_like(points[:1])
    return jnp.concatenate([zero, inner, zero], 0)


class VertexAcceleration(eqx.Module):
    """E_A (eq. 5.6): second differences of every `stride`-th posed body vertex, (T, N, 3)."""

    stride: int = eqx.field(static=True, default=8)

    def __call__(self, params, data, posed=None) -> Array:
        return _second_difference(posed_in_views(params, data, posed).vertices[:, :: self.stride])


def smoothness_term(weight: float = 1.0, stride: int = 8, delta: float | None = None) -> Term:
    """E_A (eq. 5.6): accelerations of every `stride`-th body vertex (m per frame²), bandwidth 1;
    Huber δ (m per frame²) when given (see `object_smoothness_term`)."""
    loss = None if delta is None else Huber(delta)
    return Term("smooth", VertexAcceleration(int(stride)), weight, loss=loss, bandwidth=1,
                reads=(("pose", None), ("trans", None)), posed=PosedInViews())  # fmt: skip


class CornerAcceleration(eqx.Module):
    """E_B (eq. 5.6): second differences of the posed object's bounding-box corners, (T, 8, 3)."""

    def __call__(self, params, data) -> Array:
        return _second_difference(object_world(params["object"], data.corners))


def object_smoothness_term(weight: float = 1.0, delta: float | None = None) -> Term:
    """E_B (eq. 5.6, object acceleration): accelerations of the object's bounding-box corners
    (rotation and translation in one metric quantity), bandwidth 1.

    `delta` (m per frame²): Huber δ. Quadratic, the prior penalises a real acceleration
    as it does jitter and, against the robust (saturating) data term E_O, drags a quickly
    carried object off its observations (a 20 cm bottle swung at 0.2 m per frame²: 37x
    its data cost); Huber keeps the quadratic core for jitter of the per-frame track and
    bounds the pull of a real acceleration (the thesis's learnt prior likewise allows real
    motion).
    """

    loss = None if delta is None else Huber(delta)
    return Term("object_smooth", CornerAcceleration(), weight, loss=loss, bandwidth=1, reads=(("object", None),))


class PenetrationResidual(eqx.Module):
    """max(0, -sdf) of every `stride`-th posed body vertex in the posed object, (T, N, 1) (eq. 5.6)."""

    stride: int = eqx.field(static=True, default=1)

    def __call__(self, params, data, posed=None) -> Array:
        verts = posed_in_views(params, data, posed).vertices[:, :: self.stride]
        return jax.nn.relu(-data.sdf(_object_local(params["object"], verts)))[..., None]


def penetration_term(weight: float = 1.0, stride: int = 1) -> Term:
    """Body-object interpenetration (eq. 5.6, as in PROX with a moving object): max(0, -sdf)
    of every `stride`-th posed body vertex in the posed object, (T, N, 1)."""
    return Term("penetration", PenetrationResidual(int(stride)), weight, posed=PosedInViews())


class GroundResidual(eqx.Module):
    """E_G (eq. 5.6): max(0, h - y) of every `stride`-th posed body vertex, (T, N, 1)."""

    stride: int = eqx.field(static=True, default=1)

    def __call__(self, params, data, posed=None) -> Array:
        y = posed_in_views(params, data, posed).vertices[:, :: self.stride, 1]
        return jax.nn.relu(data.floor.astype(y.dtype) - y)[..., None]


def ground_term(weight: float = 1.0, stride: int = 1) -> Term:
    """E_G (eq. 5.6): max(0, h - y) of every `stride`-th body vertex, (T, N, 1)."""
    return Term("ground", GroundResidual(int(stride)), weight, reads=(("pose", None), ("trans", None)),
                posed=PosedInViews())  # fmt: skip


class ObjectGroundResidual(eqx.Module):
    """E_G' (eq. 5.6): max(0, h - y) of the posed object's surface points, (T, S, 1)."""

    def __call__(self, params, data) -> Array:
        y = object_world(params["object"], data.surface)[..., 1]
        return jax.nn.relu(data.floor.astype(y.dtype) - y)[..., None]


def object_ground_term(weight: float = 1.0) -> Term:
    """E_G' (eq. 5.6): max(0, h - y) of the object's surface points, (T, S, 1)."""
    return Term("object_ground", ObjectGroundResidual(), weight, reads=(("object", None),))


class ContactResidual(eqx.Module):
    """E_C (eq. 5.7): √Q_t · the least signed distance of the body contact vertices to the
    posed object, (T, 1, 1) (`contact_term`)."""

    def __call__(self, params, data, posed=None) -> Array:
        verts = posed_in_views(params, data, posed).vertices[:, data.contact_vertices]
        d = jnp.min(data.sdf(_object_local(params["object"], verts)), axis=-1, keepdims=True)
        return (jnp.sqrt(data.contact.astype(d.dtype))[:, None] * d)[..., None]


def in_contact(data) -> Array:
    """The contact frames, Q_t > 0, (T, 1)."""
    return (data.contact > 0)[:, None]


def contact_term(weight: float = 1.0) -> Term:
    """E_C (eq. 5.7): Q_t · the signed distance of the closest body contact vertex to the
    posed object, (T, 1, 1).

    Q_t says that "one of the hands is in contact with the object" (§5.2.4), not which of
    its vertices: the residual is the least sdf over `data.contact_vertices` (a hand's or
    both hands' vertices; the closest object point of a vertex x is x - sdf ∇sdf, so this
    is the Chamfer distance of eq. 5.7 over the vertices that touch, ICP correspondences
    re-found at every evaluation). Ours, not the thesis's sum over every annotated vertex:
    a sum asks the whole region to lie on the surface, which a rigid SMPL hand holding an
    object by a few fingers cannot do; at the true poses of the tables' development scenes
    (right grip, 9 palm-extreme vertices) it was 72-113 mm off, the true contact vertex not
    among them, so the sum dragged the object (and the hand) away from the truth. Signed, a
    penetrating closest vertex is pushed out.
    """

    return Term("contact", ContactResidual(), weight, mask=in_contact, posed=PosedInViews())


class FloorContactResidual(eqx.Module):
    """E_G and E_C (eq. 5.6-5.7) with the floor {x: up·x = height} as the surface: the
    signed height of the lowest sole point, ρ_σ when `sigma` is given, (T, 1, 1)
    (`floor_contact_term`)."""

    up: tuple[float, float, float] = eqx.field(static=True)
    height: float = eqx.field(static=True)
    points: tuple[int, ...] = eqx.field(static=True)
    offsets: tuple[float, ...] = eqx.field(static=True)
    sigma: float | None = eqx.field(static=True, default=None)

    def __call__(self, params, data, posed=None) -> Array:
        body = posed_in_views(params, data, posed)
        points = np.asarray(self.points, np.int32)
        feet = regress_keypoints(data.regressor, body.vertices, body.joints)[:, points]  # (T, P, 3)
        up, offsets = np.asarray(self.up, np.float64), np.asarray(self.offsets, np.float64)
        above = feet @ jnp.asarray(up, feet.dtype) - jnp.asarray(offsets, feet.dtype) - self.height
        r = jnp.min(above, axis=-1)[:, None, None]
        return r if self.sigma is None else GemanMcClure(self.sigma)(r)


def floor_contact_term(up, height: float, points, offsets, sigma: float | None = None, weight: float = 1.0) -> Term:
    """E_G and E_C (eq. 5.6-5.7) with the floor as the surface touched: per frame, the signed
    height above the floor {x: up·x = height} of the lowest of the feet, (T, 1, 1).

    The feet are the keypoints `points` (indices into `data.regressor`'s rows, e.g. heels
    and toes) less `offsets` (each one's height above the sole when the foot is flat), so
    the residual is the sole's height: negative below the floor (E_G, pushed out) and
    positive above it (E_C, pulled down). As in `contact_term`, only the closest point
    enters (which part of the foot touches is the fit's). E_C applies in contact frames
    (Q_t); where no one says which those are, `sigma` (m) makes it a Geman-McClure cost
    that a frame with both feet in the air (a jump) hardly feels; None: quadratic. Reads
    `CameraData` (the keypoints of `energies.camera.keypoint_term`).
    """
    up = np.asarray(up, np.float64)
    if up.shape != (3,) or not np.linalg.norm(up) > 0:
        raise ValueError(f"floor_contact_term: up must be a non-zero 3-vector; got {up!r}.")
    up = up / np.linalg.norm(up)
    points = np.asarray(points, np.int32).reshape(-1)
    offsets = np.broadcast_to(np.asarray(offsets, np.float64), points.shape)
    fn = FloorContactResidual(tuple(up.tolist()), float(height), tuple(points.tolist()), tuple(offsets.tolist()),
                              None if sigma is None else float(sigma))  # fmt: skip
    return Term("floor", fn, weight, posed=PosedInViews())
