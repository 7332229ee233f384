"""Multi-view SMPLify on real recordings: Pose2Sim's demo videos through MediaPipe Pose (issue 47).

    python experiments/multiview_real.py [--pose2sim DIR] [--detector-python PY] [--frames N]
        [--out experiments/results/multiview_real.json] [--work DIR]

The pose2sim package ships two real 4-camera recordings (60 fps, 1088 x 1920 portrait
videos, a Qualisys calibration each): Demo_SinglePerson and Demo_MultiPerson (its
Demo_Batch trials are byte-identical copies of these two). Each is run as a user would:
`jaxmocap.app.multiview_video.fit_videos` (= `jaxmocap multiview --videos DIR --calib
FILE`, library defaults, default-low body), and the fit is compared with what the same
detections give without a body model: a confidence-weighted per-keypoint triangulation of
the subject that `select_person` picked (the same points the fit sees), over the points
both have (confidence >= 0.2, seen by two views):
  - reprojection: median pixel error of the fit and of the triangulation
    (`fit_over_triangulation` = their ratio; the triangulation is the least-squares optimum
    per point, so the ratio measures what the body's constraints cost);
  - limb lengths: the fit's (median over frames) against the triangulated ones' median;
  - jitter: mean |second difference| x fps^2 of the 12 limb keypoints (shoulders to
    ankles) per 30-frame DCT window of stage 2 (the last window is partial), fit and
    triangulated; and of SMPL's 24 joints for the fit;
  - run time: the detector per camera and each stage of the fit.
Nothing here is tuned: the library's default weights are used as they are (the "validated"
preset, `MuVSWeights()`: λ_θ = 1, λ_β = 50, chosen on synthetic CMU subjects 02 and 131 by
experiments/muvs_tuning.py; until 2026-12-07 λ_θ was 20). Demo_MultiPerson is the held-out recording: it was not run while the detector,
the layout and this script were built, and is reported separately. It has several people;
MediaPipe's legacy pose solution tracks one person per video, so the views may follow
different people, and `select_person` has no second candidate per view to choose from.
Data are read from the installed (or unpacked) pose2sim package, never copied.
"""

from __future__ import annotations

import sys as _sys
from pathlib import Path as _Path

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import _provenance  # noqa: E402,F401  (its commit is taken now, at the start of the run)

import argparse  # noqa: E402
import importlib.util  # noqa: E402
import os  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

DEVELOPMENT = "Demo_SinglePerson"
HELD_OUT = "Demo_MultiPerson"
LIMBS = [(f"{s}_{a}", f"{s}_{b}") for s in ("left", "right")
         for a, b in (("shoulder", "elbow"), ("elbow", "wrist"), ("hip", "knee"), ("knee", "ankle"))]  # fmt: skip
WIDTHS = [("left_shoulder", "right_shoulder"), ("left_hip", "right_hip")]
LIMB_POINTS = [f"{s}_{j}" for s in ("left", "right") for j in ("shoulder", "elbow", "wrist", "hip", "knee", "ankle")]


def pose2sim_root(path=None) -> Path:
    """The folder holding pose2sim's Demo_* folders: `path`, else the installed package's."""
    if path is not None:
        root = Path(path)
    else:
        spec = importlib.util.find_spec("Pose2Sim")
        if spec is None or not spec.submodule_search_locations:
            raise SystemExit("pose2sim is not installed: pip install pose2sim==0.10.49 (or unzip its wheel and "
                             "pass --pose2sim DIR/Pose2Sim).")  # fmt: skip
        root = Path(next(iter(spec.submodule_search_locations)))
    missing = [n for n in (DEVELOPMENT, HELD_OUT) if not (root / n / "videos").is_dir()]
    if missing:
        raise SystemExit(f"{root}: no {missing} with videos/; give pose2sim's package folder (--pose2sim).")
    return root


def _stats(x):
    x = np.asarray(x, np.float64)
    x = x[np.isfinite(x)]
    return {"median": float(np.median(x)), "mean": float(x.mean()), "p90": float(np.percentile(x, 90)),
            "count": int(x.size)} if x.size else {"median": None, "mean": None, "p90": None, "count": 0}  # fmt: skip


def _accel(points, fps):
    """(T, ...) |second difference| x fps^2 at frames 1..T-2, NaN-padded to (T, ...)."""
    a = np.linalg.norm(points[2:] - 2 * points[1:-1] + points[:-2], axis=-1) * fps**2
    pad = np.full((1,) + a.shape[1:], np.nan)
    return np.concatenate([pad, a, pad])


