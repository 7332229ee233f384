"""Pictures of a Video Inertial Poser fit: detections against the model in the image, error
over time, and a 3D scene of bodies and the moving camera.

Draws the arrays it is given (projections, assignments, errors are computed by the caller).
Image coordinates are pixels (u right, v down, pixel centres at integers); cameras follow
jaxmocap's OpenCV convention (x right, y down, z forward; R world-to-camera); the scene is
in the y-up world, metres.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["COCO18_LIMBS", "PERSON_COLORS", "UNASSIGNED_COLOR", "error_over_time_png", "overlay_png", "scene_glb"]

#: COCO-18 bones (OpenPose's POSE_COCO_PAIRS without the two ear-shoulder PAF-only pairs),
#: by index in `geometry.keypoints.COCO18_NAMES` (nose, neck, r/l shoulder, elbow, wrist,
#: r/l hip, knee, ankle, r/l eye, ear).
COCO18_LIMBS = (
    (1, 2), (2, 3), (3, 4), (1, 5), (5, 6), (6, 7), (1, 8), (8, 9), (9, 10), (1, 11), (11, 12),
    (12, 13), (1, 0), (0, 14), (14, 16), (0, 15), (15, 17),
)  # fmt: skip
#: One colour per person (matplotlib's tab10 without its grey), shared by every picture here.
PERSON_COLORS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#bcbd22", "#17becf")
UNASSIGNED_COLOR = "#8a8a8a"


def _person_color(p: int) -> str:
    return PERSON_COLORS[p % len(PERSON_COLORS)]


def _limb_segments(points, seen):
    return [points[[a, b]] for a, b in COCO18_LIMBS if seen[a] and seen[b]]


def overlay_png(
    path,
    image_size,
    detections,
    assignment,
    projected_joints,
    projected_vertices=None,
    faces=None,
    background=None,
    title: str = "",
) -> Path:
    """Detections and the fitted people's projections over one image, as PNG.

    Detections are solid skeletons coloured by their assigned person (grey: unassigned);
    each person's projected model keypoints are a dashed skeleton with crosses in the same
    colour, and their projected mesh a filled silhouette (with `faces`) or a point cloud.

    Args:
        path: output PNG; image_size: (width, height) in pixels.
        detections: (D, 18, 3) COCO-18 (u, v, confidence); confidence 0 (or NaN) = missing.
        assignment: (D,) person index of each detection, -1 for unassigned.
        projected_joints: (P, 18, 2) the model's COCO-18 keypoints in pixels (NaN = hidden).
        projected_vertices: optional (P, V, 2) projected mesh vertices; faces: (F, 3).
        background: optional (height, width, 3|4) image, float in [0, 1] or uint8.
    Returns:
        The path written.
    """
    from matplotlib.collections import LineCollection
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D

    from .plot import save_figure

    W, H = (int(s) for s in image_size)
    det = np.asarray(detections, np.float64).reshape(-1, 18, 3)
    assignment = np.asarray(assignment, int).reshape(-1)
    model = np.asarray(projected_joints, np.float64)
    if model.ndim != 3 or model.shape[1:] != (18, 2):
        raise ValueError(f"projected_joints has shape {model.shape}; expected (P, 18, 2) COCO-18 pixels.")
    P = len(model)
    if assignment.shape != (len(det),) or (assignment < -1).any() or (assignment >= P).any():
        raise ValueError(f"assignment must be ({len(det)},) person indices in [-1, {P}), got {assignment.tolist()}.")
    fig = Figure(figsize=(6.0, min(6.0 * H / W, 9.0) + 0.6), dpi=110, layout="constrained")
    ax = fig.add_subplot()
    if background is not None:
        ax.imshow(np.asarray(background), extent=(-0.5, W - 0.5, H - 0.5, -0.5), zorder=0)
    else:
        ax.set_facecolor("#f4f4f4")
    if projected_vertices is not None:
        _draw_meshes(ax, np.asarray(projected_vertices, np.float64), faces, W, H)
    for d, a in zip(det, assignment):
        color = UNASSIGNED_COLOR if a < 0 else _person_color(a)
        seen = np.isfinite(d).all(-1) & (np.nan_to_num(d[:, 2]) > 0)
        ax.add_collection(LineCollection(_limb_segments(d[:, :2], seen), colors=color, lw=2.2, zorder=3))
        ax.scatter(*d[seen, :2].T, s=14, c=color, edgecolors="white", linewidths=0.5, zorder=4)
    for p, m in enumerate(model):
        seen = np.isfinite(m).all(-1)
        ax.add_collection(LineCollection(_limb_segments(m, seen), colors=_person_color(p), lw=1.6,
                                         linestyles=(0, (4, 2)), zorder=5))  # fmt: skip
        ax.scatter(*m[seen].T, marker="x", s=22, c=_person_color(p), lw=1.2, zorder=6)
    ax.set_xlim(-0.5, W - 0.5)
    ax.set_ylim(H - 0.5, -0.5)  # image rows grow downwards
    ax.set_aspect("equal")
    ax.tick_params(labelsize=7)
    handles = [Line2D([], [], color=_person_color(p), lw=2, label=f"person {p}") for p in range(P)]
    handles += [Line2D([], [], color=UNASSIGNED_COLOR, lw=2, label="unassigned"),
                Line2D([], [], color="k", lw=2, label="detection"),
                Line2D([], [], color="k", lw=1.5, ls=(0, (4, 2)), marker="x", label="model")]  # fmt: skip
    fig.legend(handles=handles, fontsize=7, loc="outside lower center", ncol=min(len(handles), 6), frameon=False)
    if title:
        ax.set_title(title, fontsize=9)
    return save_figure(fig, path)


def _draw_meshes(ax, vertices, faces, W, H):
    """Each person's projected mesh: a filled silhouette (faces given) or a point cloud."""
    from matplotlib.colors import to_rgb

    if vertices.ndim != 3 or vertices.shape[-1] != 2:
        raise ValueError(f"projected_vertices has shape {vertices.shape}; expected (P, V, 2) pixels.")
    if faces is None:
        for p, v in enumerate(vertices):
            ax.scatter(*v.T, s=0.5, c=_person_color(p), alpha=0.25, lw=0, zorder=1)
        return
    from PIL import Image, ImageDraw

    # One image for all silhouettes: thousands of polygon artists would be slow to draw.
    rgba = np.zeros((H, W, 4))
    for p, v in enumerate(vertices):
        mask = Image.new("L", (W, H))
        draw = ImageDraw.Draw(mask)
        for tri in v[np.asarray(faces)]:
            if np.isfinite(tri).all():
                draw.polygon(tri.ravel().tolist(), fill=255)
        inside = np.asarray(mask) > 0
        rgba[inside, :3], rgba[inside, 3] = to_rgb(_person_color(p)), 0.35
    ax.imshow(rgba, extent=(-0.5, W - 0.5, H - 0.5, -0.5), interpolation="nearest", zorder=1)


