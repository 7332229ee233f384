"""Posed meshes out of jaxmocap: batched posing of a Motion and export through trimesh.

Coordinates are written as they are: metres, y up, the body facing +z at zero root
rotation. glTF (.glb) is y up with metres too, so viewers show the body upright; PLY and
OBJ carry no convention (most tools, e.g. MeshLab and Blender's OBJ importer with
"Y up", read them upright as well).
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np
import trimesh

from .._progress import progress as show_progress

__all__ = [
    "MESH_FORMATS",
    "MeshExportError",
    "export_mesh",
    "export_sequence",
    "scalars_to_colors",
]

MESH_FORMATS = ("ply", "glb", "obj")


class MeshExportError(ValueError):
    """A mesh cannot be written: unknown format, or arrays of the wrong shape."""


def mesh_format(path: Path) -> str:
    """The format named by `path`'s suffix, one of `MESH_FORMATS` (MeshExportError otherwise)."""
    fmt = path.suffix.lower().lstrip(".")
    if fmt not in MESH_FORMATS:
        raise MeshExportError(
            f"{path}: unknown mesh format {path.suffix or '(no suffix)'!r}; "
            f"use one of {', '.join('.' + f for f in MESH_FORMATS)}."
        )
    return fmt


def scalars_to_colors(values, cmap: str = "inferno", vmin=None, vmax=None) -> np.ndarray:
    """Per-vertex scalars (e.g. contact probability) as RGBA uint8 through a colormap.

    Args:
        values: (..., V) scalars.
        cmap: a matplotlib colormap name.
        vmin, vmax: value range mapped onto the colormap (default: the data's range).
    Returns:
        (..., V, 4) uint8 RGBA.
    """
    import matplotlib

    values = np.asarray(values, np.float64)
    lo = np.nanmin(values) if vmin is None else vmin
    hi = np.nanmax(values) if vmax is None else vmax
    scaled = (values - lo) / (hi - lo) if hi > lo else np.zeros_like(values)
    rgba = matplotlib.colormaps[cmap](np.clip(scaled, 0.0, 1.0))
    return (rgba * 255).round().astype(np.uint8)


def _vertex_colors(colors, num_vertices: int, cmap: str, vmin, vmax) -> np.ndarray | None:
    if colors is None:
        return None
    colors = np.asarray(colors)
    if colors.shape == (num_vertices,):
        return scalars_to_colors(colors, cmap, vmin, vmax)
    if colors.shape in ((num_vertices, 3), (num_vertices, 4)):
        if np.issubdtype(colors.dtype, np.floating):
            colors = (np.clip(colors, 0.0, 1.0) * 255).round()
        colors = colors.astype(np.uint8)
        if colors.shape[1] == 3:
            colors = np.concatenate([colors, np.full((num_vertices, 1), 255, np.uint8)], 1)
        return colors
    raise MeshExportError(
        f"colors has shape {colors.shape}; expected ({num_vertices},) scalars or "
        f"({num_vertices}, 3|4) RGB(A) for {num_vertices} vertices."
    )


