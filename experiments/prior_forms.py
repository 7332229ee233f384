"""Does a richer pose prior help SIP on held-apart subjects? One Gaussian vs SMPLify's mixture.

    python experiments/prior_forms.py --only 05     # one outer fold (subject 05), cached as JSON
    python experiments/prior_forms.py               # gather the cached folds (computing missing ones)
    python experiments/prior_forms.py --out experiments/results   # the committed summary
    python experiments/prior_forms.py --clips 1 --frames 60 --forms 1,2 --steps 5   # tiny run

Issue 12, item 5: the anthropometric prior of SIP (von Marcard eq. 3.14-3.16) is one
Gaussian over the 69 non-root joint angles. The richer form tried here is SMPLify's
mixture (Bogo et al. 2016): K full-covariance Gaussians, each frame paying for its best
component, E = min_k [½ d_k² − log w_k + ½ log det Σ_k] (`jaxmocap.priors.MixturePosePrior`,
fitted by scikit-learn's EM with the single Gaussian's (5°)² floor on every Σ_k;
`jaxmocap.priors.build`). Forms: K ∈ `--forms` (default 1, 4, 8; K = 1 is today's prior).

**Protocol**: sip_tables' held-out weight selection (its `Fold`, `scenarios`, `item`,
`mean_errors`), leave-one-subject-out over the CMU subjects of `jaxmocap.motion.corpus()`.
For outer subject s and each form: the prior is built without s; w_mahal is chosen from
the form's grid by the lowest MPJAE pooled (frame-weighted) over the development subjects
u ≠ s (02, 131: `jaxmocap.motion.splits`), each fitted with the prior of that form built
without s *and* u; s is reported at that weight. The summary pools the evaluated subjects
05, 06, 07 (the development subjects' folds are kept under `development_folds`). Before
2026-11-28 the inner subjects were all the others, so 07 (locked) and the evaluated
subjects chose each other's weights, and the summary pooled all five. No evaluated frame
shapes its prior or its weight. Grids: `GRID` around the 1e-4
sip_tables chose for the single Gaussian, `MIXTURE_GRID` one step lower for the mixtures
(narrower components: a held-out pose is further, in d_k², from its best component). SIP
with the six "sip6" IMUs and `IMUErrorModel.xsens()` errors (seed 0), low-resolution
default body, mean shape, float64 solves to rtol = atol = 1e-4 or `--steps` LM steps
(default 20, the thesis's; sip_tables' grid used 50, and its step study found the error at
20 steps within 0.3 mm / 0.21° of converged).

**Bounded work** (a fold is 46 SIP solves of 300 frames, ~3 s each on one CPU core; ~5 min): per
subject its `--clips` (default 1) longest clips, one window each, the first `--frames`
frames (300) from the calibration frame (the first where every sensor of both of
sip_tables' sets reports). Subjects 07 (walks, ≤ 130 frames at 30 fps) and 131 (one clip of
249) have no clip that long: their windows are their clips whole. Sharing that the
protocol permits:

- the SOP start of a window is the inertial tracker (20 LM steps) with the single-Gaussian
  prior of the window's fold (without s, or without s and u), as in sip_tables, and every
  form starts from it: forms differ only by the SIP prior term (paired comparisons);
- the outer windows are solved at every grid weight along with the inner ones (the same
  compiled solve; this also gives the held-out error curve). Only the inner windows choose
  the weight; the outer cells at other weights are reported as the curve, never used to
  choose;
- every window is padded to `--frames` (one compiled solve per form; padded frames drop
  out of every term and of the errors).

Also reported: SIP without the Mahalanobis term (w_mahal = 0, the same for every form) and,
as a cheap diagnostic of generalisation, the "distance to prior" of the held-out truth
poses of s (every frame of every clip of s) under each form's outer prior: the solver's
squared residual ‖r‖² (d_mahal² for K = 1; 2 (E − min_k c_k) for a mixture) and the exact
negative log-likelihood per frame (nats; comparable across forms), against the same on
the prior's own training frames.

`--only SUBJECT` computes one outer fold and writes it atomically to
`--cache/prior_forms_fold_<SUBJECT>_<config>.json`; a run without `--only` gathers those
files (computing any missing fold in-process) into `prior_forms.json` and `.md` in `--out`.
Concurrent folds synthesise each subject's IMU readings once (under a file lock) and cache
priors with per-process temporary files. On a many-core machine give each fold its own
cores and one XLA thread (oversubscribed XLA CPU thread pools slow down many-fold):

    export XLA_FLAGS="--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1" OMP_NUM_THREADS=2
    for i in 0 1 2 3 4; do s=$(echo 02 05 06 07 131 | cut -d' ' -f$((i + 1)))
        taskset -c $((3 * i))-$((3 * i + 2)) python experiments/prior_forms.py --only $s > out/prior_forms_$s.log 2>&1 &
    done; wait; python experiments/prior_forms.py --out experiments/results
"""

