"""Sweeps at scale (issue 19): SIP B = 1000 × T = 1000 × 20 LM steps in memory-sized chunks,
the SIP ablation sweep end to end, and the speed-up from a second GPU.

    python benchmarks/sweep_scale.py                                   # on a GPU: the full run
    python benchmarks/sweep_scale.py --sequences 6 --frames 40 --iters 2 --no-sweep --suffix smoke   # CPU check

Parts (keys of results/sweep_scale.json):

- `batch`: SIP on B sequences of T frames, 20 LM steps forced (rtol = atol = 0), float32,
  `solve_batch` choosing the chunk size from its bytes-per-sequence estimate and the
  device's free memory (`plan`: chunk size, chunks, estimate, free bytes). The data are
  `--pool` distinct generated sequences (procedural library motions, Xsens-like errors)
  tiled to B: the cost of a forced 20-step solve does not depend on which motion it
  is. Timed twice: the first call includes compilation (`first_call_s`), the second is
  the steady state (`wall_s`, `frame_iterations_per_s` = B·T·iterations / wall_s).
  `peak_memory_bytes` is the device's peak over the process; `measured_bytes_per_sequence`
  = peak / chunk size, against the estimate.
- `baseline_one_chunk`: the same solve as one vmap over all B (what `solve_batch` did
  before chunking), run in the same process after the chunked one: on one H200 it fails
  with RESOURCE_EXHAUSTED, recorded as `error`; if it fits, its time and the ratio.
- `sweep`: `run_sweep` on experiments/sweeps/sip_ablation.toml (16 128 cells of 120
  frames × 20 steps): wall time, cells, frames × iterations per second. Its summary is
  copied to `--sweep-summary` if given.
- `speedup_2_gpus`, `speedup_4_gpus`, `speedup_8_gpus` (those the machine has): the batch on
  the first 2, 4, 8 local GPUs over the batch on one (same process,
  same data). null when fewer than 2 devices are visible (recorded in
  `speedup_2_gpus_note`). Timed before the one-chunk baseline, so that its deliberate
  out-of-memory failure cannot disturb them. `multi_gpu[n]` names the machine it ran
  on and the one-device time it is divided by.

`--multi-gpu-only` times the one-device batch and the multi-GPU speed-ups alone and
updates those keys of an existing result file, keeping its one-GPU `batch`, baseline
and `sweep` (each says the machine it ran on): the two-GPU kinds are lent on other
days than the one-GPU kind, and the speed-up is a ratio within one machine.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import jaxmocap  # noqa: F401 - before JAX's CPU backend starts: it widens the thread pool (jaxmocap._threads)

sys.path.insert(0, str(Path(__file__).parent))
from _common import RESULTS, machine, peak_memory_bytes, write_json  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent


def _pool(frames: int, count: int, seed: int = 0):
    """`count` calibrated SIP sequences of `frames` frames and their SOP starts."""
    from jaxmocap.app.scenarios import inertial_setup
    from jaxmocap.app.sweep_methods import _sop_batch
    from jaxmocap.body import default_body
    from jaxmocap.methods import inertial as I
    from jaxmocap.motion import library
    from jaxmocap.sensors import IMUErrorModel, ScenarioConfig, make_scenario

    body = default_body("low")
    names = ["walk", "run", "jumping_jacks", "arm_raises", "leg_raises", "squats", "sit_stand", "static_hold"]
    motions = [library.MOTIONS[names[i % len(names)]](num_frames=frames, fps=30.0, body=body) for i in range(count)]
    cfg = ScenarioConfig(fps=30.0, max_frames=frames, imu_set="sip6", imu_errors=IMUErrorModel.xsens(), betas_std=1.0)
    sc = make_scenario(motions, cfg, seed=seed, body=body)
    setups = [inertial_setup(sc, i, body) for i in range(sc.num_sequences)]
    stacked = I.stack_setups(setups)
    init = _sop_batch(stacked)
    return stacked, jnp.asarray(init)


def _tile(tree, B: int):
    n = jax.tree_util.tree_leaves(tree)[0].shape[0]
    idx = jnp.asarray(np.arange(B) % n)
    return jax.tree_util.tree_map(lambda x: x[idx], tree)


def _solve(stacked, init, iters, **kw):
    from jaxmocap.methods import inertial as I
    from jaxmocap.solve import VonMarcardLM, solve_batch

    B, T = init.shape[:2]
    problem = I.inertial_problem(stacked, acceleration=True)
    trans = jnp.broadcast_to(stacked.trans0[:, None], (B, T, 3))
    return solve_batch(problem, {"pose": init, "trans": trans}, stacked.data, max_steps=iters,
                       solver=VonMarcardLM(rtol=0.0, atol=0.0), **kw)  # fmt: skip


def _plan(stacked, init, **kw):
    from jaxmocap.methods import inertial as I
    from jaxmocap.solve.batch import plan_batch

    B, T = init.shape[:2]
    problem = I.inertial_problem(stacked, acceleration=True)
    trans = jnp.broadcast_to(stacked.trans0[:, None], (B, T, 3))
    return plan_batch(problem, {"pose": init, "trans": trans}, stacked.data, **kw)


def _timed(fn):
    t0 = time.perf_counter()
    out = fn()
    jax.block_until_ready(out)
    return out, time.perf_counter() - t0


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sequences", type=int, default=1000)
    p.add_argument("--frames", type=int, default=1000)
    p.add_argument("--iters", type=int, default=20)
    p.add_argument("--pool", type=int, default=8, help="distinct generated sequences, tiled to --sequences")
    p.add_argument("--no-baseline", action="store_true", help="skip the one-chunk (unchunked) attempt")
    p.add_argument("--no-sweep", action="store_true")
    p.add_argument("--sweep", default=str(ROOT / "experiments" / "sweeps" / "sip_ablation.toml"))
    p.add_argument("--sweep-out", default="out/sweeps/sip_ablation", help="the sweep's store (may hold cached data)")
    p.add_argument("--sweep-summary", help="copy the sweep's summary files here")
    p.add_argument("--suffix", default="")
    p.add_argument(
        "--refresh-one-gpu",
        action="store_true",
        help="also write this run's one-GPU `batch` into results/sweep_scale.json (keeping its sweep)",
    )
    p.add_argument(
        "--multi-gpu-only",
        action="store_true",
        help="time the one-device batch and the multi-GPU speed-ups alone; update those keys of the result file",
    )
    args = p.parse_args(argv)
    B, T, it = args.sequences, args.frames, args.iters
    out = {"benchmark": "sweep_scale", "machine": machine(), "dtype": "float32", "sequences": B, "frames": T,
           "lm_iterations": it}  # fmt: skip

    name = f"sweep_scale{'_' + args.suffix if args.suffix else ''}.json"
    if args.multi_gpu_only:
        earlier = RESULTS / name
        if not earlier.exists():
            p.error(f"--multi-gpu-only updates {earlier}, which does not exist; run without it first")
        kept = json.loads(earlier.read_text())
        if (kept["sequences"], kept["frames"], kept["lm_iterations"]) != (B, T, it):
            p.error(f"{earlier} is for B={kept['sequences']} T={kept['frames']} x {kept['lm_iterations']}; "
                    "give the same --sequences, --frames and --iters")  # fmt: skip
        out = {**kept, "multi_gpu": {}}

    def save():
        return write_json(name, out)

    t0 = time.perf_counter()
    pool, pool_init = _pool(T, min(args.pool, B))
    jax.block_until_ready(pool_init)
    if not args.multi_gpu_only:
        out["data_and_sop_init_s"] = time.perf_counter() - t0
    stacked, init = _tile(pool, B), _tile(pool_init, B)
    one = jax.local_devices()[:1]
    plan = _plan(stacked, init, devices=one)
    sol, first = _timed(lambda: _solve(stacked, init, it, devices=one))
    sol, wall = _timed(lambda: _solve(stacked, init, it, devices=one))
    work = B * T * it
    peak = peak_memory_bytes()
    steps = np.asarray(sol.num_steps)
    one_device = {"wall_s": wall, "first_call_s": first, "compile_s": max(first - wall, 0.0), "plan": plan.to_dict(),
                  "peak_memory_bytes": peak}  # fmt: skip
    if not args.multi_gpu_only:
        out["batch"] = {
            "plan": plan.to_dict(), "first_call_s": first, "wall_s": wall, "frame_iterations_per_s": work / wall,
            "frames_per_s": B * T / wall, "peak_memory_bytes": peak,
            "measured_bytes_per_sequence": None if peak is None else peak / plan.chunk_size,
            "estimated_bytes_per_sequence": plan.bytes_per_sequence, "num_steps_min_max": [int(steps.min()), int(steps.max())],
            "finite_costs": int(np.isfinite(np.asarray(sol.cost)).sum()), "out_of_memory": False,
        }  # fmt: skip
    print(f"SIP B={B} T={T} x {it}: {wall:.1f} s ({work / wall:.3g} frame-iterations/s), chunks of "
          f"{plan.chunk_size} ({plan.num_chunks}), estimate {plan.bytes_per_sequence / 2**20:.0f} MiB/seq, "
          f"peak {0 if peak is None else peak / 2**30:.1f} GiB", flush=True)  # fmt: skip
    del sol
    save()
    if args.refresh_one_gpu and not args.multi_gpu_only:
        # The one-GPU part of the main file (its sweep part, a separate run, is kept).
        main_file = RESULTS / "sweep_scale.json"
        kept = json.loads(main_file.read_text()) if main_file.exists() else {}
        if (kept.get("sequences"), kept.get("frames"), kept.get("lm_iterations")) not in (
            (B, T, it),
            (None, None, None),
        ):
            p.error(f"--refresh-one-gpu: {main_file} is for another problem size; give the same sizes")
        kept.update(
            {k: out[k] for k in ("sequences", "frames", "lm_iterations", "dtype", "batch", "data_and_sop_init_s")}
        )
        kept["batch"] = dict(out["batch"], machine=machine(), refreshed_by=f"sweep_scale.py --suffix {args.suffix}")
        print(f"refreshed the one-GPU part of {write_json('sweep_scale.json', kept)}", flush=True)

    devices = jax.local_devices()
    counts = [n for n in (2, 4, 8) if n <= len(devices)]
    out["multi_gpu"] = {}
    for n in counts:  # the same batch on the first n devices of this machine
        subset = devices[:n]
        _, first_n = _timed(lambda subset=subset: _solve(stacked, init, it, devices=subset))  # with compilation
        _, wall_n = _timed(lambda subset=subset: _solve(stacked, init, it, devices=subset))
        out[f"speedup_{n}_gpus"] = wall / wall_n
        stats = [d.memory_stats() or {} for d in subset]
        out["multi_gpu"][str(n)] = {
            "machine": machine(), "wall_s": wall_n, "first_call_s": first_n, "compile_s": max(first_n - wall_n, 0.0),
            "one_device": one_device,
            "plan": _plan(stacked, init, devices=subset).to_dict(),
            "peak_bytes_per_device": [st.get("peak_bytes_in_use") for st in stats],
        }  # fmt: skip
        print(f"{n} devices: {wall_n:.1f} s (first call {first_n:.1f} s), speed-up {wall / wall_n:.2f}", flush=True)
    if not counts:
        out["speedup_2_gpus"] = None
        out["speedup_2_gpus_note"] = (
            f"unmeasured: {len(devices)} device visible ({devices[0].device_kind}); run this script on a "
            "2-GPU machine (nvidia-h200-x2) to fill it in"
        )
    if args.multi_gpu_only:
        if "speedup_2_gpus" in out:
            out.setdefault("speedup_2_gpus_history", {})[f"{len(devices)}x {devices[0].device_kind}"] = out[
                "speedup_2_gpus"
            ]
        print(f"updated {save()}")
        return 0
    save()

    if not args.no_baseline:
        try:
            base, bt = _timed(lambda: _solve(stacked, init, it, devices=one, chunk_size=None))
            out["baseline_one_chunk"] = {"wall_s_including_compile": bt, "error": None}
            del base
        except Exception as e:  # noqa: BLE001 - the out-of-memory failure is the point
            msg = str(e).splitlines()[0][:400]
            out["baseline_one_chunk"] = {"error": f"{type(e).__name__}: {msg}"}
        print(f"one chunk of {B}: {out['baseline_one_chunk']}", flush=True)
        save()

    if not args.no_sweep:
        from jaxmocap.app import load_config, run_sweep
        from jaxmocap.app.sweep import Store, variants

        config = load_config(args.sweep)
        store = Store(args.sweep_out, config)
        before = len(list(store.cells.glob("*.json"))) if store.cells.exists() else 0
        t0 = time.perf_counter()
        root = run_sweep(config, args.sweep_out, progress=False)
        sw = time.perf_counter() - t0
        recs = store.records()
        ran = len(recs) - before
        frames = sum(r["metrics"]["frames"] for r in recs if "metrics" in r)
        out["sweep"] = {
            "config": str(Path(args.sweep).resolve().relative_to(ROOT)) if Path(args.sweep).resolve().is_relative_to(ROOT) else args.sweep,
            "variants": len(variants(config)), "cells": len(recs), "cells_run_now": ran,
            "failed_cells": sum("error" in r for r in recs), "frames_total": frames,
            "wall_s_including_compile_data_and_summary": sw,
            "frame_iterations_per_s": frames * config["options"]["max_steps"] / sw if ran == len(recs) else None,
            "peak_memory_bytes": peak_memory_bytes(), "batch_size_cells": config["batch_size"],
        }  # fmt: skip
        print(f"sweep: {len(recs)} cells in {sw:.0f} s", flush=True)
        if args.sweep_summary:
            dst = Path(args.sweep_summary)
            dst.mkdir(parents=True, exist_ok=True)
            for f in ("summary.md", "summary.csv", "summary.json", "cells.csv", *(p.name for p in root.glob("*.png"))):
                if (root / f).exists():
                    shutil.copy(root / f, dst / f)
    out["load_average_1_5_15min_at_end"] = list(os.getloadavg())
    print(f"wrote {save()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
