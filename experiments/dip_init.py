"""SIP started from the Deep Inertial Poser instead of the inertial tracker, on held-apart subjects.

    python experiments/train_dip.py --out out/dip          # the fold networks (GPU)
    python experiments/dip_init.py --models out/dip --out experiments/results
    python experiments/dip_init.py --models out/dip --clips 3 --frames 60   # smoke run

**Protocol**: exactly `experiments/sip_tables.py`'s: every CMU clip at 30 fps in full, the
six "sip6" IMUs with `IMUErrorModel.xsens()` errors (seed 0), low-resolution default body,
mean shape, calibration on the true pose of the first frame where every sensor reports;
the pose prior built without the clip's subject and the w_mahal that `sip_tables` chose for
that subject (on the development subjects); float64 solves to rtol = atol = 1e-4. The
table pools the evaluated subjects 05, 06, 07 (`jaxmocap.motion.splits`); the development
subjects' clips are run too and reported per subject only (before 2026-11-28 the table
pooled all five).

**No overlap**: a clip of subject s is posed by the network of fold "without s"
(`train_dip.py`), which never saw a clip of s (early stopping included, and never on the
locked subject 07).

Rows: the BiRNN alone; SIP from its usual start (SOP: the inertial tracker on the six
sensors, §3.4.1, 20 LM steps per frame); SIP from the BiRNN poses. Each SIP at the thesis's
20 LM steps and converged (at most `--steps`). Writes `dip_init.json` and `dip_init.md`.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import jax  # noqa: E402
import numpy as np  # noqa: E402
from sip_tables import TOL, Fold, fit, item, mean_errors, scenarios, with_starts  # noqa: E402

from jaxmocap.app.sweep_methods import InertialMethod  # noqa: E402
from jaxmocap.body import default_body  # noqa: E402
from jaxmocap.learned.dip import birnn_poses, load_dip_model  # noqa: E402
from jaxmocap.methods import inertial as I  # noqa: E402
from jaxmocap.motion.corpus import corpus  # noqa: E402
from jaxmocap.motion.splits import LEAVE_SUBJECT_OUT, Split  # noqa: E402
from _provenance import subjects_of, write_json, write_text  # noqa: E402

#: Networks and priors leave-subject-out, early stopping inside each fold (never on 07),
#: w_mahal from sip_tables (development subjects): the table evaluates 05, 06, 07.
SPLIT = Split("dip_init", tuning=LEAVE_SUBJECT_OUT, training=LEAVE_SUBJECT_OUT)
from jaxmocap.sensors import load_scenario  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
THESIS = {"table_6_3_totalcapture_deg": {"SIP": 16.98, "BiRNN(Acc+Dropout)": 15.85},
          "note": "TotalCapture real IMUs, SIP and BiRNN run separately; the thesis does not start SIP from DIP"}  # fmt: skip


def sip6_scenario(clips, args, body, cache: Path, calibration: dict):
    """sip_tables' IMU-6 scenario (its cache file when present) and its calibration frames
    (sip_tables': the first frame where both of its sensor sets report)."""
    key = hashlib.sha1(json.dumps([[c.name for c in clips], args.frames, args.seed, 30.0]).encode()).hexdigest()[:12]
    path = cache / f"scenario_sip6_{key}.npz"
    sc6 = load_scenario(path) if path.is_file() else scenarios(clips, args.frames, args.seed, body, cache)[0]
    starts = []
    for i, c in enumerate(clips):
        first = I.first_complete_frame(sc6.sequence(i)["imu_ori"][0])
        starts.append(calibration.get(c.name, first) if args.frames >= 100000 and first is not None else first)
    return sc6, starts


def plot(res: dict, path: Path) -> None:
    """Per-clip MPJAE of every row (clips sorted by SIP from SOP) and the pooled table as bars."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    clips = sorted(res["per_clip"], key=lambda r: r["methods"]["SIP from SOP"]["mpjae"])
    fig, ax = plt.subplots(1, 2, figsize=(13, 4.2), gridspec_kw={"width_ratios": [3, 1]})
    for name, style in (("BiRNN", "o"), ("SOP", "s"), ("SIP from SOP", "^"), ("SIP from BiRNN", "v")):
        ax[0].plot([r["methods"][name]["mpjae"] for r in clips], style, ms=4, label=name)
    ax[0].set_xticks(range(len(clips)), [r["clip"].split(".")[0] for r in clips], rotation=90, fontsize=6)
    ax[0].set_ylabel("MPJAE (degrees)")
    ax[0].set_title("held-apart clips (each posed by the network trained without its subject)")
    ax[0].legend(fontsize=8)
    ax[0].grid(alpha=0.3)
    names = list(res["table"])
    ax[1].barh(names, [res["table"][n]["mpjae"] for n in names], color="tab:gray")
    ax[1].invert_yaxis()
    ax[1].set_xlabel("MPJAE (degrees), pooled")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def markdown(res: dict, path: Path, data: dict) -> None:
    lines = ["| method | MPJPE mm | MPJAE ° | converged | mean LM steps |", "| --- | --- | --- | --- | --- |"]
    for name, v in res["table"].items():
        conv, steps = res["converged"].get(name), res["mean_steps"].get(name)
        lines.append(f"| {name} | {v['mpjpe']:.1f} | {v['mpjae']:.2f} | {'' if conv is None else f'{100 * conv:.0f} %'} | "
                     f"{'' if steps is None else f'{steps:.0f}'} |")  # fmt: skip
    r, clips = res["sip_birnn_vs_sip_it_percent"], [c for c in res["per_clip"] if c["subject"] in SPLIT.evaluation]
    lines.append(f"\nSIP from the BiRNN vs SIP from SOP: MPJAE {r['mpjae']:+.1f} %, MPJPE {r['mpjpe']:+.1f} % "
                 f"({len(clips)} clips, {sum(c['frames'] for c in clips)} frames, subjects "
                 f"{', '.join(sorted({c['subject'] for c in clips}))}).")  # fmt: skip
    write_text(path, "\n".join(lines) + "\n", split=SPLIT, data=data)
    print("\n".join(lines))


def pooled(errs: list[dict], key: str) -> float:
    return float(np.concatenate([e[key].ravel() for e in errs]).mean())


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--models", default=str(Path(__file__).resolve().parents[1] / "out" / "dip"))
    p.add_argument("--out", default=str(Path(__file__).resolve().parents[1] / "out" / "dip_init"))
    p.add_argument(
        "--cache",
        default=str(Path(__file__).resolve().parents[1] / "out" / "sip_tables" / "cache"),
        help="sip_tables' cache (scenarios and held-out priors are shared)",
    )
    p.add_argument("--frames", type=int, default=100000)
    p.add_argument("--steps", type=int, default=200)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--clips", type=int, help="use N clips spread over the subjects (smoke runs)")
    p.add_argument(
        "--birnn-only",
        action="store_true",
        help="only the networks' own errors (e.g. another width), to OUT/dip_init_birnn_only.json",
    )
    args = p.parse_args(argv)
    t0 = time.perf_counter()
    out, cache = Path(args.out), Path(args.cache)
    out.mkdir(parents=True, exist_ok=True)
    cache.mkdir(parents=True, exist_ok=True)
    clips = corpus()
    if args.clips:
        clips = [clips[i] for i in np.linspace(0, len(clips) - 1, args.clips).astype(int)]
    body = default_body("low")
    folds = Fold(corpus(), cache)
    tables = json.loads((RESULTS / "sip_tables.json").read_text())
    chosen = tables["protocol"]["chosen_w_mahal"]
    sc6, starts = sip6_scenario(
        clips, args, body, cache, {r["clip"]: r["calibration_frame"] for r in tables["per_clip"]}
    )
    keep = [i for i, s in enumerate(starts) if s is not None]
    nets, metas = {}, {}
    for s in sorted({clips[i].subject for i in keep}):
        nets[s], metas[s] = load_dip_model(Path(args.models) / f"dip_{s}.npz")
        if metas[s].get("held_apart_subject") != s or s in metas[s].get("trained_on_groups", [s]):
            raise SystemExit(f"dip_{s}.npz was trained on subject {s}: it cannot be evaluated on its clips.")
    sop, sip = InertialMethod("sop"), InertialMethod("sip")
    base = [item(sc6, i, starts[i], body, folds.prior((clips[i].subject,)), clips[i].name) for i in keep]
    w = {"mahal": np.asarray([chosen[clips[i].subject] for i in keep])}
    t1 = time.perf_counter()
    learned = [np.asarray(birnn_poses(it.setup, nets[clips[i].subject])) for it, i in zip(base, keep)]
    birnn_seconds = time.perf_counter() - t1
    if args.birnn_only:
        L = max(b.length for b in base)
        errs = [mean_errors(body, p, b, length=L) for p, b in zip(learned, base)]
        res = {"BiRNN": {k: pooled(errs, k) for k in ("mpjpe", "mpjae")},
               "per_subject": {s: {k: pooled([e for e, i in zip(errs, keep) if clips[i].subject == s], k)
                                   for k in ("mpjpe", "mpjae")} for s in nets},
               "networks": {s: {"hidden": m["config"]["hidden"], "best_step": m.get("best_step"),
                                "steps": m["config"]["steps"], "commit": m.get("commit")} for s, m in metas.items()},
               "clips": len(base), "frames": sum(b.length for b in base), "device": str(jax.devices()[0])}  # fmt: skip
        (out / "dip_init_birnn_only.json").write_text(json.dumps(res, indent=1))
        print(json.dumps({k: res[k] for k in ("BiRNN", "per_subject", "networks")}, indent=1))
        return
    with_starts(base, sop)
    sop_poses = [it.init for it in base]
    runs = {"BiRNN": [(p, 0, 0, float("nan")) for p in learned], "SOP": [(p, 0, 20, float("nan")) for p in sop_poses]}
    for steps, tag in ((20, "@20"), (args.steps, "")):
        for start, poses in (("SOP", sop_poses), ("BiRNN", learned)):
            for it, p0 in zip(base, poses):
                it.init = p0
            t = time.perf_counter()
            runs[f"SIP from {start}{tag}"] = fit(sip, base, w, max_steps=steps, rtol=TOL, atol=TOL)
            print(f"SIP from {start}{tag}: {time.perf_counter() - t:.0f} s", flush=True)

    L = max(b.length for b in base)
    errs = {name: [mean_errors(body, r[0], b, length=L) for r, b in zip(rs, base)] for name, rs in runs.items()}
    per_clip = []
    for j, i in enumerate(keep):
        c = clips[i]
        rec = {"clip": c.name, "subject": c.subject, "activity": c.activity, "frames": base[j].length, "methods": {}}
        for name, rs in runs.items():
            e = errs[name][j]
            rec["methods"][name] = {"mpjpe": float(e["mpjpe"].mean()), "mpjae": float(e["mpjae"].mean()),
                                    "result": int(rs[j][1]), "steps": int(rs[j][2]), "cost": float(rs[j][3])}  # fmt: skip
        per_clip.append(rec)
        m = rec["methods"]
        print(f"{c.name:11s} {c.subject:>3s}  BiRNN {m['BiRNN']['mpjpe']:5.1f}/{m['BiRNN']['mpjae']:4.1f}  "
              f"SIP<-SOP {m['SIP from SOP']['mpjpe']:5.1f}/{m['SIP from SOP']['mpjae']:4.1f}  "
              f"SIP<-BiRNN {m['SIP from BiRNN']['mpjpe']:5.1f}/{m['SIP from BiRNN']['mpjae']:4.1f}", flush=True)  # fmt: skip

    # The table: the evaluated subjects' clips alone (per_subject has every subject).
    J = [j for j, r in enumerate(per_clip) if r["subject"] in SPLIT.evaluation]
    all_errs, errs = errs, {name: [e[j] for j in J] for name, e in errs.items()}
    runs = {name: [rs[j] for j in J] for name, rs in runs.items()}
    table = {name: {"mpjpe": pooled(e, "mpjpe"), "mpjae": pooled(e, "mpjae")} for name, e in errs.items()}
    rel = lambda a, b, k: 100.0 * (table[a][k] - table[b][k]) / table[b][k]  # noqa: E731
    cost = lambda name: np.asarray([r[3] for r in runs[name]])  # noqa: E731
    subjects = sorted({r["subject"] for r in per_clip})
    res = {
        "table": table,
        "sip_birnn_vs_sip_it_percent": {k: rel("SIP from BiRNN", "SIP from SOP", k) for k in ("mpjae", "mpjpe")},
        "sip_birnn_vs_sip_it_percent_at_20_steps": {
            k: rel("SIP from BiRNN@20", "SIP from SOP@20", k) for k in ("mpjae", "mpjpe")
        },
        "birnn_vs_sop_percent": {k: rel("BiRNN", "SOP", k) for k in ("mpjae", "mpjpe")},
        "lower_final_cost_from_birnn": {
            "clips": int(np.sum(cost("SIP from BiRNN") < cost("SIP from SOP"))),
            "of": len(J),
        },
        "converged": {name: float(np.mean([r[1] == 0 for r in runs[name]])) for name in runs if name.startswith("SIP")},
        "mean_steps": {name: float(np.mean([r[2] for r in runs[name]])) for name in runs if name.startswith("SIP")},
        "per_subject": {
            s: {
                name: {
                    k: pooled([all_errs[name][j] for j, r in enumerate(per_clip) if r["subject"] == s], k)
                    for k in ("mpjpe", "mpjae")
                }
                for name in runs
            }
            for s in subjects
        },
        "birnn_inference_seconds_all_clips": birnn_seconds,
        "protocol": {
            "split": "leave-one-subject-out: a clip of subject s is posed by the network trained without s "
            "(train_dip.py fold 'without s', validation on other subjects than s and 07 only); SIP's prior is "
            "built without s and its w_mahal chosen on the development subjects (sip_tables.json "
            "protocol.chosen_w_mahal); the table pools subjects " + ", ".join(SPLIT.evaluation),
            "sip_it_start": "SOP: the per-frame orientation poser on the six sensors (the inertial tracker with 6 IMUs; "
            "the thesis's SIP start, §3.4.1), 20 LM steps per frame",
            "data": "every CMU clip at 30 fps in full, sip6 IMUs, IMUErrorModel.xsens(), seed 0 (as sip_tables.py)",
            "solves": f"float64, rtol = atol = {TOL}; '@20' rows stop at 20 LM steps, the others at {args.steps}",
            "metrics": "MPJPE (mm, Procrustes-aligned, TotalCapture joint set) and MPJAE (degrees, global joint "
            "angles) pooled over every frame",
        },
        "networks": {
            s: {
                k: metas[s].get(k)
                for k in ("fold", "commit", "training_frames", "best_step", "device", "training_seconds_all_folds")
            }
            | {"hidden": metas[s]["config"]["hidden"]}
            for s in metas
        },  # fmt: skip
        "config": {
            "frames_cap": args.frames,
            "steps": args.steps,
            "seed": args.seed,
            "seconds": time.perf_counter() - t0,
            "device": str(jax.devices()[0]),
            "jax": jax.__version__,
        },  # fmt: skip
        "thesis": THESIS,
        "per_clip": per_clip,
    }
    names = [r["clip"] for r in per_clip]
    data = {"clips": names, "subjects": subjects_of(names), "evaluated": [per_clip[j]["clip"] for j in J],
            "frames_cap": args.frames, "seed": args.seed}  # fmt: skip
    write_json(out / "dip_init.json", res, split=SPLIT, data=data, argv=argv)
    markdown(res, out / "dip_init.md", data)
    plot(res, out / "dip_init.png")


if __name__ == "__main__":
    sys.exit(main())