def analyse(report, fit_dir: Path, calib: Path, window: int) -> dict:
    """Fit against per-keypoint triangulation of the same detections (module docstring)."""
    from jaxmocap.app.multiview import MIN_CONFIDENCE, reprojection_errors, world_to_y_up
    from jaxmocap.body import posed_vertices
    from jaxmocap.body.io import default_body
    from jaxmocap.formats import align_views, load_calibration, read_openpose
    from jaxmocap.geometry.keypoints import KEYPOINT_FORMATS, keypoint_regressor, regress_keypoints
    from jaxmocap.geometry.triangulation import projection_matrices, select_person, triangulate
    from jaxmocap.motion.amass import load_amass

    names = KEYPOINT_FORMATS["mediapipe33"]
    recording = read_openpose(fit_dir / "keypoints", "mediapipe33")
    assert len(recording.frames) == report["frames"]["count"], "a detection is missing: frames differ from the fit"
    cameras = align_views(recording, load_calibration(calib))
    subject = select_person(recording, cameras)  # (V, T, K, 3): as fit_recording picks it
    keypoints = np.moveaxis(subject, 0, 1).copy()
    bad = ~np.isfinite(keypoints).all(-1) | (keypoints[..., 2] <= 0)
    keypoints[bad] = 0.0
    P = projection_matrices(cameras)
    fps = report["frames"]["fps"]

    tri, _ = triangulate(P, np.moveaxis(keypoints[..., :2], 1, 0), np.moveaxis(keypoints[..., 2], 1, 0))  # (T, K, 3)

    body = default_body("low")  # the fit's (fit_recording's default)
    assert report["body"] == body.kind, report["body"]
    verts_y, joints_y = posed_vertices(body, load_amass(fit_dir / "smpl.npz", body=body))
    _, to_y = world_to_y_up(cameras)
    verts = np.asarray(verts_y, np.float64) @ to_y  # back to the calibration's world
    joints = np.asarray(joints_y, np.float64) @ to_y
    fit = regress_keypoints(keypoint_regressor(body, "mediapipe33"), verts, joints)

    def project(X):
        x = np.einsum("vab,tkb->tvka", P[:, :, :3], X) + P[None, :, None, :, 3]
        return x[..., :2] / x[..., 2:]

    err_fit = reprojection_errors(project(fit), keypoints)
    err_tri = reprojection_errors(project(np.nan_to_num(tri)), keypoints)
    both = np.isfinite(err_fit) & np.isfinite(err_tri) & np.isfinite(tri).all(-1)[:, None, :]
    med_fit, med_tri = float(np.median(err_fit[both])), float(np.median(err_tri[both]))
    per_view = {v: {"fit": _stats(err_fit[:, i][both[:, i]]), "triangulation": _stats(err_tri[:, i][both[:, i]])}
                for i, v in enumerate(recording.views)}  # fmt: skip
    limb_idx = [names.index(n) for n in LIMB_POINTS]
    per_keypoint = {n: {"fit_median_px": _stats(err_fit[:, :, k][both[:, :, k]])["median"],
                        "triangulation_median_px": _stats(err_tri[:, :, k][both[:, :, k]])["median"]}
                    for k, n in enumerate(names)}  # fmt: skip

    lengths = {}
    for a, b in LIMBS + WIDTHS:
        i, j = names.index(a), names.index(b)
        d_fit = np.linalg.norm(fit[:, i] - fit[:, j], axis=-1)
        d_tri = np.linalg.norm(tri[:, i] - tri[:, j], axis=-1)
        f, t = float(np.median(d_fit)), float(np.nanmedian(d_tri))
        lengths[f"{a}-{b}"] = {"fit_m": f, "triangulated_m": t, "fit_over_triangulated": f / t,
                               "triangulated_spread_m": float(np.nanpercentile(d_tri, 75) - np.nanpercentile(d_tri, 25))}  # fmt: skip

    T = len(fit)
    acc_fit, acc_tri = _accel(fit[:, limb_idx], fps), _accel(tri[:, limb_idx], fps)
    acc_joints = _accel(joints, fps)
    windows = []
    for s in range(0, T, window):
        e = min(T, s + window)
        windows.append({
            "frames": [int(recording.frames[s]), int(recording.frames[e - 1])], "partial": e - s < window,
            "fit_limb_keypoints_m_s2": _stats(acc_fit[s:e])["mean"],
            "triangulated_limb_keypoints_m_s2": _stats(acc_tri[s:e])["mean"],
            "fit_smpl_joints_m_s2": _stats(acc_joints[s:e])["mean"],
        })  # fmt: skip
    return {
        "frames": T,
        "views": list(recording.views),
        "points_compared": int(both.sum()),
        "min_confidence": MIN_CONFIDENCE,
        "reprojection_px": {
            "fit_median": med_fit,
            "triangulation_median": med_tri,
            "fit": _stats(err_fit[both]),
            "triangulation": _stats(err_tri[both]),
            "per_view": per_view,
            "per_keypoint": per_keypoint,
        },  # fmt: skip
        "fit_over_triangulation": med_fit / med_tri,
        "limb_lengths": lengths,
        "limb_length_error_max_pct": 100 * max(abs(v["fit_over_triangulated"] - 1) for v in lengths.values()),
        "jitter_per_window": windows,
        "jitter_m_s2": {
            "fit_limb_keypoints": _stats(acc_fit)["mean"],
            "triangulated_limb_keypoints": _stats(acc_tri)["mean"],
            "fit_smpl_joints": _stats(acc_joints)["mean"],
        },  # fmt: skip
    }


