"""One camera is honest (issue 47 goal 4): MuVS with one view of four, with and without the
floor contact term in the fit.

Protocol (that of `muvs_tables.py`'s one-view rows, on fewer frames): the first `--clips`
clips of the evaluated subjects (`jaxmocap.motion.splits`: CMU 05, 06, 07) with `--frames`
frames, filmed by the tables' 4 ring cameras (256 x 192 px, 1.4 m high, 4 m away) and
detector (3 px noise, misses, outliers, leg swaps), silhouettes with segmentation errors,
each fitted with its leave-subject-out pose prior and the weights `muvs_tuning.py` chose on
the development subjects; only view 0 is kept, its leg swaps flipped back over time
(`resolve_left_right`). Rows as in the tables: stage 1 on joints, + silhouettes (S), stage
2 (S,T), stage 2 with silhouettes (S,T,H). MPJPE over SMPL's 24 joints, in mm, without
alignment and after per-frame similarity alignment (Table 4.5's protocol); their ratio is
what goal 4 bounds (unaligned within 2x aligned).

Variants:
- `placed`: the library before the floor term (main at 7ae5f73): the fit knows nothing of
  the floor; after stage 1 (joints, and again after +S) `place_monocular` scales the body
  about the camera by where its feet meet the floor y = 0.
- `floor_term`: the same with the floor given to every stage (`stage_one(floor=...)`,
  `stage_two(floor=...)`: the floor contact term, `MuVSWeights.floor`), then placed alike.

Also per clip: the fit's median pelvis depth over the true one, and where the truth lies
in `monocular_depth`'s 1σ after stage 2.

    python experiments/muvs_monocular.py                               # -> out/muvs_monocular/
    python experiments/muvs_monocular.py --out experiments/results     # publish
    python experiments/muvs_monocular.py --development --weights floor=1e5   # tuning (02, 131)
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from _provenance import subjects_of, write_json, write_text
from muvs_tables import FLOOR, _override, build, joints_of, pick_clips, tuned_weights

from jaxmocap.body import default_body
from jaxmocap.methods import multiview as mv
from jaxmocap.metrics import procrustes_align
from jaxmocap.motion.splits import DEVELOPMENT, Split

SPLIT = Split("muvs_monocular", tuning=DEVELOPMENT, training="leave-subject-out")
#: The development clips (`muvs_tuning.py`'s): jump, swordplay, walk.
DEVELOPMENT_CLIPS = ("02_04.amc", "02_07.amc", "131_01.bvh")
ROWS = ("stage1", "S", "S_T", "S_T_H")
VARIANTS = ("placed", "floor_term")


def fit(d, w, floor_term: bool) -> tuple[dict, dict]:
    """The four rows' fits of one-view data `d`, and per member the depth record after stage 2."""
    floor = FLOOR if floor_term else None
    pj, _ = mv.stage_one(d, mv.initialise(d, w.num_betas), w, silhouettes=False, floor=floor)
    ps, _ = mv.stage_one(d, pj, w.replace(anneal=()), silhouettes=True, floor=floor)
    pj, _ = mv.place_monocular(d, pj, FLOOR)
    ps, _ = mv.place_monocular(d, ps, FLOOR)
    pt, _ = mv.stage_two(d, ps, w, floor=floor)
    ph, _ = mv.stage_two(d, ps, w, silhouettes=True, floor=floor)
    _, depth = mv.place_monocular(d, {**pt, "betas": np.repeat(pt["betas"][:, None], len(pt["pose"][0]), 1)}, FLOOR)
    return {"stage1": pj, "S": ps, "S_T": pt, "S_T_H": ph}, depth


