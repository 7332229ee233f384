"""Rigid objects: one mesh type for sensors, physics and interaction energies.

Frame convention: the object frame is the mesh's own coordinates (the bundled box, ball
and cylinder are centred at the origin). A pose (R, t) maps object points x to world
points R x + t, in simulation (`sensors.objects.ObjectTrajectory`), in the MJX checker
(`physics.check(..., object_rotations, object_positions)`) and in the SDF penalties
(`physics.energies.object_penetration`) alike.

Derived geometry is built lazily and kept: the convex parts MJX collides
(`RigidObject.parts`) and signed distance grids (`RigidObject.sdf`).
"""

from __future__ import annotations

import dataclasses
import functools

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.scipy.ndimage import map_coordinates

__all__ = ["ObjectSDF", "RigidObject", "Symmetry", "rotation_error_deg"]


@dataclasses.dataclass(frozen=True, eq=False)
class RigidObject:
    """A rigid mesh in its own frame: vertices (N, 3), faces (F, 3), a name.

    Attributes:
        vertices, faces, name: the mesh.
        decompose: how `parts` splits a non-convex mesh: "hull" (one convex hull),
            "decompose" (trimesh's convex decomposition; needs the optional `coacd`),
            or "auto" (the mesh itself if convex, else decompose).
        given_parts: convex parts given by the user (overrides `decompose`).
    """

    vertices: np.ndarray
    faces: np.ndarray
    name: str = "object"
    decompose: str = "auto"
    given_parts: tuple | None = None

    def __post_init__(self):
        if self.decompose not in ("auto", "hull", "decompose"):
            raise ValueError(f"decompose must be 'auto', 'hull' or 'decompose', got {self.decompose!r}.")
        v, f = np.asarray(self.vertices), np.asarray(self.faces)
        if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3 or len(v) == 0:
            raise ValueError(
                f"object {self.name!r}: vertices must be (N, 3) and faces (F, 3); got {v.shape} and {f.shape}."
            )

    @classmethod
    def from_trimesh(cls, mesh, name: str = "object", decompose: str = "auto") -> RigidObject:
        """From a `trimesh.Trimesh`, or a list of them taken as the convex parts."""
        import trimesh

        if isinstance(mesh, (list, tuple)):
            hulls = [m.convex_hull for m in mesh]
            whole = trimesh.util.concatenate(list(mesh))
            parts = tuple((np.asarray(h.vertices, np.float64), np.asarray(h.faces, np.int64)) for h in hulls)
            return cls(
                np.asarray(whole.vertices, np.float64), np.asarray(whole.faces, np.int64), name, decompose, parts
            )
        return cls(np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64), name, decompose)

    @classmethod
    def box(cls, extents=(0.3, 0.2, 0.2), name: str = "box") -> RigidObject:
        import trimesh

        return cls.from_trimesh(trimesh.creation.box(extents=extents), name)

    @classmethod
    def ball(cls, radius: float = 0.11, name: str = "ball") -> RigidObject:
        import trimesh

        return cls.from_trimesh(trimesh.creation.icosphere(subdivisions=2, radius=radius), name)

    @classmethod
    def cylinder(cls, radius: float = 0.04, height: float = 0.2, name: str = "bottle") -> RigidObject:
        import trimesh

        return cls.from_trimesh(trimesh.creation.cylinder(radius=radius, height=height, sections=16), name)

    @classmethod
    def chair(
        cls,
        width: float = 0.40,
        depth: float = 0.40,
        seat_height: float = 0.45,
        height: float = 0.80,
        thickness: float = 0.04,
        gap: float = 0.004,
        name: str = "chair",
    ) -> RigidObject:
        """A non-convex chair of six disjoint boxes (seat, backrest, four legs), its own parts.

        Seat `width` (x) by `depth` (z) with its top at `seat_height`, backrest at -z up to
        `height`; seat, backrest and legs `thickness` thick. Neighbouring boxes are `gap`
        apart (>= 2 mm): overlapping or touching boxes would make the concatenated mesh's
        inside test (ray parity) wrong. Centred on its bounding box like the other shapes.
        """
        import trimesh

        for k, v in (("width", width), ("depth", depth), ("seat_height", seat_height),
                     ("height", height), ("thickness", thickness)):  # fmt: skip
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"chair: {k} must be a positive length (m), got {v!r}.")
        if not (np.isfinite(gap) and gap >= 0.002):
            raise ValueError(f"chair: gap must be >= 0.002 m so that the parts do not touch, got {gap!r}.")
        if not (2 * thickness + gap < min(width, depth) and 2 * thickness + gap < seat_height
                and seat_height + gap + thickness < height):  # fmt: skip
            raise ValueError(
                f"chair: thickness {thickness} and gap {gap} do not fit a {width} x {depth} m seat at "
                f"{seat_height} m with a {height} m backrest."
            )

        def block(lo, hi):
            lo, hi = np.asarray(lo, float), np.asarray(hi, float)
            return trimesh.creation.box(
                extents=hi - lo, transform=trimesh.transformations.translation_matrix((lo + hi) / 2)
            )

        w, d, s, c = width / 2, depth / 2, seat_height, height / 2
        leg_top = s - thickness - gap
        boxes = [
            block((-w, s - thickness, -d), (w, s, d)),  # seat
            block((-w, s + gap, -d), (w, height, -d + thickness)),
        ]  # backrest on the seat's back edge
        for x in (-w, w - thickness):
            for z in (-d, d - thickness):
                boxes.append(block((x, 0.0, z), (x + thickness, leg_top, z + thickness)))
        for b in boxes:
            b.apply_translation((0.0, -c, 0.0))
        return cls.from_trimesh(boxes, name)

    @functools.cached_property
    def mesh(self):
        """The `trimesh.Trimesh` (built once)."""
        import trimesh

        return trimesh.Trimesh(self.vertices, self.faces, process=False)

    @functools.cached_property
    def parts(self) -> tuple[tuple[np.ndarray, np.ndarray], ...]:
        """Convex parts (vertices, faces) in the object frame, as MJX collides them."""
        import trimesh

        if self.given_parts is not None:
            return self.given_parts
        mesh = self.mesh
        if self.decompose == "hull" or (self.decompose == "auto" and mesh.is_convex):
            hulls = [mesh.convex_hull]
        else:
            try:
                pieces = mesh.convex_decomposition()
            except Exception as e:  # missing optional dependency or failed decomposition
                raise ValueError(
                    f"object {self.name!r} is not convex and convex decomposition failed ({e}); "
                    "install `coacd`, pass decompose='hull', or give a list of convex parts."
                ) from None
            pieces = pieces if isinstance(pieces, list) else [pieces]
            hulls = [trimesh.Trimesh(**p).convex_hull if isinstance(p, dict) else p.convex_hull for p in pieces]
        return tuple((np.asarray(h.vertices, np.float64), np.asarray(h.faces, np.int64)) for h in hulls)

    def sdf(self, resolution: int = 32, padding: float = 0.05) -> ObjectSDF:
        """Its signed distance field on a grid (built once per setting; see `ObjectSDF`)."""
        return _sdf(self, int(resolution), float(padding))

    @functools.cached_property
    def symmetry(self) -> Symmetry:
        """The rotations that map the mesh onto itself (`Symmetry`), found from its geometry
        (built once): a box's 180° flips about its axes (and 90° turns about an axis whose
        two cross-section sides are equal), a cylinder's turns about its axis and its
        end-over-end flip, any rotation of a ball, only the identity for a chair."""
        return _symmetry(self)