from __future__ import annotations

import argparse
import fcntl
import hashlib
import json
import os
import sys
import time
from contextlib import contextmanager
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from sip_tables import DTYPE, TOL, Fold, item, mean_errors, scenarios  # noqa: E402  (sets jax_enable_x64)

from jaxmocap.app.sweep_methods import InertialMethod  # noqa: E402
from jaxmocap.body import default_body  # noqa: E402
from jaxmocap.methods import inertial as I  # noqa: E402
from jaxmocap.motion import library  # noqa: E402
from jaxmocap.motion.corpus import corpus, training_clips  # noqa: E402
from jaxmocap.motion.splits import DEVELOPMENT, LEAVE_SUBJECT_OUT, Split  # noqa: E402
from _provenance import record, subjects_of  # noqa: E402

#: w_mahal chosen on the development subjects; priors leave-subject-out; summary on 05, 06, 07.
SPLIT = Split("prior_forms", tuning=DEVELOPMENT, training=LEAVE_SUBJECT_OUT)
from jaxmocap.priors.build import clip_poses  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
FORMS = (1, 4, 8)
#: w_mahal candidates of the single Gaussian: around the 1e-4 that sip_tables chose for every
#: subject from (0, 1e-4, 3e-4, 1e-3, 3e-3).
GRID = (3e-5, 1e-4, 3e-4)
#: ... and of the mixtures, one step lower: their components are narrower, so a held-out pose
#: is further (in d_k²) from its best component than from the single Gaussian's mean.
MIXTURE_GRID = (1e-5, 3e-5, 1e-4)
SOP_STEPS = 20


def windows(clips, per_subject: int) -> list:
    """Each subject's `per_subject` longest clips (ties by name), in corpus order."""
    by_subject: dict = {}
    for c in clips:
        by_subject.setdefault(c.subject, []).append(c)
    keep = set()
    for cs in by_subject.values():
        keep |= {c.name for c in sorted(cs, key=lambda c: (-len(clip_poses(c.path)), c.name))[:per_subject]}
    return [c for c in clips if c.name in keep]


@contextmanager
def locked(path: Path):
    """An exclusive lock on `path` (released when the block or the process ends)."""
    with open(path, "w") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def grid_of(args, K: int) -> tuple:
    return args.grid if K == 1 else args.mixture_grid


def config_key(args) -> str:
    cfg = [
        list(args.forms),
        list(args.grid),
        list(args.mixture_grid),
        args.clips,
        args.frames,
        args.steps,
        args.seed,
        "inner: development subjects",
    ]  # the folds before the splits are not reused
    return hashlib.sha1(json.dumps(cfg).encode()).hexdigest()[:10]


def fold_path(args, subject: str) -> Path:
    return Path(args.cache) / f"prior_forms_fold_{subject}_{config_key(args)}.json"


def write_json(path: Path, obj) -> None:
    """Atomically: a temporary file, then `replace`."""
    tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(obj, indent=1, default=float) + "\n")
    tmp.replace(path)


