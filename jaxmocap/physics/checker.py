"""Batched collision checking with MuJoCo MJX: per-frame contact distances of a scene.

`make_scene` fits the body geometry, writes the MJCF (`mjcf.scene_mjcf`) and loads it in
MJX. `contact_distances` is the unbatched kernel, one frame: forward kinematics → qpos of
the free bodies → `mjx.kinematics` → `mjx.collision` → the minimum signed distance per collision
pair (bone-ground, bone-object, object-ground). `check` vmaps it over any batch shape
(frames, sequences), in chunks to bound memory.

Distances are signed, metres, negative = penetration. Plane-capsule pairs (all of the
body's ground pairs) are true signed distances at any separation. Mesh pairs
(bone-object, object-ground) are exact only when touching or penetrating; when separated
MJX reports a placeholder (1 m in mujoco-mjx 3.17), so read them as penetration depths
(`jnp.minimum(d, 0)`), and use the vertex SDF of `jaxmocap.objects.ObjectSDF` for near-contact.
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from .._checks import check_finite
from .._compat import mjx_contacts
from ..body.kinematics import forward_kinematics
from ..body.model import SMPL_FEET, Body
from ..rotation import axis_angle_to_matrix, matrix_to_quaternion
from ..objects import RigidObject
from .mjcf import BodyGeometry, Ground, fit_body_geometry, scene_mjcf

__all__ = [
    "Scene",
    "ContactDistances",
    "make_scene",
    "contact_distances",
    "contact_distances_posed",
    "check",
    "pose_bones",
]


class ContactDistances(eqx.Module):
    """Minimum signed distance per collision pair of one frame (or a batch of frames).

    A pair MJX reports no contact for (none in this build) would read +inf.

    Attributes:
        ground: (..., K) bone geom k to the ground plane (true distance: < 0 below).
        obj: (..., K, O) bone geom k to object o (≤ 0 meaningful; placeholder if apart).
        object_ground: (..., O) object o to the ground (≤ 0 meaningful).
    """

    ground: Array
    obj: Array
    object_ground: Array


class Scene(eqx.Module):
    """A body shape, a ground plane and rigid objects, loaded in MJX.

    Leaves: the fitted `geometry`, the `ground`, the MJX model and its zero data.
    Static: the MJCF text, the kinematic tree, the contact-slot lookup table.
    """

    geometry: BodyGeometry
    ground: Ground
    mjx_model: object
    mjx_data: object
    xml: str = eqx.field(static=True)
    parents: tuple[int, ...] = eqx.field(static=True)
    joint_names: tuple[str, ...] = eqx.field(static=True)
    object_names: tuple[str, ...] = eqx.field(static=True)
    part_object: tuple[int, ...] = eqx.field(static=True)
    slot_table: tuple[tuple[int, ...], ...] = eqx.field(static=True)

    @property
    def num_objects(self) -> int:
        return len(self.object_names)

    def capsules_of(self, bone: str) -> list[int]:
        """Indices of the capsules on the bone called `bone`."""
        if bone not in self.joint_names:
            raise ValueError(f"No bone {bone!r}; this scene has {list(self.joint_names)}.")
        j = self.joint_names.index(bone)
        return [k for k, b in enumerate(self.geometry.bone) if b == j]

    def mj_model(self):
        """The scene as a plain `mujoco.MjModel` (for `mj_forward`, viewers)."""
        import mujoco

        return mujoco.MjModel.from_xml_string(self.xml)


def _import_mjx():
    """`mujoco.mjx`, without its "Failed to import warp" prints: warp is an optional GPU
    backend we do not use, so its absence is not worth a line on every run."""
    import contextlib
    import io
    import sys

    if "mujoco.mjx" in sys.modules:
        return sys.modules["mujoco.mjx"]
    captured = io.StringIO()
    with contextlib.redirect_stdout(captured):
        from mujoco import mjx
    rest = [
        ln
        for ln in captured.getvalue().splitlines()
        if not ln.startswith(("Failed to import warp", "Failed to import mujoco_warp"))
    ]
    if rest:
        print("\n".join(rest))
    return mjx


def make_scene(
    body: Body,
    betas=None,
    ground: Ground | None = None,
    objects: Sequence[RigidObject] = (),
    soles: Sequence[str] = SMPL_FEET,
    geometry: BodyGeometry | None = None,
) -> Scene:
    """Fit the body geometry of shape `betas`, write the MJCF and load it in MJX.

    Args:
        body: the body model.
        betas: (B,) shape; default the mean shape.
        ground: the ground plane; default y = 0 with normal +y.
        objects: rigid objects (`jaxmocap.objects.RigidObject`).
        soles: bones that get a flat-bottomed capsule pair (default the feet).
        geometry: a ready `BodyGeometry` (then `betas` and `soles` are ignored).
    """
    import mujoco

    mjx = _import_mjx()
    geometry = fit_body_geometry(body, betas, soles=soles) if geometry is None else geometry
    ground = Ground() if ground is None else ground
    xml = scene_mjcf(geometry, ground, objects)
    m = mujoco.MjModel.from_xml_string(xml)
    K = geometry.num_geoms
    gid = lambda name: mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, name)  # noqa: E731
    parts = [(o, f"{obj.name}_part{i}") for o, obj in enumerate(objects) for i in range(len(obj.parts))]
    P = len(parts)
    # Slot layout: [ground-bone (K) | bone-part (K·P) | ground-part (P)]; unused = -1.
    table = -np.ones((m.ngeom, m.ngeom), np.int64)
    g0 = gid("ground")
    for k, name in enumerate(geometry.name):
        table[g0, gid(name)] = table[gid(name), g0] = k
        for p, (_, part) in enumerate(parts):
            table[gid(name), gid(part)] = table[gid(part), gid(name)] = K + k * P + p
    for p, (_, part) in enumerate(parts):
        table[g0, gid(part)] = table[gid(part), g0] = K + K * P + p
    mx = mjx.put_model(m)
    return Scene(
        geometry=geometry,
        ground=ground,
        mjx_model=mx,
        mjx_data=mjx.make_data(mx),
        xml=xml,
        parents=tuple(body.parents),
        joint_names=tuple(body.joint_names),
        object_names=tuple(o.name for o in objects),
        part_object=tuple(o for o, _ in parts),
        slot_table=tuple(map(tuple, table.tolist())),
    )


def pose_bones(scene: Scene, pose: Array, trans: Array) -> tuple[Array, Array]:
    """Global bone rotations (J, 3, 3) and joints (J, 3) of one frame (FK only, no mesh)."""
    local = axis_angle_to_matrix(pose)
    rest = scene.geometry.rest_joints.astype(local.dtype)
    rotations, joints = forward_kinematics(scene.parents, local, rest)
    return rotations, joints + trans


def contact_distances(
    scene: Scene,
    pose: Array,
    trans: Array,
    object_rotations: Array | None = None,
    object_positions: Array | None = None,
) -> ContactDistances:
    """Contact distances of one frame through MJX collision detection.

    Args:
        scene: the scene (`make_scene`).
        pose: (J, 3) axis-angle joint rotations; trans: (3,) root translation.
        object_rotations: (O, 3, 3) world-from-object rotations (default identity).
        object_positions: (O, 3) object origins in the world (default zero).
    Returns:
        ContactDistances for this frame.
    """
    rotations, joints = pose_bones(scene, pose, trans)
    return contact_distances_posed(scene, rotations, joints, object_rotations, object_positions)


def contact_distances_posed(
    scene: Scene,
    rotations: Array,
    joints: Array,
    object_rotations: Array | None = None,
    object_positions: Array | None = None,
) -> ContactDistances:
    """`contact_distances` of one frame from its global bone rotations (J, 3, 3) and
    joints (J, 3) (translation included, as `pose_bones` returns them)."""
    mjx = _import_mjx()

    g = scene.geometry
    K, O = g.num_geoms, scene.num_objects
    P = len(scene.part_object)
    bone = np.asarray(g.bone)
    pos, quat = joints[bone], matrix_to_quaternion(rotations[bone])
    if O:
        R_o = jnp.broadcast_to(jnp.eye(3), (O, 3, 3)) if object_rotations is None else object_rotations
        p_o = jnp.zeros((O, 3)) if object_positions is None else object_positions
        pos = jnp.concatenate([pos, p_o.astype(pos.dtype)])
        quat = jnp.concatenate([quat, matrix_to_quaternion(R_o.astype(pos.dtype))])
    d0 = scene.mjx_data
    qpos = jnp.concatenate([pos, quat], -1).reshape(-1).astype(d0.qpos.dtype)
    d = d0.replace(qpos=qpos)
    d = mjx.collision(scene.mjx_model, mjx.kinematics(scene.mjx_model, d))
    contact = mjx_contacts(d)
    table = jnp.asarray(np.asarray(scene.slot_table))
    slot = table[contact.geom[:, 0], contact.geom[:, 1]]
    num_slots = K + K * P + P
    slot = jnp.where(slot < 0, num_slots, slot)  # a pair outside the table: dropped
    mins = jax.ops.segment_min(contact.dist, slot, num_segments=num_slots + 1)[:num_slots]
    ground = mins[:K]
    part_object = np.asarray(scene.part_object, np.int64)
    obj = jnp.full((K, O), jnp.inf, mins.dtype)
    obj_ground = jnp.full((O,), jnp.inf, mins.dtype)
    if P:
        by_part = mins[K : K + K * P].reshape(K, P)
        obj = jax.ops.segment_min(by_part.T, part_object, num_segments=O).T
        obj_ground = jax.ops.segment_min(mins[K + K * P :], part_object, num_segments=O)
    return ContactDistances(ground=ground, obj=obj, object_ground=obj_ground)


@eqx.filter_jit
def _check_flat(scene, pose, trans, rot, pos, chunk):
    def one(x):
        return contact_distances(scene, *x)

    xs = (pose, trans, rot, pos)
    n = pose.shape[0]
    if n <= chunk:
        return jax.vmap(one)(xs)
    # Pad to whole chunks (repeating frame 0), vmap within a chunk, scan over chunks.
    m = -(-n // chunk) * chunk
    padded = jax.tree.map(lambda x: jnp.concatenate([x, jnp.broadcast_to(x[:1], (m - n, *x.shape[1:]))]), xs)
    chunks = jax.tree.map(lambda x: x.reshape(m // chunk, chunk, *x.shape[1:]), padded)
    out = jax.lax.map(jax.vmap(one), chunks)
    return jax.tree.map(lambda x: x.reshape(m, *x.shape[2:])[:n], out)


def check(
    scene: Scene,
    poses,
    trans,
    object_rotations=None,
    object_positions=None,
    chunk: int = 4096,
) -> ContactDistances:
    """`contact_distances` over any batch shape: vmapped, in chunks of `chunk` frames.

    Args:
        scene: the scene.
        poses: (*batch, J, 3) axis-angle poses, e.g. (T, 24, 3) or (S, T, 24, 3).
        trans: (*batch, 3) root translations.
        object_rotations: (*batch, O, 3, 3), default identity.
        object_positions: (*batch, O, 3), default zero.
        chunk: frames vmapped at once; larger batches run as a `lax.map` over chunks.
    Returns:
        ContactDistances with leading axes `batch`.
    """
    poses = jnp.asarray(poses)
    dtype = poses.dtype if jnp.issubdtype(poses.dtype, jnp.floating) else jnp.float32
    J = len(scene.parents)
    if poses.ndim < 2 or poses.shape[-2:] != (J, 3):
        raise ValueError(f"poses has shape {poses.shape}; expected (*batch, {J}, 3).")
    batch = poses.shape[:-2]
    trans = jnp.asarray(trans, dtype)
    try:
        trans = jnp.broadcast_to(trans, (*batch, 3))
    except (ValueError, TypeError):
        raise ValueError(
            f"trans has shape {trans.shape}; expected (*batch, 3) = {(*batch, 3)} to match poses."
        ) from None
    if int(np.prod(batch)) == 0:
        raise ValueError(f"poses has shape {poses.shape}: no frames to check.")
    if not isinstance(chunk, (int, np.integer)) or chunk < 1:
        raise ValueError(f"chunk must be an int >= 1, got {chunk!r}.")
    # A NaN pose gives NaN distances that every statistic would silently propagate.
    check_finite("poses", poses)
    check_finite("trans", trans)
    O = scene.num_objects
    rot = (
        jnp.broadcast_to(jnp.eye(3, dtype=dtype), (*batch, O, 3, 3))
        if object_rotations is None
        else jnp.broadcast_to(jnp.asarray(object_rotations, dtype), (*batch, O, 3, 3))
    )
    pos = (
        jnp.zeros((*batch, O, 3), dtype)
        if object_positions is None
        else jnp.broadcast_to(jnp.asarray(object_positions, dtype), (*batch, O, 3))
    )
    n = int(np.prod(batch))
    out = _check_flat(
        scene,
        poses.reshape(n, J, 3).astype(dtype),
        trans.reshape(n, 3),
        rot.reshape(n, O, 3, 3),
        pos.reshape(n, O, 3),
        chunk,
    )
    return jax.tree.map(lambda x: x.reshape(*batch, *x.shape[1:]), out)