def errors(body, fits, truth, true_joints, R, t) -> dict:
    """Per row and clip: unaligned and aligned MPJPE (mm), their ratio, the depth ratio."""
    out = {}
    for key, p in fits.items():
        frames = p["pose"].shape[1]
        per_frame = p["betas"] if p["betas"].ndim == 3 else np.repeat(p["betas"][:, None], frames, 1)
        rows = {}
        for b, tr in enumerate(truth):
            pred = joints_of(body, p["pose"][b], per_frame[b], p["trans"][b])
            un = float(np.linalg.norm(pred - true_joints[b], axis=-1).mean() * 1000)
            al = procrustes_align(jnp.asarray(pred), jnp.asarray(true_joints[b]), scale=True)
            al = float(jnp.mean(jnp.linalg.norm(al - true_joints[b], axis=-1)) * 1000)
            depth = [np.median((j[:, 0] @ R[b].T + t[b])[:, 2]) for j in (pred, true_joints[b])]
            rows[tr["name"]] = {"unaligned_mm": un, "aligned_mm": al, "ratio": un / al,
                                "depth_fit_over_true": float(depth[0] / depth[1])}  # fmt: skip
        mean_un = float(np.mean([r["unaligned_mm"] for r in rows.values()]))
        mean_al = float(np.mean([r["aligned_mm"] for r in rows.values()]))
        out[key] = {"clips": rows, "unaligned_mm": mean_un, "aligned_mm": mean_al, "ratio": mean_un / mean_al}
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--clips", type=int, default=3)
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--view", type=int, default=0)
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=VARIANTS)
    ap.add_argument(
        "--development",
        action="store_true",
        help="the development clips (tuning only: never published to experiments/results)",
    )
    ap.add_argument("--out", type=Path, default=Path("out/muvs_monocular"))
    ap.add_argument("--weights", nargs="*", default=[], metavar="NAME=VALUE", help="MuVSWeights overrides")
    args = ap.parse_args(argv)
    if args.development and args.out.resolve() == (Path(__file__).resolve().parent / "results"):
        raise SystemExit("--development results are tuning runs: write them outside experiments/results.")
    args.out.mkdir(parents=True, exist_ok=True)
    body = default_body("low")
    if args.development:
        by_name = {c.name: c.path for c in SPLIT.clips("tuning")}
        clips = [by_name[f] for f in DEVELOPMENT_CLIPS[: args.clips]]
    else:
        clips = pick_clips(args.clips, args.frames)
    tuned, tuned_from = tuned_weights()
    w = tuned.replace(**dict(_override(x) for x in args.weights))
    t0 = time.perf_counter()
    data, truth = build(clips, args.frames, args.seed, body)
    d = mv.resolve_left_right(mv.mask_views(data, [args.view]))
    R, t = (np.asarray(a, np.float64)[:, args.view] for a in (data.R, data.t))
    true_joints = np.stack([joints_of(body, tr["poses"], tr["betas"][:10], tr["trans"]) for tr in truth])
    timing = {"build_s": time.perf_counter() - t0}
    result = {"clips": [tr["name"] for tr in truth], "frames": args.frames, "seed": args.seed, "view": args.view,
              "floor": FLOOR, "weights": dict(w.__dict__), "weights_tuned": tuned_from, "variants": {}}  # fmt: skip
    for variant in args.variants:
        t1 = time.perf_counter()
        fits, depth = fit(d, w, variant == "floor_term")
        timing[variant + "_s"] = time.perf_counter() - t1
        table = errors(body, fits, truth, true_joints, R, t)
        sigmas = {}
        for b, tr in enumerate(truth):
            true_depth = float(np.median((true_joints[b][:, 0] @ R[b].T + t[b])[:, 2]))
            rec = depth[b]
            sigmas[tr["name"]] = {"depth_m": rec["depth_m"], "true_m": true_depth, "sigma_m": rec["depth_uncertainty_m"],
                                  "truth_in_sigma": abs(rec["depth_m"] - true_depth) / rec["depth_uncertainty_m"],
                                  "ground_scale": rec["scale"]}  # fmt: skip
        result["variants"][variant] = {"mpjpe": table, "depth_after_stage2": sigmas}
        print(f"{variant}: " + "  ".join(f"{k} {r['unaligned_mm']:.0f}/{r['aligned_mm']:.0f} ({r['ratio']:.2f})"
                                         for k, r in table.items()) + f"  [{timing[variant + '_s']:.0f} s]", flush=True)  # fmt: skip
    result["timing_s"] = timing
    data_rec = {
        "clips": result["clips"],
        "subjects": subjects_of(result["clips"]),
        "frames": args.frames,
        "views": [args.view],
    }
    split = SPLIT  # a --development run records its clips in "data" and stays out of experiments/results
    write_json(args.out / "muvs_monocular.json", result, split=split, data=data_rec, argv=argv, indent=2, default=float)
    md = [
        "| variant | row | "
        + " | ".join(f"{n} unaligned / aligned (ratio)" for n in result["clips"])
        + " | mean unaligned / aligned (ratio) |",
        "|---|---|" + "---|" * (len(result["clips"]) + 1),
    ]
    for variant, v in result["variants"].items():
        for key, r in v["mpjpe"].items():
            cells = [f"{c['unaligned_mm']:.0f} / {c['aligned_mm']:.0f} ({c['ratio']:.2f})" for c in r["clips"].values()]
            md.append(
                f"| {variant} | {key.replace('_', ',')} | "
                + " | ".join(cells)
                + f" | {r['unaligned_mm']:.0f} / {r['aligned_mm']:.0f} ({r['ratio']:.2f}) |"
            )
    md += [
        "",
        "Depth after stage 2 (`monocular_depth`, m): fit / truth, 1σ, |error| in σ",
        "",
        "| variant | " + " | ".join(result["clips"]) + " |",
        "|---|" + "---|" * len(result["clips"]),
    ]
    for variant, v in result["variants"].items():
        md.append(
            f"| {variant} | "
            + " | ".join(
                f"{s['depth_m']:.2f} / {s['true_m']:.2f}, {s['sigma_m']:.2f}, {s['truth_in_sigma']:.1f}σ"
                for s in v["depth_after_stage2"].values()
            )
            + " |"
        )
    write_text(args.out / "muvs_monocular.md", split=split, data=data_rec, argv=argv, text=
               f"# MuVS with one view of four ({args.frames} frames; MPJPE mm, 24 joints, unaligned / per-frame "
               "similarity-aligned)\n\n" + "\n".join(md) + "\n")  # fmt: skip
    print(f"machine: {jax.devices()[0]}")


if __name__ == "__main__":
    main()