def fit_padded(method, it, w_mahal: float, length: int, args):
    """`InertialMethod.fit` (SIP) of one item padded to `length` frames, so every window shares one
    compiled solve per prior form (padded frames drop out of every term). Returns (poses, result, steps)."""
    from jaxmocap.solve import VonMarcardLM, solve_batch

    stacked, mask = I.pad_setups([it.setup], length)
    dtype = stacked.pose0.dtype
    w = {k: jnp.asarray([w_mahal if k == "mahal" else v], dtype) for k, v in method.defaults.items()}
    term_w = I.SIPWeights(**w).term_weights(len(stacked.bones))
    init = np.concatenate([it.init, np.repeat(it.init[-1:], length - it.length, 0)])[None]
    sol = solve_batch(I.inertial_problem(stacked, acceleration=True),
                      {"pose": jnp.asarray(init, dtype), "trans": jnp.broadcast_to(stacked.trans0[:, None], (1, length, 3))},
                      stacked.data, mask, weights=term_w, max_steps=args.steps,
                      solver=VonMarcardLM(rtol=TOL, atol=TOL))  # fmt: skip
    return np.asarray(sol.value["pose"])[0, : it.length], int(sol.result[0]), int(sol.num_steps[0])


def solve_cells(method, items, w_mahal, args) -> list:
    """SIP on every (item, w_mahal) cell, one at a time (a batch of one is the fastest per item on a
    few CPU cores), each padded to `--frames`. Per cell the summed per-frame MPJPE / MPJAE over its
    frames and joints, their counts, and the LM outcome."""
    out = []
    for it, w in zip(items, w_mahal):
        poses, result, steps = fit_padded(method, it, w, args.frames, args)
        e = mean_errors(method.body, poses, it, length=args.frames)
        out.append({"mpjpe_sum": float(e["mpjpe"].sum()), "mpjae_sum": float(e["mpjae"].sum()),
                    "mpjpe_n": int(e["mpjpe"].size), "mpjae_n": int(e["mpjae"].size), "frames": it.length,
                    "result": result, "steps": steps, "w_mahal": float(w)})  # fmt: skip
    return out


def pool(cells) -> dict:
    """Frame-weighted MPJPE (mm) and MPJAE (°) over cells (means over every frame and joint); the
    result keeps the sums, so pooled results pool again."""
    if not cells:
        raise ValueError("nothing to pool: no window with a calibration frame.")
    tot = {k: sum(c[k] for c in cells) for k in ("mpjpe_sum", "mpjpe_n", "mpjae_sum", "mpjae_n", "frames")}
    return {"mpjpe": tot["mpjpe_sum"] / tot["mpjpe_n"], "mpjae": tot["mpjae_sum"] / tot["mpjae_n"],
            "windows": sum(c.get("windows", 1) for c in cells), **tot}  # fmt: skip


def distances(prior, x: np.ndarray) -> dict:
    """Mean squared solver residual ‖r‖² and mean negative log-likelihood (nats) of poses x (N, 69)."""
    x = jnp.asarray(x, DTYPE)
    r = prior.mahalanobis_residual(x)
    return {"residual_sq": float(jnp.mean(jnp.sum(r**2, -1))), "nll": float(jnp.mean(prior.neg_log_likelihood(x))),
            "frames": int(len(x))}  # fmt: skip


