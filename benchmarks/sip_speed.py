"""SIP speed: one 1000-frame sequence × 20 LM iterations, and batch throughput.

    python benchmarks/sip_speed.py                   # CPU, writes results/sip_speed.json
    python benchmarks/sip_speed.py --suffix gpu --batches 1,64,1024   # on a GPU

The thesis (von Marcard §3.4.1): 1000 frames, 20 cost evaluations, 7.5 minutes in
single-core MATLAB. Here "20 iterations" means 20 LM trial steps (each one cost
evaluation; accepted steps also rebuild the Jacobian), forced by rtol = atol = 0 so the
solver never stops early. The SOP initialisation is computed once and not timed (it is
reported separately). float32 (x64 off), the default of the methods.

Baseline (same process, same problem and start): the engine without the SIP terms'
analytic Jacobians and `reads`, i.e. Jacobian blocks by forward-mode AD over all 75
unknowns per frame and no per-frame elimination (`--no-baseline` skips it).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp

sys.path.insert(0, str(Path(__file__).parent))
from _common import machine, peak_memory_bytes, time_call, write_json  # noqa: E402


def _setup(frames: int, seed: int = 0):
    from jaxmocap.body import default_body
    from jaxmocap.methods import inertial
    from jaxmocap.motion import library
    from jaxmocap.sensors import IMUErrorModel, ScenarioConfig, make_scenario

    body = default_body("low")
    motion = library.jumping_jacks(num_frames=frames, fps=30.0, body=body)
    cfg = ScenarioConfig(fps=30.0, max_frames=frames, imu_set="sip6", imu_errors=IMUErrorModel.xsens(), betas_std=0.0)
    sc = make_scenario([motion], cfg, seed=seed, body=body)
    return inertial.from_scenario(sc, 0, body)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=1000)
    p.add_argument("--iters", type=int, default=20)
    p.add_argument("--batches", default="1,16,64", help="batch sizes for the throughput test")
    p.add_argument("--batch-frames", type=int, default=100, help="frames per sequence in the batch test")
    p.add_argument("--suffix", default="", help="results/sip_speed_<suffix>.json (e.g. gpu)")
    p.add_argument("--min-seconds", type=float, default=2.0)
    p.add_argument("--no-baseline", action="store_true", help="skip the AD-Jacobian baseline")
    args = p.parse_args(argv)

    from jaxmocap.methods import inertial

    it = dict(max_steps=args.iters, rtol=0.0, atol=0.0)
    setup = _setup(args.frames)
    t0 = time.perf_counter()
    sop, _ = inertial.sparse_orientation_poser(setup)
    jax.block_until_ready(sop)
    sop_first = time.perf_counter() - t0
    sop_timing = time_call(lambda: inertial.sparse_orientation_poser(setup)[0], min_seconds=1e-9, max_repeats=1)
    sop_timing["compile_and_first_call_s"] = sop_first

    def run_sip():
        return inertial.sparse_inertial_poser(setup, init=sop, **it).solution

    single = time_call(run_sip, min_seconds=args.min_seconds, max_repeats=5)
    sol = run_sip()
    single.update(num_steps=int(sol.num_steps), frames=args.frames, lm_iterations=args.iters,
                  frames_per_second=args.frames / single["median_s"],
                  seconds_per_iteration=single["median_s"] / args.iters)  # fmt: skip
    print(f"SIP {args.frames} frames x {args.iters} LM steps: {single['median_s']:.3f} s "
          f"(compile + first {single['compile_and_first_call_s']:.1f} s); SOP {sop_timing['median_s']:.2f} s")
    baseline = None
    if not args.no_baseline:
        from jaxmocap.solve import Problem, Term, solve

        analytic = inertial.inertial_problem(setup)
        plain = Problem(
            [Term(t.name, t.fn, t.weight, t.bandwidth, t.loss, t.mask) for t in analytic.terms], analytic.rotations
        )
        params = {"pose": sop, "trans": jnp.broadcast_to(setup.trans0, (args.frames, 3))}
        baseline = time_call(lambda: solve(plain, params, setup.data, **it), min_seconds=1e-9, max_repeats=1)
        single["ratio_to_baseline"] = single["median_s"] / baseline["median_s"]
        print(f"baseline (AD Jacobians, no elimination): {baseline['median_s']:.3f} s, "
              f"ratio {single['ratio_to_baseline']:.3f}")

    short = _setup(args.batch_frames, seed=1)
    sop_short, _ = inertial.sparse_orientation_poser(short)
    batches = {}
    for B in [int(b) for b in args.batches.split(",")]:
        stacked = inertial.stack_setups([short] * B)
        init = jnp.broadcast_to(sop_short, (B,) + sop_short.shape)

        def run_batch(stacked=stacked, init=init):
            return inertial.sparse_inertial_poser_batch(stacked, init, **it).value["pose"]

        t = time_call(run_batch, min_seconds=args.min_seconds, max_repeats=5)
        t["frames_per_second"] = B * args.batch_frames / t["median_s"]
        batches[str(B)] = t
        print(f"batch {B:5d} x {args.batch_frames} frames: {t['median_s']:.3f} s, {t['frames_per_second']:.0f} frames/s")

    payload = {
        "benchmark": "sip_speed",
        "machine": machine(),
        "dtype": "float32",
        "thesis": {"frames": 1000, "cost_evaluations": 20, "seconds": 450.0, "setup": "single-core MATLAB, i7 3.5 GHz"},
        "sop_init": sop_timing,
        "sip_single": single,
        "baseline_ad_jacobians": baseline,
        "batch_frames": args.batch_frames,
        "batch": batches,
        "peak_memory_bytes": peak_memory_bytes(),
        # The CPU is shared: a load above the core count means these times are inflated.
        "load_average_1_5_15min_at_end": list(__import__("os").getloadavg()),
    }
    name = f"sip_speed{'_' + args.suffix if args.suffix else ''}.json"
    print(f"wrote {write_json(name, payload)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
