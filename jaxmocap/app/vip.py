"""The Video Inertial Poser on a recording (`jaxmocap vip demo`, `jaxmocap vip fit FILE.pkl`).

IMU wearers filmed by one hand-held camera with an IMU of its own, among bystanders:
`methods.visual_inertial.video_inertial_scene` runs the Inertial Tracker per wearer, the
association of the detections with the wearers and the fusion, twice (von Marcard §4.3).

`demo_inputs` simulates a scene from the procedural motion library (`sensors.vip_config`:
Xsens-like IMU errors with a 10° heading offset per sensor, OpenPose-like detections with
misses, swaps and false detections; nothing is downloaded); `threedpw_inputs` reads a 3DPW
sequence file (IMUs simulated from its reference poses, its own OpenPose detections:
`sensors.threedpw.vip_inputs`). Both give a `VIPInputs`; `fit_inputs` fits it and
`write_outputs` writes the files below. VIP runs in float64 (as `experiments/vip_tables.py`):
`run_vip_demo` and `run_vip_fit` switch `jax_enable_x64` on.

Outputs (`out_dir`):
    wearer{k}.npz       jaxmocap's own motion file (y up, `motion.load_motion` reads it):
                        poses (T, 24, 3), trans (T, 3), betas, fps, gender, name, and VIP's
                        camera (T, 6) camera-to-world (axis-angle, centre), heading (S,) rad,
                        x0 (24, 3), bones (S,), tracker_poses (T, 24, 3) (the IT start).
    overlay_{t:04d}.png detections coloured by the last association against each wearer's
                        projected model (keypoints and silhouette), first/middle/last frame.
    error_over_time.png MPJPE per frame of IT and VIP per wearer (when the truth is known).
    scene.glb           fitted bodies at 5 frames and the camera path (in wearer 0's world).
    report.json         settings, seconds per stage, association counts per round, heading
                        estimates (°) and errors per wearer.
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from .._progress import StageClock

__all__ = ["DEMO_MOTIONS", "VIPInputs", "demo_inputs", "threedpw_inputs", "fit_inputs", "write_outputs",
           "run_vip_demo", "run_vip_fit"]  # fmt: skip

#: Motions of the demo's people, in order (wearers first): the library's walk and a slower
#: one (0.7 strides/s). Measured (60 frames, 10 LM steps): with squats or arm raises as the
#: second wearer VIP ended worse than IT (73 vs 44 mm; headings of sensors that never tilt
#: are free); with the slow walk every detection of both wearers was assigned right.
DEMO_MOTIONS = ("walk", "slow_walk", "arm_raises", "squats")


def _demo_motion(name, frames, body):
    from ..motion import library

    if name == "slow_walk":
        return library.walk(frames, 30.0, frequency=0.7, body=body)
    return library.MOTIONS[name](num_frames=frames, fps=30.0, body=body)


@dataclasses.dataclass(frozen=True)
class VIPInputs:
    """One recording, ready for `fit_inputs`: body; datas, one `VIPData` per wearer; bones
    (S,); detections (T, D, 18, 3); labels (T, D) the detections' true person (-1 false,
    -2 empty) or None; truths, per wearer {poses, trans, betas, cam_R, cam_t} or None; people, the
    wearers' indices in the source; image_size (W, H); fps; source (a description);
    imu_heading (P, S) the true heading offsets (rad) or None; settings (for the report)."""

    body: object
    datas: tuple
    bones: tuple
    detections: np.ndarray
    labels: np.ndarray | None
    truths: tuple | None
    people: tuple
    image_size: tuple
    fps: float
    source: str
    imu_heading: np.ndarray | None = None
    settings: dict = dataclasses.field(default_factory=dict)


def _count(name, value, low, high=None):
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low or (high and value > high):
        raise ValueError(f"{name} must be an integer in {low} .. {high or 'any'}, got {value!r}.")


def demo_inputs(
    frames: int = 60, wearers: int = 2, bystanders: int = 2, seed: int = 0, body="default-low"
) -> VIPInputs:
    """The demo scene: `wearers` people with 13 IMUs and `bystanders` without, from
    `DEMO_MOTIONS`, filmed by a hand-held camera with an IMU (`sensors.vip_config`)."""
    from ..body.io import resolve_body
    from ..sensors import make_scenario
    from ..sensors.scenario import vip_config
    from .scenarios import vip_sequence

    _count("frames", frames, 8)
    _count("wearers", wearers, 1, 4)
    _count("bystanders", bystanders, 0, 3)
    _count("seed", seed, 0)  # here, not in make_scenario after the motions are built
    if wearers + bystanders > 4:
        raise ValueError(f"the demo scene holds at most 4 people; got {wearers} wearers + {bystanders} bystanders.")
    body = resolve_body(body)
    people = wearers + bystanders
    motions = [_demo_motion(m, frames, body) for m in DEMO_MOTIONS[:people]]
    sc = make_scenario(motions, vip_config(bystanders=people - 1, max_frames=frames), seed=seed,
                       body=body, num_sequences=1)  # fmt: skip
    seq = sc.sequence(0)
    datas, truths = [], []
    for p in range(wearers):
        data, truth, bones = vip_sequence(sc, 0, body, person=p)
        datas.append(data)
        truths.append({k: truth[k] for k in ("poses", "trans", "betas", "cam_R", "cam_t")})
    cams = sc.config.cameras
    names = ", ".join(f"{m} ({'IMUs' if k < wearers else 'bystander'})" for k, m in enumerate(DEMO_MOTIONS[:people]))
    settings = {"frames": int(len(seq["poses"][0])), "wearers": wearers, "bystanders": bystanders, "seed": seed,
                "motions": list(DEMO_MOTIONS[:people]), "body": body.kind, "num_vertices": body.num_vertices}  # fmt: skip
    return VIPInputs(body, tuple(datas), bones, np.asarray(seq["det_keypoints"][0]), np.asarray(seq["det_person"][0]),
                     tuple(truths), tuple(range(wearers)), (cams.width, cams.height), sc.config.fps,
                     f"simulated scene: {names}", np.asarray(seq["imu_heading"][:wearers]).mean(1), settings)  # fmt: skip


def threedpw_inputs(path, people=None, frames: slice | None = None, body="default-low") -> VIPInputs:
    """A 3DPW sequence file: `people` (default all) wear simulated IMUs (noise-free, from
    the reference poses), every person's OpenPose detections are the detections, frames
    default to the longest run where the camera pose is valid for all wearers."""
    from ..body.io import resolve_body
    from ..formats.threedpw import load_threedpw, valid_span
    from ..methods.visual_inertial import vip_data
    from ..sensors.threedpw import vip_inputs

    body = resolve_body(body)
    seq = load_threedpw(path)
    people = tuple(range(seq.num_people)) if people is None else tuple(int(p) for p in people)
    if not people:
        raise ValueError("no wearers: give at least one person index with --people (e.g. 0 or 0,1).")
    bad = [p for p in people if not 0 <= p < seq.num_people]
    if bad or len(set(people)) != len(people):
        raise ValueError(f"people {list(people)}: indices must be distinct and in 0 .. {seq.num_people - 1} "
                         f"({seq.num_people} people in {path}).")  # fmt: skip
    if frames is None:
        frames = valid_span(seq.valid[list(people)].all(0))
    span = range(seq.num_frames)[frames]
    if len(span) < 2 or span.step != 1:
        raise ValueError(f"frames {frames.start}:{frames.stop} select {len(span)} of the {seq.num_frames} frames; "
                         "VIP needs 2 or more consecutive ones.")  # fmt: skip
    frames = slice(span.start, span.stop)
    datas, truths = [], []
    for p in people:
        inputs, truth = vip_inputs(seq, person=p, body=body, frames=frames)
        bones = tuple(int(b) for b in inputs.pop("bones"))
        datas.append(vip_data(bones=bones, **inputs))
        truths.append({k: truth[k] for k in ("poses", "trans", "betas", "cam_R", "cam_t")})
    det = np.swapaxes(seq.keypoints[:, frames], 0, 1)  # (T, P_all, 18, 3)
    labels = np.where((det[..., 2] > 0).any(-1), np.arange(seq.num_people)[None], -2)
    settings = {"file": str(path), "sequence": seq.name, "people": list(people), "frames": [frames.start, frames.stop],
                "body": body.kind, "num_vertices": body.num_vertices}  # fmt: skip
    return VIPInputs(body, tuple(datas), bones, det, labels, tuple(truths), people, (seq.width, seq.height), seq.fps,
                     f"3DPW {seq.name} frames {frames.start}:{frames.stop}, people {list(people)}",
                     settings=settings)  # fmt: skip


def fit_inputs(inputs: VIPInputs, max_steps: int = 30, rounds: int = 2, log=print):
    """`video_inertial_scene` on `inputs` -> `VIPScene` (one line per round to `log`)."""
    from ..methods.visual_inertial import video_inertial_scene

    return video_inertial_scene(inputs.datas, inputs.bones, inputs.detections, rounds=rounds, max_steps=max_steps,
                                log=log)  # fmt: skip


def _project(camera, points):
    """Pixels (T, N, 2) of world points (T, N, 3) in cameras (T, 4, 4) camera-to-world; NaN behind."""
    R, c = camera[:, :3, :3], camera[:, :3, 3]
    pc = np.einsum("tba,tnb->tna", R, points - c[:, None])
    return pc, np.where(pc[..., 2:] > 1e-6, pc[..., :2] / np.maximum(pc[..., 2:], 1e-6), np.nan)


def _pixels(K, xy):
    return xy @ K[:2, :2].T + K[:2, 2]


def _association_counts(assoc, labels, people) -> dict:
    out = {"assigned": [int(n) for n in (assoc.index >= 0).sum(1)]}
    if labels is not None:
        T = labels.shape[0]
        who = labels[np.arange(T)[None], np.maximum(assoc.index, 0)]  # (P, T)
        right = (assoc.index >= 0) & (who == np.asarray(people)[:, None])
        out["right"] = [int(n) for n in right.sum(1)]
        out["wearer_frames_detected"] = [int((labels == p).any(1).sum()) for p in people]
    return out


def write_outputs(out_dir, inputs: VIPInputs, scene, log=print) -> dict:
    """Write the files of the module docstring for a fitted `scene` (`VIPScene`) of
    `inputs`; returns the report (also written as report.json)."""
    from ..body.posed import posed_arrays
    from ..methods.visual_inertial import camera_matrices, into_camera, world_keypoints
    from ..metrics import pose_errors
    from ..motion.io import FORMAT_VERSION
    from ..viz.vip import error_over_time_png, overlay_png, scene_glb

    clock = StageClock(log)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    body, fps, P = inputs.body, inputs.fps, len(inputs.datas)
    T = inputs.detections.shape[0]
    outputs, people = [], []
    cams = [np.asarray(camera_matrices(r.camera), np.float64) for r in scene.people]
    verts, kps = [], []
    for k, (data, r) in enumerate(zip(inputs.datas, scene.people)):
        betas = np.asarray(data.betas, np.float64)
        name = f"wearer{k}.npz"
        np.savez(out_dir / name, jaxmocap_motion=np.array(FORMAT_VERSION), poses=np.asarray(r.poses, np.float64),
                 trans=np.asarray(r.trans, np.float64), fps=np.array(fps), betas=betas, gender=np.array("neutral"),
                 name=np.array(f"VIP fit of person {inputs.people[k]}"), camera=np.asarray(r.camera, np.float64),
                 heading=np.asarray(r.heading, np.float64), x0=np.asarray(r.x0, np.float64),
                 bones=np.asarray(inputs.bones), tracker_poses=np.asarray(r.init, np.float64))  # fmt: skip
        outputs.append(name)
        verts.append(posed_arrays(body, r.poses, betas, r.trans, dtype=np.float64)[0])
        kps.append(world_keypoints(data, r.poses, r.trans))
        entry = {"person": int(inputs.people[k]), "heading_deg": [round(float(h), 2) for h in np.degrees(r.heading)],
                 "cost": float(r.solution.cost)}  # fmt: skip
        if inputs.imu_heading is not None:  # γ_s corrects the offset: the truth is its negative
            entry["heading_error_deg"] = float(np.degrees(np.abs(np.asarray(r.heading) + inputs.imu_heading[k])).mean())
        people.append(entry)
    clock.done("files", f"{P} wearer npz")

    # Overlays: each wearer projected by their own camera (each is fitted in its own world).
    assoc = scene.associations[-1]
    frames = sorted({0, T // 2, T - 1})
    K = np.asarray(inputs.datas[0].K, np.float64)
    for t in frames:
        joints = np.stack([_project(c[t : t + 1], x[t : t + 1])[1][0] for c, x in zip(cams, kps)])
        silhouettes = np.stack([_project(c[t : t + 1], v[t : t + 1])[1][0] for c, v in zip(cams, verts)])
        D = inputs.detections.shape[1]
        assignment = np.full(D, -1)
        for p in range(P):
            if assoc.index[p, t] >= 0:
                assignment[assoc.index[p, t]] = p
        png = overlay_png(out_dir / f"overlay_{t:04d}.png", inputs.image_size, inputs.detections[t], assignment,
                          _pixels(K, joints), _pixels(K, silhouettes), np.asarray(body.faces),
                          title=f"frame {t}: detections (solid, by association) and the VIP fit (dashed)")  # fmt: skip
        outputs.append(png.name)
    clock.done("overlays", f"frames {frames}")

    report = {"source": inputs.source, "settings": dict(inputs.settings), "frames": T, "fps": fps,
              "association": [_association_counts(a, inputs.labels, inputs.people) for a in scene.associations],
              "people": people}  # fmt: skip
    if inputs.truths is not None:
        curves = {}
        for k, (truth, r) in enumerate(zip(inputs.truths, scene.people)):
            for method, poses in (("IT", r.init), ("VIP", r.poses)):
                e = pose_errors(body, np.asarray(poses, np.float64), truth["poses"], betas=truth["betas"])
                curves[f"{method} wearer {k}"] = e["mpjpe"].mean(-1)
                people[k][f"{method.lower()}_mpjpe_mm"] = float(e["mpjpe"].mean())
                people[k][f"{method.lower()}_mpjae_deg"] = float(e["mpjae"].mean())
        png = error_over_time_png(out_dir / "error_over_time.png", curves, fps, ylabel="MPJPE [mm] (Procrustes)",
                                  title="Inertial Tracker vs VIP per wearer")  # fmt: skip
        outputs.append(png.name)
        clock.done("errors", ", ".join(f"wearer {k}: IT {e['it_mpjpe_mm']:.1f} mm -> VIP {e['vip_mpjpe_mm']:.1f} mm"
                                       for k, e in enumerate(people)))  # fmt: skip

    world = np.stack([into_camera(v, c, cams[0]) for v, c in zip(verts, cams)])  # into wearer 0's world
    glb = scene_glb(out_dir / "scene.glb", world, np.asarray(body.faces), cams[0][:, :3, 3],
                    np.swapaxes(cams[0][:, :3, :3], -1, -2))  # fmt: skip
    outputs.append(glb.name)
    clock.done("scene", f"{glb} (bodies at 5 frames, camera path)")
    report["outputs"] = outputs + ["report.json"]
    report["seconds"] = {k: round(float(v), 3) for k, v in {**scene.seconds, **clock.timings}.items()}
    (out_dir / "report.json").write_text(json.dumps(report, indent=2, allow_nan=False) + "\n")
    return report


def _run(out_dir, make_inputs, max_steps, log) -> dict:
    import jax

    jax.config.update("jax_enable_x64", True)  # VIP's solves run in float64
    out_dir = Path(out_dir)
    try:  # before minutes of work, not after
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OSError(e.errno, f"cannot create the output folder {out_dir}: {e.strerror}", str(out_dir)) from e
    say = log if log is not None else (lambda *_: None)
    start = time.perf_counter()
    inputs = make_inputs()
    T, D = inputs.detections.shape[:2]
    seconds = {"inputs": time.perf_counter() - start}
    say(f"inputs   {inputs.source}: {T} frames, {len(inputs.datas)} wearer(s) with {len(inputs.bones)} IMUs, "
        f"up to {D} detections per frame ({seconds['inputs']:.1f} s)")  # fmt: skip
    scene = fit_inputs(inputs, max_steps=max_steps, log=lambda line: say(f"vip      {line}"))
    scene = dataclasses.replace(scene, seconds={**seconds, **scene.seconds})
    report = write_outputs(out_dir, inputs, scene, log=log)
    report["settings"]["max_steps"] = max_steps
    report["seconds"]["total"] = round(time.perf_counter() - start, 3)
    (out_dir / "report.json").write_text(json.dumps(report, indent=2, allow_nan=False) + "\n")
    return report


def run_vip_demo(
    out_dir,
    frames: int = 60,
    wearers: int = 2,
    bystanders: int = 2,
    seed: int = 0,
    body="default-low",
    max_steps: int = 30,
    log=print,
) -> dict:
    """Simulate the demo scene (`demo_inputs`), fit it and write the outputs; returns the report."""
    return _run(out_dir, lambda: demo_inputs(frames, wearers, bystanders, seed, body), max_steps, log)


def run_vip_fit(
    path, out_dir, people=None, frames: slice | None = None, body="default-low", max_steps: int = 30, log=print
) -> dict:
    """Fit a 3DPW sequence file (`threedpw_inputs`) and write the outputs; returns the report."""
    from ..motion.skeleton import check_file

    check_file(path)  # a missing file is named before the output folder is made
    return _run(out_dir, lambda: threedpw_inputs(path, people, frames, body), max_steps, log)
