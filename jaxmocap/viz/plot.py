"""Pictures of bodies and motions with matplotlib, written as PNG without a display.

Figures are built with `matplotlib.figure.Figure` and rendered by the Agg canvas, so no
GUI backend (and no pyplot global state) is ever touched. Views are orthographic, equal
aspect, in metres, with world y (up) vertical on screen:

- front: the camera in front of the body (+z) looking back; screen right is world +x
  (the body's left side).
- side: the camera at the body's right (-x); screen right is world +z (forward).
- top: the camera above (+y); screen right is world +z, screen up world +x, so turns
  read as they would from above (no mirror image).

Meshes are drawn with a painter's algorithm (faces sorted far to near), back faces
culled and Lambert shading from a light above the camera's left shoulder.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib import colormaps
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import ListedColormap
from matplotlib.collections import LineCollection, PolyCollection
from matplotlib.figure import Figure

from ..body.model import SMPL_JOINT_NAMES

__all__ = ["camera_basis", "plot_body", "plot_error_curves", "plot_per_joint", "plot_pose", "plot_sequence"]

LEFT_COLOR = "#2b6cb0"  # the body's left side: blue
RIGHT_COLOR = "#c53030"  # right side: red
CENTRE_COLOR = "#2d3748"  # spine and head: slate
BODY_COLOR = np.array([0.80, 0.68, 0.56])  # clay
_TIME_CMAP = ListedColormap(colormaps["viridis"](np.linspace(0.0, 0.85, 256)), "time")  # no pale yellow
_UP = np.array([0.0, 1.0, 0.0])


def camera_basis(azimuth: float = 0.0, elevation: float = 0.0) -> np.ndarray:
    """Rows (right, up, towards-camera) of an orthographic camera around the y axis.

    Azimuth 0 is the front view (camera on +z), -90 the side view from the body's right
    (camera on -x), in degrees; elevation tilts the camera up.
    """
    az, el = np.radians(azimuth), np.radians(elevation)
    towards = np.array([np.sin(az) * np.cos(el), np.sin(el), np.cos(az) * np.cos(el)])
    right = np.cross(_UP, towards)
    right /= np.linalg.norm(right)
    up = np.cross(towards, right)
    return np.stack([right, up, towards])


def _basis_from_right(right: np.ndarray) -> np.ndarray:
    """Camera with elevation 0 whose screen-right is the horizontal direction `right`."""
    right = np.array([right[0], 0.0, right[2]])
    right /= np.linalg.norm(right)
    return np.stack([right, _UP, np.cross(right, _UP)])


_VIEWS = {
    "front": (0.0, "x (m)"),
    "side": (-90.0, "z (m)"),
}


def save_figure(fig: Figure, path) -> Path:
    """Write a pyplot-free `Figure` as PNG (parents created) and return the path.

    Plots build `matplotlib.figure.Figure` directly, so no global backend is touched.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=fig.dpi, facecolor="white")
    return path


def _side_colors(num_joints: int, joint_names) -> list[str]:
    names = joint_names
    if names is None and num_joints == len(SMPL_JOINT_NAMES):
        names = SMPL_JOINT_NAMES
    if names is None:
        return [CENTRE_COLOR] * num_joints
    out = []
    for n in names:
        n = n.lower()
        out.append(
            LEFT_COLOR
            if n.startswith(("left", "l_"))
            else RIGHT_COLOR
            if n.startswith(("right", "r_"))
            else CENTRE_COLOR
        )
    return out


def _joint_index(joint_names, num_joints: int, name: str) -> int | None:
    names = joint_names if joint_names is not None else (SMPL_JOINT_NAMES if num_joints == 24 else None)
    if names is None or name not in names:
        return None
    return list(names).index(name)