def run_fold(s: str, args) -> dict:
    """Outer fold s: every form's weight selection on the other subjects, and s at the chosen weight."""
    t0 = time.perf_counter()
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    everything = corpus()
    if not everything:
        raise SystemExit("no CMU clips found (../shared/data/cmu, ../shared/data/cmu_cc; or set JAXMOCAP_CMU).")
    clips = windows(everything, args.clips)
    if s not in {c.subject for c in clips}:
        raise SystemExit(f"subject {s!r} is not in the corpus ({', '.join(sorted({c.subject for c in everything}))}).")
    body = default_body("low")
    # IMU readings per subject (sip_tables' `scenarios`, cached), each under a lock: concurrent folds
    # start with their own subject, so each synthesises one and reads the others' files.
    subjects = sorted({c.subject for c in clips})
    order = subjects[subjects.index(s) :] + subjects[: subjects.index(s)]
    per_subject = {}
    for u in order:
        with locked(cache / f"scenario_{u}.lock"):
            per_subject[u] = scenarios([c for c in clips if c.subject == u], args.frames, args.seed, body, cache)
    clips = [c for u in subjects for c in clips if c.subject == u]
    where = [(u, j) for u in subjects for j in range(len(per_subject[u][2]))]
    sc = [per_subject[u][0] for u, _ in where]
    seq_index = [j for _, j in where]
    starts = [per_subject[u][2][j] for u, j in where]
    idx = [i for i, k in enumerate(starts) if k is not None]
    excl = {i: (s,) if clips[i].subject == s else tuple(sorted((s, clips[i].subject))) for i in idx}
    outer = [i for i in idx if clips[i].subject == s]
    inner = [i for i in idx if clips[i].subject != s and clips[i].subject in SPLIT.tuning]
    print(f"fold {s}: {len(outer)} outer and {len(inner)} inner windows ({time.perf_counter() - t0:.0f} s)", flush=True)

    # The SOP start of every window: the tracker with the single Gaussian of its fold (sip_tables' start).
    folds = {K: Fold(everything, cache, K) for K in args.forms}
    gauss = folds[1] if 1 in folds else Fold(everything, cache, 1)
    base = [item(sc[i], seq_index[i], starts[i], body, gauss.prior(excl[i]), clips[i].name) for i in idx]
    sop, sip = InertialMethod("sop"), InertialMethod("sip")
    t = time.perf_counter()
    poses = np.asarray(sop.fit(base, {}, {"max_steps": SOP_STEPS})[0])
    for j, it in enumerate(base):
        it.init = poses[j, : it.length]
    print(f"  SOP starts: {len(base)} windows ({time.perf_counter() - t:.0f} s)", flush=True)

    held_truth = np.concatenate([clip_poses(c.path) for c in everything if c.subject == s])
    train_truth = np.concatenate([clip_poses(c.path) for c in training_clips(everything, (s,))]
                                 + [clip_poses(n) for n in sorted(library.MOTIONS)])  # fmt: skip
    position = {i: j for j, i in enumerate(idx)}
    res = {"subject": s, "outer_windows": [clips[i].name for i in outer], "inner_windows": [clips[i].name for i in inner],
           "forms": {}}  # fmt: skip
    for K in args.forms:
        t = time.perf_counter()
        items = []
        for i in idx:
            it = item(sc[i], seq_index[i], starts[i], body, folds[K].prior(excl[i]), clips[i].name)
            it.init = base[position[i]].init
            items.append(it)
        grid = grid_of(args, K)
        cells = [(j, w) for j in range(len(items)) for w in grid]
        if K == min(args.forms):  # SIP without the Mahalanobis term: the same for every form, once
            cells += [(position[i], 0.0) for i in outer]
        out = solve_cells(sip, [items[j] for j, _ in cells], [w for _, w in cells], args)
        by = {(idx[j], w): o for (j, w), o in zip(cells, out)}
        inner_curve = {repr(w): pool([by[i, w] for i in inner]) for w in grid} if inner else {}
        chosen = min(grid, key=lambda w: inner_curve[repr(w)]["mpjae"]) if inner else grid[0]
        outer_prior = folds[K].prior((s,))
        form = {
            "w_mahal": chosen,
            "grid": list(grid),
            "chosen_at_grid_edge": len(grid) > 1 and chosen in (min(grid), max(grid)),
            "inner_by_w": inner_curve,
            "outer": pool([by[i, chosen] for i in outer]),
            "outer_by_window": {clips[i].name: by[i, chosen] for i in outer},
            "outer_by_w": {repr(w): pool([by[i, w] for i in outer]) for w in grid},
            "converged_fraction": float(np.mean([o["result"] == 0 for o in out])),
            "distance_held_out": distances(outer_prior, held_truth),
            "distance_training": distances(outer_prior, train_truth),
            "seconds": time.perf_counter() - t,
        }
        if K == min(args.forms):
            res["no_mahalanobis"] = {"outer": pool([by[i, 0.0] for i in outer]),
                                     "outer_by_window": {clips[i].name: by[i, 0.0] for i in outer}}  # fmt: skip
        res["forms"][str(K)] = form
        o = form["outer"]
        print(f"  K={K}: w_mahal {chosen:g} (inner MPJAE by w: "
              + ", ".join(f"{w}: {v['mpjae']:.2f}" for w, v in inner_curve.items())
              + f"); outer {o['mpjpe']:.1f} mm / {o['mpjae']:.2f}°; held-out NLL {form['distance_held_out']['nll']:.1f}"
              f" ({len(cells)} solves, {form['seconds']:.0f} s)", flush=True)  # fmt: skip
    res["config"] = {"forms": list(args.forms), "grid": list(args.grid), "mixture_grid": list(args.mixture_grid),
                     "clips_per_subject": args.clips, "frames": args.frames, "steps": args.steps, "seed": args.seed, "seconds": time.perf_counter() - t0,
                     "device": str(jax.devices()[0]), "jax": jax.__version__}  # fmt: skip
    return res