def error_over_time_png(path, errors: dict, fps: float, ylabel: str = "error", title: str = "") -> Path:
    """Per-frame errors of several fits over time, one line each (NaN frames are gaps).

    errors: {label: (T,) per-frame error}; fps: frames per second of the x axis.
    """
    from .plot import plot_error_curves

    curves = {}
    for label, e in errors.items():
        e = np.asarray(e, np.float64)
        if e.ndim != 1:
            raise ValueError(f"errors[{label!r}] has shape {e.shape}; expected (T,) per-frame values.")
        curves[label] = e
    if not curves:
        raise ValueError("errors is empty: give at least one {label: (T,) errors} entry.")
    return plot_error_curves(curves, path, fps=fps, ylabel=ylabel, title=title)


def _frustum(centre, R, size):
    """A camera pyramid (5 vertices, 6 faces): apex at the centre, its 4:3 base `size` m ahead."""
    w, h = 0.5 * size, 0.375 * size
    corners = np.array([[-w, -h, size], [w, -h, size], [w, h, size], [-w, h, size]])  # camera frame
    vertices = np.concatenate([centre[None], centre + corners @ R])  # world = Rᵀ p_c + centre
    faces = np.array([[0, 2, 1], [0, 3, 2], [0, 4, 3], [0, 1, 4], [1, 2, 3], [1, 3, 4]])
    return vertices, faces


