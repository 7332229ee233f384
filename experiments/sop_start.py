"""SIP's start: the thesis's sequential SOP against all frames of SOP solved at once.

SIP (eq. 3.5) starts from SOP's poses (§3.4.2). The thesis's SOP solves frame after frame,
each from the previous result: a scan of T small solves, 7.2 s per 1000 frames on an H200
(benchmarks/results/cold_start_gpu.json), far more than SIP itself (0.07 s). Solved all at
once (`orientation_poser(sequential=False)`: every frame from x₀, one batched solve) the
start costs one solve's latency. This script measures what that does to SIP on clips no
prior saw: the evaluated subjects 05, 06, 07 (`jaxmocap.motion.splits`) on the Character
Creator rig (../shared/data/cmu_cc), one subject in turn, each with the pose prior built
without its subject (`evaluation_prior`), 6 Xsens-like IMUs.

    python experiments/sop_start.py [--clips 6] [--frames 120]   # results/sop_start.json (+ .md)
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import jax
import numpy as np

import jaxmocap  # noqa: F401  (thread pool, compilation cache)
from jaxmocap.app.scenarios import inertial_setup
from jaxmocap.body import default_body
from jaxmocap.methods import inertial as I
from jaxmocap.metrics import pose_errors
from jaxmocap.priors.build import evaluation_prior
from jaxmocap.motion.corpus import corpus, interleave
from jaxmocap.motion.splits import DEVELOPMENT, LEAVE_SUBJECT_OUT, Split
from jaxmocap.sensors import IMUErrorModel, ScenarioConfig, make_scenario

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _provenance import subjects_of, write_json, write_text  # noqa: E402

SPLIT = Split("sop_start", tuning=DEVELOPMENT, training=LEAVE_SUBJECT_OUT)

ROOT = Path(__file__).resolve().parents[1]
CLIPS = ROOT.parent / "shared" / "data" / "cmu_cc"
RESULTS = Path(__file__).parent / "results"


STARTS = ("sequential", "batched", "x0")


def _start(setup, name):
    """SIP's initial poses: SOP frame after frame (the thesis), SOP on all frames at once
    (each from x₀), or x₀ itself on every frame (no SOP at all)."""
    if name == "x0":
        return jax.numpy.broadcast_to(setup.pose0, (setup.num_frames, *setup.pose0.shape))
    return I.orientation_poser(setup, sequential=name == "sequential")[0]


def _timed(fn):
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn())
    return out, time.perf_counter() - t0


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--clips", type=int, default=6, help="clips, taken in turn from subjects 5, 6, 7")
    p.add_argument("--frames", type=int, default=120)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    if not CLIPS.is_dir():
        sys.exit(f"{CLIPS} is missing: this experiment needs ../shared/data/cmu_cc beside the checkout")
    clips = [c.path for c in interleave(SPLIT.clips("evaluation", corpus([CLIPS])), args.clips)]
    body = default_body("low")
    cfg = ScenarioConfig(fps=30.0, max_frames=args.frames, imu_set="sip6", imu_errors=IMUErrorModel.xsens())
    rows = []
    for k, clip in enumerate(clips):
        scenario = make_scenario([clip], cfg, seed=args.seed + k, body=body)
        setup = inertial_setup(scenario, 0, body, prior=evaluation_prior(clip.name))
        truth = scenario.sequence(0)["poses"][0]
        row = {"clip": clip.name, "frames": int(setup.num_frames)}
        for name in STARTS:
            start = lambda n=name, u=setup: _start(u, n)  # noqa: E731
            _timed(start)  # compile
            sop, sop_s = _timed(start)
            sip = I.sparse_inertial_poser(setup, init=sop)
            _, sip_s = _timed(lambda sop=sop, u=setup: I.sparse_inertial_poser(u, init=sop).poses)
            for label, poses in (("sop", sop), ("sip", sip.poses)):
                e = pose_errors(body, np.asarray(poses), truth)
                row[f"{label}_{name}_mpjpe_mm"] = float(e["mpjpe"].mean())
                row[f"{label}_{name}_mpjae_deg"] = float(e["mpjae"].mean())
            row[f"sop_{name}_s"], row[f"sip_from_{name}_s"] = sop_s, sip_s
        rows.append(row)
        print(f"{clip.name}: SIP from " + ", ".join(
            f"{n} {row[f'sip_{n}_mpjpe_mm']:.1f} mm / {row[f'sip_{n}_mpjae_deg']:.1f}° (start {row[f'sop_{n}_s']:.2f} s)"
            for n in STARTS), flush=True)  # fmt: skip
    keys = [k for k in rows[0] if k not in ("clip", "frames")]
    mean = {k: float(np.mean([r[k] for r in rows])) for k in keys}
    out = {
        "experiment": "sop_start", "clips": [r["clip"] for r in rows], "frames": args.frames, "imu_set": "sip6",
        "imu_errors": "xsens", "prior": "held_out (evaluation_prior: built without the clip's subject)",
        "rows": rows, "mean": mean, "backend": jax.default_backend(),
        "sip_batched_vs_sequential_mpjpe_percent": 100 * (mean["sip_batched_mpjpe_mm"] / mean["sip_sequential_mpjpe_mm"] - 1),
        "sip_batched_vs_sequential_mpjae_percent": 100 * (mean["sip_batched_mpjae_deg"] / mean["sip_sequential_mpjae_deg"] - 1),
        "sop_speedup": mean["sop_sequential_s"] / mean["sop_batched_s"],
        "sip_x0_vs_sequential_mpjpe_percent": 100 * (mean["sip_x0_mpjpe_mm"] / mean["sip_sequential_mpjpe_mm"] - 1),
        "sip_x0_vs_sequential_mpjae_percent": 100 * (mean["sip_x0_mpjae_deg"] / mean["sip_sequential_mpjae_deg"] - 1),
    }  # fmt: skip
    data = {"clips": out["clips"], "subjects": subjects_of(out["clips"]), "frames": [r["frames"] for r in rows]}
    write_json(RESULTS / "sop_start.json", out, split=SPLIT, data=data, argv=argv, indent=2)
    n = [r["frames"] for r in rows]
    d = out["sip_batched_vs_sequential_mpjpe_percent"]
    better = "as good (within 0.05 %)" if abs(d) < 0.05 else ("better" if d < 0 else "worse")
    md = [
        "# SIP from a sequential, a batched or no SOP start", "",
        f"{len(rows)} held-out cmu_cc clips (subjects {', '.join(data['subjects'])}) × "
        f"{f'{min(n)}' if min(n) == max(n) else f'{min(n)}-{max(n)}'} frames, 6 Xsens-like IMUs, prior without the clip's subject "
        f"({jax.default_backend()}). Generated by `experiments/sop_start.py`.", "",
        "| start | start MPJPE mm | start MPJAE ° | SIP MPJPE mm | SIP MPJAE ° | start s / sequence |", "|---|---|---|---|---|---|",
    ]  # fmt: skip
    for name in STARTS:
        md.append(f"| {name} | {mean[f'sop_{name}_mpjpe_mm']:.1f} | {mean[f'sop_{name}_mpjae_deg']:.2f} | "
                  f"{mean[f'sip_{name}_mpjpe_mm']:.1f} | {mean[f'sip_{name}_mpjae_deg']:.2f} | {mean[f'sop_{name}_s']:.3f} |")  # fmt: skip
    md += ["", f"From the batched start SIP is {'' if abs(d) < 0.05 else f'{abs(d):.1f} % '}{better} in "
           f"MPJPE ({out['sip_batched_vs_sequential_mpjae_percent']:+.1f} % MPJAE); the batched start took "
           f"{1 / out['sop_speedup']:.2f}× the sequential one's time on this machine ({out['backend']}). From x₀ on every frame (no SOP) SIP is "
           f"{out['sip_x0_vs_sequential_mpjpe_percent']:+.1f} % in MPJPE and {out['sip_x0_vs_sequential_mpjae_percent']:+.1f} % "
           "in MPJAE against the thesis's start."]  # fmt: skip
    write_text(RESULTS / "sop_start.md", "\n".join(md) + "\n", split=SPLIT, data=data, argv=argv)
    print("\n".join(md))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