def _draw_skeleton(ax, points2d, depth, parents, colors, linewidth=2.5, markersize=14, alpha=1.0, zorder=3):
    """Bones as lines (far ones first, a little lighter), joints as dots, on a 2D axes."""
    bones = [(j, p) for j, p in enumerate(parents) if p >= 0]
    order = sorted(bones, key=lambda jp: depth[jp[0]] + depth[jp[1]])
    if not order:
        return
    dmin, dmax = float(np.min(depth)), float(np.max(depth))
    span = max(dmax - dmin, 1e-6)
    segments = [points2d[[p, j]] for j, p in order]
    fade = [0.45 + 0.55 * ((depth[j] + depth[p]) / 2 - dmin) / span for j, p in order]
    import matplotlib.colors as mcolors

    rgba = [mcolors.to_rgba(colors[j], alpha * f) for (j, _), f in zip(order, fade)]
    ax.add_collection(LineCollection(segments, colors=rgba, linewidths=linewidth, capstyle="round", zorder=zorder))
    ax.scatter(
        points2d[:, 0],
        points2d[:, 1],
        s=markersize,
        c=[mcolors.to_rgba(c, alpha) for c in colors],
        edgecolors="white",
        linewidths=0.6,
        zorder=zorder + 1,
    )


def plot_pose(
    joints,
    parents,
    ax=None,
    view: str = "front",
    joint_names=None,
    title: str | None = None,
    path=None,
    linewidth: float = 2.5,
):
    """A skeleton stick figure: left limbs blue, right limbs red, spine slate.

    Args:
        joints: (J, 3) joint positions in metres (y up).
        parents: parent index per joint (-1 for the root), e.g. `body.parents`.
        ax: a 2D matplotlib axes to draw into (default: a new figure).
        view: "front" or "side" (see the module docstring), or an azimuth in degrees.
        joint_names: names used to tell left from right (default SMPL's for 24 joints).
        title: axes title.
        path: if given, the (whole) figure is written there as PNG.
    Returns:
        The axes (or the path written, when `path` is given).
    """
    joints = np.asarray(joints, np.float64)
    if joints.ndim != 2 or joints.shape[1] != 3 or len(parents) != len(joints):
        raise ValueError(f"joints has shape {joints.shape}; expected ({len(parents)}, 3), one per parent entry.")
    fig = None
    if ax is None:
        fig = Figure(figsize=(4, 5), dpi=120, layout="constrained")
        ax = fig.add_subplot()
    azimuth, xlabel = _VIEWS.get(view, (float(view) if not isinstance(view, str) else None, "m"))
    if azimuth is None:
        raise ValueError(f"view must be 'front', 'side' or an azimuth in degrees, got {view!r}.")
    basis = camera_basis(azimuth)
    projected = joints @ basis.T
    _draw_skeleton(ax, projected[:, :2], projected[:, 2], parents, _side_colors(len(joints), joint_names), linewidth)
    _style_axes(ax, xlabel, "y (m)")
    lo, hi = projected[:, :2].min(0), projected[:, :2].max(0)
    _set_limits(ax, lo, hi, margin=0.15)
    if title:
        ax.set_title(title)
    if path is not None:
        return save_figure(ax.figure if fig is None else fig, path)
    return ax


def _style_axes(ax, xlabel: str, ylabel: str):
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(True, color="#e2e8f0", linewidth=0.7, zorder=0)
    ax.set_axisbelow(True)
    for side in ("top", "right"):
        ax.spines[side].set_visible(False)
    ax.tick_params(labelsize=8)


def _set_limits(ax, lo, hi, margin=0.1):
    centre = (lo + hi) / 2
    half = np.maximum((hi - lo) / 2 + margin, 0.2)
    ax.set_xlim(centre[0] - half[0], centre[0] + half[0])
    ax.set_ylim(centre[1] - half[1], centre[1] + half[1])


def _shade_mesh(ax, vertices, faces, basis, colors=None, max_faces=60000, seed=0, zorder=2):
    """Painter's-algorithm render of a mesh onto a 2D axes in the camera `basis`."""
    tri = vertices[faces]  # (F, 3, 3)
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    lengths = np.linalg.norm(normals, axis=1, keepdims=True)
    normals = normals / np.where(lengths > 0, lengths, 1.0)
    towards = basis[2]
    facing = normals @ towards
    keep = facing > -0.05  # back faces culled (a sliver of tolerance for grazing faces)
    if keep.sum() > max_faces:
        idx = np.flatnonzero(keep)
        chosen = np.random.default_rng(seed).choice(idx, max_faces, replace=False)
        keep = np.zeros_like(keep)
        keep[chosen] = True
    tri, normals = tri[keep], normals[keep]
    # Key light above the camera's left shoulder plus a weak fill from the right.
    key = 0.75 * towards + 0.55 * basis[1] - 0.35 * basis[0]
    key /= np.linalg.norm(key)
    fill = towards + 0.4 * basis[0]
    fill /= np.linalg.norm(fill)
    lambert = 0.25 + 0.65 * np.clip(normals @ key, 0, 1) + 0.15 * np.clip(normals @ fill, 0, 1)
    if colors is None:
        base = np.broadcast_to(BODY_COLOR, (len(tri), 3))
    else:
        base = np.asarray(colors)[keep][:, :3]
    rgb = np.clip(base * lambert[:, None], 0, 1)
    projected = tri @ basis.T
    order = np.argsort(projected[:, :, 2].mean(1))  # far first
    polys = projected[order][:, :, :2]
    ax.add_collection(
        PolyCollection(polys, facecolors=rgb[order], edgecolors=rgb[order], linewidths=0.25, zorder=zorder)
    )
    flat = vertices @ basis.T
    return flat[:, :2].min(0), flat[:, :2].max(0)