@dataclasses.dataclass(frozen=True)
class Symmetry:
    """Proper rotations S about `centre` (object frame) with S(x - c) + c on the surface for
    every surface point x: the poses (R, t) and (R S, t + R(c - S c)) look the same.

    rotations: (K, 3, 3) the discrete ones, identity first (with `axis`: the identity and,
        if any, the flips that reverse the axis); axis: (3,) unit axis of a continuous
        symmetry (every turn about it), or None; spherical: every rotation.
    """

    centre: np.ndarray
    rotations: np.ndarray
    axis: np.ndarray | None = None
    spherical: bool = False


def _maps_onto(mesh, points, centre, S, tol) -> bool:
    """Whether S(points - c) + c all lie within `tol` of the mesh surface."""
    moved = (points - centre) @ S.T + centre
    _, dist, _ = mesh.nearest.on_surface(moved)
    return bool(dist.max() <= tol)


def _about(axis, angle) -> np.ndarray:
    from .rotation import host_exp

    return host_exp(np.asarray(axis, np.float64) * angle)


def _symmetry(obj: RigidObject, rel_tol: float = 0.01) -> Symmetry:
    import trimesh

    mesh = obj.mesh
    lo, hi = mesh.vertices.min(0), mesh.vertices.max(0)
    centre = (lo + hi) / 2
    # A 1 % of the diagonal tolerance accepts faceting (a 16-gon cylinder turned half a
    # step moves its vertices 0.8 mm off a 4 cm radius) and rejects real asymmetry (a
    # 30 x 20 x 20 cm box turned 45° about its long axis: 41 mm).
    tol = rel_tol * float(np.linalg.norm(hi - lo))
    points = np.concatenate([mesh.vertices, trimesh.sample.sample_surface_even(mesh, 300, seed=0)[0]])
    # Candidate axes: the mesh's own axes (the bundled shapes are axis-aligned) and its
    # principal axes of inertia.
    _, vecs = np.linalg.eigh(np.asarray(mesh.moment_inertia if mesh.is_volume else np.cov(points.T)))
    axes = [a / np.linalg.norm(a) for a in np.concatenate([np.eye(3), vecs.T])]
    odd = (0.37, 1.9)  # turns that no discrete symmetry of a mesh this coarse contains exactly
    continuous = [a for a in axes if all(_maps_onto(mesh, points, centre, _about(a, x), tol) for x in odd)]
    if len(continuous) >= 2 and abs(continuous[0] @ continuous[-1]) < 0.99:
        return Symmetry(centre, np.eye(3)[None], None, True)
    flips = (
        [_about(a, np.pi) for a in axes] + [_about(a, np.pi / 2) for a in axes] + [_about(a, -np.pi / 2) for a in axes]
    )
    if continuous:
        axis = continuous[0]
        reverse = [S for S in flips if S @ axis @ axis < -0.99 and _maps_onto(mesh, points, centre, S, tol)]
        return Symmetry(centre, np.stack([np.eye(3)] + reverse[:1]), axis, False)
    found = [np.eye(3)]
    for S in flips:
        if _maps_onto(mesh, points, centre, S, tol) and all(np.abs(S - F).max() > 1e-6 for F in found):
            found.append(S)
    # Close the set under composition (two flips about perpendicular axes give the third).
    while True:
        new = [A @ B for A in found for B in found]
        extra = [S for S in new if all(np.abs(S - F).max() > 1e-6 for F in found)]
        if not extra:
            break
        found.append(extra[0])
    return Symmetry(centre, np.stack(found))


