"""SIP on two devices: one sequence's frames split over two (CPU) devices, "twisted" factorisation.

    python benchmarks/sip_two_devices.py      # this CPU as two devices, writes results/sip_two_devices.json

The process starts with two host devices (`--xla_force_host_platform_device_count=2`,
set here before JAX starts) and times, alternating, the same SIP solve as
`sip_speed.py`'s single sequence (1000 frames x 20 LM steps from the SOP start, float32):

- `rows`: the CPU default, inputs on one device (the baseline);
- `twisted`: `tridiagonal="twisted"` (jaxmocap/solve/rows.py: the frame-order scan run
  from both ends, a half on each device), inputs on one device, so the rest of the
  step runs replicated on both;
- `rows_sharded`, `twisted_sharded`: the same with params0 and data split over the
  devices along frames (`jaxmocap.solve.shard_frames`), so XLA partitions the per-frame
  work too.

Keys: `<variant>.median_s`, `<variant>.final_cost`, `ratio_vs_rows` (median / rows').
"""

from __future__ import annotations

import argparse
import os
import sys

os.environ["XLA_FLAGS"] = os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=2"

import jaxmocap  # noqa: E402, F401  (first: it sizes XLA's CPU thread pool)
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

sys.path.insert(0, os.path.dirname(__file__))
from _common import machine, time_call, write_json  # noqa: E402
from sip_speed import _setup  # noqa: E402

VARIANTS = (("rows", False), ("twisted", False), ("rows", True), ("twisted", True))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=1000)
    p.add_argument("--iters", type=int, default=20)
    p.add_argument("--rounds", type=int, default=3, help="alternated rounds; each variant's median over them")
    p.add_argument("--suffix", default="")
    args = p.parse_args(argv)
    if jax.local_device_count() < 2:
        raise SystemExit("expected two devices; is XLA_FLAGS overriding the device count?")
    from jaxmocap.methods import inertial
    from jaxmocap.solve import shard_frames, solve

    setup = _setup(args.frames)
    sop, _ = inertial.sparse_orientation_poser(setup)
    problem = inertial.inertial_problem(setup)
    params = {"pose": sop, "trans": jnp.broadcast_to(setup.trans0, (args.frames, 3))}
    inputs = {False: (params, setup.data), True: shard_frames((params, setup.data), args.frames)}

    def run(method, sharded):
        p0, data = inputs[sharded]
        return solve(problem, p0, data, tridiagonal=method, max_steps=args.iters, rtol=0.0, atol=0.0, progress=False)

    times = {f"{m}{'_sharded' if s else ''}": [] for m, s in VARIANTS}
    results = {}
    for r in range(args.rounds):
        for method, sharded in VARIANTS:
            key = f"{method}{'_sharded' if sharded else ''}"
            t = time_call(lambda m=method, s=sharded: run(m, s).value, min_seconds=1e-9, max_repeats=1)
            times[key].append(t["median_s"])
            if r == 0:
                results[key] = {"compile_and_first_call_s": t["compile_and_first_call_s"],
                                "final_cost": float(run(method, sharded).cost)}  # fmt: skip
            print(f"round {r}: {key}: {t['median_s']:.3f} s", flush=True)
    base = sorted(times["rows"])[len(times["rows"]) // 2]
    for key, ts in times.items():
        med = sorted(ts)[len(ts) // 2]
        results[key].update(median_s=med, times_s=ts, ratio_vs_rows=med / base)
        print(f"{key}: {med:.3f} s ({med / base:.3f}x rows), final cost {results[key]['final_cost']:.9g}")
    payload = {
        "benchmark": "sip_two_devices",
        "description": __doc__.split("\n\n")[1].replace("\n", " "),
        "frames": args.frames, "lm_iterations": args.iters, "rounds": args.rounds,
        "machine": machine(), "variants": results,
    }  # fmt: skip
    print("wrote", write_json(f"sip_two_devices{'_' + args.suffix if args.suffix else ''}.json", payload))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