def summary(folds: dict, args) -> dict:
    """Pool the outer folds: per form, errors pooled and per subject, weights, diagnostics, and vs K = 1."""
    subjects = sorted(folds)
    forms = [str(K) for K in args.forms]
    windows_of = lambda f: [c for s in subjects for c in folds[s]["forms"][f]["outer_by_window"].values()]  # noqa: E731
    res = {"subjects": subjects, "forms": {}}
    for f in forms:
        res["forms"][f] = {
            "components": int(f),
            "outer": pool(windows_of(f)),
            "per_subject": {s: folds[s]["forms"][f]["outer"] for s in subjects},
            "w_mahal": {s: folds[s]["forms"][f]["w_mahal"] for s in subjects},
            "chosen_at_grid_edge": {s: folds[s]["forms"][f]["chosen_at_grid_edge"] for s in subjects},
            "outer_by_w": {repr(w): pool([folds[s]["forms"][f]["outer_by_w"][repr(w)] for s in subjects])
                           for w in grid_of(args, int(f))},
            "distance_held_out": {s: folds[s]["forms"][f]["distance_held_out"] for s in subjects},
            "distance_training": {s: folds[s]["forms"][f]["distance_training"] for s in subjects},
            "mean_nll_held_out": float(np.mean([folds[s]["forms"][f]["distance_held_out"]["nll"] for s in subjects])),
            "mean_nll_training": float(np.mean([folds[s]["forms"][f]["distance_training"]["nll"] for s in subjects])),
            "mean_residual_sq_held_out": float(np.mean([folds[s]["forms"][f]["distance_held_out"]["residual_sq"]
                                                        for s in subjects])),
            "inner_by_w_mean": {w: {k: float(np.mean([folds[s]["forms"][f]["inner_by_w"][w][k] for s in subjects
                                                      if w in folds[s]["forms"][f]["inner_by_w"]])) for k in ("mpjpe", "mpjae")}
                                for w in folds[subjects[0]]["forms"][f]["inner_by_w"]},
            "converged_fraction": float(np.mean([folds[s]["forms"][f]["converged_fraction"] for s in subjects])),
        }  # fmt: skip
    res["no_mahalanobis"] = pool([c for s in subjects for c in folds[s]["no_mahalanobis"]["outer_by_window"].values()])
    # Paired differences per window (each form at its chosen weights vs the single Gaussian at its own).
    if "1" in forms:
        ref = {(s, n): c for s in subjects for n, c in folds[s]["forms"]["1"]["outer_by_window"].items()}
        res["vs_single_gaussian"] = {}
        for f in forms:
            if f == "1":
                continue
            d = {k: [] for k in ("mpjpe", "mpjae")}
            for s in subjects:
                for n, c in folds[s]["forms"][f]["outer_by_window"].items():
                    r = ref[s, n]
                    for k in d:
                        d[k].append(c[f"{k}_sum"] / c[f"{k}_n"] - r[f"{k}_sum"] / r[f"{k}_n"])
            pooled_delta = {k: res["forms"][f]["outer"][k] - res["forms"]["1"]["outer"][k] for k in d}
            res["vs_single_gaussian"][f] = {
                "pooled_delta": pooled_delta,
                "pooled_delta_percent": {k: 100 * v / res["forms"]["1"]["outer"][k] for k, v in pooled_delta.items()},
                "window_delta_mean": {k: float(np.mean(v)) for k, v in d.items()},
                "window_delta_stderr": {k: float(np.std(v, ddof=1) / np.sqrt(len(v))) if len(v) > 1 else float("nan")
                                        for k, v in d.items()},
                "windows_better": {k: int(np.sum(np.asarray(v) < 0)) for k, v in d.items()},
                "windows": len(d["mpjae"]),
                "subjects_better_mpjae": int(sum(res["forms"][f]["per_subject"][s]["mpjae"]
                                                 < res["forms"]["1"]["per_subject"][s]["mpjae"] for s in subjects)),
            }  # fmt: skip
        res["verdict"] = verdict(res)
    res["protocol"] = __doc__.split("**Protocol**: ")[1].split("\n\n")[0].replace("\n", " ")
    res["config"] = {"forms": list(args.forms), "grid": list(args.grid), "mixture_grid": list(args.mixture_grid),
                     "clips_per_subject": args.clips, "window_frames": args.frames, "steps": args.steps, "seed": args.seed,
                     "fold_seconds": {s: folds[s]["config"]["seconds"] for s in subjects},
                     "device": folds[subjects[0]]["config"]["device"], "jax": jax.__version__}  # fmt: skip
    res["folds"] = folds
    return res