def scene_glb(
    path,
    vertices,
    faces,
    camera_centres,
    camera_R,
    frames=None,
    frustum_size: float = 0.25,
) -> Path:
    """The fitted bodies at a few frames and the camera's path, as one GLB (or PLY) scene.

    GLB: a node per body and frame (`person{p}_frame{t:04d}`, coloured per person as in
    `overlay_png`), a camera pyramid per frame (`camera_{t:04d}`, pointing along the camera's
    +z) and the camera centres as a polyline (`camera_path`). PLY holds one mesh, so there
    the path is left out and the bodies and pyramids are merged.

    Args:
        path: .glb or .ply output.
        vertices: (P, T, V, 3) posed vertices per person and frame, or (P, V, 3) one frame.
        faces: (F, 3) body faces.
        camera_centres: (T, 3) world positions; camera_R: (T, 3, 3) world-to-camera rotations.
        frames: frame indices to draw (default: 5 evenly spaced, ends included).
        frustum_size: pyramid depth in metres.
    Returns:
        The path written.
    """
    import trimesh

    from .mesh import mesh_format, to_trimesh, write_mesh

    path = Path(path)
    fmt = mesh_format(path)
    if fmt == "obj":
        raise ValueError(f"{path}: a scene is written as .glb or .ply.")
    verts = np.asarray(vertices, np.float64)
    centres = np.asarray(camera_centres, np.float64)
    Rc = np.asarray(camera_R, np.float64)
    T = len(centres)
    if centres.shape != (T, 3) or Rc.shape != (T, 3, 3) or T == 0:
        raise ValueError(f"camera_centres {centres.shape} and camera_R {Rc.shape} must be (T, 3) and (T, 3, 3).")
    if verts.ndim == 3:
        verts = verts[:, None]
    if verts.ndim != 4 or verts.shape[-1] != 3 or verts.shape[1] not in (1, T):
        raise ValueError(f"vertices has shape {np.shape(vertices)}; expected (P, T, V, 3) with T = {T}, or (P, V, 3).")
    frames = np.unique(np.linspace(0, T - 1, min(T, 5)).round().astype(int)) if frames is None else np.asarray(frames)
    if frames.size == 0 or frames.min() < 0 or frames.max() >= T:
        raise ValueError(f"frames must index the {T} camera frames, got {frames.tolist()}.")
    meshes = {}
    for p in range(len(verts)):
        rgba = (np.array([*_rgb(_person_color(p)), 1.0]) * 255).astype(np.uint8)
        for t in frames if verts.shape[1] == T else [0]:
            meshes[f"person{p}_frame{t:04d}"] = to_trimesh(verts[p, t], faces, np.tile(rgba, (verts.shape[2], 1)))
    for t in frames:
        v, f = _frustum(centres[t], Rc[t], frustum_size)
        meshes[f"camera_{t:04d}"] = to_trimesh(v, f, np.tile([60, 60, 60, 255], (5, 1)).astype(np.uint8))
    if fmt == "ply":
        return write_mesh(trimesh.util.concatenate(list(meshes.values())), path, fmt)
    scene = trimesh.Scene()
    for name, mesh in meshes.items():
        scene.add_geometry(mesh, node_name=name, geom_name=name)
    if T > 1:
        scene.add_geometry(trimesh.load_path(centres), node_name="camera_path", geom_name="camera_path")
    return write_mesh(scene, path, fmt)


def _rgb(color: str):
    from matplotlib.colors import to_rgb

    return to_rgb(color)
