"""Body scale from the accelerations (issues 12 and 46): SIP with an estimated body size, on held-out motion.

    python experiments/sip_body_scale.py --role tuning --clips 3 --candidates 0.70,0.75,...,1.40 --refine 0 --no-refit \\
        --criterion data --out experiments/results          # the choice: sip_body_scale_tuning.json/.md
    python experiments/sip_body_scale.py --clips 6 --no-refit --out experiments/results   # the table (evaluation subjects)
    python experiments/sip_body_scale.py --list                   # the clips and their indices
    python experiments/sip_body_scale.py --only 0,1               # one process per clip group (cached)

**Split** (`jaxmocap.motion.splits`, `SPLIT`): the estimator's settings (criterion, grid,
refinement) were chosen with `--role tuning` on the development subjects (02, 131): a
0.05 grid over 0.70-1.40, from which every coarser grid with or without bisection is read
off. The table (`--role evaluation`, the default) reports the evaluation subjects (05, 06,
07) with the estimator's defaults; `body_scale_mean_abs_error_percent` is the mean of
|estimate / true scale - 1| over every (clip, true scale), and `body_scale_at_edge` counts
the estimates whose grid bound won. Priors leave the clip's subject out.

**Question.** With a wrong body size SIP's MPJPE rises sharply (Table 3.2 of sip_tables: 41.5 →
66.3 / 105.2 mm for SIP-110 / SIP-120, rigid Procrustes) while the pose itself barely changes.
Can SIP estimate one uniform body scale from the IMU data (`inertial.estimate_body_scale`:
SIP fitted on candidate scalings of the model, the scale minimising the compared final cost)?

**Protocol** (sip_tables', by import): six "sip6" IMUs with `IMUErrorModel.xsens()` errors
(seed `--seed` + a
checksum of the clip's name: every clip its own errors), 30 fps, the low-resolution default body with the mean shape as the model,
calibration on the true pose of the first frame where every sensor reports, SOP start
(20 LM steps per frame), float64 solves to rtol = atol = 1e-4 (at most `--steps`, default 60). Every
clip of the role's subjects with at least `--frames` + 5 frames at 30 fps is used (`--clips
N`: N of them, spread over the subjects), one window of exactly `--frames` frames (90). A clip of
subject s is fitted with the prior built without s (sip_tables' `Fold`, i.e.
`held_out_prior(exclude=[s])`) and the w_mahal sip_tables chose for s by nested
leave-subject-out (experiments/results/sip_tables.json; the thesis's 0.003 if absent).

**Subjects of several sizes.** For each true scale t in `TRUE_SCALES` the IMU readings are
synthesised on the default body scaled by t (same window, same sensor errors: paired); the
model is the default body, so the subject is t × the model. Rows: SIP with the
default-size model (the candidate s = 1 of the estimate's own solves) and SIP refitted from
SOP on the body scaled by the estimate (not with `--no-refit`). Table 3.2 with the estimate: the t = 1 subject
fitted with models of 100 / 110 / 120 % (the candidates 1.0 / 1.1 / 1.2), and with the
estimate. The candidates are the same bodies whatever size the user assumed, so the
estimate, and SIP refitted with it, is the same in all three rows.

MPJPE as in sip_tables' Table 3.2: joints of the fitted model (its own size) against the
true body's after per-frame rigid Procrustes, after Procrustes with scale, and the fitted
pose put on the true body (size error removed); MPJAE on the TotalCapture joints.

Results are cached in `--cache` as one JSON per (clip, true scale), written to a temporary
file and renamed, so parallel processes can split the work (`--only`, `--true-scales`); a
run without them computes whatever is still missing, then writes `sip_body_scale.json` and
`.md` (`sip_body_scale_tuning.*` for the tuning role, with every criterion and search read
off its grid by `replay`) to `--out`.
"""

from __future__ import annotations

import argparse
import dataclasses
import fcntl
import hashlib
import inspect
import json
import sys
import time
import zlib
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import equinox as eqx  # noqa: E402
import jax  # noqa: E402
import numpy as np  # noqa: E402
from sip_tables import DTYPE, THESIS_W_MAHAL, TOL, Fold, item, mean_errors, with_starts  # noqa: E402  (sets jax_enable_x64)