def to_trimesh(vertices, faces, colors=None, cmap="inferno", vmin=None, vmax=None) -> trimesh.Trimesh:
    """One checked `trimesh.Trimesh` (arguments as `export_mesh`'s), vertex order kept."""
    vertices = np.asarray(vertices, np.float64)
    faces = np.asarray(faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise MeshExportError(f"vertices has shape {vertices.shape}; expected (V, 3).")
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise MeshExportError(f"faces has shape {faces.shape}; expected (F, 3).")
    if faces.size and (faces.min() < 0 or faces.max() >= len(vertices)):
        raise MeshExportError(f"faces index outside the {len(vertices)} vertices.")
    if not np.isfinite(vertices).all():
        # A viewer shows nothing, or a spike to infinity: refuse rather than write it.
        bad = int(np.argmax(~np.isfinite(vertices).all(1)))
        raise MeshExportError(f"vertices contain NaN or inf (vertex {bad} first); a failed fit or a dropped frame?")
    rgba = _vertex_colors(colors, len(vertices), cmap, vmin, vmax)
    # process=False: keep vertex order and count exactly (no merging, no reordering).
    return trimesh.Trimesh(vertices=vertices, faces=faces, vertex_colors=rgba, process=False)


def write_mesh(mesh_or_scene, path: Path, fmt: str) -> Path:
    """Write a trimesh mesh or scene to `path` as `fmt` (from `mesh_format`), folders made."""
    path.parent.mkdir(parents=True, exist_ok=True)
    if fmt == "obj":
        # No normals: an OBJ with normals is split per corner on reload by some readers.
        data = trimesh.exchange.obj.export_obj(mesh_or_scene, include_normals=False, include_color=True)
        path.write_text(data)
    else:
        mesh_or_scene.export(path, file_type=fmt)
    return path


def export_mesh(
    vertices,
    faces,
    path,
    colors=None,
    cmap: str = "inferno",
    vmin=None,
    vmax=None,
) -> Path:
    """Write one triangle mesh as .ply, .glb or .obj (chosen by the suffix of `path`).

    Args:
        vertices: (V, 3) positions in metres (y up; written unchanged).
        faces: (F, 3) vertex indices, e.g. `body.faces`.
        path: output file; its parent folders are created.
        colors: optional per-vertex colours: (V,) scalars mapped through `cmap` over
            [vmin, vmax] (e.g. contact heat), or (V, 3|4) RGB(A) floats in [0, 1] or uint8.
    Returns:
        The path written.
    Raises:
        MeshExportError: unknown suffix or wrongly shaped arrays.
    """
    path = Path(path)
    fmt = mesh_format(path)
    return write_mesh(to_trimesh(vertices, faces, colors, cmap, vmin, vmax), path, fmt)


def export_sequence(
    vertices,
    faces,
    folder,
    fmt: str = "ply",
    every: int = 1,
    colors=None,
    cmap: str = "inferno",
    vmin=None,
    vmax=None,
    prefix: str = "frame_",
    progress: bool = False,
) -> list[Path]:
    """Write a mesh sequence: one file per kept frame, or one GLB scene holding all of them.

    For "ply" and "obj", frames 0, every, 2·every, ... are written as
    `folder/frame_0000.ply`, `frame_0001.ply`, ... (numbered by the original frame index).
    For "glb", one file `folder/sequence.glb` holds a glTF scene with one node per kept
    frame, named `frame_0000`, ... (glTF has no vertex animation in trimesh; a viewer can
    toggle the nodes, and together they show the motion as a trail).

    Args:
        vertices: (T, V, 3) posed vertices in metres (y up).
        faces: (F, 3) vertex indices.
        folder: output folder (created).
        fmt: "ply", "obj" or "glb".
        every: keep every n-th frame.
        colors: None, (V,) / (V, 3|4) shared by all frames, or (T, V) / (T, V, 3|4) per frame;
            scalars are mapped through `cmap` (vmin/vmax default to the whole sequence's range).
        progress: show a tqdm progress bar.
    Returns:
        The paths written, in frame order.
    """
    fmt = fmt.lower().lstrip(".")
    if fmt not in MESH_FORMATS:
        raise MeshExportError(f"unknown mesh format {fmt!r}; use one of {', '.join(MESH_FORMATS)}.")
    if int(every) < 1:
        raise MeshExportError(f"every must be a positive integer, got {every}.")
    vertices = np.asarray(vertices)
    if vertices.ndim != 3 or vertices.shape[2] != 3:
        raise MeshExportError(f"vertices has shape {vertices.shape}; expected (T, V, 3).")
    T, V = vertices.shape[:2]
    if T == 0:
        raise MeshExportError(f"vertices has shape {vertices.shape}: no frames to write.")
    frames = range(0, T, int(every))
    colors = None if colors is None else np.asarray(colors)
    per_frame = colors is not None and colors.ndim >= 2 and colors.shape[:2] == (T, V)
    if per_frame and colors.ndim == 2:  # (T, V) scalars: one colour scale for all frames
        vmin = np.nanmin(colors) if vmin is None else vmin
        vmax = np.nanmax(colors) if vmax is None else vmax

    def colors_at(t: int):
        return colors[t] if per_frame else colors

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    iterator: Iterable[int] = show_progress(frames, progress, f"writing {fmt.upper()}")
    if fmt == "glb":
        scene = trimesh.Scene()
        for t in iterator:
            mesh = to_trimesh(vertices[t], faces, colors_at(t), cmap, vmin, vmax)
            name = f"{prefix}{t:04d}"
            scene.add_geometry(mesh, node_name=name, geom_name=name)
        return [write_mesh(scene, folder / "sequence.glb", "glb")]
    paths = []
    for t in iterator:
        mesh = to_trimesh(vertices[t], faces, colors_at(t), cmap, vmin, vmax)
        paths.append(write_mesh(mesh, folder / f"{prefix}{t:04d}.{fmt}", fmt))
    return paths