def rotation_error_deg(pred_R, true_R, symmetry: Symmetry | None = None) -> np.ndarray:
    """Geodesic angle (°) between rotations (..., 3, 3), the least over the object's
    symmetries: min_S ∠(R_pred, R_true S). With a continuous axis a this is the angle
    between the world axes R_pred a and R_true S a (the closest turn about a takes up
    the rest); spherical: 0."""
    pred_R, true_R = np.asarray(pred_R, np.float64), np.asarray(true_R, np.float64)
    if symmetry is None:
        group = np.eye(3)[None]
    elif symmetry.spherical:
        return np.zeros(np.broadcast_shapes(pred_R.shape, true_R.shape)[:-2])
    else:
        group = symmetry.rotations
    # atan2(sin, cos) rather than arccos(cos): exact near 0 (a flipped-back fit scores 0, not 1e-6°).
    if symmetry is not None and symmetry.axis is not None:
        a = np.asarray(symmetry.axis, np.float64)
        pa = pred_R @ a
        ta = np.stack([true_R @ (S @ a) for S in group])
        angle = np.arctan2(np.linalg.norm(np.cross(pa, ta), axis=-1), np.sum(pa * ta, -1))
    else:
        true_S = np.einsum("...ab,kbc->k...ac", true_R, group)
        rel = np.einsum("...ba,k...bc->k...ac", pred_R, true_S)
        cos = (np.trace(rel, axis1=-2, axis2=-1) - 1) / 2
        skew = rel - np.swapaxes(rel, -1, -2)
        sin = 0.5 * np.linalg.norm(np.stack([skew[..., 2, 1], skew[..., 0, 2], skew[..., 1, 0]], -1), axis=-1)
        angle = np.arctan2(sin, cos)
    return np.degrees(angle).min(0)


