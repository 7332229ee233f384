"""The body model as an immutable pytree: SMPL's parameters as leaves, topology static.

Huang §2.1 and von Marcard §2.2.3: M(β, θ) = W(T(β, θ), J(β), θ, 𝒲) with
T = T̄ + B_s(β) + B_p(θ). The arrays here are exactly those of an SMPL file
(`v_template`, `shapedirs`, `posedirs`, `J_regressor`, `weights`) so that a real
SMPL file, our default body and a random test model all run the same code.
"""

from __future__ import annotations

import hashlib

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

__all__ = ["Body", "SMPL_FEET", "SMPL_JOINT_NAMES", "SMPL_PARENTS", "StaticArray", "scaled_body"]

SMPL_JOINT_NAMES: tuple[str, ...] = (
    "pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2",
    "left_ankle", "right_ankle", "spine3", "left_foot", "right_foot", "neck",
    "left_collar", "right_collar", "head", "left_shoulder", "right_shoulder",
    "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_hand", "right_hand",
)  # fmt: skip
SMPL_PARENTS: tuple[int, ...] = (
    -1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21,
)  # fmt: skip
#: The feet: ankles and toe joints (ground contact, skating, soles), one definition for all.
SMPL_FEET: tuple[str, ...] = ("left_ankle", "right_ankle", "left_foot", "right_foot")


class StaticArray:
    """A read-only NumPy array that can sit in a pytree's static (hashed) metadata.

    Faces are topology: they never change under jit and must not become tracers, but a
    plain ndarray is unhashable. Hashing by content keeps jit caches shared between
    bodies with the same mesh.
    """

    __slots__ = ("array", "_hash")

    def __init__(self, array: np.ndarray):
        array = np.ascontiguousarray(array)
        array.setflags(write=False)
        self.array = array
        digest = hashlib.blake2b(array.tobytes(), digest_size=8).digest()
        self._hash = hash((array.shape, str(array.dtype), digest))

    def __hash__(self) -> int:
        return self._hash

    def __eq__(self, other: object) -> bool:
        return isinstance(other, StaticArray) and self._hash == other._hash and np.array_equal(self.array, other.array)

    def __repr__(self) -> str:
        return f"StaticArray(shape={self.array.shape}, dtype={self.array.dtype})"


class Body(eqx.Module):
    """An SMPL-layout body model.

    Leaves (arrays, all of one floating dtype):
        v_template: (V, 3) mean template mesh T̄, metres, y up, facing +z.
        shapedirs: (B, V, 3) shape blend shapes 𝒮; B_s(β) = Σ_k β_k 𝒮_k.
        posedirs: (9(J-1), V, 3) pose blend shapes 𝒫, linear in vec(R_j - I), j ≥ 1.
        (SMPL files store both as (V, 3, K); we keep K first so that each blend is
        one row-major matrix product. `make_body` takes the file layout.)
        J_regressor: (J, V) joint regressor 𝒥; joints J(β) = 𝒥 (T̄ + B_s(β)).
        weights: (V, J) linear blend skinning weights 𝒲, rows sum to one.
    Static metadata (hashed; changing it recompiles):
        faces: (F, 3) triangle indices.
        parents: parent index per joint, -1 for the root.
        joint_names: one name per joint.
        kind: "smpl", "smplh", "smplx" (reduced to the SMPL tree) or "default".
        gender: "neutral", "male", "female".
        max_influences: the most non-zero skinning weights of any vertex (6 for the
            default body), counted by `make_body`; the GPU forward then blends only that
            many joints per vertex. None (unknown): dense skinning everywhere.
    """

    v_template: Array
    shapedirs: Array
    posedirs: Array
    J_regressor: Array
    weights: Array
    faces_static: StaticArray = eqx.field(static=True)
    parents: tuple[int, ...] = eqx.field(static=True)
    joint_names: tuple[str, ...] = eqx.field(static=True)
    kind: str = eqx.field(static=True, default="smpl")
    gender: str = eqx.field(static=True, default="neutral")
    max_influences: int | None = eqx.field(static=True, default=None)

    def __check_init__(self):
        V = self.v_template.shape[0]
        J = len(self.parents)
        expected = {
            "v_template": (V, 3),
            "shapedirs": (self.shapedirs.shape[0], V, 3),
            "posedirs": (9 * (J - 1), V, 3),
            "J_regressor": (J, V),
            "weights": (V, J),
        }
        for name, shape in expected.items():
            got = getattr(self, name).shape
            if got != shape:
                raise ValueError(
                    f"Body.{name} has shape {got}; expected {shape} for a model with {V} vertices and {J} joints."
                )
        if len(self.joint_names) != J:
            raise ValueError(f"{len(self.joint_names)} joint names for {J} joints.")
        for j, p in enumerate(self.parents):
            if not (p == -1 if j == 0 else 0 <= p < j):
                raise ValueError(
                    f"parents must list each joint after its parent with the root first; joint {j} has parent {p}."
                )
        if self.max_influences is not None:
            K = self.max_influences
            if not isinstance(K, int) or not 1 <= K <= J:
                raise ValueError(f"max_influences must be an int in [1, {J}] or None, got {K!r}.")
            if not isinstance(self.weights, jax.core.Tracer):
                # Sparse skinning would silently drop any joint beyond the K largest weights.
                most = int(np.max(np.count_nonzero(np.asarray(self.weights), axis=1)))
                if most > K:
                    raise ValueError(f"max_influences={K} but a vertex has {most} non-zero skinning weights.")
        faces = self.faces_static.array
        if faces.ndim != 2 or faces.shape[1] != 3 or faces.min() < 0 or faces.max() >= V:
            raise ValueError(f"faces must be (F, 3) indices into {V} vertices.")

    @property
    def faces(self) -> np.ndarray:
        """(F, 3) int32 triangle indices (NumPy, static)."""
        return self.faces_static.array

    @property
    def num_vertices(self) -> int:
        return self.v_template.shape[0]

    @property
    def num_joints(self) -> int:
        return len(self.parents)

    @property
    def num_betas(self) -> int:
        return self.shapedirs.shape[0]

    @property
    def dtype(self):
        return self.v_template.dtype

    def astype(self, dtype) -> Body:
        """The same body with every leaf cast to `dtype` (float32 or float64)."""
        return eqx.tree_at(
            lambda b: (b.v_template, b.shapedirs, b.posedirs, b.J_regressor, b.weights),
            self,
            tuple(
                jnp.asarray(x, dtype)
                for x in (self.v_template, self.shapedirs, self.posedirs, self.J_regressor, self.weights)
            ),
        )

    def joint_index(self, name: str) -> int:
        """Index of the joint called `name`; the error lists the valid names."""
        try:
            return self.joint_names.index(name)
        except ValueError:
            raise ValueError(f"No joint {name!r}; this body has {list(self.joint_names)}.") from None