def run(name: str, root: Path, work: Path, frames: int, python) -> dict:
    from jaxmocap.app.multiview_video import fit_videos
    from jaxmocap.methods.multiview import MuVSWeights

    demo = root / name
    calib = next((demo / "calibration").glob("*.qca.txt"))
    lines: list[str] = []
    start, cpu = time.perf_counter(), time.process_time()
    report = fit_videos(demo / "videos", calib, work / name, detector_python=python, frames=slice(0, frames),
                        progress=False, log=lambda s: (lines.append(s), print(f"  {s}", flush=True)))  # fmt: skip
    wall = time.perf_counter() - start
    out = analyse(report, work / name, calib, MuVSWeights().window)
    det = report["detection"]
    out["report"] = {
        "reprojection_median_px": {k: report["reprojection"][k]["overall"]["median_px"] for k in ("stage1", "final")},
        "jitter_mm_s2": report["jitter_mm_s2"], "layout_check": report["layout_check"]["verdict"],
        "frames_without_subject": report["frames"]["without_subject"],
        "frames_with_subject_per_view": {v: i["frames_with_subject"] for v, i in report["views"].items()},
    }  # fmt: skip
    out["detection"] = {"mediapipe": det["mediapipe"], "fps": det["fps"], "frames": det["frames"],
                        "frames_with_a_person": det["detected"], "seconds": det["seconds"]}  # fmt: skip
    out["run_time_s"] = {"detector": round(sum(det["seconds"].values()), 1), "fit": report["timings_s"],
                         "wall_total": round(wall, 1), "cpu_this_process": round(time.process_time() - cpu, 1)}  # fmt: skip
    out["notes"] = [s for s in lines if s.startswith("warning")]
    out["calibration"] = str(calib.relative_to(root.parent))
    return out