@functools.lru_cache(maxsize=32)
def _sdf(obj: RigidObject, resolution: int, padding: float) -> ObjectSDF:
    return ObjectSDF.from_trimesh(obj.mesh, resolution, padding)


class ObjectSDF(eqx.Module):
    """Signed distance field of a rigid object on a regular grid (m; < 0 inside).

    Attributes:
        values: (Nx, Ny, Nz) signed distances at the grid points.
        origin: (3,) position of grid point (0, 0, 0) in the object frame.
        spacing: (3,) grid step.
    """

    values: Array
    origin: Array
    spacing: Array

    @classmethod
    def from_trimesh(cls, mesh, resolution: int = 32, padding: float = 0.05) -> ObjectSDF:
        """Sample the mesh's signed distance on a grid covering its bounds + `padding`.

        Distances and inside/outside from trimesh (`proximity.signed_distance`: exact
        closest points, ray-parity inside test), so the mesh must be watertight.
        """
        import trimesh

        if not mesh.is_watertight:
            raise ValueError(
                "the object mesh is not watertight, so inside and outside are undefined for its "
                "signed distance; repair it (trimesh: mesh.fill_holes(), or use mesh.convex_hull)."
            )
        lo, hi = np.asarray(mesh.bounds[0]) - padding, np.asarray(mesh.bounds[1]) + padding
        axes = [np.linspace(lo[i], hi[i], resolution) for i in range(3)]
        grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
        values = -trimesh.proximity.signed_distance(mesh, grid)  # trimesh: positive inside
        return cls(
            values=jnp.asarray(values.reshape(resolution, resolution, resolution)),
            origin=jnp.asarray(lo),
            spacing=jnp.asarray((hi - lo) / (resolution - 1)),
        )

    def __call__(self, points: Array) -> Array:
        """Signed distance at points (..., 3) in the object frame, trilinear.

        Outside the grid the value at the clamped point plus the distance to the grid
        box (an upper bound that keeps the sign and a useful gradient).
        """
        dtype = points.dtype
        spacing, origin = self.spacing.astype(dtype), self.origin.astype(dtype)
        shape = jnp.asarray(self.values.shape, dtype)
        u = (points - origin) / spacing
        uc = jnp.clip(u, 0.0, shape - 1.0)
        d2 = jnp.sum(((u - uc) * spacing) ** 2, -1)
        # Zero inside the grid, where a plain norm would have a NaN gradient.
        outside = jnp.where(d2 > 0, jnp.sqrt(jnp.where(d2 > 0, d2, 1.0)), 0.0)
        inside = map_coordinates(self.values.astype(dtype), list(jnp.moveaxis(uc, -1, 0)), order=1, mode="nearest")
        return inside + outside
