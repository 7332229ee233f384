"""InterCap on a bundled synthetic scene (`jaxmocap interaction demo`): a person walks and
carries a rigid object, seen by a ring of static RGB-D cameras; the object, the person and
the contact frames are recovered with `methods.interaction` and compared with the truth.

Nothing is downloaded: the motion is the library's procedural walk and the object one of
the bundled meshes ("box", "bottle", "chair"). The scene is `sensors.scenario.interaction_config`
(label images, noisy depth points with holes, BODY_25 detections with OpenPose-like errors,
instance-segmenter mask candidates with distractors).

`simulate_scene` -> `fit_scene` -> `write_outputs`; `run_interaction_demo` chains them.
`fit_scene` runs the method stage by stage, as `methods.interaction.intercap` chains it
(object-only tracking, human-only fit, contact frames detected from the two, joint fit over
all frames, its object kept where `accept_object` accepts it), with E_C on the contact region of the part `detect_contact` found, so every
stage's time is printed and the part is reported. The contact frames and heat map are the
fit's own (no truth); the metrics compare with the truth (penetration and contact gap in
the true contact frames, the gap from the true part's closest vertex, as E_C measures it).

Outputs (`out_dir`):
    result.npz          poses (T, 24, 3) axis-angle, trans (T, 3), betas (B,), object_R (T, 3, 3),
                        object_t (T, 3), contact (T,) bool (the detected contact frames),
                        plus contact_true (T,), fps, contact_part, object_vertices/faces.
    metrics.json        the joint fit's `metrics.interaction_metrics` and
                        `metrics.object_pose_errors` at the top level, contact detection
                        against the truth (precision, recall, F1), the same numbers for the
                        separate fits (object tracking + human-only, "separate"), settings
                        and stage timings.
    contact_heatmap.ply the fitted shape's rest mesh coloured by contact frequency: per body
                        vertex, the fraction of the contact frames in which it is within
                        `physics.metrics.CONTACT_THRESHOLD` (4.5 mm) of the object surface
                        or inside the object (exact point-to-mesh distances, trimesh).
    contact_heatmap.png the same heat on the shaded mesh (front, side, ¾).
    penetration.png     histogram over the contact frames of the deepest body vertex inside
                        the object (mm; 0 = no penetration), with the thesis' 5/7/20 mm marks.
    scene_frame_XXXX.glb the fitted body (clay) and object (blue) of the middle frame, y up.
    plausibility.txt    the MJX plausibility report of the fitted body (`physics.report`:
                        ground penetration, floating, foot contact and skating); its
                        summary is also in metrics.json under "plausibility".
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from .._progress import StageClock

__all__ = [
    "DEMO_OBJECTS",
    "HEAT_CMAP",
    "contact_heat",
    "contact_scores",
    "fit_scene",
    "run_interaction_demo",
    "score_fit",
    "simulate_scene",
    "write_outputs",
]

#: Objects the demo can carry (the bundled meshes of `sensors.scenario`).
DEMO_OBJECTS = ("box", "bottle", "chair")
#: Depth marks (m) of the penetration histogram: the thesis' thresholds (Huang §5.4).
PENETRATION_MARKS = (0.005, 0.007, 0.020)
#: Colour map of the contact heat (PLY and PNG): pale at 0 so the body stays readable.
HEAT_CMAP = "YlOrRd"
_BODY_RGBA = (204, 173, 143, 255)
_OBJECT_RGBA = (66, 110, 190, 255)


def contact_scores(predicted, true) -> dict:
    """Frame-wise contact detection against the truth: precision, recall, F1 and counts.

    With no contact frame in either, all three scores are 1 (nothing to find, nothing
    claimed); precision (recall) is 0 when nothing is claimed (found) but there is truth.
    """
    p, t = np.asarray(predicted, bool), np.asarray(true, bool)
    if p.shape != t.shape:
        raise ValueError(f"predicted contact {p.shape} and true contact {t.shape} must have the same shape.")
    tp, fp, fn = int((p & t).sum()), int((p & ~t).sum()), int((~p & t).sum())
    if tp + fp + fn == 0:
        precision = recall = f1 = 1.0
    else:
        precision = tp / (tp + fp) if tp + fp else 0.0
        recall = tp / (tp + fn) if tp + fn else 0.0
        f1 = 2 * tp / (2 * tp + fp + fn)
    return {"contact_precision": precision, "contact_recall": recall, "contact_f1": f1,
            "contact_true_positives": tp, "contact_false_positives": fp, "contact_false_negatives": fn}  # fmt: skip


def contact_heat(signed_distances, contact, threshold: float | None = None) -> np.ndarray:
    """Per body vertex, the fraction of the `contact` frames (T,) in which its signed
    distance (T, N) to the object is below `threshold` (default 4.5 mm,
    `physics.metrics.CONTACT_THRESHOLD`; inside counts); zeros without contact frames."""
    from ..physics.metrics import CONTACT_THRESHOLD, contact_heatmap

    d, contact = np.asarray(signed_distances, np.float64), np.asarray(contact, bool)
    if d.ndim != 2 or contact.shape != d.shape[:1]:
        raise ValueError(f"signed_distances must be (T, N) and contact (T,); got {d.shape} and {contact.shape}.")
    if not contact.any():
        return np.zeros(d.shape[1])
    return contact_heatmap(d[contact], CONTACT_THRESHOLD if threshold is None else threshold)


def _signed_distances(obj, vertices, R, t) -> np.ndarray:
    """Exact signed distances (T, N) of world points (T, N, 3) to the object posed at
    (R, t) (T, 3, 3), (T, 3): < 0 inside (trimesh's closest points and inside test)."""
    import trimesh

    local = np.einsum("tba,tnb->tna", R, vertices - t[:, None])
    T, N = local.shape[:2]
    return -trimesh.proximity.signed_distance(obj.mesh, local.reshape(-1, 3)).reshape(T, N)


def _strict(x):
    """NaN/inf as null, NumPy scalars as Python numbers: strict JSON."""
    if isinstance(x, dict):
        return {k: _strict(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_strict(v) for v in x]
    if isinstance(x, np.generic):
        x = x.item()
    return None if isinstance(x, float) and not math.isfinite(x) else x


def _penetration_figure(depth_mm: np.ndarray, path: Path, title: str) -> Path:
    from matplotlib.figure import Figure

    from ..viz.plot import save_figure

    fig = Figure(figsize=(6.0, 3.6), dpi=120, layout="constrained")
    ax = fig.subplots()
    if depth_mm.size:
        top = max(float(depth_mm.max()), 25.0)
        ax.hist(depth_mm, bins=np.linspace(0.0, top, 26), color="#4a6fb5", edgecolor="white")
    else:
        ax.text(0.5, 0.5, "no contact frames", ha="center", va="center", transform=ax.transAxes)
    for mark in PENETRATION_MARKS:
        ax.axvline(1e3 * mark, color="#c53030", lw=1.0, ls="--")
        ax.text(1e3 * mark, 1.0, f" {1e3 * mark:g} mm", color="#c53030", fontsize=8, va="top",
                transform=ax.get_xaxis_transform())  # fmt: skip
    ax.set_xlabel("deepest body vertex inside the object (mm)")
    ax.set_ylabel("contact frames")
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    return save_figure(fig, path)


def simulate_scene(
    frames: int = 30,
    object: str = "box",
    views: int = 3,
    width: int = 160,
    height: int = 120,
    depth_points: int = 512,
    seed: int = 0,
    body="default-low",
):
    """The demo's scene: (body, scenario, observations) of the library walk carrying `object`
    (`sensors.scenario.interaction_config`; `scenarios.interaction_observations`)."""
    from ..body.io import resolve_body
    from ..sensors.scenario import interaction_config, make_scenario
    from .scenarios import interaction_observations

    if object not in DEMO_OBJECTS:
        raise ValueError(f"unknown object {object!r}; choose from {list(DEMO_OBJECTS)}.")
    for name, value, low in (("frames", frames, 6), ("views", views, 2)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
            raise ValueError(f"{name} must be an integer >= {low}, got {value!r}.")
    body_model = resolve_body(body)
    config = interaction_config(object=object, num_views=views, max_frames=frames, width=width, height=height,
                                depth_points=depth_points)  # fmt: skip
    scenario = make_scenario(["walk"], config, seed=seed, body=body_model)
    return body_model, scenario, interaction_observations(scenario, 0, seed=seed)


def fit_scene(obs, body, progress: bool = False, log=print) -> dict:
    """InterCap stage by stage (as `methods.interaction.intercap` chains them, the contact
    frames detected): object tracking, human-only fit, contact frames and the part holding
    the object, joint fit with E_C on that part. One progress line per stage to `log`.

    Returns {pose (T, 24, 3) axis-angle, trans, betas (B,), object_R, object_t, contact (T,)
    bool, part, separate: the same keys for the object tracking + human-only fits,
    timings_s}.
    """
    from ..methods.interaction import accept_object, detect_contact, fit_human, fit_joint, track_object

    clock = StageClock(log)
    T = obs.num_frames
    obj = track_object(obs, body=body, progress=progress)
    clock.done("object", f"tracked over {T} frames, seen in {int(obj['observed'].sum())}")
    human = fit_human(obs, body)
    clock.done("human", "per-frame fit (keypoints, depth, bend, self-penetration)")
    contact, part = detect_contact(body, human, obj, obs.obj, obs.fps)
    contact = np.asarray(contact, bool)
    found = f"frames {_ranges(contact)} held by {part}" if contact.any() else "no contact frame detected"
    clock.done("contact", found)
    joint = fit_joint(obs, human, obj, contact, body, parts=(part,))
    kept = accept_object(obs, obj, joint, body)  # as methods.interaction.intercap
    joint = {**joint, "object_R": kept["object_R"], "object_t": kept["object_t"]}
    clock.done("joint", f"all {T} frames together" + (f", E_C on {part}" if contact.any() else "")
               + f"; object accepted in {int(kept['accepted'].sum())} of {T} frames")  # fmt: skip
    separate = {"pose": np.asarray(human["pose"]), "trans": np.asarray(human["trans"]),
                "betas": np.asarray(human["betas"]).mean(0), "object_R": obj["R"], "object_t": obj["t"]}  # fmt: skip
    return {"pose": np.asarray(joint["pose"]), "trans": np.asarray(joint["trans"]), "betas": np.asarray(joint["betas"]),
            "object_R": np.asarray(joint["object_R"]), "object_t": np.asarray(joint["object_t"]), "contact": contact,
            "part": part, "separate": separate, "timings_s": clock.timings}  # fmt: skip


def score_fit(body, obs, truth: dict, true_part: str, fit: dict) -> tuple[dict, np.ndarray]:
    """`metrics.interaction_metrics` (true contact frames, contact region of the true part)
    and `metrics.object_pose_errors` of a fit (keys of `fit_scene`'s result) against the
    scene's truth (`Scenario.sequence`); returns (metrics, posed vertices (T, N, 3))."""
    from ..body.posed import posed_arrays
    from ..methods.interaction import object_sdf
    from ..metrics import interaction_metrics, object_pose_errors
    from ..motion.reach import contact_vertices

    verts, joints = posed_arrays(body, fit["pose"], fit["betas"], fit["trans"], dtype=np.float64)
    R, t = np.asarray(fit["object_R"], np.float64), np.asarray(fit["object_t"], np.float64)
    m = interaction_metrics(verts, joints, truth["joints"][0], R, t, object_sdf(obs.obj), truth["contact"],
                            obs.body_points, obs.body_valid, obs.object_points, obs.object_valid,
                            contact_vertices(body, true_part), obs.obj.vertices)  # fmt: skip
    m.update(object_pose_errors(R, t, truth["obj_R"], truth["obj_t"], obs.obj.vertices, symmetry=obs.obj.symmetry))
    return m, verts


def write_outputs(
    out_dir, body, obs, truth: dict, true_part: str, fit: dict, settings: dict | None = None, log=print
) -> dict:
    """Score `fit` (keys of `fit_scene`'s result; "separate" optional) against the truth and
    write the files of the module docstring into `out_dir`; returns the report (metrics.json)."""
    from ..body.posed import posed_arrays
    from ..viz.mesh import export_mesh
    from ..viz.plot import plot_body

    clock = StageClock(log)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    T = obs.num_frames
    contact, part = np.asarray(fit["contact"], bool), fit["part"]
    true_contact = np.asarray(truth["contact"], bool)
    if contact.shape != (T,):
        raise ValueError(f"fit['contact'] must be ({T},) for {T} frames, got {contact.shape}.")
    report, verts = score_fit(body, obs, truth, true_part, fit)
    report.update(contact_scores(contact, true_contact))
    if fit.get("separate") is not None:
        report["separate"], _ = score_fit(body, obs, truth, true_part, fit["separate"])

    betas = np.asarray(fit["betas"], np.float64)
    R, t = np.asarray(fit["object_R"], np.float64), np.asarray(fit["object_t"], np.float64)
    signed = _signed_distances(obs.obj, verts, R, t)  # (T, N), exact
    heat = contact_heat(signed, contact)
    depth_mm = 1e3 * np.maximum(-signed.min(1), 0.0)[contact]
    np.savez(
        out_dir / "result.npz", poses=np.asarray(fit["pose"], np.float64), trans=np.asarray(fit["trans"], np.float64),
        betas=betas, object_R=R, object_t=t, contact=contact, contact_true=true_contact, fps=np.float64(obs.fps),
        contact_part=np.array(part), object_vertices=np.asarray(obs.obj.vertices, np.float64),
        object_faces=np.asarray(obs.obj.faces, np.int64),
    )  # fmt: skip
    (rest,), _ = posed_arrays(body, np.zeros((1, 24, 3)), betas, dtype=np.float64)
    ply = export_mesh(rest, body.faces, out_dir / "contact_heatmap.ply", colors=heat, cmap=HEAT_CMAP, vmin=0.0,
                      vmax=max(float(heat.max()), 1e-6))  # fmt: skip
    png = plot_body(rest, body.faces, out_dir / "contact_heatmap.png", vertex_values=heat, cmap=HEAT_CMAP,
                    title=f"contact heat ({part}): fraction of the {int(contact.sum())} contact frames "
                          "within 4.5 mm of the object")  # fmt: skip
    name = obs.obj.name
    hist = _penetration_figure(depth_mm, out_dir / "penetration.png",
                               f"{name}: penetration in the {int(contact.sum())} contact frames of the fit")  # fmt: skip
    mid = T // 2
    obj_world = np.asarray(obs.obj.vertices, np.float64) @ R[mid].T + t[mid]
    nb = verts.shape[1]
    colors = np.concatenate([np.tile(_BODY_RGBA, (nb, 1)), np.tile(_OBJECT_RGBA, (len(obj_world), 1))]).astype(np.uint8)
    glb = export_mesh(np.concatenate([verts[mid], obj_world]),
                      np.concatenate([np.asarray(body.faces), np.asarray(obs.obj.faces) + nb]),
                      out_dir / f"scene_frame_{mid:04d}.glb", colors=colors)  # fmt: skip

    from ..motion.sequence import Motion
    from ..physics.mjcf import Ground
    from ..physics.report import format_report, plausibility_report

    plaus = plausibility_report(body, Motion(np.asarray(fit["pose"], np.float64), np.asarray(fit["trans"], np.float64),
                                             obs.fps, betas=betas, name="InterCap fit"), ground=Ground(obs.floor))  # fmt: skip
    phys = out_dir / "plausibility.txt"
    phys.write_text(format_report(plaus) + "\n")
    report["plausibility"] = {"mesh": plaus.summary["mesh"], "feet": plaus.feet}
    clock.done("physics", "MJX plausibility report of the fitted body")

    report["contact_part"] = part
    report["contact_frames"] = [int(i) for i in np.flatnonzero(contact)]
    report["true_contact_part"] = true_part
    report["true_contact_frames"] = [int(i) for i in np.flatnonzero(true_contact)]
    report["max_contact_heat"] = float(heat.max())
    report["settings"] = dict(settings or {})
    report["outputs"] = [p.name for p in (out_dir / "result.npz", out_dir / "metrics.json", ply, png, hist, glb, phys)]
    clock.done("write", f"{len(report['outputs'])} files in {out_dir}")
    report["timings_s"] = {k: round(float(v), 3) for k, v in {**fit.get("timings_s", {}), **clock.timings}.items()}
    report = _strict(report)
    (out_dir / "metrics.json").write_text(json.dumps(report, indent=2, allow_nan=False) + "\n")
    return report


def run_interaction_demo(
    out_dir,
    frames: int = 30,
    object: str = "box",
    views: int = 3,
    width: int = 160,
    height: int = 120,
    depth_points: int = 512,
    seed: int = 0,
    body="default-low",
    progress: bool = False,
    log=print,
) -> dict:
    """Simulate an InterCap scene (`simulate_scene`), fit it (`fit_scene`), score it and
    write the files of the module docstring into `out_dir` (`write_outputs`); `log`
    receives one progress line per stage (None: silent).

    Returns the report (also written as metrics.json): the joint fit's metrics at the top
    level, "separate" (the fits before the joint one), contact frames and parts, settings,
    "timings_s" per stage and "outputs" (the file names written, relative to `out_dir`).
    """
    out_dir = Path(out_dir)
    try:  # before minutes of work, not after
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OSError(e.errno, f"cannot create the output folder {out_dir}: {e.strerror}", str(out_dir)) from e
    clock = StageClock(log)
    body_model, scenario, obs = simulate_scene(frames, object, views, width, height, depth_points, seed, body)
    truth = scenario.sequence(0)
    true_part = scenario.config.contact_part
    clock.done("scene", f"walk carrying a {object}: {obs.num_frames} frames, {views} views of {width} x {height} px, "
                        f"{depth_points} depth points per view, true contact frames {_ranges(truth['contact'])} "
                        f"({true_part})")  # fmt: skip
    fit = fit_scene(obs, body_model, progress=progress, log=log)
    fit["timings_s"] = {**clock.timings, **fit.get("timings_s", {})}
    settings = {"motion": "walk", "object": object, "frames": obs.num_frames, "views": views, "width": width,
                "height": height, "depth_points": depth_points, "seed": seed, "body": body_model.kind,
                "num_vertices": body_model.num_vertices, "fps": obs.fps}  # fmt: skip
    report = write_outputs(out_dir, body_model, obs, truth, true_part, fit, settings, log=log)
    report["timings_s"]["total"] = round(sum(v for k, v in report["timings_s"].items() if k != "total"), 3)
    (out_dir / "metrics.json").write_text(json.dumps(report, indent=2, allow_nan=False) + "\n")
    return report


def _ranges(flags) -> str:
    """(T,) bool -> "10-19, 25-27" (inclusive frame ranges), or "none"."""
    idx = np.flatnonzero(np.asarray(flags, bool))
    if not idx.size:
        return "none"
    breaks = np.flatnonzero(np.diff(idx) > 1)
    starts, ends = np.r_[idx[0], idx[breaks + 1]], np.r_[idx[breaks], idx[-1]]
    return ", ".join(f"{a}-{b}" if b > a else f"{a}" for a, b in zip(starts, ends))
