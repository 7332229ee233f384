"""Body scale from the accelerations (issue 12, item 4): SIP with an estimated body size, on held-out motion.

    python experiments/sip_body_scale.py --clips 2 --frames 120   # tiny run: computes, gathers, prints
    python experiments/sip_body_scale.py --list                   # the clips and their indices
    python experiments/sip_body_scale.py --only 0,1               # one process per clip group (cached)
    python experiments/sip_body_scale.py --only 0 --true-scales 0.9,1.0   # or per half of a clip's scales
    python experiments/sip_body_scale.py --out experiments/results   # gathers the cache, writes the summary

The full run (6 windows of 300 frames; 12 processes, each ~2 of the 4 true scales of a clip):

    for i in 0 1 2 3 4 5; do for t in 0.9,1.0 1.1,1.2; do
        python experiments/sip_body_scale.py --only $i --true-scales $t & done; done; wait
    python experiments/sip_body_scale.py --out experiments/results

**Question.** With a wrong body size SIP's MPJPE rises sharply (Table 3.2 of sip_tables: 41.5 →
66.3 / 105.2 mm for SIP-110 / SIP-120, rigid Procrustes) while the pose itself barely changes.
Can SIP estimate one uniform body scale from the IMU data (`inertial.estimate_body_scale`:
SIP fitted on candidate scalings of the model, the scale minimising the compared final cost)?

**Protocol** (sip_tables', by import): six "sip6" IMUs with `IMUErrorModel.xsens()` errors
(seed `--seed` + a
checksum of the clip's name: every clip its own errors), 30 fps, the low-resolution default body with the mean shape as the model,
calibration on the true pose of the first frame where every sensor reports, SOP start
(20 LM steps per frame), float64 solves to rtol = atol = 1e-4 (at most `--steps`, default 60). Every
clip of `jaxmocap.motion.corpus()` with at least `--frames` + 5 frames at 30 fps is used,
one window of exactly `--frames` frames (300: only the longest clips qualify). A clip of
subject s is fitted with the prior built without s (sip_tables' `Fold`, i.e.
`held_out_prior(exclude=[s])`) and the w_mahal sip_tables chose for s by nested
leave-subject-out (experiments/results/sip_tables.json; the thesis's 0.003 if absent).

**Subjects of several sizes.** For each true scale t in `TRUE_SCALES` the IMU readings are
synthesised on the default body scaled by t (same window, same sensor errors: paired); the
model is the default body, so the subject is t × the model. Rows: SIP with the
default-size model (the candidate s = 1 of the estimate's own solves) and SIP refitted from
SOP on the body scaled by the estimate. Table 3.2 with the estimate: the t = 1 subject
fitted with models of 100 / 110 / 120 % (the candidates 1.0 / 1.1 / 1.2), and with the
estimate. The candidates are the same bodies whatever size the user assumed, so the
estimate, and SIP refitted with it, is the same in all three rows.

MPJPE as in sip_tables' Table 3.2: joints of the fitted model (its own size) against the
true body's after per-frame rigid Procrustes, after Procrustes with scale, and the fitted
pose put on the true body (size error removed); MPJAE on the TotalCapture joints.

Results are cached in `--cache` as one JSON per (clip, true scale), written to a temporary
file and renamed, so parallel processes can split the work (`--only`, `--true-scales`); a
run without them computes whatever is still missing, then writes `sip_body_scale.json` and
`.md` to `--out`.
"""

from __future__ import annotations

import argparse
import fcntl
import hashlib
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

