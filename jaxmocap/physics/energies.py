"""Physics-aware residuals: ground support, foot-contact stationarity, object non-penetration.

Each energy has a kernel on posed points (vertices, joints) and a residual module in the
energy protocol of `jaxmocap.solve` (one row per frame, last axis one observation):

- the residual is an `eqx.Module` whose fields are static configuration only (vertex ids,
  joint ids, margins), so equal configurations compare and hash equal and a rebuilt
  problem reuses the compiled solve;
- `params["pose"]` reaches it as local rotation matrices (T, 24, 3, 3) (a rotation key of
  the `Problem`), `params["trans"]` (T, 3) as given; the posed body (`jaxmocap.energies.posed.PosedBody`, `Term.posed`) reaches it as a third
  argument, one forward pass per evaluation shared by all terms;
- body, ground, contact weights, object SDF and pose are data, read by attribute
  (`PhysicsData`): new data of the same shapes does not recompile. IMU and physics terms
  compose in one `Problem(..., rotations=("pose",))` with
  `CombinedData((inertial_data, physics_data))`.

`*_term` wraps a residual in a `Term` (name, weight, bandwidth, reads). Weights are scales
on the residuals (`Term(weight=...)`), never special cases.

Distances are analytic where they are better than MJX's:
- ground: the signed distance of every vertex to the plane, n·v - h (exact, smooth,
  one-sided hinge: zero gradient above the floor);
- objects: a signed distance field of the object mesh, precomputed on a grid from the
  trimesh triangles (exact point-triangle distances, sign by the generalised winding
  number) and trilinearly interpolated, so gradients are finite and continuous;
- `MJXGroundResidual`: the same ground term through MJX's plane-capsule contacts, for
  comparison (capsule-level rather than vertex-level; the plane-capsule distance is
  exact, so its gradients are finite).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..body.kinematics import forward_kinematics
from ..body.model import SMPL_FEET, SMPL_JOINT_NAMES, SMPL_PARENTS, Body
from ..energies.posed import PosedBody
from ..objects import ObjectSDF
from ..solve import Term
from .mjcf import Ground

__all__ = [
    "PhysicsData",
    "ground_support",
    "GroundSupportResidual",
    "ground_support_term",
    "detect_foot_contact",
    "foot_stationarity",
    "FootStationarityResidual",
    "foot_stationarity_term",
    "object_penetration",
    "ObjectPenetrationResidual",
    "object_penetration_term",
    "MJXGroundResidual",
    "mjx_ground_term",
]

#: Joints used as heel (ankles) and toe (feet) points for foot contact.


class PhysicsData(eqx.Module):
    """What the physics residuals read from `data` (by attribute; None where unused).

    body: the body model (ground, contact, object terms).
    betas: (B,) or (T, B) shape; None for the mean shape.
    ground: the plane (ground support).
    contact_weights: (T-1, F) or (T, F) foot-contact weights of the steps t -> t+1
        (`detect_foot_contact`; a last row is ignored).
    sdf: the object's `ObjectSDF`; object_rotation (T, 3, 3) and object_position (T, 3)
        its world-from-object pose per frame.
    scene: the MJX `Scene` (`MJXGroundResidual`).
    """

    body: Body | None = None
    betas: Array | None = None
    ground: Ground | None = None
    contact_weights: Array | None = None
    sdf: ObjectSDF | None = None
    object_rotation: Array | None = None
    object_position: Array | None = None
    scene: Any = None


def _ids(ids) -> tuple[int, ...] | None:
    return None if ids is None else tuple(int(i) for i in np.asarray(ids).reshape(-1))


def _posed(params, data, posed):
    """The posed body as the problem passes it, or (a residual called on its own) its own pass."""
    return PosedBody()(params, data) if posed is None else posed


def _vertices(params, data, posed, ids) -> Array:
    """Posed vertices (T, N, 3) of `data.body` (the shared forward pass), subset `ids`."""
    vertices = _posed(params, data, posed).vertices
    return vertices if ids is None else vertices[..., np.asarray(ids), :]


# --- ground support ------------------------------------------------------------------


def ground_support(points: Array, ground: Ground, margin: float = 0.0) -> Array:
    """Hinge residual max(0, margin - (n·x - h)) per point: (..., N, 3) -> (..., N).

    Zero for points at least `margin` above the plane; the penetration depth below it
    (Huang eq. 5.6's E_G: nothing below the ground).
    """
    return jax.nn.relu(margin - ground.signed_distance(points))


class GroundSupportResidual(eqx.Module):
    """`ground_support` of the posed vertices against `data.ground`: (T, N, 1).

    vertex_ids: static, restrict to these vertices (e.g. soles); None for all.
    margin: static, keep points this far above the plane (m).
    Reads data.body, data.betas, data.ground.
    """

    vertex_ids: tuple[int, ...] | None = eqx.field(static=True, default=None, converter=_ids)
    margin: float = eqx.field(static=True, default=0.0, converter=float)

    def __call__(self, params, data, posed=None) -> Array:
        vertices = _vertices(params, data, posed, self.vertex_ids)
        return ground_support(vertices, data.ground, self.margin)[..., None]


def ground_support_term(vertex_ids=None, margin: float = 0.0, weight=1.0, loss=None, name: str = "ground") -> Term:
    """`GroundSupportResidual` as a per-frame `Term`; it reads every unknown (through the
    pose blend shapes every vertex depends on every joint)."""
    return Term(name, GroundSupportResidual(vertex_ids, margin), weight, 0, loss, posed=PosedBody())


# --- foot contact ---------------------------------------------------------------------


def detect_foot_contact(
    foot_positions,
    ground: Ground,
    fps: float,
    height: float = 0.06,
    speed: float = 0.4,
    softness: float = 0.2,
) -> Array:
    """Soft foot-contact weights from the motion itself (no annotation).

    A foot point is in contact when it is low (height above the plane < `height`) and
    slow (speed < `speed` m/s): the two conditions of the zero-velocity detectors used
    for foot contacts (von Marcard §3.5 suggests detecting contacts from the motion and
    fixing contact points in time). Each condition is a logistic step of relative width
    `softness`; the weight is their product, under `stop_gradient`.

    Args:
        foot_positions: (T, F, 3) heel/toe points.
        ground: the plane; fps: frame rate.
    Returns:
        (T-1, F) weights in [0, 1] for the steps t -> t+1.
    """
    p = jnp.asarray(foot_positions)
    h = ground.signed_distance(p)
    h_step = jnp.maximum(h[1:], h[:-1])
    v = jnp.linalg.norm(ground.horizontal(p[1:] - p[:-1]), axis=-1) * fps
    low = jax.nn.sigmoid((height - h_step) / (softness * height))
    slow = jax.nn.sigmoid((speed - v) / (softness * speed))
    return jax.lax.stop_gradient(low * slow)


def foot_stationarity(foot_positions: Array, weights: Array) -> Array:
    """Weighted foot displacement w_t (p_{t+1} - p_t): (T, F, 3), (T-1, F) -> (T-1, F, 3).

    A foot in contact does not slide (nor lift): the whole displacement is penalised.
    """
    return weights[..., None] * (foot_positions[1:] - foot_positions[:-1])


def _joint_ids(joints) -> tuple[int, ...]:
    return tuple(SMPL_JOINT_NAMES.index(j) if isinstance(j, str) else int(j) for j in joints)


class FootStationarityResidual(eqx.Module):
    """`foot_stationarity` of the posed foot joints: (T, F, 3), bandwidth 1 (row t:
    frames t and t+1; the last row is zero padding so there is one row per frame).

    joints: static, the F foot joint indices (default `SMPL_FEET`).
    Reads data.body, data.betas, data.contact_weights.
    """

    joints: tuple[int, ...] = eqx.field(static=True, default=_joint_ids(SMPL_FEET), converter=_joint_ids)

    def __call__(self, params, data, posed=None) -> Array:
        joints = _posed(params, data, posed).joints
        feet = joints[:, np.asarray(self.joints)]
        weights = data.contact_weights[: feet.shape[0] - 1].astype(feet.dtype)
        r = foot_stationarity(feet, weights)
        return jnp.concatenate([r, jnp.zeros_like(r[:1])], 0)


def foot_stationarity_term(
    joints: Sequence[str | int] = SMPL_FEET, weight=1.0, loss=None, name: str = "contact"
) -> Term:
    """`FootStationarityResidual` as a `Term`, bandwidth 1, reading the foot joints'
    chains and the translation (joint names are SMPL's)."""
    fn = FootStationarityResidual(joints)
    chains = set()
    for j in fn.joints:
        while j >= 0:
            chains.add(j)
            j = SMPL_PARENTS[j]
    return Term(name, fn, weight, 1, loss, reads=(("pose", tuple(sorted(chains))), ("trans", None)), posed=PosedBody())


# --- objects --------------------------------------------------------------------------


def object_penetration(points: Array, sdf: ObjectSDF, rotation: Array, position: Array, margin: float = 0.0) -> Array:
    """Hinge max(0, margin - sdf(Rᵀ(x - t))) of points (..., N, 3) against a posed object.

    rotation (..., 3, 3) and position (..., 3): world-from-object pose.
    """
    local = jnp.einsum("...ba,...nb->...na", rotation, points - position[..., None, :])
    return jax.nn.relu(margin - sdf(local))


class ObjectPenetrationResidual(eqx.Module):
    """`object_penetration` of the posed vertices against one rigid object: (T, N, 1).

    vertex_ids: static, restrict to these vertices; None for all. margin: static (m).
    Reads data.body, data.betas, data.sdf, data.object_rotation (T, 3, 3),
    data.object_position (T, 3).
    """

    vertex_ids: tuple[int, ...] | None = eqx.field(static=True, default=None, converter=_ids)
    margin: float = eqx.field(static=True, default=0.0, converter=float)

    def __call__(self, params, data, posed=None) -> Array:
        vertices = _vertices(params, data, posed, self.vertex_ids)
        dtype = vertices.dtype
        rotation, position = data.object_rotation.astype(dtype), data.object_position.astype(dtype)
        return object_penetration(vertices, data.sdf, rotation, position, self.margin)[..., None]


def object_penetration_term(vertex_ids=None, margin: float = 0.0, weight=1.0, loss=None, name: str = "object") -> Term:
    """`ObjectPenetrationResidual` as a per-frame `Term`."""
    return Term(name, ObjectPenetrationResidual(vertex_ids, margin), weight, 0, loss, posed=PosedBody())


# --- MJX variant -----------------------------------------------------------------------


class MJXGroundResidual(eqx.Module):
    """Ground support through MJX contacts: (T, K, 1) = max(0, -d_k), d_k the
    plane-capsule distance of capsule k of `data.scene` (`mjx.collision`), for comparison
    with the vertex term. The capsules are fitted to one shape: the scene's rest joints
    are used, not data.body/betas. Reads data.scene.
    """

    def __call__(self, params, data) -> Array:
        from .checker import contact_distances_posed

        scene = data.scene
        local = params["pose"]
        rest = scene.geometry.rest_joints.astype(local.dtype)
        rotations, joints = forward_kinematics(scene.parents, local, rest)
        if "trans" in params:
            joints = joints + params["trans"][:, None, :]
        d = jax.vmap(lambda R, p: contact_distances_posed(scene, R, p).ground)(rotations, joints)
        return jax.nn.relu(-d.astype(local.dtype))[..., None]


def mjx_ground_term(weight=1.0, loss=None, name: str = "mjx_ground") -> Term:
    """`MJXGroundResidual` as a per-frame `Term`."""
    return Term(name, MJXGroundResidual(), weight, 0, loss)
