"""Von Marcard's SIP tables (ch. 3, Tables 3.1-3.5) reproduced on simulated IMU data.

    python experiments/sip_tables.py [--frames 72] [--out out/sip_tables]

Data: the CMU clips in `find_cmu_dir()` (walks, run, jump, punch, bend/lift, swordplay,
wash) retargeted to the low-resolution default body, cropped to `--frames` frames at
30 fps, mean shape, with virtual IMUs (`jaxmocap.sensors`) and Xsens-like errors
(`IMUErrorModel.xsens()`: noise, bias, heading offset and drift, 5° mounting error, 2 cm
placement error, dropouts). IMU-6 = sip6 (forearms, shanks, head, pelvis), IMU-13 =
TotalCapture's 13 sensors. Every method is calibrated on the true pose (§3.4.1) of the first
frame where every sensor of both sets reports (a dropout at frame 0 would leave a sensor
uncalibrated); the frames before it are left out of every method and metric.

The default output folder is `out/sip_tables` (untracked); the tables committed in
`experiments/results/` are regenerated with `--out experiments/results`.

Tables written to `sip_tables.json` and `sip_tables.md`:
- 3.1: SOP and SIP under TNT15's protocol (§3.4.2): MPJPE on 13 virtual markers, MPJAE
  of the validation sensors on thighs and upper arms, which do not take part in tracking;
- 3.3: SOP, IT (13 IMUs), SIP: MPJPE (Procrustes, TotalCapture joints) and MPJAE;
- 3.4 / 3.5: the same per activity (walking, dynamic "freestyle", acting);
- 3.2: SIP with the body scaled to 110 % and 120 % (data from the true body);
- ablations: SIP without E_acc, without the Mahalanobis prior, without joint limits,
  and IT on noise-free data (thesis weights, and a vanishing prior weight);
plus error curves and per-joint plots.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import equinox as eqx
import numpy as np

from jaxmocap import metrics
from jaxmocap.body import default_body, forward
from jaxmocap.methods import inertial as I
from jaxmocap.sensors import IMUErrorModel, ScenarioConfig, make_scenario
from jaxmocap.motion.io import find_cmu_dir
from jaxmocap.viz.plot import plot_error_curves

#: CMU clips and the TotalCapture-style activity they stand for (Tables 3.4-3.5).
CLIPS = {
    "02_01.amc": "walking", "02_02.amc": "walking", "131_01.bvh": "walking",
    "02_03.amc": "freestyle", "02_04.amc": "freestyle", "02_07.amc": "freestyle",
    "02_05.amc": "acting", "02_06.amc": "acting", "02_09.amc": "acting",
}  # fmt: skip

THESIS = {
    "table_3_1_tnt15": {"SOP": {"mpjae": 19.6, "mpjpe": 72.2}, "SIP-M": {"mpjae": 18.2, "mpjpe": 55.9},
                        "SIP": {"mpjae": 13.3, "mpjpe": 39.1}},
    "table_3_2_tnt15": {"SIP-BW": {"mpjae": 13.5, "mpjpe": 41.5}, "SIP-110": {"mpjae": 13.7, "mpjpe": 45.7},
                        "SIP-120": {"mpjae": 14.3, "mpjpe": 55.8}, "SIP": {"mpjae": 13.3, "mpjpe": 39.1}},
    "table_3_3_totalcapture": {"SOP": {"mpjpe": 76.2, "mpjae": 19.7}, "IT": {"mpjpe": 30.5, "mpjae": 13.2},
                               "SIP": {"mpjpe": 52.2, "mpjae": 14.6}},
    "table_3_4_mpjpe": {"SOP": {"walking": 55.3, "freestyle": 104.1, "acting": 71.3, "mean": 76.2},
                        "IT": {"walking": 29.8, "freestyle": 34.8, "acting": 27.0, "mean": 30.5},
                        "SIP": {"walking": 34.7, "freestyle": 71.9, "acting": 51.8, "mean": 52.2}},
    "table_3_5_mpjae": {"SOP": {"walking": 15.7, "freestyle": 25.8, "acting": 18.0, "mean": 19.7},
                        "IT": {"walking": 11.3, "freestyle": 16.4, "acting": 12.2, "mean": 13.2},
                        "SIP": {"walking": 11.1, "freestyle": 19.2, "acting": 14.0, "mean": 14.6}},
}  # fmt: skip


#: TNT15's metrics (§3.4.2): 13 virtual markers; validation sensors on thighs and upper arms.
TNT15_SETS = ("tnt15_mpjpe", "tnt15_mpjae")


def scaled_body(body, s: float):
    """The body uniformly scaled by s (template, shape and pose blend shapes)."""
    return eqx.tree_at(
        lambda b: (b.v_template, b.shapedirs, b.posedirs), body, (body.v_template * s, body.shapedirs * s, body.posedirs * s)
    )


def run(frames: int, out: Path, seed: int = 0, max_steps: int = 20, max_clips: int | None = None) -> dict:
    cmu = find_cmu_dir()
    if cmu is None:
        raise SystemExit("CMU clips not found (set JAXMOCAP_CMU).")
    clips = [c for c in CLIPS if (cmu / c).is_file()][:max_clips]
    body = default_body("low")
    noisy = IMUErrorModel.xsens()
    cfg = lambda imu, err: ScenarioConfig(fps=30.0, max_frames=frames, imu_set=imu, imu_errors=err, betas_std=0.0)  # noqa: E731
    paths = [str(cmu / c) for c in clips]
    t0 = time.perf_counter()
    sc6 = make_scenario(paths, cfg("sip6", noisy), seed=seed, body=body)
    sc13 = make_scenario(paths, cfg("totalcapture13", noisy), seed=seed, body=body)
    sc13_clean = make_scenario(paths, cfg("totalcapture13", IMUErrorModel.off()), seed=seed, body=body)
    print(f"scenarios: {len(clips)} clips x {frames} frames ({time.perf_counter() - t0:.0f} s)", flush=True)
    W = I.SIPWeights()
    variants = {
        "SIP no-acc": W.replace(acc=0.0),
        "SIP no-prior": W.replace(mahal=0.0),
        "SIP no-limits": W.replace(limit=0.0),
    }
    per_seq, curves = [], {}
    for i, clip in enumerate(clips):
        t1 = time.perf_counter()
        seq = sc6.sequence(i)
        # Calibrate where every sensor of the 6- and 13-IMU sets (noisy and clean) reports.
        starts = [I.first_complete_frame(sc.sequence(i)["imu_ori"][0]) for sc in (sc6, sc13, sc13_clean)]
        if None in starts:
            print(f"{clip}: skipped, no frame where every sensor reports", flush=True)
            continue
        k = max(starts)
        n = int(sc6["length"][i]) - k
        truth = seq["poses"][0][k:]
        rec = {"clip": clip, "activity": CLIPS[clip], "frames": n, "calibration_frame": k, "methods": {}}
        err = {}
        setup = I.from_scenario(sc6, i, body, start=k)
        sop, _ = I.sparse_orientation_poser(setup)
        err["SOP"] = metrics.pose_errors(body, sop, truth)
        sip = I.sparse_inertial_poser(setup, init=sop, max_steps=max_steps)
        err["SIP"] = metrics.pose_errors(body, sip.poses, truth)
        for name, poses in (("SOP", sop), ("SIP", sip.poses)):
            err[f"{name} (TNT15 protocol)"] = metrics.pose_errors(body, poses, truth, None, None, None, *TNT15_SETS)
        rec["sip_steps"], rec["sip_result"] = int(sip.solution.num_steps), int(sip.solution.result)
        for name, w in variants.items():
            r = I.sparse_inertial_poser(setup, w, init=sop, max_steps=max_steps)
            err[name] = metrics.pose_errors(body, r.poses, truth)
        for s in (1.1, 1.2):
            b = scaled_body(body, s)
            st = I.from_scenario(sc6, i, b, start=k)
            sop_s, _ = I.sparse_orientation_poser(st)
            r = I.sparse_inertial_poser(st, init=sop_s, max_steps=max_steps)
            # The tracker's output is the scaled body: compare its joints with the truth.
            pj = forward(b, r.poses).joints
            tj = forward(body, truth).joints
            tr = forward(body, truth).joint_rotations
            pr = forward(b, r.poses).joint_rotations
            err[f"SIP-{round(s * 100)}"] = {
                "mpjpe": np.asarray(metrics.position_errors(pj, tj)) * 1000.0,
                "mpjae": np.asarray(metrics.angle_errors(pr, tr)),
            }
        st13 = I.from_scenario(sc13, i, body, start=k)
        it, _ = I.inertial_tracker(st13)
        err["IT"] = metrics.pose_errors(body, it, sc13.sequence(i)["poses"][0][k:])
        st13c = I.from_scenario(sc13_clean, i, body, start=k)
        itc, _ = I.inertial_tracker(st13c, sequential=False)
        err["IT noise-free"] = metrics.pose_errors(body, itc, sc13_clean.sequence(i)["poses"][0][k:])
        itc0, _ = I.inertial_tracker(st13c, W.replace(mahal=1e-5), sequential=False)
        err["IT noise-free, w_mahal=1e-5"] = metrics.pose_errors(body, itc0, sc13_clean.sequence(i)["poses"][0][k:])
        for name, e in err.items():
            rec["methods"][name] = {
                "mpjpe": float(e["mpjpe"].mean()), "mpjae": float(e["mpjae"].mean()),
                "mpjpe_per_joint": e["mpjpe"].mean(0).tolist(), "mpjae_per_joint": e["mpjae"].mean(0).tolist(),
                "_frames": e,
            }  # fmt: skip
        curves[clip] = {k: err[k] for k in ("SOP", "SIP", "IT")}
        per_seq.append(rec)
        m = rec["methods"]
        print(f"{clip:11s} {CLIPS[clip]:9s} SOP {m['SOP']['mpjpe']:5.1f} mm {m['SOP']['mpjae']:4.1f}°  "
              f"SIP {m['SIP']['mpjpe']:5.1f} mm {m['SIP']['mpjae']:4.1f}°  IT {m['IT']['mpjpe']:5.1f} mm "
              f"{m['IT']['mpjae']:4.1f}°  ({time.perf_counter() - t1:.0f} s)", flush=True)  # fmt: skip
    results = _tables(per_seq)
    results["config"] = {
        "frames": frames, "fps": 30.0, "seed": seed, "body": "default_body('low'), mean shape",
        "imu_errors": "IMUErrorModel.xsens()", "weights": vars(W), "sip_lm_steps": max_steps,
        "clips": CLIPS, "seconds": time.perf_counter() - t0,
    }  # fmt: skip
    results["thesis"] = THESIS
    results["per_sequence"] = [
        {**r, "methods": {k: {kk: vv for kk, vv in v.items() if kk != "_frames"} for k, v in r["methods"].items()}}
        for r in per_seq
    ]
    _plots(per_seq, curves, out)
    return results


def _pool(per_seq, method, key, activity=None):
    arrays = [r["methods"][method]["_frames"][key] for r in per_seq if activity in (None, r["activity"])]
    x = np.concatenate([a.reshape(-1) for a in arrays]) if arrays else np.array([np.nan])
    return float(np.mean(x)), float(np.std(x))


def _tables(per_seq) -> dict:
    methods = list(per_seq[0]["methods"])
    acts = ["walking", "freestyle", "acting"]
    overall = {m: {k: dict(zip(("mean", "std"), _pool(per_seq, m, k))) for k in ("mpjpe", "mpjae")} for m in methods}
    by_act = {
        k: {m: {**{a: _pool(per_seq, m, k, a)[0] for a in acts}, "mean": overall[m][k]["mean"]} for m in ("SOP", "IT", "SIP")}
        for k in ("mpjpe", "mpjae")
    }
    gain = {k: 100.0 * (overall["SIP"][k]["mean"] - overall["SOP"][k]["mean"]) / overall["SOP"][k]["mean"] for k in ("mpjpe", "mpjae")}
    wins = {k: sum(r["methods"]["SIP"][k] < r["methods"]["SOP"][k] for r in per_seq) for k in ("mpjpe", "mpjae")}
    return {
        "table_3_1": {m: overall[f"{m} (TNT15 protocol)"] for m in ("SOP", "SIP")},
        "table_3_3": {m: overall[m] for m in ("SOP", "IT", "SIP")},
        "table_3_4_mpjpe": by_act["mpjpe"],
        "table_3_5_mpjae": by_act["mpjae"],
        "table_3_2": {m: overall[m] for m in ("SIP", "SIP-110", "SIP-120")},
        "ablations": {
            m: overall[m] for m in methods if m not in ("SOP", "IT", "SIP-110", "SIP-120") and "TNT15" not in m
        },
        "sip_vs_sop_relative_change_percent": {**gain, "thesis_totalcapture": {"mpjpe": -31.5, "mpjae": -25.9}},
        "sip_beats_sop_sequences": {**wins, "of": len(per_seq)},
    }


def _plots(per_seq, curves, out: Path):
    out.mkdir(parents=True, exist_ok=True)
    dyn = next((c for c in ("02_04.amc", "02_03.amc") if c in curves), next(iter(curves)))
    c = curves[dyn]
    plot_error_curves({k: e["mpjae"] for k, e in c.items()}, out / "sip_tables_curve_mpjae.png", 30.0,
                              "MPJAE [°]", f"CMU {dyn}: SOP / SIP (6 IMUs), IT (13 IMUs)")
    plot_error_curves({k: e["mpjpe"] for k, e in c.items()}, out / "sip_tables_curve_mpjpe.png", 30.0,
                              "MPJPE [mm]", f"CMU {dyn}: SOP / SIP (6 IMUs), IT (13 IMUs)")
    per_joint = {m: np.concatenate([r["methods"][m]["_frames"]["mpjae"] for r in per_seq]) for m in ("SOP", "SIP", "IT")}
    metrics.plot_per_joint(per_joint, metrics.JOINT_SETS["totalcapture_mpjae"], out / "sip_tables_joints_mpjae.png",
                           "MPJAE [°]", "all clips")
    per_joint = {m: np.concatenate([r["methods"][m]["_frames"]["mpjpe"] for r in per_seq]) for m in ("SOP", "SIP", "IT")}
    metrics.plot_per_joint(per_joint, metrics.JOINT_SETS["totalcapture_mpjpe"], out / "sip_tables_joints_mpjpe.png",
                           "MPJPE [mm]", "all clips")  # fmt: skip


NOTES = [
    "- **Absolute errors are lower than the thesis's** for every method: the data are simulated with the "
    "same body model that fits them (no soft tissue, no marker-vs-IMU reference discrepancy, which the "
    "thesis names as the main part of IT's 13.2°), the clips are short (72 frames, 2.4 s: little heading "
    "drift) and the calibration uses the exact pose of its frame (the first where every sensor reports). The errors that remain come from the simulated "
    "sensor errors (5° mounting, 2 cm placement, heading offsets and drift, noise, dropouts) and the "
    "ambiguity of 6 sensors.",
    "- **The relative gain of SIP over SOP** is of the thesis's size and sign (see above); SIP wins on every "
    "clip. Like the thesis, SIP's largest remaining errors are on the slow 'acting' clips (bend/lift, "
    "wash), where accelerations are small and the prior pulls towards the mean pose (§3.4.3).",
    "- **'SIP no-acc' equals SOP**: the whole-sequence problem without E_acc is SOP's per-frame problem, "
    "already solved by the initialisation.",
    "- **Prior**: learnt from motion clips (including the evaluated ones; `jaxmocap/priors/README.md`), "
    "narrower than the thesis's static-scan prior, so w_mahal = 0.003 weighs more here: without it SIP's "
    "MPJPE improves slightly but its MPJAE and its spread get worse; on noise-free 13-IMU data the prior "
    "biases IT to ~5.6° MPJAE, while with w_mahal = 1e-5 (the prior only fills the null space: spine and "
    "neck/head splits) IT recovers the poses (< 1°). Joint limits are never active on these clips.",
    "- **Table 3.2**: the predicted joints come from the scaled body and Procrustes alignment is rigid "
    "(no scale, §2.5.2), so our MPJPE includes the 10 % / 20 % size error itself; MPJAE, which is "
    "size-free, barely changes, as in the thesis.",
    "- **Sample size**: 9 clips, one seed, 72 frames each (the default keeps the run under ~15 minutes "
    "on 2 shared cores); `--frames` and `--seed` give larger runs.",
]


def markdown(res: dict) -> str:
    T = res["thesis"]
    L = ["# SIP tables on simulated IMU data (von Marcard ch. 3)", "",
         f"Generated by `experiments/sip_tables.py`: {len(res['per_sequence'])} CMU clips × {res['config']['frames']} "
         f"frames at 30 fps, default body (low), Xsens-like IMU errors, thesis weights {res['config']['weights']}, "
         f"SIP {res['config']['sip_lm_steps']} LM steps from SOP. MPJPE after per-frame Procrustes (rigid) on the "
         "TotalCapture joints (§3.4.3), MPJAE on global orientations of hips, knees, neck, shoulders, elbows.", "",
         "## Table 3.1: TNT15 protocol, ours vs thesis (TNT15)", "",
         "MPJPE on the 13 virtual markers of §3.4.2 (hips, knees, ankles, shoulders, elbows, wrists, neck; "
         "Procrustes), MPJAE of the validation sensors on thighs and upper arms, which the 6 tracking IMUs "
         "do not include. SIP-M (the thesis's manually rigged body) has no counterpart here.", "",
         "| method | MPJAE [°] | MPJPE [mm] | thesis MPJAE | thesis MPJPE |", "| --- | --- | --- | --- | --- |"]
    for m in ("SOP", "SIP"):
        o, t = res["table_3_1"][m], T["table_3_1_tnt15"][m]
        L.append(f"| {m} | {o['mpjae']['mean']:.1f} ± {o['mpjae']['std']:.1f} | {o['mpjpe']['mean']:.1f} ± "
                 f"{o['mpjpe']['std']:.1f} | {t['mpjae']} | {t['mpjpe']} |")
    L += ["", "## Table 3.3 (overall): ours vs thesis (TotalCapture)", "",
         "| method | MPJPE [mm] | MPJAE [°] | thesis MPJPE | thesis MPJAE |", "| --- | --- | --- | --- | --- |"]  # fmt: skip
    for m in ("SOP", "IT", "SIP"):
        o, t = res["table_3_3"][m], T["table_3_3_totalcapture"][m]
        L.append(f"| {m} | {o['mpjpe']['mean']:.1f} ± {o['mpjpe']['std']:.1f} | {o['mpjae']['mean']:.1f} ± "
                 f"{o['mpjae']['std']:.1f} | {t['mpjpe']} | {t['mpjae']} |")
    g = res["sip_vs_sop_relative_change_percent"]
    w = res["sip_beats_sop_sequences"]
    L += ["", f"SIP vs SOP: MPJPE {g['mpjpe']:+.1f} %, MPJAE {g['mpjae']:+.1f} % "
          f"(thesis, TotalCapture: {g['thesis_totalcapture']['mpjpe']:+.1f} %, {g['thesis_totalcapture']['mpjae']:+.1f} %; "
          f"TNT15: -45.8 %, -32.1 %). SIP better than SOP on {w['mpjpe']}/{w['of']} clips (MPJPE) and "
          f"{w['mpjae']}/{w['of']} (MPJAE).", ""]  # fmt: skip
    for key, title, tk in (("table_3_4_mpjpe", "Table 3.4: MPJPE [mm] per activity", "table_3_4_mpjpe"),
                           ("table_3_5_mpjae", "Table 3.5: MPJAE [°] per activity", "table_3_5_mpjae")):  # fmt: skip
        L += [f"## {title} (thesis in parentheses)", "", "| method | walking | freestyle | acting | mean |",
              "| --- | --- | --- | --- | --- |"]
        for m in ("SOP", "IT", "SIP"):
            o, t = res[key][m], T[tk][m]
            L.append(f"| {m} | " + " | ".join(f"{o[a]:.1f} ({t[a]})" for a in ("walking", "freestyle", "acting", "mean")) + " |")
        L.append("")
    L += ["## Table 3.2: body scaled (thesis TNT15 in parentheses)", "", "| method | MPJPE [mm] | MPJAE [°] |",
          "| --- | --- | --- |"]
    for m in ("SIP", "SIP-110", "SIP-120"):
        o, t = res["table_3_2"][m], T["table_3_2_tnt15"][m]
        L.append(f"| {m} | {o['mpjpe']['mean']:.1f} ({t['mpjpe']}) | {o['mpjae']['mean']:.1f} ({t['mpjae']}) |")
    L += ["", "## Ablations", "", "| variant | MPJPE [mm] | MPJAE [°] |", "| --- | --- | --- |"]
    for m, o in res["ablations"].items():
        L.append(f"| {m} | {o['mpjpe']['mean']:.1f} ± {o['mpjpe']['std']:.1f} | {o['mpjae']['mean']:.1f} ± {o['mpjae']['std']:.1f} |")
    L += ["", "## Per clip", "", "| clip | activity | SOP mm / ° | SIP mm / ° | IT mm / ° |", "| --- | --- | --- | --- | --- |"]
    for r in res["per_sequence"]:
        m = r["methods"]
        L.append(f"| {r['clip']} | {r['activity']} | " + " | ".join(
            f"{m[k]['mpjpe']:.1f} / {m[k]['mpjae']:.1f}" for k in ("SOP", "SIP", "IT")) + " |")
    L += ["", "## Where and why our numbers differ from the thesis", "", *NOTES]
    L += ["", "Plots: `sip_tables_curve_mpjae.png`, `sip_tables_curve_mpjpe.png`, `sip_tables_joints_mpjae.png`, "
          "`sip_tables_joints_mpjpe.png`.", ""]
    return "\n".join(L)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=72)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--steps", type=int, default=20, help="SIP LM steps")
    p.add_argument("--clips", type=int, help="use only the first N clips (smoke runs)")
    # Not the tracked experiments/results/ by default: a trial run must not overwrite them.
    p.add_argument("--out", default=str(Path(__file__).resolve().parents[1] / "out" / "sip_tables"),
                   help="output folder (default: out/sip_tables; the committed tables: experiments/results)")
    args = p.parse_args(argv)
    out = Path(args.out)
    res = run(args.frames, out, args.seed, args.steps, args.clips)
    (out / "sip_tables.json").write_text(json.dumps(res, indent=1) + "\n")
    (out / "sip_tables.md").write_text(markdown(res))
    print(markdown(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