from jaxmocap import metrics  # noqa: E402
from jaxmocap.app.scenarios import inertial_setup  # noqa: E402
from jaxmocap.app.sweep import atomic_write  # noqa: E402
from jaxmocap.app.sweep_methods import InertialItem, InertialMethod  # noqa: E402
from jaxmocap.body import default_body, forward, scaled_body  # noqa: E402
from jaxmocap.methods import inertial as I  # noqa: E402
from jaxmocap.motion.corpus import corpus, interleave  # noqa: E402
from jaxmocap.motion.io import load_motion  # noqa: E402
from jaxmocap.sensors import IMUErrorModel, ScenarioConfig, make_scenario  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "experiments" / "results"
#: True subject sizes relative to the model (the default body).
TRUE_SCALES = (0.9, 1.0, 1.1, 1.2)
#: Candidate scales of the estimate (relative to the default body); must hold 1.0, 1.1, 1.2
#: (the Table 3.2 models). Skewed upwards: the estimates lean towards larger bodies.
CANDIDATES = (0.9, 1.0, 1.1, 1.2, 1.3, 1.4)
CRITERIA = tuple(I.SCALE_CRITERIA)
MARGIN = 5  # frames synthesised beyond the window: room for a calibration frame after a dropout
FPS = 30.0
CACHE_VERSION = 3  # bump when a per-clip result changes meaning


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
    return eqx.tree_at(lambda s: (s.data.orientation, s.data.acceleration), setup, (d.orientation[:T], d.acceleration[:T]))


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
    cfg = ScenarioConfig(fps=FPS, max_frames=T + MARGIN, imu_set="sip6", imu_errors=IMUErrorModel.xsens(), betas_std=0.0)
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
    ests = []
    for sc, k in scs:
        make = lambda s, sc=sc, k=k: window(inertial_setup(sc, 0, scaled_body(body, s), start=k, prior=prior, dtype=DTYPE), T)  # noqa: E731
        ests.append(I.estimate_body_scale(make, items[len(ests)].init, CANDIDATES, criterion=args.criterion, **options))
    t2 = time.perf_counter()
    # SIP refitted from SOP on the estimated bodies, in one batch padded to the candidates'
    # batch size: the same compiled solve as the estimates.
    K, n = len(CANDIDATES), len(true_scales)
    pick = [min(j, n - 1) for j in range(max(K, n))]
    setups = [window(inertial_setup(sc, 0, scaled_body(body, e.scale), start=k, prior=prior, dtype=DTYPE), T)
              for (sc, k), e in zip(scs, ests)]  # fmt: skip
    final = I.sparse_inertial_poser_batch(I.stack_setups([setups[j] for j in pick]),
                                          np.stack([items[j].init for j in pick]), **options)  # fmt: skip
    t3 = time.perf_counter()
    one = CANDIDATES.index(1.0)
    rec = {"clip": clip.name, "subject": clip.subject, "activity": clip.activity, "group": clip.group, "frames": T,
           "seed": seed, "w_mahal": w.mahal, "candidates": list(CANDIDATES), "criterion": args.criterion, "true_scales": {}}  # fmt: skip
    for j, (t, it, e) in enumerate(zip(true_scales, items, ests)):
        true_body = scaled_body(body, t)
        by = {c: e.scale_by(c) for c in CRITERIA}
        rec["true_scales"][repr(t)] = {
            "estimate": e.scale, "estimate_by_criterion": by, "at_edge": e.at_edge,
            "costs": {k: v.tolist() for k, v in e.costs.items()},
            "steps": np.asarray(e.solution.num_steps).tolist(), "result": np.asarray(e.solution.result).tolist(),
            "final_steps": int(final.num_steps[j]), "final_result": int(final.result[j]),
            "default_size": errors(body, true_body, e.solution.value["pose"][one], it),
            "scale_estimated": errors(scaled_body(body, e.scale), true_body, final.value["pose"][j], it),
        }  # fmt: skip
    if 1.0 in true_scales:  # Table 3.2: the true body is the model; models of 100, 110, 120 %
        e, it = ests[true_scales.index(1.0)], items[true_scales.index(1.0)]
        est = rec["true_scales"][repr(1.0)]["scale_estimated"]
        rec["table_3_2"] = {
            name: {"model_size_known": errors(scaled_body(body, m), body, e.solution.value["pose"][CANDIDATES.index(m)], it),
                   "scale_estimated": est}
            for name, m in (("SIP", 1.0), ("SIP-110", 1.1), ("SIP-120", 1.2))
        }  # fmt: skip
    rec["seconds"] = {"synthesis_and_sop": t1 - t0, "estimates": t2 - t1, "refits": t3 - t2, "total": time.perf_counter() - t0}
    scales = "  ".join(f"{t}→{v['estimate']:.3f}" for t, v in rec["true_scales"].items())
    print(f"{clip.name:11s} {clip.subject:>3s} true→estimated: {scales}  ({rec['seconds']['total']:.0f} s)", flush=True)
    return rec


def summary(per_clip: list[dict], args) -> dict:
    ok = [r for r in per_clip if "skipped" not in r]
    f = np.asarray([r["frames"] for r in ok], float)
    avg = lambda xs: float(np.average(xs, weights=f))  # noqa: E731
    keys = ("mpjpe_rigid", "mpjpe_scaled_procrustes", "mpjpe_pose_on_true_body", "mpjae")
    est, by_scale = {}, {}
    for t in map(repr, TRUE_SCALES):
        v = np.asarray([r["true_scales"][t]["estimate"] for r in ok])
        est[t] = {"mean": float(v.mean()), "std": float(v.std()), "relative_error_mean": float(np.mean(v / float(t) - 1)),
                  "at_edge": sum(r["true_scales"][t]["at_edge"] for r in ok),
                  "per_clip": {r["clip"]: r["true_scales"][t]["estimate"] for r in ok},
                  "by_criterion": {c: {"mean": float(np.mean([r["true_scales"][t]["estimate_by_criterion"][c] for r in ok])),
                                       "std": float(np.std([r["true_scales"][t]["estimate_by_criterion"][c] for r in ok]))}
                                   for c in CRITERIA}}  # fmt: skip
        by_scale[t] = {m: {k: avg([r["true_scales"][t][m][k] for r in ok]) for k in keys} for m in ("default_size", "scale_estimated")}
    t32 = {name: {m: {k: avg([r["table_3_2"][name][m][k] for r in ok]) for k in keys} for m in ("model_size_known", "scale_estimated")}
           for name in ("SIP", "SIP-110", "SIP-120")}  # fmt: skip
    return {
        "scale_estimate": est,
        "errors_by_true_scale": by_scale,
        "table_3_2_with_scale_estimate": t32,
        "table_3_2_sip_tables": json.loads((RESULTS / "sip_tables.json").read_text())["table_3_2"]
        if (RESULTS / "sip_tables.json").is_file() else None,
        "protocol": {"true_scales": list(TRUE_SCALES), "candidates": list(CANDIDATES), "criterion": args.criterion,
                     "frames_per_window": args.frames, "clips": len(ok), "subjects": sorted({r["subject"] for r in ok}),
                     "skipped": [r["clip"] for r in per_clip if "skipped" in r], "imu": "sip6, IMUErrorModel.xsens(), 30 fps",
                     "prior": "held_out_prior(exclude=[subject]) with sip_tables' chosen w_mahal",
                     "solves": f"float64, rtol = atol = {TOL}, at most {args.steps} LM steps, SOP start", "seed": args.seed},
        "per_clip": per_clip,
    }  # fmt: skip


