"""A small wooden-mannequin body in SMPL's layout: a sphere at every joint, a tube per bone.

It is a stand-in for a real body model where none is at hand (tests, the demo before the
bundled body exists): 24 SMPL joints at typical adult positions (metres, y up, facing +z,
left is +x, feet on y = 0), rigid skinning (each sphere follows its joint, each tube its
parent joint), and a joint regressor that averages each joint's sphere, so the regressed
joints are exactly the sphere centres. Shape space: β₀ scales height, β₁ girth, the
rest are small seeded random fields; pose blend shapes are zero unless asked for.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import trimesh

from .model import SMPL_JOINT_NAMES, SMPL_PARENTS, Body, make_body

__all__ = ["mannequin_body", "MANNEQUIN_JOINTS"]

# Rest joint centres (metres), roughly SMPL's mean adult in its T pose, feet on the floor.
MANNEQUIN_JOINTS = np.array(
    [
        [0.00, 0.93, 0.00],  # pelvis
        [0.09, 0.85, -0.01],  # left_hip
        [-0.09, 0.85, -0.01],  # right_hip
        [0.00, 1.04, -0.01],  # spine1
        [0.10, 0.48, 0.00],  # left_knee
        [-0.10, 0.48, 0.00],  # right_knee
        [0.00, 1.17, -0.00],  # spine2
        [0.11, 0.08, -0.04],  # left_ankle
        [-0.11, 0.08, -0.04],  # right_ankle
        [0.00, 1.23, 0.01],  # spine3
        [0.12, 0.02, 0.09],  # left_foot
        [-0.12, 0.02, 0.09],  # right_foot
        [0.00, 1.45, -0.01],  # neck
        [0.07, 1.37, -0.01],  # left_collar
        [-0.07, 1.37, -0.01],  # right_collar
        [0.00, 1.56, 0.02],  # head
        [0.17, 1.40, -0.02],  # left_shoulder
        [-0.17, 1.40, -0.02],  # right_shoulder
        [0.43, 1.39, -0.03],  # left_elbow
        [-0.43, 1.39, -0.03],  # right_elbow
        [0.67, 1.39, -0.02],  # left_wrist
        [-0.67, 1.39, -0.02],  # right_wrist
        [0.75, 1.38, -0.02],  # left_hand
        [-0.75, 1.38, -0.02],  # right_hand
    ]
)

# Sphere radius per joint; a bone's tube takes the smaller radius of its two ends.
_RADII = np.array(
    [0.13, 0.085, 0.085, 0.12, 0.055, 0.055, 0.13, 0.045, 0.045, 0.13, 0.035, 0.035,
     0.05, 0.06, 0.06, 0.10, 0.055, 0.055, 0.04, 0.04, 0.035, 0.035, 0.04, 0.04]
)  # fmt: skip


def _tube(a: np.ndarray, b: np.ndarray, radius: float, sections: int) -> trimesh.Trimesh:
    """An open cylinder from a to b (no caps: the joint spheres close it)."""
    import trimesh

    axis = b - a
    length = float(np.linalg.norm(axis))
    cyl = trimesh.creation.cylinder(radius=radius, height=length, sections=sections)
    # Drop the cap faces and their centre vertices: keep faces whose normals are radial.
    radial = np.abs(cyl.face_normals[:, 2]) < 0.5
    cyl = trimesh.Trimesh(cyl.vertices, cyl.faces[radial], process=False)
    cyl.remove_unreferenced_vertices()
    align = trimesh.geometry.align_vectors([0, 0, 1], axis / length)
    cyl.apply_transform(align)
    cyl.apply_translation((a + b) / 2)
    return cyl


def mannequin_body(
    detail: int = 1,
    num_betas: int = 10,
    pose_blend_scale: float = 0.0,
    seed: int = 0,
    dtype=None,
) -> Body:
    """A jointed mannequin in SMPL's layout (see the module docstring).

    Args:
        detail: 0 (656 vertices, for tests), 1 (1560) or 2 (4808).
        num_betas: number of shape components B (β₀ height, β₁ girth, then random).
        pose_blend_scale: size (metres) of seeded random pose blend shapes; 0 gives none.
        seed: seed for the random shape and pose directions.
        dtype: leaf dtype (default float32).
    Returns:
        A `Body` with kind "mannequin", 24 joints, rigid skinning weights.
    """
    import trimesh  # only when a mannequin is built: `import jaxmocap` stays light

    if detail not in (0, 1, 2):
        raise ValueError(f"detail must be 0, 1 or 2, got {detail}.")
    sections = (8, 12, 20)[detail]
    parts: list[tuple[trimesh.Trimesh, int]] = []  # (mesh, joint it is skinned to)
    for j, centre in enumerate(MANNEQUIN_JOINTS):
        sphere = trimesh.creation.icosphere(subdivisions=detail, radius=_RADII[j])
        sphere.apply_translation(centre)
        parts.append((sphere, j))
    for j in range(1, 24):
        p = SMPL_PARENTS[j]
        r = 0.8 * min(_RADII[j], _RADII[p])
        parts.append((_tube(MANNEQUIN_JOINTS[p], MANNEQUIN_JOINTS[j], r, sections), p))

    vertices, faces, owner = [], [], []
    offset = 0
    sphere_slices = {}
    for k, (mesh, j) in enumerate(parts):
        n = len(mesh.vertices)
        if k < 24:  # the joint spheres come first
            sphere_slices[j] = (offset, offset + n)
        vertices.append(np.asarray(mesh.vertices))
        faces.append(np.asarray(mesh.faces) + offset)
        owner.append(np.full(n, j))
        offset += n
    v = np.concatenate(vertices)
    f = np.concatenate(faces)
    owner = np.concatenate(owner)
    V = len(v)

    weights = np.zeros((V, 24))
    weights[np.arange(V), owner] = 1.0
    regressor = np.zeros((24, V))
    for j, (lo, hi) in sphere_slices.items():
        regressor[j, lo:hi] = 1.0 / (hi - lo)  # icosphere vertices average to its centre

    rng = np.random.default_rng(seed)
    shapedirs = np.zeros((V, 3, num_betas))
    if num_betas > 0:
        shapedirs[:, :, 0] = 0.06 * v  # +6 % size per unit β₀ about the floor origin
    if num_betas > 1:
        # Girth: push each vertex away from its part's joint (or bone axis) horizontally.
        centres = MANNEQUIN_JOINTS[owner]
        radial = v - centres
        radial[:, 1] *= 0.3
        shapedirs[:, :, 1] = 0.15 * radial
    if num_betas > 2:
        smooth = rng.normal(size=(24, 3, num_betas - 2)) * 0.004
        shapedirs[:, :, 2:] = smooth[owner]
    posedirs = rng.normal(size=(V, 3, 207)) * pose_blend_scale
    kwargs = {} if dtype is None else {"dtype": dtype}
    return make_body(
        v_template=v,
        faces=f,
        shapedirs=shapedirs,
        posedirs=posedirs,
        J_regressor=regressor,
        weights=weights,
        parents=SMPL_PARENTS,
        joint_names=SMPL_JOINT_NAMES,
        kind="mannequin",
        **kwargs,
    )
