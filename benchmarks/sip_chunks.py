"""SIP big batch by factorisation and chunk size: 1000 sequences x 1000 frames x 20 LM steps.

    python benchmarks/sip_chunks.py default:auto cyclic:250 rows:250 twisted:250 --suffix h100

Each METHOD:CHUNK runs in a fresh process (one compile each, and the card's memory
as a new process finds it: an out-of-memory run in a process that had run a smaller
chunk first fit when run alone) through `solve_batch(..., tridiagonal=METHOD,
chunk_size=CHUNK)` with rtol = atol = 0; "default" is the backend's choice and "auto"
`plan_batch`'s chunk. Writes results/sip_chunks_<suffix>.json: per run `median_s`
(one timed call after the compiling one), `compile_and_first_call_s`, `peak_bytes`
(the device's peak in that process), or `error` (out of memory). The question it answers
(issue 20, goal 5): the frame-order factorisations ("rows", "twisted") are latency-bound
on a GPU, so larger chunks should help them where cyclic reduction is throughput-bound.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile

import jaxmocap  # noqa: F401  (first: it sizes XLA's CPU thread pool)
import jax
import jax.numpy as jnp

sys.path.insert(0, os.path.dirname(__file__))
from _common import machine, time_call, write_json  # noqa: E402
from sip_speed import _setup  # noqa: E402


def _one(spec: str, sequences: int, frames: int, iters: int) -> dict:
    from jaxmocap.methods import inertial
    from jaxmocap.solve import plan_batch, solve_batch

    method, chunk = spec.split(":")
    chunk = chunk if chunk == "auto" else int(chunk)
    setup = _setup(frames)
    sop, _ = inertial.sparse_orientation_poser(setup)
    stacked = inertial.stack_setups([setup] * sequences)
    problem = inertial.inertial_problem(stacked, inertial.SIPWeights(), acceleration=True)
    params = {"pose": jnp.broadcast_to(sop, (sequences,) + sop.shape),
              "trans": jnp.broadcast_to(stacked.trans0[:, None], (sequences, frames, 3))}  # fmt: skip
    row = {"method": method, "chunk": chunk, "auto_plan": str(plan_batch(problem, params, stacked.data))}
    try:
        t = time_call(lambda: solve_batch(problem, params, stacked.data, max_steps=iters, rtol=0.0, atol=0.0,
                                          tridiagonal=None if method == "default" else method,
                                          chunk_size=chunk).value["pose"], min_seconds=1e-9, max_repeats=1)  # fmt: skip
        row.update(t, peak_bytes=(jax.devices()[0].memory_stats() or {}).get("peak_bytes_in_use"))
    except Exception as e:  # out of memory: recorded, the next run goes on
        row["error"] = str(e)[:300]
    return row


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("specs", nargs="+", help="METHOD:CHUNK, e.g. default:auto twisted:250")
    p.add_argument("--sequences", type=int, default=1000)
    p.add_argument("--frames", type=int, default=1000)
    p.add_argument("--iters", type=int, default=20)
    p.add_argument("--suffix", default="gpu")
    p.add_argument("--child", help="internal: run one spec here and write its row to this file")
    args = p.parse_args(argv)
    if args.child:
        row = _one(args.specs[0], args.sequences, args.frames, args.iters)
        with open(args.child, "w") as f:
            json.dump(row, f)
        return 0
    runs = []
    for spec in args.specs:
        with tempfile.NamedTemporaryFile(suffix=".json", delete=False) as tmp:
            out = tmp.name
        cmd = [sys.executable, __file__, spec, "--child", out, "--sequences", str(args.sequences),
               "--frames", str(args.frames), "--iters", str(args.iters)]  # fmt: skip
        subprocess.run(cmd, check=True)
        with open(out) as f:
            row = json.load(f)
        os.unlink(out)
        runs.append(row)
        print({k: v for k, v in row.items() if k != "auto_plan"}, flush=True)
    payload = {"benchmark": "sip_chunks", "description": __doc__.split("\n\n")[2].replace("\n", " "),
               "sequences": args.sequences, "frames": args.frames, "lm_iterations": args.iters,
               "machine": machine(), "runs": runs}  # fmt: skip
    print("wrote", write_json(f"sip_chunks_{args.suffix}.json", payload))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