from _provenance import write_json, write_text  # noqa: E402

from jaxmocap import metrics  # noqa: E402
from jaxmocap.app.scenarios import inertial_setup  # noqa: E402
from jaxmocap.app.sweep import atomic_write  # noqa: E402
from jaxmocap.app.sweep_methods import InertialItem, InertialMethod  # noqa: E402
from jaxmocap.body import default_body, forward, scaled_body  # noqa: E402
from jaxmocap.methods import inertial as I  # noqa: E402
from jaxmocap.motion.corpus import corpus, interleave  # noqa: E402
from jaxmocap.motion.io import load_motion  # noqa: E402
from jaxmocap.motion.splits import DEVELOPMENT, LEAVE_SUBJECT_OUT, Split  # noqa: E402
from jaxmocap.sensors import IMUErrorModel, ScenarioConfig, make_scenario  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "experiments" / "results"
#: True subject sizes relative to the model (the default body).
TRUE_SCALES = (0.9, 1.0, 1.1)
#: Settings (criterion, candidates, refinement) are chosen on the development subjects
#: (`--role tuning`); the table reports the evaluation subjects, priors leave the subject out.
SPLIT = Split("sip_body_scale", tuning=DEVELOPMENT, training=LEAVE_SUBJECT_OUT)
CRITERIA = tuple(I.SCALE_CRITERIA)
MARGIN = 5  # frames synthesised beyond the window: room for a calibration frame after a dropout
FPS = 30.0
CACHE_VERSION = 4  # bump when a per-clip result changes meaning


def eligible_clips(frames: int, cache: Path) -> list:
    """Corpus clips with at least frames + MARGIN frames at 30 fps (lengths cached: reading
    every clip takes a while, and every parallel process needs the list)."""
    path = cache / "clip_lengths.json"
    lengths = json.loads(path.read_text()) if path.is_file() else {}
    clips = corpus()
    missing = [c for c in clips if str(c.path) not in lengths]
    if missing:
        for c in missing:
            lengths[str(c.path)] = int(load_motion(c.path, fps=FPS).num_frames)
        atomic_write(path, json.dumps(lengths))
    return [c for c in clips if lengths[str(c.path)] >= frames + MARGIN]