def markdown(result: dict) -> str:
    lines = ["# Multi-view SMPLify on real recordings (Pose2Sim demo videos, MediaPipe Pose)", "",
             result["description"], "",
             f"Machine: {result['machine']}, shared with other jobs (load average {result['load_average']['start']:.1f} "
             f"at the start, {result['load_average']['end']:.1f} at the end). Frames: the first "
             f"{result['frames_per_recording']} of each recording (100 is all of them). Run time "
             f"{result['run_time_s']:.0f} s in all (wall clock: "
             + "; ".join(f"{n} {r['run_time_s']['wall_total']:.0f} s, of which the detector "
                         f"{r['run_time_s']['detector']:.0f} s = {r['run_time_s']['detector'] / (r['frames'] * len(r['views'])):.2f} "
                         "s a frame and camera" for n, r in result["recordings"].items())
             + "); the fit's stages per recording are in the JSON (`run_time_s.fit`).", "",
             "| recording | role | frames x views | fit median px | triangulation median px | fit_over_triangulation "
             "| worst limb length vs triangulated | jitter fit / triangulated (limb points, m/s²) | detector s | fit s |",
             "|---|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for name, r in result["recordings"].items():
        rp = r["reprojection_px"]
        j = r["jitter_m_s2"]
        lines.append(f"| {name} | {r['role']} | {r['frames']} x {len(r['views'])} | {rp['fit_median']:.1f} | "
                     f"{rp['triangulation_median']:.1f} | {r['fit_over_triangulation']:.2f} | "
                     f"{r['limb_length_error_max_pct']:.1f} % | {j['fit_limb_keypoints']:.1f} / "
                     f"{j['triangulated_limb_keypoints']:.1f} | {r['run_time_s']['detector']:.0f} | "
                     f"{r['run_time_s']['fit']['total']:.0f} |")  # fmt: skip
    for name, r in result["recordings"].items():
        lines += ["", f"## {name} ({r['role']})", "", "| limb | fit m | triangulated m (IQR) | fit / triangulated |",
                  "|---|---|---|---|"]  # fmt: skip
        for limb, v in r["limb_lengths"].items():
            lines.append(f"| {limb} | {v['fit_m']:.3f} | {v['triangulated_m']:.3f} ({v['triangulated_spread_m']:.3f}) "
                         f"| {v['fit_over_triangulated']:.3f} |")  # fmt: skip
        lines += ["", "| window (frames) | partial | fit limb points m/s² | triangulated m/s² | fit SMPL joints m/s² |",
                  "|---|---|---|---|---|"]  # fmt: skip
        for w in r["jitter_per_window"]:
            lines.append(f"| {w['frames'][0]}-{w['frames'][1]} | {'yes' if w['partial'] else 'no'} | "
                         f"{w['fit_limb_keypoints_m_s2']:.1f} | {w['triangulated_limb_keypoints_m_s2']:.1f} | "
                         f"{w['fit_smpl_joints_m_s2']:.1f} |")  # fmt: skip
        pv = r["reprojection_px"]["per_view"]
        lines += ["", "Per view, median px fit / triangulation: "
                  + ", ".join(f"{v} {s['fit']['median']:.1f} / {s['triangulation']['median']:.1f}" for v, s in pv.items())
                  + f". The fit's own report: stage 1 {r['report']['reprojection_median_px']['stage1']:.1f} px, "
                  f"final {r['report']['reprojection_median_px']['final']:.1f} px (all detections ≥ 0.2). "
                  f"Frames with the subject per view: {r['report']['frames_with_subject_per_view']}."]  # fmt: skip
        if r["notes"]:
            lines += ["", "Warnings of the run: " + " / ".join(r["notes"])]
    return "\n".join(lines) + "\n"


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--pose2sim", default=None, help="pose2sim's package folder (default: the installed package)")
    p.add_argument(
        "--detector-python",
        default=None,
        help="the Python with mediapipe 0.10.21 (default: $JAXMOCAP_VIDEO_PYTHON, else this one)",
    )
    p.add_argument("--frames", type=int, default=100, help="first frames of each recording (default: 100, all)")
    p.add_argument("--out", type=Path, default=Path("experiments/results/multiview_real.json"))
    p.add_argument("--work", type=Path, default=None, help="where fits are written (default: a temporary folder)")
    args = p.parse_args(argv)
    from _provenance import machine, write_json, write_text

    from jaxmocap.motion.splits import Split

    root = pose2sim_root(args.pose2sim)
    result = {"description": __doc__.split("\n\n")[2].strip(), "frames_per_recording": args.frames,
              "held_out": HELD_OUT, "pose2sim": str(root), "recordings": {}}  # fmt: skip
    load_start = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        work = args.work or Path(tmp)
        start = time.perf_counter()
        for name, role in ((DEVELOPMENT, "development"), (HELD_OUT, "held out")):
            print(f"{name} ({role})", flush=True)
            result["recordings"][name] = {"role": role, **run(name, root, work, args.frames, args.detector_python)}
            r = result["recordings"][name]
            print(f"  fit {r['reprojection_px']['fit_median']:.1f} px, triangulation "
                  f"{r['reprojection_px']['triangulation_median']:.1f} px: x{r['fit_over_triangulation']:.2f}; "
                  f"limbs within {r['limb_length_error_max_pct']:.1f} %", flush=True)  # fmt: skip
        result["run_time_s"] = round(time.perf_counter() - start, 1)
    # the machine is shared: its load (runnable processes, 1-minute mean) says how much of it this run had
    result["load_average"] = {"start": round(load_start, 2), "end": round(os.getloadavg()[0], 2)}
    m = machine()
    result["machine"] = f"{m.get('processor') or m.get('platform')}, {os.cpu_count()} CPUs"
    split = Split("multiview_real", tuning=(), training=(), evaluation=())  # no CMU subject is involved
    data = {"recordings": [f"pose2sim 0.10.49 {n}" for n in (DEVELOPMENT, HELD_OUT)], "held_out": HELD_OUT,
            "subjects": []}  # fmt: skip
    write_json(args.out, result, split=split, data=data, argv=argv)
    write_text(args.out.with_suffix(".md"), markdown(result), split=split, data=data, argv=argv)
    return result


if __name__ == "__main__":
    main()
