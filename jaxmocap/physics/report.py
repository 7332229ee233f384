"""A plausibility report for a motion: table of statistics and a plot over time.

`plausibility_report(body, motion)` poses the mesh (exact vertex-to-plane distances),
runs the batched MJX checker on the capsules, and gathers the statistics of `metrics`;
`format_report` prints them as a table; `plot_report` draws penetration, lowest-point
height and foot contacts over time.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from ..body.model import SMPL_FEET, Body
from .checker import Scene, check, make_scene
from .metrics import (
    CONTACT_THRESHOLD,
    bone_min_distance,
    contact_heatmap,
    foot_contact,
    foot_skating,
    penetration_summary,
)
from .mjcf import Ground

__all__ = ["PlausibilityReport", "plausibility_report", "format_report", "plot_report", "estimate_ground_height"]


@dataclasses.dataclass(frozen=True)
class PlausibilityReport:
    """Per-frame arrays and sequence statistics of one motion.

    Attributes:
        name, fps: of the motion.
        ground_height: the plane height used (normal +y).
        lowest_mesh: (T,) lowest vertex height above the plane (m; < 0 penetrating).
        lowest_capsules: (T,) lowest capsule height from MJX (m).
        foot_heights: (T, 4) lowest capsule of heels and toes (`SMPL_FEET`), m.
        foot_contact: (T, 4) bool.
        skating: (T-1, 4) horizontal foot speed in contact (m/s; NaN out of contact).
        heatmap: (V,) fraction of frames each vertex is within 4.5 mm of the floor.
        summary: {"mesh": {...}, "capsules (MJX)": {...}} from `penetration_summary`.
        feet: foot statistics (contact fraction, skating mean/p95 speed, sliding share).
    """

    name: str
    fps: float
    ground_height: float
    lowest_mesh: np.ndarray
    lowest_capsules: np.ndarray
    foot_heights: np.ndarray
    foot_contact: np.ndarray
    skating: np.ndarray
    heatmap: np.ndarray
    summary: dict
    feet: dict


def estimate_ground_height(lowest_heights, percentile: float = 5.0) -> float:
    """Floor height from per-frame lowest vertex heights: their `percentile`-th percentile.

    (Huang §5.2.4 fits a plane to chosen floor vertices; for a level floor the low
    percentile of the per-frame lowest points is the one-parameter version, robust to
    jumps and to a few frames dipping below.)
    """
    return float(np.percentile(np.asarray(lowest_heights), percentile))


def plausibility_report(
    body: Body,
    motion,
    ground: Ground | str | None = None,
    scene: Scene | None = None,
    contact_height: float = 0.02,
    slide_speed: float = 0.1,
    chunk: int = 256,
) -> PlausibilityReport:
    """Statistics of a `Motion` posed on `body` against a ground plane.

    Args:
        body: the body model; motion: a `Motion` (y up).
        ground: a `Ground`, "auto" (estimated level floor) or None (y = 0).
        scene: a ready scene for this body shape (else fitted here).
        contact_height: foot contact when the foot's lowest capsule is below this (m).
        slide_speed: a contact step faster than this (m/s) counts as sliding.
        chunk: frames posed at once.
    """
    from ..motion.sequence import Motion
    from ..body.posed import posed_vertices

    if not isinstance(body, Body):
        raise ValueError(
            f"body must be a jaxmocap Body, got {type(body).__name__}: call plausibility_report(body, motion)."
        )
    if not isinstance(motion, Motion):
        raise ValueError(
            f"motion must be a jaxmocap.motion.Motion, got {type(motion).__name__}; wrap arrays as "
            "Motion(poses=(T, 24, 3), trans=(T, 3), fps=...)."
        )
    vertices, _ = posed_vertices(body, motion, chunk=chunk)
    vertices = vertices.astype(np.float64)
    if ground is None:
        ground = Ground(0.0)
    elif isinstance(ground, str):
        if ground != "auto":
            raise ValueError(f"ground must be a Ground, 'auto' or None, got {ground!r}.")
        ground = Ground(estimate_ground_height(vertices[..., 1].min(-1)))
    n = np.asarray(ground.normal, np.float64)
    heights = vertices @ n - float(ground.height)
    betas = np.asarray(motion.betas)[: body.num_betas]
    if scene is None:
        scene = make_scene(body, betas if betas.size else None, ground=ground)
    distances = check(scene, np.asarray(motion.poses, np.float32), np.asarray(motion.trans, np.float32), chunk=chunk)
    ground_d = np.asarray(distances.ground, np.float64)
    foot_h = bone_min_distance(scene, ground_d, SMPL_FEET)
    contact = foot_contact(foot_h, contact_height)
    from .checker import pose_bones
    import jax

    _, joints = jax.jit(jax.vmap(lambda p, t: pose_bones(scene, p, t)))(
        np.asarray(motion.poses, np.float32), np.asarray(motion.trans, np.float32)
    )
    feet_idx = [scene.joint_names.index(name) for name in SMPL_FEET]
    skating = foot_skating(np.asarray(joints)[:, feet_idx], contact, ground, motion.fps)
    valid = skating[np.isfinite(skating)]
    feet = {
        "contact_fraction": [float(x) for x in contact.mean(0)],
        "skating_mean_m_s": float(valid.mean()) if valid.size else 0.0,
        "skating_p95_m_s": float(np.percentile(valid, 95)) if valid.size else 0.0,
        "sliding_fraction": float((valid > slide_speed).mean()) if valid.size else 0.0,
        "contact_steps": int(valid.size),
    }
    summary = {
        "mesh": penetration_summary(heights.min(-1)),
        "capsules (MJX)": penetration_summary(ground_d.min(-1)),
    }
    return PlausibilityReport(
        name=motion.name,
        fps=motion.fps,
        ground_height=float(ground.height),
        lowest_mesh=heights.min(-1),
        lowest_capsules=ground_d.min(-1),
        foot_heights=foot_h,
        foot_contact=contact,
        skating=skating,
        heatmap=contact_heatmap(heights, CONTACT_THRESHOLD),
        summary=summary,
        feet=feet,
    )


_ROWS = (
    ("penetration mean (mm)", "penetration_mean_mm", "{:.1f}"),
    ("penetration max (mm)", "penetration_max_mm", "{:.1f}"),
    ("lowest point mean (mm)", "lowest_mean_mm", "{:.1f}"),
    ("lowest point min..max (mm)", ("lowest_min_mm", "lowest_max_mm"), "{:.1f} .. {:.1f}"),
    ("contact frames (< 4.5 mm)", "contact_frames", "{:d}"),
    ("mean penetration, contact frames (mm)", "penetration_in_contact_mean_mm", "{:.1f}"),
    ("contact frames > 5 mm", "frac_above_5mm", "{:.1%}"),
    ("contact frames > 7 mm", "frac_above_7mm", "{:.1%}"),
    ("contact frames > 10 mm", "frac_above_10mm", "{:.1%}"),
    ("contact frames > 20 mm", "frac_above_20mm", "{:.1%}"),
)


def format_report(report: PlausibilityReport) -> str:
    """The report as a plain-text table (mesh vs capsule columns, then the feet)."""
    T = len(report.lowest_mesh)
    cols = list(report.summary)
    lines = [
        f"motion   {report.name or '?'}: {T} frames at {report.fps:g} fps; ground y = {report.ground_height:.4f} m",
        f"{'ground':40s}" + "".join(f"{c:>18s}" for c in cols),
    ]
    for label, key, fmt in _ROWS:
        cells = []
        for c in cols:
            s = report.summary[c]
            cells.append(fmt.format(*(s[k] for k in key)) if isinstance(key, tuple) else fmt.format(s[key]))
        lines.append(f"{label:40s}" + "".join(f"{x:>18s}" for x in cells))
    f = report.feet
    contact = " ".join(
        f"{n.replace('left_', 'L ').replace('right_', 'R ')} {x:.0%}" for n, x in zip(SMPL_FEET, f["contact_fraction"])
    )
    lines += [
        "feet",
        f"  in contact (< 2 cm)                  {contact}",
        f"  skating speed in contact             mean {1e3 * f['skating_mean_m_s']:.0f} mm/s, "
        f"p95 {1e3 * f['skating_p95_m_s']:.0f} mm/s over {f['contact_steps']} contact steps",
        f"  sliding steps (> 0.1 m/s)            {f['sliding_fraction']:.1%}",
    ]
    return "\n".join(lines)


def plot_report(report: PlausibilityReport, path) -> Path:
    """PNG: lowest point (mesh and capsules) and penetration over time, foot contacts below."""
    from matplotlib.figure import Figure

    from ..viz.plot import save_figure

    T = len(report.lowest_mesh)
    t = np.arange(T) / report.fps
    fig = Figure(figsize=(11.5, 6), dpi=110)
    ax0, ax1 = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [3, 1]})
    ax0.plot(t, 1e3 * report.lowest_mesh, lw=1.2, label="lowest vertex (mesh)")
    ax0.plot(t, 1e3 * report.lowest_capsules, lw=1.0, ls="--", label="lowest capsule (MJX)")
    pen = np.maximum(-report.lowest_mesh, 0)
    ax0.fill_between(t, -1e3 * pen, 0, color="tab:red", alpha=0.35, label="penetration (mesh)")
    for thr in (5, 10, 20):
        ax0.axhline(-thr, color="tab:red", lw=0.5, ls=":")
    ax0.axhline(0, color="k", lw=0.8)
    ax0.set_ylabel("height above floor (mm)")
    # A loaded motion is named by its path: the file name says which, the folders only crowd.
    name = Path(report.name).name if report.name and ("/" in report.name or "\\" in report.name) else report.name
    ax0.set_title(f"plausibility: {name or 'motion'}")
    # Beside the axes: inside, the legend covered the curve wherever the motion dipped.
    ax0.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, fontsize=8)
    for i in range(len(SMPL_FEET)):
        on = report.foot_contact[:, i]
        ax1.fill_between(t, i, i + 0.8 * on, step="mid", alpha=0.6)
    ax1.set_yticks(np.arange(4) + 0.4, [n.replace("_", " ") for n in SMPL_FEET], fontsize=8)
    ax1.set_xlabel("time (s)")
    ax1.set_title("foot contact", fontsize=9)
    fig.tight_layout()
    return save_figure(fig, path)