def held_out_prior(folds: Fold, subject: str):
    """The prior built without `subject`, under a file lock: parallel processes build each
    fold once (the others wait, then read the cached file)."""
    with open(folds.cache / f"prior_{subject}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        return folds.prior((subject,))


def chosen_w_mahal(subject: str) -> float:
    """The w_mahal sip_tables chose for `subject` by nested leave-subject-out."""
    path = RESULTS / "sip_tables.json"
    if path.is_file():
        return float(json.loads(path.read_text())["protocol"]["chosen_w_mahal"].get(subject, THESIS_W_MAHAL))
    return THESIS_W_MAHAL


def window(setup: I.InertialSetup, T: int) -> I.InertialSetup:
    """The first T frames of a calibrated sequence."""
    d = setup.data
    return eqx.tree_at(
        lambda s: (s.data.orientation, s.data.acceleration), setup, (d.orientation[:T], d.acceleration[:T])
    )


def errors(model_body, true_body, poses, it: InertialItem) -> dict:
    """sip_tables' Table 3.2 errors of `poses` fitted with `model_body` against the truth on `true_body`."""
    tj = forward(true_body, it.truth).joints
    pj = forward(model_body, np.asarray(poses)).joints
    mm = lambda align: float(np.asarray(metrics.position_errors(pj, tj, align=align)).mean() * 1000)  # noqa: E731
    on_true = mean_errors(true_body, poses, it)
    return {"mpjpe_rigid": mm("procrustes"), "mpjpe_scaled_procrustes": mm("procrustes_scaled"),
            "mpjpe_pose_on_true_body": float(on_true["mpjpe"].mean()), "mpjae": float(on_true["mpjae"].mean())}  # fmt: skip


def run_clip(clip, args, body, folds, true_scales) -> dict:
    """`true_scales` of one clip: scale estimates, SIP with the default size and with the estimate."""
    t0 = time.perf_counter()
    T = args.frames
    prior = held_out_prior(folds, clip.subject)
    w = I.SIPWeights(mahal=chosen_w_mahal(clip.subject))
    errs = IMUErrorModel.xsens()
    if not args.placement_error:  # a diagnosis: how much of the scale error the 2 cm placement error makes
        errs = dataclasses.replace(errs, placement_offset=0.0)
    cfg = ScenarioConfig(fps=FPS, max_frames=T + MARGIN, imu_set="sip6", imu_errors=errs, betas_std=0.0)
    # Each clip is its own scenario: a seed per clip gives each its own sensor errors (one
    # seed for all would repeat one draw of placement offsets, biases, ...), the same
    # for every true scale (paired).
    seed = args.seed + zlib.crc32(clip.name.encode())
    scs, items = [], []
    for t in true_scales:
        sc = make_scenario([str(clip.path)], cfg, seed=seed, body=scaled_body(body, t))
        k = I.first_complete_frame(sc.sequence(0)["imu_ori"][0])
        if k is None or len(sc.sequence(0)["imu_ori"][0]) - k < T:
            return {"clip": clip.name, "skipped": f"no calibration frame within the first {MARGIN} frames"}
        it = item(sc, 0, k, body, prior, clip.name)  # the setup on the model (default) body
        scs.append((sc, k))
        items.append(InertialItem(window(it.setup, T), it.truth[:T], it.betas, None, it.name))
    with_starts(items, InertialMethod("sop"))  # SOP is size-free: one start per true scale
    t1 = time.perf_counter()
    options = dict(weights=w, max_steps=args.steps, rtol=TOL, atol=TOL)
    if args.candidates:
        options["scales"] = args.candidates
    if args.refine is not None:
        options["refine"] = args.refine
    ests = []
    for sc, k in scs:

        def make(s, sc=sc, k=k):
            return window(inertial_setup(sc, 0, scaled_body(body, s), start=k, prior=prior, dtype=DTYPE), T)

        ests.append(I.estimate_body_scale(make, items[len(ests)].init, criterion=args.criterion, **options))
    t2 = time.perf_counter()
    final = None
    if args.refit:  # SIP refitted from SOP on the estimated bodies, in one batch
        setups = [window(inertial_setup(sc, 0, scaled_body(body, e.scale), start=k, prior=prior, dtype=DTYPE), T)
                  for (sc, k), e in zip(scs, ests)]  # fmt: skip
        final = I.sparse_inertial_poser_batch(I.stack_setups(setups), np.stack([it.init for it in items]),
                                              weights=w, max_steps=args.steps, rtol=TOL, atol=TOL)  # fmt: skip
    t3 = time.perf_counter()
    rec = {"clip": clip.name, "subject": clip.subject, "activity": clip.activity, "group": clip.group, "frames": T,
           "seed": seed, "w_mahal": w.mahal, "criterion": args.criterion, "true_scales": {}}  # fmt: skip

    def pose_at(e, m):  # the fitted poses of candidate m, if m was one
        hit = np.flatnonzero(np.isclose(e.scales, m))
        return e.solution.value["pose"][hit[0]] if len(hit) else None

    for j, (t, it, e) in enumerate(zip(true_scales, items, ests)):
        true_body = scaled_body(body, t)
        r = rec["true_scales"][repr(t)] = {
            "estimate": e.scale, "estimate_by_criterion": {c: e.scale_by(c) for c in CRITERIA}, "at_edge": e.at_edge,
            "candidates": e.scales.tolist(), "costs": {k: v.tolist() for k, v in e.costs.items()},
            "steps": np.asarray(e.solution.num_steps).tolist(), "result": np.asarray(e.solution.result).tolist(),
        }  # fmt: skip
        if pose_at(e, 1.0) is not None:
            r["default_size"] = errors(body, true_body, pose_at(e, 1.0), it)
        if final is not None:
            r["final_steps"], r["final_result"] = int(final.num_steps[j]), int(final.result[j])
            r["scale_estimated"] = errors(scaled_body(body, e.scale), true_body, final.value["pose"][j], it)
    e = ests[true_scales.index(1.0)] if 1.0 in true_scales else None
    models = (("SIP", 1.0), ("SIP-110", 1.1), ("SIP-120", 1.2))
    if e is not None and final is not None and all(pose_at(e, m) is not None for _, m in models):
        # Table 3.2: the true body is the model; models of 100, 110, 120 %
        it, est = items[true_scales.index(1.0)], rec["true_scales"][repr(1.0)]["scale_estimated"]
        rec["table_3_2"] = {name: {"model_size_known": errors(scaled_body(body, m), body, pose_at(e, m), it), "scale_estimated": est}
                            for name, m in models}  # fmt: skip
    rec["seconds"] = {
        "synthesis_and_sop": t1 - t0,
        "estimates": t2 - t1,
        "refits": t3 - t2,
        "total": time.perf_counter() - t0,
    }
    scales = "  ".join(f"{t}→{v['estimate']:.3f}" for t, v in rec["true_scales"].items())
    print(f"{clip.name:11s} {clip.subject:>3s} true→estimated: {scales}  ({rec['seconds']['total']:.0f} s)", flush=True)
    return rec


def summary(per_clip: list[dict], args) -> dict:
    ok = [r for r in per_clip if "skipped" not in r]
    f = np.asarray([r["frames"] for r in ok], float)
    avg = lambda xs: float(np.average(xs, weights=f))  # noqa: E731
    keys = ("mpjpe_rigid", "mpjpe_scaled_procrustes", "mpjpe_pose_on_true_body", "mpjae")
    est, by_scale, abs_err = {}, {}, []
    for t in map(repr, TRUE_SCALES):
        v = np.asarray([r["true_scales"][t]["estimate"] for r in ok])
        rel = v / float(t) - 1
        abs_err += list(np.abs(rel))
        est[t] = {"mean": float(v.mean()), "std": float(v.std()), "relative_error_mean": float(rel.mean()),
                  "abs_error_mean_percent": float(100 * np.abs(rel).mean()),
                  "abs_error_max_percent": float(100 * np.abs(rel).max()),
                  "at_edge": sum(r["true_scales"][t]["at_edge"] for r in ok),
                  "per_clip": {r["clip"]: r["true_scales"][t]["estimate"] for r in ok},
                  "by_criterion": {c: {"mean": float(np.mean([r["true_scales"][t]["estimate_by_criterion"][c] for r in ok])),
                                       "std": float(np.std([r["true_scales"][t]["estimate_by_criterion"][c] for r in ok]))}
                                   for c in CRITERIA if all(c in r["true_scales"][t]["estimate_by_criterion"] for r in ok)}}  # fmt: skip
        by_scale[t] = {m: {k: avg([r["true_scales"][t][m][k] for r in ok]) for k in keys}
                       for m in ("default_size", "scale_estimated") if all(m in r["true_scales"][t] for r in ok)}  # fmt: skip
    t32 = None
    if ok and all("table_3_2" in r for r in ok):
        t32 = {name: {m: {k: avg([r["table_3_2"][name][m][k] for r in ok]) for k in keys} for m in ("model_size_known", "scale_estimated")}
               for name in ("SIP", "SIP-110", "SIP-120")}  # fmt: skip
    return {
        # Over every (clip, true scale) of this run's role: the number issue 46 asks for.
        "body_scale_mean_abs_error_percent": float(100 * np.mean(abs_err)) if args.role == "evaluation" else None,
        "body_scale_at_edge": int(sum(v["at_edge"] for v in est.values())),
        "role": args.role,
        "tuning": tuning_table(ok) if args.role == "tuning" else None,
        "scale_estimate": est,
        "errors_by_true_scale": by_scale,
        "table_3_2_with_scale_estimate": t32,
        "protocol": {"true_scales": list(TRUE_SCALES), "candidates": list(args.candidates or I.SCALE_CANDIDATES),
                     "refine": args.refine if args.refine is not None else inspect.signature(I.estimate_body_scale).parameters["refine"].default,
                     "criterion": args.criterion,
                     "frames_per_window": args.frames, "clips": len(ok), "subjects": sorted({r["subject"] for r in ok}),
                     "skipped": [r["clip"] for r in per_clip if "skipped" in r],
                     "imu": "sip6, IMUErrorModel.xsens()" + ("" if args.placement_error else " without placement error") + ", 30 fps",
                     "prior": "held_out_prior(exclude=[subject]) with sip_tables' chosen w_mahal",
                     "solves": f"float64, rtol = atol = {TOL}, at most {args.steps} LM steps, SOP start", "seed": args.seed},
        "per_clip": per_clip,
    }  # fmt: skip


#: The searches the tuning role compares, read off its 0.05 grid: (name, grid step, bisection rounds).
SEARCHES = (("grid 0.05", 0.05, 0), ("grid 0.1", 0.1, 0), ("grid 0.1 + 1 bisection", 0.1, 1))


def replay(fine: np.ndarray, profile: np.ndarray, step: float, refine: int):
    """`estimate_body_scale`'s search (grid over the fine grid's range, bisection rounds,
    parabola) on costs already fitted on a finer grid that holds every point it visits."""
    lo, hi = fine[0], fine[-1]
    at = lambda xs: [int(np.argmin(np.abs(fine - x))) for x in xs]  # noqa: E731
    idx = at(np.arange(lo, hi + step / 2, step))
    s, c = fine[idx], profile[idx]
    edge = int(np.argmin(c)) in (0, len(s) - 1)
    for _ in range(0 if edge else refine):
        b = int(np.argmin(c))
        j = at([(s[b - 1] + s[b]) / 2, (s[b] + s[b + 1]) / 2])
        s, c = np.concatenate([s, fine[j]]), np.concatenate([c, profile[j]])
        o = np.argsort(s)
        s, c = s[o], c[o]
    return I._parabola_vertex(s, c, int(np.argmin(c))), edge


def tuning_table(ok: list[dict]) -> dict:
    """Mean absolute error, bias and bound hits of every criterion and search on the tuning clips."""
    out = {}
    for crit in CRITERIA:
        for name, step, refine in SEARCHES:
            rel, edges = [], 0
            for r in ok:
                for t, v in r["true_scales"].items():
                    fine = np.asarray(v["candidates"])
                    e, edge = replay(
                        fine, I._profile({k: np.asarray(x) for k, x in v["costs"].items()}, crit), step, refine
                    )
                    rel.append(e / float(t) - 1)
                    edges += edge
            rel = np.asarray(rel)
            out[f"{crit}, {name}"] = {"mean_abs_error_percent": float(100 * np.abs(rel).mean()), "bias_percent": float(100 * rel.mean()),
                                      "max_abs_error_percent": float(100 * np.abs(rel).max()), "at_edge": edges, "cases": len(rel)}  # fmt: skip
    return out


def markdown(res: dict) -> str:
    p = res["protocol"]
    mae = res["body_scale_mean_abs_error_percent"]
    crits = list(next(iter(res["scale_estimate"].values()))["by_criterion"])
    L = ["# SIP with a body scale estimated from the accelerations (issues 12 and 46)", "",
         f"Generated by `experiments/sip_body_scale.py`: {p['clips']} windows of {p['frames_per_window']} frames "
         f"of the {res['role']} subjects ({', '.join(p['subjects'])}; split `{res['split']['name']}`: settings chosen on "
         f"{', '.join(res['split']['tuning'])}), {p['imu']}, criterion `{p['criterion']}`, candidates {p['candidates']}, "
         f"{p['refine']} bisection round(s).", ""]  # fmt: skip
    if res.get("tuning") is not None:
        L += [
            "## Criteria and searches on the development subjects (read off the 0.05 grid)",
            "",
            "| criterion, search | mean abs error | bias | max abs error | at a bound |",
            "| --- | --- | --- | --- | --- |",
        ]
        L += [f"| {k} | {v['mean_abs_error_percent']:.2f} % | {v['bias_percent']:+.2f} % | {v['max_abs_error_percent']:.1f} % | "
              f"{v['at_edge']} of {v['cases']} |" for k, v in res["tuning"].items()]  # fmt: skip
        L.append("")
    if mae is not None:
        L += [
            f"**Mean absolute error of the estimate: {mae:.2f} %** over {p['clips']} clips × {len(p['true_scales'])} "
            f"true scales; estimates at a search bound: {res['body_scale_at_edge']}.",
            "",
        ]
    L += ["## Estimated scale (subject = true scale × the model)", "",
          "| true scale | mean | std over clips | mean relative error | mean abs error | max abs error | at a search bound | "
          + " | ".join(f"{c} (mean ± std)" for c in crits) + " |",
          "| --- | --- | --- | --- | --- | --- | --- |" + " --- |" * len(crits)]  # fmt: skip
    for t, v in res["scale_estimate"].items():
        L.append(f"| {t} | {v['mean']:.3f} | {v['std']:.3f} | {100 * v['relative_error_mean']:+.1f} % | "
                 f"{v['abs_error_mean_percent']:.1f} % | {v['abs_error_max_percent']:.1f} % | {v['at_edge']} | "
                 + " | ".join(f"{b['mean']:.3f} ± {b['std']:.3f}" for b in v["by_criterion"].values()) + " |")  # fmt: skip
    if all(len(v) == 2 for v in res["errors_by_true_scale"].values()):
        L += _paired_table(
            "Errors by true scale: default-size model / estimated scale",
            "true scale",
            res["errors_by_true_scale"],
            "default_size",
            "scale_estimated",
        )
    if res["table_3_2_with_scale_estimate"] is not None:
        L += _paired_table(
            "Table 3.2 with the scale estimate (true body = model at 100 %): model size as given / estimated",
            "",
            res["table_3_2_with_scale_estimate"],
            "model_size_known",
            "scale_estimated",
        )
        L += [
            "",
            "The estimate does not depend on the size the user assumed (the candidates are the same bodies), "
            "so the three rows share one estimate.",
            "",
        ]
    L.append("")
    return "\n".join(L)


def _paired_table(title: str, first: str, rows: dict, a: str, b: str) -> list[str]:
    """Markdown rows "a / b" of the four errors for every row of `rows`."""
    L = ["", f"## {title}", "", f"| {first} | MPJPE rigid [mm] | MPJPE Procrustes with scale [mm] | pose on the true body [mm] | MPJAE [°] |",
         "| --- | --- | --- | --- | --- |"]  # fmt: skip
    for name, v in rows.items():
        L.append(f"| {name} | " + " | ".join(f"{v[a][k]:.1f} / {v[b][k]:.1f}" for k in v[a]) + " |")
    return L


def cache_key(args) -> str:
    what = [CACHE_VERSION, args.frames, args.seed, args.steps, args.criterion, args.candidates, args.refine, args.refit]
    if not args.placement_error:  # keeps the keys of the runs made before this option
        what.append("no placement error")
    return hashlib.sha1(json.dumps(what).encode()).hexdigest()[:10]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument(
        "--role",
        default="evaluation",
        choices=("tuning", "evaluation"),
        help="the split's subjects: tuning (development, to choose settings) or evaluation (the table)",
    )
    p.add_argument("--frames", type=int, default=90, help="window length in frames at 30 fps (default 90)")
    p.add_argument("--clips", type=int, help="only N of the eligible clips, spread over the subjects")
    p.add_argument(
        "--candidates",
        type=lambda x: tuple(float(v) for v in x.split(",")),
        help="comma-separated candidate scales (default inertial.SCALE_CANDIDATES)",
    )
    p.add_argument(
        "--refine", type=int, help="bisection rounds of the estimate (default inertial.estimate_body_scale's)"
    )
    p.add_argument("--no-refit", dest="refit", action="store_false", help="skip SIP refitted on the estimated body")
    p.add_argument(
        "--no-placement-error",
        dest="placement_error",
        action="store_false",
        help="sensors exactly where the model puts them (IMUErrorModel.xsens() with placement_offset=0)",
    )
    p.add_argument("--only", help="comma-separated clip indices (see --list): compute and cache those, no summary")
    p.add_argument(
        "--true-scales", help="comma-separated true scales of TRUE_SCALES to compute (default all; no summary)"
    )
    p.add_argument("--list", action="store_true", help="print the clips and their indices")
    p.add_argument("--steps", type=int, default=60, help="LM step limit of every SIP solve (default 60)")
    p.add_argument("--criterion", default="ori", choices=CRITERIA, help="the cost compared between candidates")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--out", default=str(ROOT / "out" / "sip_body_scale"), help="summary folder (default out/sip_body_scale)"
    )
    p.add_argument(
        "--cache", default=str(ROOT / "out" / "sip_body_scale" / "cache"), help="per-clip results and priors"
    )
    args = p.parse_args(argv)
    out, cache = Path(args.out), Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    clips = [c for c in eligible_clips(args.frames, cache) if c.subject in getattr(SPLIT, args.role)]
    if args.clips:
        clips = interleave(clips, args.clips)
    if not clips:
        raise SystemExit(f"no clip with {args.frames + MARGIN} frames at 30 fps (set JAXMOCAP_CMU / JAXMOCAP_CMU_CC?).")
    if args.list:
        for i, c in enumerate(clips):
            print(i, c.name, c.subject, c.activity)
        return 0
    todo = range(len(clips)) if args.only is None else [int(i) for i in args.only.split(",")]
    bad = [i for i in todo if not 0 <= i < len(clips)]
    if bad:
        raise SystemExit(f"--only {bad}: clip indices are 0 .. {len(clips) - 1} (see --list).")
    scales = TRUE_SCALES if args.true_scales is None else tuple(float(x) for x in args.true_scales.split(","))
    if not set(scales) <= set(TRUE_SCALES):
        raise SystemExit(f"--true-scales {scales}: pick from {TRUE_SCALES}.")
    body, folds, key = default_body("low"), Fold(corpus(), cache), cache_key(args)
    path = lambda c, t: cache / f"clip_{c.path.stem}_t{t}_{key}.json"  # noqa: E731
    for i in todo:
        missing = [t for t in scales if not path(clips[i], t).is_file()]
        if missing:
            rec = run_clip(clips[i], args, body, folds, missing)
            for t in missing:  # one file per (clip, true scale): processes may split a clip's scales
                part = {k: v for k, v in rec.items() if k not in ("true_scales", "table_3_2")}
                if "true_scales" in rec:
                    part["true_scales"] = {repr(t): rec["true_scales"][repr(t)]}
                if t == 1.0 and "table_3_2" in rec:
                    part["table_3_2"] = rec["table_3_2"]
                atomic_write(path(clips[i], t), json.dumps(part))
    if args.only is not None or args.true_scales is not None:
        return 0
    per_clip = []
    for c in clips:
        parts = [json.loads(path(c, t).read_text()) for t in TRUE_SCALES]
        rec = {k: v for k, v in parts[0].items() if k not in ("true_scales", "seconds")}
        skipped = [p["skipped"] for p in parts if "skipped" in p]
        if skipped:
            rec["skipped"] = skipped[0]
        else:
            rec["true_scales"] = {k: v for p in parts for k, v in p["true_scales"].items()}
            rec["seconds"] = {repr(t): p["seconds"] for t, p in zip(TRUE_SCALES, parts)}
            if "table_3_2" in parts[TRUE_SCALES.index(1.0)]:  # only with the refits
                rec["table_3_2"] = parts[TRUE_SCALES.index(1.0)]["table_3_2"]
        per_clip.append(rec)
    res = summary(per_clip, args)
    res["config"] = {"device": str(jax.devices()[0]), "jax": jax.__version__, "body": "default_body('low'), mean shape"}
    out.mkdir(parents=True, exist_ok=True)
    data = {"clips": [c.name for c in clips], "role": args.role}
    res["split"] = SPLIT.record()
    name = (
        "sip_body_scale"
        + ("" if args.role == "evaluation" else "_tuning")
        + ("" if args.placement_error else "_no_placement_error")
    )
    write_json(out / f"{name}.json", res, split=SPLIT, data=data, argv=argv)
    write_text(out / f"{name}.md", markdown(res), split=SPLIT, data=data, argv=argv)
    print(markdown(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
