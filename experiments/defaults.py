"""The inertial posers' defaults: chosen on development subjects, measured on unseen ones.

    python experiments/defaults.py                 # results/defaults.json (+ .md, .png)
    python experiments/defaults.py --clips 3 --tune-clips 2   # smoke run (a few minutes)

**Protocol** (`jaxmocap.motion.splits`): every choice is made on the development subjects
02 and 131 (9 clips); the numbers are measured on subjects 05, 06, 07 (cmu_cc, taken in
turn), which nothing of the choice saw. Each clip: 72 frames at 30 fps, six Xsens-like
"sip6" IMUs (thirteen "totalcapture13" for IT), the low-resolution default body, mean
shape, calibration on the true first pose; the pose prior is built without the clip's
subject (`evaluation_prior`), on development and evaluation clips alike.

**Tuning** (development subjects only):
1. w_mahal from {3e-3 (thesis), 1e-3, 3e-4, 1e-4, 3e-5} by pooled MPJAE of SIP solved to
   convergence (float32, rtol = atol = 1e-4, at most 200 steps), as `sip_tables.py` does
   per fold,
   with the one-standard-error rule, paired over clips (the strongest prior within one
   standard error of the per-clip differences to the lowest: a weaker prior that wins by
   less than the noise only costs steps);
2. the tolerance: the loosest of {1e-4, 3e-4, 1e-3} within 0.5 % MPJPE of 1e-4's;
3. the step budget: the largest cap in {20, 30, 50} whose mean steps stay within 1.5× the
   thesis's 20 (the time rule of issue 46), at that w_mahal;
4. the dtype: float32 unless float64 lowers the pooled MPJPE by more than 0.5 %.
The library's `PRESETS["validated"]` must equal the choice (tests/test_presets.py reads
it back from defaults.json).

**Evaluation** rows: SOP and IT (per frame, 20 steps) and SIP under the "thesis" preset
(§3.4.1 weights, 20 steps), the "validated" preset (the library's default) and the best
setting of `sip_tables.md` (float64, chosen w_mahal, rtol = atol = 1e-4, ≤ 200 steps).
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import jax

sys.path.insert(0, str(Path(__file__).resolve().parent))
jax.config.update("jax_enable_x64", True)  # the float64 rows; float32 rows stay float32

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import jaxmocap  # noqa: E402,F401  (thread pool, compilation cache)
from _provenance import record, write_json, write_text  # noqa: E402
from jaxmocap._files import atomic_write  # noqa: E402
from jaxmocap.app.scenarios import inertial_setup  # noqa: E402
from jaxmocap.body import default_body  # noqa: E402
from jaxmocap.methods import inertial as I  # noqa: E402
from jaxmocap.metrics import pose_errors  # noqa: E402
from jaxmocap.motion.corpus import interleave, subject_of  # noqa: E402
from jaxmocap.motion.splits import Split  # noqa: E402
from jaxmocap.priors.build import evaluation_prior  # noqa: E402
from jaxmocap.sensors import IMUErrorModel, ScenarioConfig, make_scenario  # noqa: E402

RESULTS = Path(__file__).parent / "results"
SPLIT = Split("defaults", training="leave-subject-out")
FRAMES, FPS = 72, 30.0
MAHAL_GRID = (3e-3, 1e-3, 3e-4, 1e-4, 3e-5)
CAPS = (20, 30, 50)
TOL = 1e-4
TOLS = (TOL, 3e-4, 1e-3)
TOL_RULE = 0.5  # % MPJPE a looser tolerance may cost
#: the best setting of sip_tables.md: float64, rtol = atol = 1e-4, at most 200 steps
BEST = dict(max_steps=200, rtol=TOL, atol=TOL)
TIME_RULE = 1.5  # mean steps within 1.5x the thesis's 20 (issue 46, goal 2)
DTYPE_RULE = 0.5  # % MPJPE float64 must win by to be the default


class Clip:
    """One simulated clip: its setups per dtype and sensor set, and the truth."""

    def __init__(self, clip, seed: int, body):
        self.name, self.body, self.seed = clip.name, body, seed
        self._sc = {}
        for imus in ("sip6", "totalcapture13"):
            cfg = ScenarioConfig(fps=FPS, max_frames=FRAMES, imu_set=imus, imu_errors=IMUErrorModel.xsens())
            self._sc[imus] = make_scenario([clip.path], cfg, seed=seed, body=body)
        self.truth = self._sc["sip6"].sequence(0)["poses"][0]
        self._setups = {}

    def setup(self, dtype=jnp.float32, imus="sip6") -> I.InertialSetup:
        key = (jnp.dtype(dtype).name, imus)
        if key not in self._setups:
            prior = evaluation_prior(self.name, dtype=dtype)
            self._setups[key] = inertial_setup(self._sc[imus], 0, self.body, prior=prior, dtype=dtype)
        return self._setups[key]

    def errors(self, poses) -> tuple[float, float]:
        e = pose_errors(self.body, np.asarray(poses, np.float64), self.truth)
        return float(e["mpjpe"].mean()), float(e["mpjae"].mean())


def _timed(fn):
    out = jax.block_until_ready(fn())  # compile and warm
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn())
    return out, time.perf_counter() - t0


def sop_row(clip: Clip, weights, imus="sip6") -> dict:
    setup = clip.setup(imus=imus)
    (poses, codes), s = _timed(lambda: I.orientation_poser(setup, weights))
    mpjpe, mpjae = clip.errors(poses)
    return {"mpjpe_mm": mpjpe, "mpjae_deg": mpjae, "converged": float(np.mean(np.asarray(codes) == 0)), "s": s}


_CACHE: dict = {}
_CACHE_FILE: Path | None = None


def sip_row(clip: Clip, weights, dtype=jnp.float32, **limits) -> dict:
    """SIP from SOP under `weights` (cached by its settings in --cache: reruns resume)."""
    key = json.dumps([clip.name, clip.seed, repr(I.preset(weights)), jnp.dtype(dtype).name, limits], sort_keys=True)
    if key not in _CACHE:
        _CACHE[key] = _sip_row(clip, weights, dtype, **limits)
        if _CACHE_FILE is not None:
            atomic_write(_CACHE_FILE, json.dumps(_CACHE))
    return _CACHE[key]


def _sip_row(clip: Clip, weights, dtype=jnp.float32, **limits) -> dict:
    setup = clip.setup(dtype)
    sop, sop_s = _timed(lambda: I.sparse_orientation_poser(setup, weights)[0])
    r, s = _timed(lambda: I.sparse_inertial_poser(setup, weights, init=sop, **limits))
    mpjpe, mpjae = clip.errors(r.poses)
    sol = r.solution
    return {"mpjpe_mm": mpjpe, "mpjae_deg": mpjae, "converged": float(int(sol.result) == 0),
            "steps": int(sol.num_steps), "decrease": float(sol.decrease), "s": s + sop_s}  # fmt: skip


def pooled(rows: list[dict]) -> dict:
    keys = [k for k in rows[0] if isinstance(rows[0][k], (int, float))]
    return {k: float(np.mean([r[k] for r in rows])) for k in keys}


def tune(clips: list[Clip], log) -> dict:
    """The validated preset, chosen on development clips only."""
    grid, per_clip = {}, {}
    for w in MAHAL_GRID:
        weights = I.SIPWeights(mahal=w)
        per_clip[w] = [sip_row(c, weights, **BEST) for c in clips]
        grid[w] = pooled(per_clip[w])
        log(f"tune: w_mahal {w:g}: {grid[w]['mpjpe_mm']:.1f} mm / {grid[w]['mpjae_deg']:.2f}° converged "
            f"in {grid[w]['steps']:.0f} steps")  # fmt: skip
    # One-standard-error rule (Breiman et al. 1984), paired over clips: the strongest prior
    # whose pooled MPJAE is within one standard error of the per-clip differences to the
    # lowest; a weaker prior that wins by less than the noise only costs steps.
    low = min(grid, key=lambda w: grid[w]["mpjae_deg"])

    def paired_se(w):  # standard error of the per-clip MPJAE differences to the lowest
        d = [a["mpjae_deg"] - b["mpjae_deg"] for a, b in zip(per_clip[w], per_clip[low])]
        return float(np.std(d, ddof=1) / np.sqrt(len(d))) if len(d) > 1 else 0.0

    se = {w: paired_se(w) for w in grid}
    mahal = max(w for w in grid if grid[w]["mpjae_deg"] <= grid[low]["mpjae_deg"] + se[w])
    weights = I.SIPWeights(mahal=mahal)
    # The loosest tolerance whose converged fits stay within TOL_RULE % MPJPE of 1e-4's.
    tols = {TOL: grid[mahal]}
    for tol in TOLS[1:]:
        tols[tol] = pooled([sip_row(c, weights, max_steps=BEST["max_steps"], rtol=tol, atol=tol) for c in clips])
        log(f"tune: tolerance {tol:g}: {tols[tol]['mpjpe_mm']:.1f} mm in {tols[tol]['steps']:.1f} steps")
    tol = max(t for t in tols if tols[t]["mpjpe_mm"] <= (1 + TOL_RULE / 100) * tols[TOL]["mpjpe_mm"])
    caps = {}
    for cap in CAPS:
        caps[cap] = pooled([sip_row(c, weights, max_steps=cap, rtol=tol, atol=tol) for c in clips])
        log(f"tune: cap {cap}: {caps[cap]['mpjpe_mm']:.1f} mm, mean steps {caps[cap]['steps']:.1f}, "
            f"converged {100 * caps[cap]['converged']:.0f} %")  # fmt: skip
    within = [c for c in CAPS if caps[c]["steps"] <= TIME_RULE * 20]
    cap = max(within) if within else min(CAPS)
    f64 = pooled([sip_row(c, weights, jnp.float64, max_steps=cap, rtol=tol, atol=tol) for c in clips])
    gain = 100 * (1 - f64["mpjpe_mm"] / caps[cap]["mpjpe_mm"])
    dtype = "float64" if gain > DTYPE_RULE else "float32"
    log(f"tune: w_mahal {mahal:g}, tolerance {tol:g}, cap {cap}, {dtype} (float64 gains {gain:.2f} % MPJPE)")
    return {
        "clips": [c.name for c in clips],
        "grid_w_mahal": {f"{w:g}": v for w, v in grid.items()}, "mpjae_paired_standard_error": {f"{w:g}": v for w, v in se.items()},
        "tolerances": {f"{t:g}": v for t, v in tols.items()},
        "caps": {str(c): v for c, v in caps.items()},
        "float64_at_cap": f64, "float64_gain_percent": gain,
        "chosen": {"mahal": mahal, "max_steps": cap, "rtol": tol, "atol": tol, "dtype": dtype},
        "rules": {"w_mahal": "largest within one standard error of the lowest pooled MPJAE at convergence",
                  "tolerance": f"loosest of {list(TOLS)} within {TOL_RULE} % MPJPE of {TOL:g}",
                  "max_steps": f"largest of {list(CAPS)} with mean steps <= {TIME_RULE} x 20",
                  "dtype": f"float64 only if it lowers MPJPE by > {DTYPE_RULE} %"},
    }  # fmt: skip


def evaluate(clips: list[Clip], log) -> dict:
    best_w = I.SIPWeights(mahal=I.PRESETS["validated"].weights.mahal)
    rows: dict[str, list] = {k: [] for k in ("sop_thesis", "sop_validated", "it_thesis", "it_validated",
                                                "sip_thesis", "sip_validated", "sip_best")}  # fmt: skip
    for c in clips:
        rows["sop_thesis"].append(sop_row(c, "thesis"))
        rows["sop_validated"].append(sop_row(c, "validated"))
        rows["it_thesis"].append(sop_row(c, "thesis", "totalcapture13"))
        rows["it_validated"].append(sop_row(c, "validated", "totalcapture13"))
        rows["sip_thesis"].append(sip_row(c, "thesis"))
        rows["sip_validated"].append(sip_row(c, "validated"))
        rows["sip_best"].append(sip_row(c, best_w, jnp.float64, **BEST))
        log(f"{c.name}: " + ", ".join(f"{k} {v[-1]['mpjpe_mm']:.1f} mm" for k, v in rows.items()))
    return {"clips": [c.name for c in clips], "per_clip": rows, "mean": {k: pooled(v) for k, v in rows.items()}}


def write(out: dict, folder: Path) -> None:
    m = out["evaluation"]["mean"]
    lines = [
        "# The inertial posers' defaults on unseen subjects", "",
        f"Generated by `experiments/defaults.py`: chosen on subjects {', '.join(SPLIT.tuning)} "
        f"({len(out['tuning']['clips'])} clips), measured on {len(out['evaluation']['clips'])} clips of subjects "
        f"{', '.join(SPLIT.evaluation)} × {FRAMES} frames, 6 Xsens-like IMUs (13 for IT), prior without the "
        f"clip's subject ({out['machine']['backend']}).", "",
        "| method | setting | MPJPE mm | MPJAE ° | converged | s / sequence |", "| --- | --- | --- | --- | --- | --- |",
    ]  # fmt: skip
    names = {"thesis": "thesis (§3.4.1, 20 steps)", "validated": "**validated (default)**",
             "best": "best of sip_tables (float64, ≤ 200 steps)"}  # fmt: skip
    for key, r in m.items():
        method, setting = key.split("_")
        lines.append(f"| {method.upper()} | {names[setting]} | {r['mpjpe_mm']:.1f} | {r['mpjae_deg']:.2f} | "
                     f"{100 * r['converged']:.0f} % | {r['s']:.2f} |")  # fmt: skip
    c = out["tuning"]["chosen"]
    d, v = out["sip_default_vs_best_percent"], out["sip_vs_sop_percent"]
    lines += [
        "", f"Chosen on the development subjects: w_mahal = {c['mahal']:g} (thesis 0.003), at most "
        f"{c['max_steps']} LM steps to rtol = atol = {c['rtol']:g}, {c['dtype']}.",
        f"The default SIP is {abs(d):.1f} % {'worse' if d > 0 else 'better'} in MPJPE than the best setting "
        f"({out['sip_default_vs_best_mpjae_percent']:+.1f} % MPJAE) and {abs(v):.1f} % "
        f"{'better' if v < 0 else 'worse'} than SOP ({out['sip_vs_sop_mpjae_percent']:+.1f} % MPJAE); with the "
        f"thesis preset SIP is {out['sip_thesis_vs_best_percent']:+.1f} % against the best.",
        "", "Per subject (SIP MPJPE mm; subject 07 is locked out of all tuning):", "",
        "| subject | clips | thesis | validated (default) | best | SOP (default) |", "| --- | --- | --- | --- | --- | --- |",
    ]  # fmt: skip
    rows = out["evaluation"]["per_clip"]
    names = out["evaluation"]["clips"]
    for subject in SPLIT.evaluation:
        idx = [i for i, n in enumerate(names) if subject_of(n) == subject]
        mean = lambda k, idx=idx: np.mean([rows[k][i]["mpjpe_mm"] for i in idx])  # noqa: E731
        lines.append(f"| {subject} | {len(idx)} | {mean('sip_thesis'):.1f} | {mean('sip_validated'):.1f} | "
                     f"{mean('sip_best'):.1f} | {mean('sop_validated'):.1f} |")  # fmt: skip
    n_worse = sum(rows["sip_validated"][i]["mpjpe_mm"] > rows["sip_thesis"][i]["mpjpe_mm"] for i in range(len(names)))
    lines += ["", f"The default is worse than the thesis preset on {n_worse} of {len(names)} clips."]
    copied = [
        f"- `{k}`: {out[k]:.4g} (from {src})" for k, src in out.get("copied_from", {}).items() if out.get(k) is not None
    ]
    if copied:
        lines += ["", "Measured by other experiments on the evaluation subjects, copied here:", "", *copied]
    data = {"tuning_clips": out["tuning"]["clips"], "evaluation_clips": out["evaluation"]["clips"]}
    write_text(folder / "defaults.md", "\n".join(lines) + "\n", split=SPLIT, data=data)
    write_json(folder / "defaults.json", out, split=SPLIT, data=data)
    from jaxmocap.viz.plot import plot_lines  # noqa: F401  (matplotlib only when writing)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.6))
    keys = list(m)
    ax.bar(range(len(keys)), [m[k]["mpjpe_mm"] for k in keys], color=["C0" if "validated" in k else "C7" for k in keys])
    ax.set_xticks(range(len(keys)), [k.replace("_", "\n") for k in keys], fontsize=8)
    ax.set_ylabel("MPJPE [mm]")
    ax.set_title(f"Unseen subjects {', '.join(SPLIT.evaluation)}: defaults (blue) against thesis and best", fontsize=9)
    fig.tight_layout()
    fig.savefig(folder / "defaults.png", dpi=120)
    plt.close(fig)
    record(folder / "defaults.png", split=SPLIT, data=data)


#: The reproduction check tests/test_presets.py re-runs: SIP under each preset on a short
#: clip with the bundled prior (the jump of tests/test_inertial.py; a check, not a result).
CHECK = {"clip": "02_04.amc", "frames": 45, "imu_set": "sip6", "errors": "xsens", "seed": 0, "prior": "bundled"}


def reproduction_check(body) -> dict:
    from jaxmocap.motion.io import find_cmu_dir

    cfg = ScenarioConfig(fps=FPS, max_frames=CHECK["frames"], imu_set=CHECK["imu_set"],
                         imu_errors=IMUErrorModel.xsens(), betas_std=0.0)  # fmt: skip
    sc = make_scenario([find_cmu_dir() / CHECK["clip"]], cfg, seed=CHECK["seed"], body=body)
    setup = inertial_setup(sc, 0, body)
    truth = sc.sequence(0)["poses"][0]
    out = dict(CHECK)
    for name in I.PRESETS:
        r = I.sparse_inertial_poser(setup, name)
        e = pose_errors(body, np.asarray(r.poses, np.float64), truth)
        out[name] = {"mpjpe_mm": float(e["mpjpe"].mean()), "mpjae_deg": float(e["mpjae"].mean()),
                     "result": int(r.solution.result), "steps": int(r.solution.num_steps)}  # fmt: skip
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--clips", type=int, default=15, help="evaluation clips, taken in turn from subjects 05, 06, 07")
    p.add_argument("--tune-clips", type=int, default=9, help="development clips (subjects 02, 131)")
    p.add_argument("--out", type=Path, default=RESULTS)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--cache",
        type=Path,
        default=Path("out/defaults_cache.json"),
        help="finished SIP fits by setting, so that a rerun resumes ('' for none)",
    )
    p.add_argument(
        "--stage",
        choices=("all", "tune", "evaluate", "report"),
        default="all",
        help="tune: only the choice (written to defaults.json); evaluate: reuse it from defaults.json; "
        "report: rewrite defaults.md/.png and the copied numbers from defaults.json",
    )
    p.add_argument("--check-only", action="store_true", help="only refresh the reproduction check in defaults.json")
    args = p.parse_args(argv)
    body = default_body("low")
    global _CACHE_FILE
    if str(args.cache):
        _CACHE_FILE = args.cache
        _CACHE_FILE.parent.mkdir(parents=True, exist_ok=True)
        if _CACHE_FILE.is_file():
            _CACHE.update(json.loads(_CACHE_FILE.read_text()))
    if args.stage == "report":
        out = json.loads((args.out / "defaults.json").read_text())
        out.update(_copied(args.out))
        write(out, args.out)
        print((args.out / "defaults.md").read_text())
        return 0
    if args.check_only:
        out = json.loads((args.out / "defaults.json").read_text())
        out["check"] = reproduction_check(body)
        out.update(_copied(args.out))
        write_json(args.out / "defaults.json", out, split=SPLIT, data={"check": CHECK})
        print(json.dumps(out["check"], indent=1))
        return 0
    log = lambda msg: print(msg, flush=True)  # noqa: E731
    try:
        tune_clips = SPLIT.clips("tuning")[: args.tune_clips]
        eval_clips = interleave(SPLIT.clips("evaluation"), args.clips)
    except FileNotFoundError as e:
        sys.exit(f"{e}: this experiment needs ../shared/data/cmu and cmu_cc beside the checkout")
    t0 = time.perf_counter()
    if args.stage == "evaluate":
        tuning = json.loads((args.out / "defaults.json").read_text())["tuning"]
    else:
        tuning = tune([Clip(c, args.seed + k, body) for k, c in enumerate(tune_clips)], log)
        if args.stage == "tune":
            args.out.mkdir(parents=True, exist_ok=True)
            write_json(
                args.out / "defaults.json", {"tuning": tuning}, split=SPLIT, data={"tuning_clips": tuning["clips"]}
            )
            log(
                f"tuning written to {args.out / 'defaults.json'}; set PRESETS['validated'] to it, then --stage evaluate"
            )
            return 0
    v, c = I.PRESETS["validated"], tuning["chosen"]
    matches = (v.weights.mahal, v.max_steps, v.rtol, v.atol) == (c["mahal"], c["max_steps"], c["rtol"], c["atol"])
    if not matches:
        log(f"WARNING: PRESETS['validated'] differs from the tuned choice {c}: update jaxmocap/methods/inertial.py "
            "and run again with --stage evaluate")  # fmt: skip
    evaluation = evaluate([Clip(c, args.seed + 100 + k, body) for k, c in enumerate(eval_clips)], log)
    m = evaluation["mean"]
    pct = lambda a, b, k="mpjpe_mm": 100 * (m[a][k] / m[b][k] - 1)  # noqa: E731
    out = {
        "experiment": "defaults", "split": SPLIT.record(), "frames": FRAMES, "fps": FPS,
        "presets": {k: {"mahal": v.weights.mahal, "max_steps": v.max_steps, "rtol": v.rtol, "atol": v.atol}
                    for k, v in I.PRESETS.items()},
        "tuning": tuning, "preset_matches_tuning": matches, "evaluation": evaluation,
        "sip_default_vs_best_percent": pct("sip_validated", "sip_best"),
        "sip_default_vs_best_mpjae_percent": pct("sip_validated", "sip_best", "mpjae_deg"),
        "sip_thesis_vs_best_percent": pct("sip_thesis", "sip_best"),
        "sip_vs_sop_percent": pct("sip_validated", "sop_validated"),
        "sip_vs_sop_mpjae_percent": pct("sip_validated", "sop_validated", "mpjae_deg"),
        "converged_fraction": m["sip_validated"]["converged"],
        "s_per_sequence": m["sip_validated"]["s"],
        "mpjpe_mm": m["sip_validated"]["mpjpe_mm"], "mpjae_deg": m["sip_validated"]["mpjae_deg"],
        "machine": {"backend": jax.default_backend(), "platform": platform.platform(), "jax": jax.__version__},
        "seconds": time.perf_counter() - t0,
    }  # fmt: skip
    out["check"] = reproduction_check(body)
    out.update(_copied(args.out))
    args.out.mkdir(parents=True, exist_ok=True)
    write(out, args.out)
    print((args.out / "defaults.md").read_text())
    return 0


def _copied(folder: Path) -> dict:
    """Numbers other experiments measure on unseen subjects, copied with their source (not
    re-run here; None where that experiment has not measured them)."""
    out = {"copied_from": {}}
    # The association's fresh evaluation set (seed 1): the seed-0 set's worst scene led to the
    # identity check and bounds its margin, so it no longer measures the defaults unseen.
    sources = {"vip_association_precision": ("vip_association.json", "defaults_unseen_seed1.final_round.precision"),
               "vip_association_recall": ("vip_association.json", "defaults_unseen_seed1.final_round.recall"),
               "body_scale_mean_abs_error_percent": ("sip_body_scale.json", "body_scale_mean_abs_error_percent")}  # fmt: skip
    for key, (name, keys) in sources.items():
        path = folder / name
        value = json.loads(path.read_text()) if path.is_file() else {}
        for k in keys.split("."):
            value = value.get(k) if isinstance(value, dict) else None
        out[key] = value if isinstance(value, (int, float)) else None
        out["copied_from"][key] = f"{name}: {keys}" + ("" if out[key] is not None else " (not measured)")
    return out


if __name__ == "__main__":
    raise SystemExit(main())
