"""Choosing MuVS's weights on the development subjects (never on an evaluated subject).

Three clips of the development subjects (`jaxmocap.motion.splits.DEVELOPMENT`: CMU 02 and
131, ../shared/data/cmu; `muvs_tables.py` evaluates subjects 05, 06, 07): 02_04 jump,
02_07 swordplay, 131_01 walk, 40 frames, 4 views, the same sensor errors, each fitted
with the prior built without its subject. Stage 1 on joints
for several pose-prior weights λ_θ, then the silhouette stage for several silhouette
settings from the best λ_θ; MPJPE (mm, 24 joints), the share of frames with legs on the
correct side, and the shape error (mm, zero-pose vertices).

    python experiments/muvs_tuning.py            # -> out/muvs_tuning/muvs_tuning.json
    python experiments/muvs_tuning.py --out experiments/results   # publish (~15 min on 2 CPU cores)

Until 2026-11-28 the tuning clips were 005_03, 006_04 and 007_02: subjects the MuVS table
evaluates (issue 52). `muvs_tables.py` and `muvs_resolution.py` fit with this script's
choice (`muvs_tables.tuned_weights`: `best_pose_prior` and the best silhouette variant
`best_silhouettes`); `defaults_agree` says whether `MuVSWeights()` holds it.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from _provenance import write_json
from muvs_tables import build, joints_of, legs_correct, shape_error

from jaxmocap.body import default_body
from jaxmocap.methods import multiview as mv
from jaxmocap.motion.splits import DEVELOPMENT, Split

#: MuVS's weights are chosen on the development subjects; the tables evaluate 05, 06, 07.
SPLIT = Split("muvs_tuning", tuning=DEVELOPMENT, training="leave-subject-out", evaluation=())
TUNING = ("02_04.amc", "02_07.amc", "131_01.bvh")  # jump, swordplay, walk


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--priors", type=float, nargs="+", default=[20.0, 5.0, 1.0, 0.3],
                    help="pose-prior weights λ_θ tried (1.0 won on the development clips: 0.3 checks below it)")
    ap.add_argument("--out", type=Path, default=Path("out/muvs_tuning"))
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    body = default_body("low")
    clips = {c.name: c.path for c in SPLIT.clips("tuning")}
    missing = [f for f in TUNING if f not in clips]
    if missing:
        raise SystemExit(f"development clips {missing} not found (../shared/data/cmu; set JAXMOCAP_CMU).")
    data, truth = build([clips[f] for f in TUNING], args.frames, 100, body)
    true_joints = np.stack([joints_of(body, t["poses"], t["betas"][:10], t["trans"]) for t in truth])
    p0 = mv.initialise(data)

    def score(p):
        B = len(truth)
        betas = p["betas"] if p["betas"].ndim == 3 else np.repeat(p["betas"][:, None], args.frames, 1)
        pred = np.stack([joints_of(body, p["pose"][b], betas[b], p["trans"][b]) for b in range(B)])
        legs = [legs_correct(pred[b], true_joints[b], body) for b in range(B)]
        return {
            "mpjpe_mm": float(np.linalg.norm(pred - true_joints, axis=-1).mean() * 1000),
            "legs_correct": float(sum(ok[a].sum() for ok, a in legs) / max(sum(a.sum() for _, a in legs), 1)),
            "shape_error_mm": float(np.mean([shape_error(body, np.median(betas[b], 0), truth[b]["betas"]) for b in range(B)])),
        }

    result = {"clips": list(TUNING), "frames": args.frames, "prior": {}, "silhouettes": {}}
    best, fits = None, {}
    for prior in args.priors:
        t0 = time.perf_counter()
        pj, _ = mv.stage_one(data, p0, mv.MuVSWeights(pose_prior=prior), silhouettes=False)
        result["prior"][str(prior)] = {**score(pj), "time_s": time.perf_counter() - t0}
        fits[prior] = pj
        print("pose_prior", prior, result["prior"][str(prior)], flush=True)
        if best is None or result["prior"][str(prior)]["mpjpe_mm"] < result["prior"][str(best)]["mpjpe_mm"]:
            best = prior
    variants = {"default": {}, "slack_4px": {"silhouette_slack": 4.0},
                "weight_0.03": {"silhouette_model": 0.03, "silhouette_mask": 0.03}}
    for name, change in variants.items():
        w = mv.MuVSWeights(pose_prior=best, anneal=(), **change)
        ps, _ = mv.stage_one(data, fits[best], w, silhouettes=True)
        result["silhouettes"][name] = {**change, **score(ps)}
        print("silhouettes", name, result["silhouettes"][name], flush=True)
    result["best_pose_prior"] = best
    result["best_silhouettes"] = min(result["silhouettes"], key=lambda k: result["silhouettes"][k]["mpjpe_mm"])
    default = mv.MuVSWeights()
    result["defaults_agree"] = {
        "pose_prior": default.pose_prior == best,
        "silhouettes": result["best_silhouettes"] == "default",
        "note": "whether MuVSWeights() holds this run's choice; the tables take the choice from this file either way",
    }
    print("best pose prior", best, "best silhouettes", result["best_silhouettes"], result["defaults_agree"], flush=True)
    write_json(args.out / "muvs_tuning.json", result, split=SPLIT, argv=argv, indent=2,
               data={"clips": list(TUNING), "subjects": sorted({clips[f].name.split("_")[0] for f in TUNING}),
                     "frames": args.frames})


if __name__ == "__main__":
    main()