def markdown(res: dict) -> str:
    p = res["protocol"]
    L = ["# SIP with a body scale estimated from the accelerations (issue 12, item 4)", "",
         f"Generated by `experiments/sip_body_scale.py`: {p['clips']} held-out windows of {p['frames_per_window']} frames "
         f"(subjects {', '.join(p['subjects'])}), {p['imu']}, criterion `{p['criterion']}`, candidates {p['candidates']}.", "",
         "## Estimated scale (subject = true scale × the model)", "",
         "| true scale | mean | std over clips | mean relative error | at a candidate edge | " + " | ".join(f"{c} (mean ± std)" for c in CRITERIA) + " |",
         "| --- | --- | --- | --- | --- |" + " --- |" * len(CRITERIA)]  # fmt: skip
    for t, v in res["scale_estimate"].items():
        L.append(f"| {t} | {v['mean']:.3f} | {v['std']:.3f} | {100 * v['relative_error_mean']:+.1f} % | {v['at_edge']} | "
                 + " | ".join(f"{b['mean']:.3f} ± {b['std']:.3f}" for b in v["by_criterion"].values()) + " |")
    L += _paired_table("Errors by true scale: default-size model / estimated scale", "true scale",
                       res["errors_by_true_scale"], "default_size", "scale_estimated")
    L += _paired_table("Table 3.2 with the scale estimate (true body = model at 100 %): model size as given / estimated", "",
                       res["table_3_2_with_scale_estimate"], "model_size_known", "scale_estimated")
    L += ["", "The estimate does not depend on the size the user assumed (the candidates are the same bodies), "
          "so the three rows share one estimate.", ""]
    return "\n".join(L)


def _paired_table(title: str, first: str, rows: dict, a: str, b: str) -> list[str]:
    """Markdown rows "a / b" of the four errors for every row of `rows`."""
    L = ["", f"## {title}", "", f"| {first} | MPJPE rigid [mm] | MPJPE Procrustes with scale [mm] | pose on the true body [mm] | MPJAE [°] |",
         "| --- | --- | --- | --- | --- |"]  # fmt: skip
    for name, v in rows.items():
        L.append(f"| {name} | " + " | ".join(f"{v[a][k]:.1f} / {v[b][k]:.1f}" for k in v[a]) + " |")
    return L


def cache_key(args) -> str:
    what = [CACHE_VERSION, args.frames, args.seed, args.steps, args.criterion, TRUE_SCALES, CANDIDATES]
    return hashlib.sha1(json.dumps(what).encode()).hexdigest()[:10]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=300, help="window length in frames at 30 fps (default 300)")
    p.add_argument("--clips", type=int, help="only N of the eligible clips, spread over the subjects")
    p.add_argument("--only", help="comma-separated clip indices (see --list): compute and cache those, no summary")
    p.add_argument("--true-scales", help="comma-separated true scales of TRUE_SCALES to compute (default all; no summary)")
    p.add_argument("--list", action="store_true", help="print the clips and their indices")
    p.add_argument("--steps", type=int, default=60, help="LM step limit of every SIP solve (default 60)")
    p.add_argument("--criterion", default="data", choices=CRITERIA, help="the cost compared between candidates")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default=str(ROOT / "out" / "sip_body_scale"), help="summary folder (default out/sip_body_scale)")
    p.add_argument("--cache", default=str(ROOT / "out" / "sip_body_scale" / "cache"), help="per-clip results and priors")
    args = p.parse_args(argv)
    out, cache = Path(args.out), Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    clips = eligible_clips(args.frames, cache)
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
            rec["table_3_2"] = parts[TRUE_SCALES.index(1.0)]["table_3_2"]
        per_clip.append(rec)
    res = summary(per_clip, args)
    res["config"] = {"device": str(jax.devices()[0]), "jax": jax.__version__, "body": "default_body('low'), mean shape"}
    out.mkdir(parents=True, exist_ok=True)
    atomic_write(out / "sip_body_scale.json", json.dumps(res, indent=1) + "\n")
    (out / "sip_body_scale.md").write_text(markdown(res))
    print(markdown(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