def verdict(res: dict) -> str:
    """Per mixture: helps, hurts or mixed against the single Gaussian (pooled MPJPE and MPJAE), by how
    much, how often per window and subject, and whether the per-window differences exceed their noise."""
    out = []
    for f, v in res["vs_single_gaussian"].items():
        d, p, m, se = v["pooled_delta"], v["pooled_delta_percent"], v["window_delta_mean"], v["window_delta_stderr"]
        sign = (
            "helps"
            if d["mpjpe"] < 0 and d["mpjae"] < 0
            else "hurts"
            if d["mpjpe"] > 0 and d["mpjae"] > 0
            else "is mixed"
        )
        resolved = [k for k in ("mpjpe", "mpjae") if np.isfinite(se[k]) and abs(m[k]) > 2 * se[k]]
        out.append(f"K = {f} {sign} (pooled vs one Gaussian: MPJPE {d['mpjpe']:+.1f} mm, {p['mpjpe']:+.1f} %; MPJAE "
                   f"{d['mpjae']:+.2f}°, {p['mpjae']:+.1f} %); better on {v['windows_better']['mpjae']}/{v['windows']} "
                   f"windows and {v['subjects_better_mpjae']}/{len(res['subjects'])} subjects (MPJAE); the per-window "
                   + (f"differences in {' and '.join(k.upper() for k in resolved)} exceed twice their standard error."
                      if resolved else "differences are within twice their standard error (not resolved)."))  # fmt: skip
    best = min(res["forms"], key=lambda f: res["forms"][f]["outer"]["mpjae"])
    out.append(f"Lowest pooled MPJAE: {'one Gaussian' if best == '1' else f'mixture K = {best}'}.")
    return " ".join(out)