def make_body(
    v_template,
    faces,
    shapedirs,
    posedirs,
    J_regressor,
    weights,
    parents=SMPL_PARENTS,
    joint_names=SMPL_JOINT_NAMES,
    kind: str = "smpl",
    gender: str = "neutral",
    dtype=jnp.float32,
) -> Body:
    """Build a `Body` from arrays in SMPL's file layout, casting leaves to `dtype`.

    shapedirs and posedirs are (V, 3, K) as in SMPL files. `max_influences` is counted
    here from the concrete weights (exactly non-zero entries per vertex).
    """
    weights = np.asarray(weights)
    influences = max(1, int(np.count_nonzero(weights, axis=1).max())) if weights.ndim == 2 and weights.size else None
    as_leaf = lambda x: jnp.asarray(np.asarray(x), dtype)  # noqa: E731
    blend_first = lambda x: as_leaf(np.moveaxis(np.asarray(x), -1, 0))  # noqa: E731
    return Body(
        v_template=as_leaf(v_template),
        shapedirs=blend_first(shapedirs),
        posedirs=blend_first(posedirs),
        J_regressor=as_leaf(J_regressor),
        weights=as_leaf(weights),
        faces_static=StaticArray(np.asarray(faces, np.int32)),
        parents=tuple(int(p) for p in parents),
        joint_names=tuple(str(n) for n in joint_names),
        kind=kind,
        gender=gender,
        max_influences=influences,
    )


def scaled_body(body: Body, s: float) -> Body:
    """`body` uniformly scaled by s about its origin (template, shape and pose blend shapes).

    The joints, regressed linearly from the vertices, scale with them; rotations, skinning
    weights and topology are unchanged, so a pose means the same on every scaled copy.
    """
    v = np.asarray(s) if not isinstance(s, jax.core.Tracer) else None
    if v is not None and (v.ndim != 0 or not np.issubdtype(v.dtype, np.number) or not (np.isfinite(v) and v > 0)):
        raise ValueError(f"scaled_body: s must be one finite number > 0, got {s!r}.")
    k = jnp.asarray(s, body.dtype)  # a NumPy float64 s must not promote a float32 body
    return eqx.tree_at(lambda b: (b.v_template, b.shapedirs, b.posedirs), body,
                       (body.v_template * k, body.shapedirs * k, body.posedirs * k))  # fmt: skip
