"""MuJoCo scene of a body, a ground plane and rigid objects, written as MJCF.

Collision geometry per bone is fitted to the skinned mesh of one body shape β, all of it
capsules (Huang §2.1's segmentation: each vertex belongs to its bone of largest weight):

- one capsule per bone, around the bone's rest vertices (principal axis, least-squares
  radius, caps at the extreme vertices), and
- for the feet (ankle and foot bones, by default) a flat-bottomed pair: two parallel
  capsules along the long edges of the foot's bounding box, radius half its height. One
  round capsule misplaces a flat sole by 1-2 cm on a tilted foot, which is the very
  effect being measured.

Why capsules and not boxes or convex hulls: MJX's plane-capsule collider returns the
true signed distance at any separation (floating heights come for free and agree with
MuJoCo C to float32 rounding), while its plane-box/plane-mesh collider (`plane_convex`)
is exact only when penetrating: a separated box reports an arbitrary corner (measured
2.4 cm off `mj_forward`), and separated mesh pairs report a 1 m placeholder. Hulls of
skinned vertices also rotate rigidly with one bone, so their extra detail is partly
fictitious, and mesh pairs cost several times more per pair.

Coordinates: jaxmocap's world is y up (SMPL). The MJCF keeps it: gravity is -9.81 along
the ground normal (default +y) and the plane geom is rotated so its z axis is that
normal. Nothing is converted at the boundary.

Every bone and object is a free body (one free joint each, qpos = position and quaternion
(w, x, y, z) per body, bones first in geometry order, then objects): a frame is placed by
writing qpos, and collisions are explicit `<pair>` elements
(ground-bone, bone-object part, object part-ground), so the contact layout is fixed and
self-collisions are never computed. The file loads in plain MuJoCo (`mj_forward`).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Sequence

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..body.kinematics import forward
from ..body.model import SMPL_FEET, Body
from ..objects import RigidObject

__all__ = [
    "Ground",
    "BodyGeometry",
    "fit_body_geometry",
    "scene_mjcf",
    "capsule_plane_distance",
]

#: Bones that get a flat-bottomed capsule pair by default (SMPL names).


class Ground(eqx.Module):
    """The ground plane {x : n·x = height}, n a unit normal (default +y, y up).

    `signed_distance(points)` is n·x - height: positive above, negative below.
    """

    normal: Array
    height: Array

    def __init__(self, height=0.0, normal=(0.0, 1.0, 0.0)):
        normal = jnp.asarray(normal, dtype=float)
        if normal.shape != (3,):
            raise ValueError(f"Ground normal has shape {normal.shape}; expected (3,).")
        norm = jnp.linalg.norm(normal)
        self.normal = normal / norm
        self.height = jnp.asarray(height, dtype=normal.dtype)

    def signed_distance(self, points: Array) -> Array:
        """(..., 3) -> (...,) signed distance to the plane, metres, + above."""
        return points @ self.normal.astype(points.dtype) - self.height.astype(points.dtype)

    def horizontal(self, vectors: Array) -> Array:
        """(..., 3) -> (..., 3) the component of `vectors` in the plane."""
        n = self.normal.astype(vectors.dtype)
        return vectors - (vectors @ n)[..., None] * n


class BodyGeometry(eqx.Module):
    """Collision capsules of one body shape (one per bone, two per sole bone).

    Capsule k sits on bone `bone[k]`; its pose in the bone frame is `pos[k]`, `quat[k]`
    (w, x, y, z), where the bone frame is the rest (zero pose) frame translated to the
    bone's rest joint, so that a posed geom is at R_j (x - J_j) + p_j (global rotation
    R_j, posed joint p_j; the skinning transform of the bone).

    Attributes:
        bone: static tuple, joint index per capsule.
        name: static tuple, geom names (bone name, + "_a"/"_b" for sole pairs).
        pos: (K, 3) capsule centre in the bone frame.
        quat: (K, 4) capsule orientation in the bone frame; its axis is the local z.
        size: (K, 2) radius and half-length of the segment.
        rest_joints: (J, 3) the rest joints J(β) the fit used.
        betas: (B,) the shape the fit used.
        fit_rms: (K,) RMS distance of the bone's rest vertices to its capsule surface(s).
    """

    pos: Array
    quat: Array
    size: Array
    rest_joints: Array
    betas: Array
    fit_rms: Array
    bone: tuple[int, ...] = eqx.field(static=True)
    name: tuple[str, ...] = eqx.field(static=True)

    @property
    def num_geoms(self) -> int:
        return len(self.bone)

    def world_poses(self, joint_rotations: Array, joints: Array) -> tuple[Array, Array]:
        """Capsule centres (..., K, 3) and rotations (..., K, 3, 3) for a posed body.

        Args:
            joint_rotations: (..., J, 3, 3) global bone rotations (`BodyOutput`).
            joints: (..., J, 3) posed joints, translation included.
        """
        from ..rotation import quaternion_to_matrix

        bone = np.asarray(self.bone)
        R = joint_rotations[..., bone, :, :]
        centre = joints[..., bone, :] + jnp.einsum("...kab,kb->...ka", R, self.pos.astype(R.dtype))
        return centre, R @ quaternion_to_matrix(self.quat.astype(R.dtype))

    def capsule_segments(self, joint_rotations: Array, joints: Array) -> tuple[Array, Array, Array]:
        """World end points a, b (..., K, 3) and radii (K,) of the posed capsules."""
        centre, R = self.world_poses(joint_rotations, joints)
        axis = R[..., :, :, 2] * self.size[:, 1, None].astype(R.dtype)
        return centre - axis, centre + axis, self.size[:, 0].astype(R.dtype)


def _capsule_fit(points: np.ndarray, iterations: int = 20) -> tuple[np.ndarray, np.ndarray, float, float, float]:
    """Capsule around `points`: principal axis, then radius and half-length alternated.

    Axis and centre: the principal axis through the middle of the projected extent.
    Then alternate r ← mean distance of the points to the segment (the least-squares
    radius for a fixed segment) and h ← half the extent minus r, so the caps end at the
    extreme vertices. (A free least-squares fit of both end points is degenerate: a
    segment running past the points does not change their distances.)

    Returns (centre, unit axis, radius, half-length, rms distance to the surface).
    """
    mean = points.mean(0)
    _, _, vt = np.linalg.svd(points - mean, full_matrices=False)
    axis = vt[0]
    t = (points - mean) @ axis
    centre = mean + 0.5 * (t.max() + t.min()) * axis
    t = (points - centre) @ axis
    half_extent = 0.5 * float(t.max() - t.min())
    h = half_extent
    for _ in range(iterations):
        dist = np.linalg.norm(points - centre - np.clip(t, -h, h)[:, None] * axis, axis=1)
        r = float(dist.mean())
        h = max(half_extent - r, 0.0)
    dist = np.linalg.norm(points - centre - np.clip(t, -h, h)[:, None] * axis, axis=1)
    rms = float(np.sqrt(np.mean((dist - r) ** 2)))
    return centre, axis, r, h, rms


def _z_to(axis: np.ndarray) -> np.ndarray:
    """Quaternion (w, x, y, z) rotating +z onto the unit vector `axis`."""
    z = np.array([0.0, 0.0, 1.0])
    c = float(z @ axis)
    if c < -1 + 1e-12:
        return np.array([0.0, 1.0, 0.0, 0.0])
    q = np.concatenate([[1.0 + c], np.cross(z, axis)])
    return q / np.linalg.norm(q)


def _segment_distance(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    u = np.clip((points - a) @ ab / max(ab @ ab, 1e-12), 0.0, 1.0)
    return np.linalg.norm(points - a - u[:, None] * ab, axis=1)


def _sole_pair(points: np.ndarray) -> tuple[list, float, float, float]:
    """Two capsules along the long edges of the rest-frame bounding box of `points`.

    Returns ([(centre, axis), (centre, axis)], radius, half-length, rms).
    """
    lo, hi = points.min(0), points.max(0)
    centre, half = 0.5 * (lo + hi), np.maximum(0.5 * (hi - lo), 1e-3)
    long_ax = int(np.argmax(half[[0, 2]]) * 2)  # x or z: the foot's length (z when facing +z)
    side_ax = 2 - long_ax
    r = float(half[1])  # half the height: the flat underside sits on the box's bottom
    h = max(float(half[long_ax]) - r, 0.0)
    offset = max(float(half[side_ax]) - r, 0.0)
    axis = np.eye(3)[long_ax]
    pair = []
    for sign in (-1.0, 1.0):
        c = centre.copy()
        c[side_ax] += sign * offset
        pair.append((c, axis))
    dist = np.minimum(*[_segment_distance(points, c - h * axis, c + h * axis) for c, _ in pair])
    rms = float(np.sqrt(np.mean((dist - r) ** 2)))
    return pair, r, h, rms


def fit_body_geometry(
    body: Body,
    betas=None,
    soles: Sequence[str] = SMPL_FEET,
    min_vertices: int = 8,
) -> BodyGeometry:
    """Fit capsules per bone to the rest mesh of shape `betas`.

    Vertices are assigned to the bone of largest skinning weight; bones with fewer than
    `min_vertices` vertices get no geom (their vertices are covered by neighbours).

    Args:
        body: the body model.
        betas: (B,) shape (default: mean shape).
        soles: names of bones that get a flat-bottomed pair of capsules instead of one
            (default the feet). Pass () for one capsule per bone.
        min_vertices: smallest vertex count that gets a geom.
    Returns:
        BodyGeometry (arrays in JAX's default float dtype; float64 with x64 on).
    """
    unknown = set(soles) - set(body.joint_names)
    if unknown:
        raise ValueError(f"soles names unknown bones {sorted(unknown)}; valid: {list(body.joint_names)}.")
    b = jnp.zeros((body.num_betas,)) if betas is None else jnp.asarray(betas, float).reshape(-1)
    rest = forward(body, jnp.zeros((body.num_joints, 3), body.dtype), b.astype(body.dtype))
    vertices = np.asarray(rest.vertices, np.float64)
    rest_joints = np.asarray(rest.joints, np.float64)
    owner = np.asarray(body.weights).argmax(1)
    bones, names, pos, quat, size, rms = [], [], [], [], [], []
    for j, name in enumerate(body.joint_names):
        pts = vertices[owner == j]
        if len(pts) < min_vertices:
            continue
        if name in soles:
            pair, r, h, err = _sole_pair(pts)
            for (c, axis), suffix in zip(pair, ("a", "b")):
                bones.append(j), names.append(f"{name}_{suffix}")
                pos.append(c - rest_joints[j]), quat.append(_z_to(axis))
                size.append([r, h]), rms.append(err)
        else:
            c, axis, r, h, err = _capsule_fit(pts)
            bones.append(j), names.append(name)
            pos.append(c - rest_joints[j]), quat.append(_z_to(axis))
            size.append([r, h]), rms.append(err)
    f = lambda x: jnp.asarray(np.asarray(x, np.float64))  # noqa: E731
    return BodyGeometry(
        pos=f(pos),
        quat=f(quat),
        size=f(size),
        rest_joints=f(rest_joints),
        betas=f(np.asarray(b)),
        fit_rms=f(rms),
        bone=tuple(bones),
        name=tuple(names),
    )


def _fmt(values) -> str:
    return " ".join(f"{float(v):.9g}" for v in np.ravel(values))


def scene_mjcf(
    geometry: BodyGeometry,
    ground: Ground | None = None,
    objects: Sequence[RigidObject] = (),
    ground_margin: float = 3.0,
) -> str:
    """The MJCF text of the scene: bones as free bodies, the plane, the objects.

    Args:
        geometry: fitted body geometry (`fit_body_geometry`).
        ground: the ground plane (default y = 0, normal +y); None for the default.
        objects: rigid objects, each one free body with its convex parts as mesh geoms.
        ground_margin: contact margin (m) of plane pairs, so that MuJoCo C also reports
            plane distances up to this height (MJX reports them at any height).
    Returns:
        MJCF XML as a string.
    """
    ground = Ground() if ground is None else ground
    n = np.asarray(ground.normal, np.float64)
    root = ET.Element("mujoco", model="jaxmocap_scene")
    ET.SubElement(root, "compiler", angle="radian")
    ET.SubElement(root, "option", gravity=_fmt(-9.81 * n))
    asset = ET.SubElement(root, "asset")
    world = ET.SubElement(root, "worldbody")
    hidden = {"contype": "0", "conaffinity": "0"}  # collisions only through <pair>
    ET.SubElement(
        world,
        "geom",
        name="ground",
        type="plane",
        size="0 0 1",
        pos=_fmt(n * float(ground.height)),
        quat=_fmt(_z_to(n)),
        **hidden,
    )
    for k in range(geometry.num_geoms):
        body = ET.SubElement(world, "body", name=f"bone_{geometry.name[k]}")
        ET.SubElement(body, "freejoint", name=f"bone_{geometry.name[k]}")
        ET.SubElement(
            body,
            "geom",
            name=geometry.name[k],
            type="capsule",
            size=_fmt(geometry.size[k]),
            pos=_fmt(geometry.pos[k]),
            quat=_fmt(geometry.quat[k]),
            **hidden,
        )
    for obj in objects:
        body = ET.SubElement(world, "body", name=f"object_{obj.name}")
        ET.SubElement(body, "freejoint", name=f"object_{obj.name}")
        for i, (v, f) in enumerate(obj.parts):
            mesh = f"{obj.name}_part{i}"
            ET.SubElement(asset, "mesh", name=mesh, vertex=_fmt(v), face=_fmt(f))
            ET.SubElement(body, "geom", name=mesh, type="mesh", mesh=mesh, **hidden)
    contact = ET.SubElement(root, "contact")
    for name in geometry.name:
        ET.SubElement(contact, "pair", geom1="ground", geom2=name, margin=f"{ground_margin:g}")
    for obj in objects:
        for i in range(len(obj.parts)):
            for name in geometry.name:
                ET.SubElement(contact, "pair", geom1=name, geom2=f"{obj.name}_part{i}")
            ET.SubElement(contact, "pair", geom1="ground", geom2=f"{obj.name}_part{i}")
    if not len(asset):
        root.remove(asset)
    ET.indent(root)
    return ET.tostring(root, encoding="unicode")


def capsule_plane_distance(a: Array, b: Array, radius: Array, ground: Ground) -> Array:
    """Analytic signed distance of capsules (end points a, b (..., 3), radius) to the plane.

    min(n·a, n·b) - height - r: the same quantity MJX's plane-capsule collider returns.
    """
    return jnp.minimum(ground.signed_distance(a), ground.signed_distance(b)) - radius