def markdown(res: dict) -> str:
    forms = list(res["forms"])
    c = res["config"]
    L = ["# Pose prior forms for SIP on held-apart subjects (issue 12, item 5)", "",
         f"Generated by `experiments/prior_forms.py`: subjects {', '.join(res['subjects'])}, {c['clips_per_subject']} "
         f"window(s) of ≤ {c['window_frames']} frames per subject (its longest clips), 6 IMUs (SIP), Xsens-like errors, "
         f"≤ {c['steps']} LM steps (float64, rtol = atol = 1e-4). MPJPE (mm) after per-frame rigid Procrustes on the "
         "TotalCapture joints, MPJAE (°) on hips, knees, neck, shoulders, elbows, pooled over frames.", "",
         f"**Protocol**: {res['protocol']}", "",
         f"**Verdict**: {res.get('verdict', '')}", "",
         "## Outer error, pooled (w_mahal chosen per subject on the others)", "",
         "| prior | MPJPE [mm] | MPJAE [°] | w_mahal per subject | held-out NLL [nats/frame] | training NLL | held-out ‖r‖² |",
         "| --- | --- | --- | --- | --- | --- | --- |"]  # fmt: skip
    for f in forms:
        v = res["forms"][f]
        name = "one Gaussian (K = 1)" if f == "1" else f"mixture, K = {f}"
        ws = ", ".join(f"{s}: {w:g}" + ("*" if v["chosen_at_grid_edge"][s] else "") for s, w in v["w_mahal"].items())
        L.append(f"| {name} | {v['outer']['mpjpe']:.1f} | {v['outer']['mpjae']:.2f} | {ws} | {v['mean_nll_held_out']:.1f} | "
                 f"{v['mean_nll_training']:.1f} | {v['mean_residual_sq_held_out']:.1f} |")  # fmt: skip
    n = res["no_mahalanobis"]
    L += [f"| no Mahalanobis term (w_mahal = 0) | {n['mpjpe']:.1f} | {n['mpjae']:.2f} | | | | |", "",
          "\\* at the edge of the grid. NLL: the exact density's negative log-likelihood per frame of every frame of the "
          "held-out subject's clips under its outer prior (mean over subjects), and of the prior's own training frames; "
          "‖r‖²: the solver's squared prior residual (d² for K = 1).", "",
          "## Per subject (MPJPE mm / MPJAE °)", "", "| subject | " + " | ".join(f"K = {f}" for f in forms) + " | frames |",
          "| --- |" + " --- |" * (len(forms) + 1)]  # fmt: skip
    for s in res["subjects"]:
        L.append(f"| {s} | " + " | ".join(f"{res['forms'][f]['per_subject'][s]['mpjpe']:.1f} / "
                                          f"{res['forms'][f]['per_subject'][s]['mpjae']:.2f}" for f in forms)
                 + f" | {res['forms'][forms[0]]['per_subject'][s]['frames']} |")  # fmt: skip
    if res.get("vs_single_gaussian"):
        L += ["", "## Against the single Gaussian (paired per window)", "",
              "| mixture | Δ MPJPE pooled | Δ MPJAE pooled | Δ per window (mean ± s.e.) MPJPE / MPJAE | windows better (MPJAE) |",
              "| --- | --- | --- | --- | --- |"]  # fmt: skip
        for f, v in res["vs_single_gaussian"].items():
            m, se = v["window_delta_mean"], v["window_delta_stderr"]
            L.append(f"| K = {f} | {v['pooled_delta']['mpjpe']:+.1f} mm ({v['pooled_delta_percent']['mpjpe']:+.1f} %) | "
                     f"{v['pooled_delta']['mpjae']:+.2f}° ({v['pooled_delta_percent']['mpjae']:+.1f} %) | "
                     f"{m['mpjpe']:+.1f} ± {se['mpjpe']:.1f} mm / {m['mpjae']:+.2f} ± {se['mpjae']:.2f}° | "
                     f"{v['windows_better']['mpjae']}/{v['windows']} |")  # fmt: skip
    L += [
        "",
        "## Error against w_mahal (MPJPE mm / MPJAE °): inner (chooses), outer (reported at the choice)",
        "",
        "| prior | w_mahal | outer, pooled over subjects | inner, mean over folds |",
        "| --- | --- | --- | --- |",
    ]
    for f in forms:
        for w, v in res["forms"][f]["outer_by_w"].items():
            inner = res["forms"][f]["inner_by_w_mean"].get(w)
            L.append(
                f"| K = {f} | {float(w):g} | {v['mpjpe']:.1f} / {v['mpjae']:.2f} | "
                + (f"{inner['mpjpe']:.1f} / {inner['mpjae']:.2f} |" if inner else " |")
            )
    L += [
        "",
        f"Fold run times (s): {', '.join(f'{s}: {t:.0f}' for s, t in c['fold_seconds'].items())}; {c['device']}.",
        "",
    ]
    return "\n".join(L)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--only", metavar="SUBJECT", help="compute one outer fold (e.g. 05) and cache it; no summary")
    p.add_argument("--forms", default=",".join(map(str, FORMS)), help="numbers of components, e.g. 1,4,8")
    p.add_argument("--grid", default=",".join(map(repr, GRID)), help="w_mahal candidates of the single Gaussian")
    p.add_argument(
        "--mixture-grid", default=",".join(map(repr, MIXTURE_GRID)), help="w_mahal candidates of the mixtures"
    )
    p.add_argument("--clips", type=int, default=1, help="windows (longest clips) per subject")
    p.add_argument("--frames", type=int, default=300, help="window length (frames at 30 fps)")
    p.add_argument("--steps", type=int, default=20, help="LM step limit of the SIP solves")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--cache",
        default=str(ROOT / "out" / "prior_forms" / "cache"),
        help="scenarios, priors and fold results (shared by concurrent --only runs)",
    )
    p.add_argument(
        "--out",
        default=str(ROOT / "out" / "prior_forms"),
        help="where prior_forms.json and .md go (the committed ones: experiments/results)",
    )
    args = p.parse_args(argv)
    args.forms = tuple(sorted({int(k) for k in args.forms.split(",")}))
    args.grid = tuple(float(w) for w in args.grid.split(","))
    args.mixture_grid = tuple(float(w) for w in args.mixture_grid.split(","))
    if min(args.forms) < 1 or min(args.grid + args.mixture_grid) < 0 or args.clips < 1 or args.frames < 3:
        raise SystemExit(
            "--forms must be positive integers, the grids non-negative weights, --clips >= 1, --frames >= 3."
        )
    Path(args.cache).mkdir(parents=True, exist_ok=True)
    if args.only:
        s = f"{int(args.only):02d}" if args.only.isdigit() else args.only
        write_json(fold_path(args, s), run_fold(s, args))
        print(f"wrote {fold_path(args, s)}", flush=True)
        return 0
    subjects = sorted({c.subject for c in corpus()})
    folds = {}
    for s in subjects:
        path = fold_path(args, s)
        if not path.is_file():
            write_json(path, run_fold(s, args))
        folds[s] = json.loads(path.read_text())
    evaluated = {s: f for s, f in folds.items() if s in SPLIT.evaluation} or folds  # tiny runs: what there is
    res = summary(evaluated, args)
    res["development_folds"] = {s: {f: v["outer"] for f, v in folds[s]["forms"].items()}
                                for s in folds if s not in evaluated}  # fmt: skip
    res["split"] = SPLIT.record()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    windows = sorted({n for f in evaluated.values() for n in f["outer_windows"]})
    data = {"clips": windows, "subjects": subjects_of(windows), "frames": args.frames, "folds": sorted(folds)}
    write_json(out / "prior_forms.json", res)
    record(out / "prior_forms.json", split=SPLIT, data=data, argv=argv)
    md = markdown(res)
    tmp = out / f"prior_forms.md.{os.getpid()}.tmp"
    tmp.write_text(md)
    tmp.replace(out / "prior_forms.md")
    record(out / "prior_forms.md", split=SPLIT, data=data, argv=argv)
    print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