def plot_body(
    vertices,
    faces,
    path,
    joints=None,
    parents=None,
    vertex_values=None,
    cmap: str = "inferno",
    title: str | None = None,
    views=("front", "side", "three-quarter"),
    max_faces: int = 60000,
) -> Path:
    """A shaded picture of one posed mesh in front and side views (plus a ¾ view).

    Args:
        vertices: (V, 3) posed vertices, metres, y up.
        faces: (F, 3) triangle indices.
        path: the PNG to write (folders are created).
        joints: optional (J, 3) joints drawn as a skeleton over the mesh (needs `parents`,
            default SMPL's for 24 joints).
        vertex_values: optional (V,) scalars shown as a colour map (e.g. contact heat)
            with a colour bar.
        views: any of "front", "side", "three-quarter" (the last has no metric axes).
        max_faces: faces beyond this many (after back-face culling) are subsampled.
    Returns:
        The path written.
    """
    vertices = np.asarray(vertices, np.float64)
    faces = np.asarray(faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise ValueError(f"vertices has shape {vertices.shape}; expected (V, 3).")
    face_colors = None
    if vertex_values is not None:
        import matplotlib

        values = np.asarray(vertex_values, np.float64)
        if values.shape != (len(vertices),):
            raise ValueError(f"vertex_values has shape {values.shape}; expected ({len(vertices)},).")
        vmin, vmax = np.nanmin(values), np.nanmax(values)
        norm = matplotlib.colors.Normalize(vmin, vmax if vmax > vmin else vmin + 1)
        face_colors = matplotlib.colormaps[cmap](norm(values[faces].mean(1)))
    if joints is not None:
        joints = np.asarray(joints, np.float64)
        if parents is None:
            if len(joints) != 24:
                raise ValueError("give parents for a skeleton that is not SMPL's 24 joints.")
            from ..body.model import SMPL_PARENTS

            parents = SMPL_PARENTS
    bases = []
    for view in views:
        if view == "three-quarter":
            bases.append(camera_basis(-35.0, 12.0))
        elif view in _VIEWS:
            bases.append(camera_basis(_VIEWS[view][0]))
        else:
            raise ValueError(f"unknown view {view!r}; use 'front', 'side' or 'three-quarter'.")
    # Panel widths follow each view's extent, so all views share one scale.
    extents = [np.ptp(vertices @ b.T, axis=0)[:2] + 0.2 for b in bases]
    height = max(e[1] for e in extents)
    widths = [max(e[0], 0.5) for e in extents]
    fig_h = 5.4
    fig_w = fig_h * 0.92 * sum(widths) / height + 0.5 * len(views) + (1.0 if face_colors is not None else 0)
    fig = Figure(figsize=(max(fig_w, 5.0), fig_h), dpi=130, layout="constrained")
    axes = fig.subplots(1, len(views), squeeze=False, width_ratios=widths)[0]
    floor = vertices[:, 1].min()
    for ax, view, basis in zip(axes, views, bases):
        lo, hi = _shade_mesh(ax, vertices, faces, basis, face_colors, max_faces)
        if view != "three-quarter":
            ax.axhline(floor, color="#a0aec0", linewidth=1.2, zorder=1)
            ax.fill_between([lo[0] - 5, hi[0] + 5], floor - 5, floor, color="#edf2f7", zorder=0)
        if joints is not None:
            p = joints @ basis.T
            _draw_skeleton(
                ax,
                p[:, :2],
                p[:, 2] + 10.0,
                parents,
                _side_colors(len(joints), None),
                linewidth=1.6,
                markersize=9,
                alpha=0.9,
                zorder=5,
            )
        if view == "three-quarter":
            ax.set_aspect("equal", adjustable="box")
            ax.set_axis_off()
            ax.set_title("¾ view", fontsize=10)
        else:
            _style_axes(ax, _VIEWS[view][1], "y (m)")
            ax.set_title(f"{view} view", fontsize=10)
        _set_limits(ax, lo, hi, margin=0.08)
    if face_colors is not None:
        import matplotlib

        mappable = matplotlib.cm.ScalarMappable(norm=norm, cmap=cmap)
        fig.colorbar(mappable, ax=list(axes), shrink=0.6, label="value")
    height = vertices[:, 1].max() - floor
    fig.suptitle(
        title or f"Posed body: {len(vertices)} vertices, {len(faces)} faces, height {height:.2f} m",
        fontsize=11,
    )
    return save_figure(fig, path)


def _heading(joints, joint_names) -> np.ndarray | None:
    """(T, 3) unit facing direction from the hips, (left - right) × up, or None."""
    J = joints.shape[1]
    li, ri = _joint_index(joint_names, J, "left_hip"), _joint_index(joint_names, J, "right_hip")
    if li is None or ri is None:
        return None
    forward = np.cross(joints[:, li] - joints[:, ri], _UP)
    forward[:, 1] = 0
    norm = np.linalg.norm(forward, axis=1, keepdims=True)
    return forward / np.where(norm > 0, norm, 1)


def plot_sequence(
    joints,
    parents,
    path,
    num_panels: int = 8,
    fps: float | None = None,
    joint_names=None,
    title: str | None = None,
) -> Path:
    """A filmstrip of skeletons over time, the root's path from above, and its height/speed.

    Top row: `num_panels` evenly spaced frames seen from the side of the overall
    direction of travel (the camera's screen-right is that direction, so the figure
    moves left to right), each centred on its root, all at one scale. Bottom left: the
    root trajectory on the x–z ground plane (from above, coloured by time), with the
    panel frames numbered and the facing direction as arrows. Bottom right: root height
    and horizontal speed against time.

    Args:
        joints: (T, J, 3) joint positions, metres, y up; joint 0 is the root.
        parents: parent index per joint.
        path: the PNG to write.
        num_panels: number of filmstrip frames.
        fps: frame rate, for a time axis in seconds (default: frame numbers).
        joint_names: to tell left from right and find the hips (default SMPL's).
    Returns:
        The path written.
    """
    import matplotlib

    joints = np.asarray(joints, np.float64)
    if joints.ndim != 3 or joints.shape[2] != 3 or joints.shape[1] != len(parents):
        raise ValueError(f"joints has shape {joints.shape}; expected (T, {len(parents)}, 3).")
    T, J = joints.shape[:2]
    num_panels = max(1, min(int(num_panels), T))
    frames = np.unique(np.linspace(0, T - 1, num_panels).round().astype(int))
    time = np.arange(T) / fps if fps else np.arange(T, dtype=float)
    time_label = "time (s)" if fps else "frame"
    root = joints[:, 0]
    heading = _heading(joints, joint_names)

    # Filmstrip camera: screen right is the body's own heading at that frame (a clean
    # side view even on a curved path); without hips, the overall direction of travel.
    travel = root[-1] - root[0]
    travel[1] = 0
    fallback = travel if np.linalg.norm(travel) > 0.3 else np.array([0.0, 0.0, 1.0])
    colors = _side_colors(J, joint_names)
    cmap = _TIME_CMAP
    tnorm = matplotlib.colors.Normalize(time[0], time[-1] if T > 1 else time[0] + 1)

    panels = []
    for t in frames:
        right = heading[t] if heading is not None and np.linalg.norm(heading[t]) > 0.5 else fallback
        p = (joints[t] - root[t] * np.array([1.0, 0.0, 1.0])) @ _basis_from_right(right).T
        panels.append(p)
    floor = joints[..., 1].min()
    reach = max(np.abs(p[:, 0]).max() for p in panels)
    half_width = max(0.45, reach + 0.12)
    ytop = max(p[:, 1].max() for p in panels) + 0.08
    panel_w = 1.45
    panel_h = panel_w * (ytop - floor + 0.1) / (2 * half_width)
    fig = Figure(figsize=(max(10.0, panel_w * len(frames) + 0.8), panel_h + 4.6), dpi=120, layout="constrained")
    top, bottom = fig.subfigures(2, 1, height_ratios=[panel_h + 0.8, 3.8])
    strip = top.subplots(1, len(frames), sharey=True, squeeze=False)[0]
    for k, (ax, t, p) in enumerate(zip(strip, frames, panels)):
        ax.axhline(floor, color="#a0aec0", linewidth=1.2, zorder=1)
        ax.fill_between([-5, 5], floor - 5, floor, color="#edf2f7", zorder=0)
        _draw_skeleton(ax, p[:, :2], p[:, 2], parents, colors, linewidth=2.2, markersize=10)
        ax.set_xlim(-half_width, half_width)
        ax.set_ylim(floor - 0.08, ytop)
        ax.set_aspect("equal", adjustable="box")
        label = f"t = {time[t]:.2f} s" if fps else f"frame {t}"
        ax.set_title(f"{k + 1}", fontsize=9, fontweight="bold", color=cmap(tnorm(time[t])), loc="left")
        ax.set_title(label, fontsize=8, loc="right")
        ax.tick_params(labelsize=6)
        ax.grid(True, color="#e2e8f0", linewidth=0.6, zorder=0)
        ax.set_axisbelow(True)
        for side in ("top", "right"):
            ax.spines[side].set_visible(False)
        ax.set_xlabel("forward (m)", fontsize=7)
    strip[0].set_ylabel("y (m)")
    top.suptitle(
        "Side views, each centred on the root and turned to the body's heading (left limbs blue, right limbs red)",
        fontsize=9,
    )

    ax_top, ax_curve = bottom.subplots(1, 2, width_ratios=[1.3, 1.0])
    # Trajectory from above: screen right = world z, screen up = world x (see docstring).
    z, x = root[:, 2], root[:, 0]
    points = np.stack([z, x], 1)
    if T > 1:
        segs = np.stack([points[:-1], points[1:]], 1)
        lc = LineCollection(segs, cmap=cmap, norm=tnorm, linewidths=2.5, zorder=3)
        lc.set_array((time[:-1] + time[1:]) / 2)
        ax_top.add_collection(lc)
        bottom.colorbar(lc, ax=ax_top, label=time_label, shrink=0.85, pad=0.02)
    ax_top.scatter([z[0]], [x[0]], marker="o", s=50, color=cmap(0.0), edgecolors="black", zorder=5, label="start")
    ax_top.scatter([z[-1]], [x[-1]], marker="s", s=50, color=cmap(1.0), edgecolors="black", zorder=5, label="end")
    extent = max(np.ptp(z), np.ptp(x), 0.5)
    if heading is not None:
        arrow = 0.1 * extent + 0.12
        ax_top.quiver(
            z[frames],
            x[frames],
            heading[frames, 2] * arrow,
            heading[frames, 0] * arrow,
            angles="xy",
            scale_units="xy",
            scale=1,
            color="#4a5568",
            width=0.004,
            zorder=4,
        )
    for k, t in enumerate(frames):
        ax_top.annotate(str(k + 1), (z[t], x[t]), textcoords="offset points", xytext=(4, 5), fontsize=7, zorder=6)
    # Feet, faintly: where the ankles went.
    for name, c in (("left_ankle", LEFT_COLOR), ("right_ankle", RIGHT_COLOR)):
        i = _joint_index(joint_names, J, name)
        if i is not None:
            ax_top.plot(joints[:, i, 2], joints[:, i, 0], color=c, alpha=0.3, linewidth=1.0, zorder=2)
    _style_axes(ax_top, "z (m)", "x (m)")
    lo, hi = np.array([z.min(), x.min()]) - 0.25, np.array([z.max(), x.max()]) + 0.25
    span = hi - lo
    pad = np.maximum(0.45 * span[::-1] - span, 0) / 2  # no thinner than about 1 : 2.2
    _set_limits(ax_top, lo - pad, hi + pad, margin=0.0)
    length = np.linalg.norm(np.diff(root[:, [0, 2]], axis=0), axis=1).sum()
    ax_top.set_title(f"Root path from above: {length:.2f} m", fontsize=10)
    ax_top.legend(loc="best", fontsize=7, framealpha=0.8)

    ax_curve.plot(time, root[:, 1], color="#2d3748", linewidth=1.8, label="root height (m)")
    ax_curve.set_xlabel(time_label)
    ax_curve.set_ylabel("root height (m)")
    ax_curve.grid(True, color="#e2e8f0", linewidth=0.7)
    ax_curve.set_title("Root height and horizontal speed", fontsize=10)
    for t in frames:
        ax_curve.axvline(time[t], color=cmap(tnorm(time[t])), linewidth=0.8, alpha=0.6)
    if T > 1 and fps:
        speed = np.linalg.norm(np.gradient(root[:, [0, 2]], 1.0 / fps, axis=0), axis=1)
        ax_speed = ax_curve.twinx()
        ax_speed.plot(time, speed, color="#dd6b20", linewidth=1.4, label="speed (m/s)")
        ax_speed.set_ylabel("horizontal speed (m/s)", color="#dd6b20")
        ax_speed.tick_params(axis="y", colors="#dd6b20", labelsize=8)
        ax_speed.set_ylim(0, max(speed.max() * 1.15, 0.1))
    ax_curve.tick_params(labelsize=8)
    duration = f"{time[-1] - time[0]:.2f} s" if fps else f"{T} frames"
    fig.suptitle(title or f"Motion: {T} frames, {duration}", fontsize=12, fontweight="bold")
    return save_figure(fig, path)


def plot_error_curves(curves: dict, path, fps: float = 30.0, ylabel: str = "MPJAE [°]", title: str = "") -> Path:
    """Per-frame error (mean over joints) of several methods over time, one line each.

    curves: {method name: (T,) or (T, N_J) errors}; NaN frames are gaps, left out of the mean.
    """
    from .._checks import check_rate

    check_rate("fps", fps)
    fig = Figure(figsize=(8, 3.2))
    ax = fig.subplots()
    for name, e in curves.items():
        e = np.asarray(e, np.float64)
        e = e.mean(-1) if e.ndim == 2 else e
        finite = e[np.isfinite(e)]
        mean = finite.mean() if finite.size else np.nan
        ax.plot(np.arange(len(e)) / fps, e, label=f"{name} (mean {mean:.1f})", lw=1.4)
    ax.set_xlabel("time [s]")
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(frameon=False, fontsize=9)
    fig.set_dpi(120)
    fig.tight_layout()
    return save_figure(fig, path)


def plot_per_joint(errors: dict, joint_names: Sequence[str], path, ylabel: str = "MPJAE [°]", title: str = "") -> Path:
    """Grouped bars: mean error per joint for each method. errors: {method: (T, N_J) or (N_J,)}."""
    names = list(joint_names)
    fig = Figure(figsize=(max(6, 0.6 * len(names)), 3.4))
    ax = fig.subplots()
    width = 0.8 / max(len(errors), 1)
    x = np.arange(len(names))
    for i, (method, e) in enumerate(errors.items()):
        e = np.asarray(e)
        e = e.mean(0) if e.ndim == 2 else e
        ax.bar(x + (i - (len(errors) - 1) / 2) * width, e, width, label=method)
    ax.set_xticks(x, [n.replace("_", " ") for n in names], rotation=45, ha="right", fontsize=8)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3, axis="y")
    ax.legend(frameon=False, fontsize=9)
    fig.set_dpi(120)
    fig.tight_layout()
    return save_figure(fig, path)


def plot_lines(series: dict, path, xlabel: str, ylabel: str, title: str = "", logx: bool = False) -> Path:
    """One line per entry of `series` ({label: (x, y)}), markers on the points."""
    fig = Figure(figsize=(6, 3.4))
    ax = fig.subplots()
    for label, (x, y) in series.items():
        ax.plot(np.asarray(x), np.asarray(y), "o-", lw=1.4, ms=4, label=label)
    if logx:
        ax.set_xscale("symlog", linthresh=min(v for x, _ in series.values() for v in np.asarray(x) if v > 0))
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(frameon=False, fontsize=8)
    fig.set_dpi(120)
    fig.tight_layout()
    return save_figure(fig, path)
