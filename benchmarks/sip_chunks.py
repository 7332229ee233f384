"""SIP big batch by factorisation and chunk size: 1000 sequences x 1000 frames x 20 LM steps.

    python benchmarks/sip_chunks.py default:auto cyclic:250 rows:250 --suffix h100

Each METHOD:CHUNK runs in a fresh process (one compile each, and the card's memory
as a new process finds it: an out-of-memory run in a process that had run a smaller
chunk first fit when run alone) through `solve_batch(...,
solver=VonMarcardLM(tridiagonal=METHOD), chunk_size=CHUNK)` with rtol = atol = 0; "default" is the backend's choice and "auto"
`plan_batch`'s chunk. Writes results/sip_chunks_<suffix>.json: per run `median_s`
(one timed call after the compiling one), `compile_and_first_call_s`, `peak_bytes`
(the device's peak in that process), or `error` (out of memory). The question it answers
(issue 20, goal 5): the frame-order factorisations ("rows"; "twisted", since removed) are latency-bound
on a GPU, so larger chunks should help them where cyclic reduction is throughput-bound.

`--step` times one LM step's factorisation and solve alone, per chunk (`factorise.factor`
and `solve_factored`, vmapped over the chunk, on SIP normal equations of 125 sequences
linearised once and repeated), so that a chunk's memory is only the step's. It asks
whether the scans ever catch up with cyclic reduction once memory allows bigger chunks.
On one H100 (sip_chunks_step_gpu.json), per sequence and step: cyclic reduction 0.57 ms
at 125; "twisted" 0.96 ms at 125 and 0.69 ms at 250; "rows" 1.66 ms at 125. The scans
stop being latency-bound by 250 sequences, short of cyclic reduction, and at 500
"twisted" asked for a 37 GiB buffer and ran out of memory (cyclic at 250: 28 GiB, out of
memory beside the 125 linearised sequences). Even at 0.57 ms the factorisation and
solve alone take 1000 x 20 x 0.57 ms = 11.4 s of the goal's 5 s. The scans' loops
recorded as CUDA graphs (`XLA_FLAGS=--xla_gpu_enable_command_buffer=+WHILE`) ran as
fast as without ("twisted" at 125: 129 ms per step either way, same H100).
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
    from jaxmocap.solve import VonMarcardLM, solve_batch
    from jaxmocap.solve.batch import plan_batch

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
        t = time_call(lambda: solve_batch(problem, params, stacked.data, max_steps=iters,
                                          solver=VonMarcardLM(rtol=0.0, atol=0.0, tridiagonal=None if method == "default" else method),
                                          chunk_size=chunk).value["pose"], min_seconds=1e-9, max_repeats=1)  # fmt: skip
        row.update(t, peak_bytes=(jax.devices()[0].memory_stats() or {}).get("peak_bytes_in_use"))
    except Exception as e:  # out of memory: recorded, the next run goes on
        row["error"] = str(e)[:300]
    return row


def _one_step(spec: str, frames: int) -> dict:
    """One LM step's factor + solve for a chunk of `spec`'s size (see `--step`)."""
    from jaxmocap.methods import inertial
    from jaxmocap.solve import factorise, linearisation, solver

    method, chunk = spec.split(":")
    chunk, base = int(chunk), min(int(chunk), 125)
    setup = _setup(frames)
    problem = inertial.inertial_problem(setup)
    params = {"pose": jnp.broadcast_to(setup.pose0, (frames, 24, 3)) + 0.01,
              "trans": jnp.broadcast_to(setup.trans0, (frames, 3))}  # fmt: skip
    layout, params, _, dtype = solver.check_inputs(problem, params, setup.data, None, None)
    st = linearisation.Args(problem, setup.data, None, layout).structure()
    method = None if method == "default" else method
    stack = lambda tree, k: jax.tree.map(lambda x: jnp.array(jnp.broadcast_to(x, (k,) + jnp.shape(x))), tree)  # noqa: E731

    @jax.vmap
    def linearise(y, data):
        return linearisation.linearise(y, linearisation.Args(problem, data, None, layout), st, dtype, dtype, method)[:2]

    @jax.vmap
    def step(normal, grad):
        return factorise.solve_factored(factorise.factor(normal, st, jnp.float32(10.0), False, method), *grad)

    row = {"method": spec.split(":")[0], "chunk": chunk}
    with jax.default_matmul_precision("highest"):
        normal, grad = jax.jit(linearise)(stack(params, base), stack(setup.data, base))
        normal, grad = jax.tree.map(lambda x: jnp.concatenate([x] * (chunk // base), 0), (normal, grad))
        try:
            t = time_call(jax.jit(step), normal, grad, min_seconds=0.5, max_repeats=5)
            row.update(t, step_per_sequence_ms=t["median_s"] / chunk * 1e3,
                       peak_bytes=(jax.devices()[0].memory_stats() or {}).get("peak_bytes_in_use"))  # fmt: skip
        except Exception as e:  # out of memory: recorded, the next run goes on
            row["error"] = str(e)[:300]
    return row


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("specs", nargs="+", help="METHOD:CHUNK, e.g. default:auto cyclic:250")
    p.add_argument("--sequences", type=int, default=1000)
    p.add_argument("--frames", type=int, default=1000)
    p.add_argument("--iters", type=int, default=20)
    p.add_argument("--suffix", default="gpu")
    p.add_argument("--step", action="store_true", help="time one LM step's factor + solve per chunk (see above)")
    p.add_argument("--child", help="internal: run one spec here and write its row to this file")
    args = p.parse_args(argv)
    if args.child:
        row = (
            _one_step(args.specs[0], args.frames)
            if args.step
            else _one(args.specs[0], args.sequences, args.frames, args.iters)
        )
        with open(args.child, "w") as f:
            json.dump(row, f)
        return 0
    runs = []
    for spec in args.specs:
        with tempfile.NamedTemporaryFile(suffix=".json", delete=False) as tmp:
            out = tmp.name
        cmd = [sys.executable, __file__, spec, "--child", out, "--sequences", str(args.sequences),
               "--frames", str(args.frames), "--iters", str(args.iters)] + ["--step"] * args.step  # fmt: skip
        subprocess.run(cmd, check=True)
        with open(out) as f:
            row = json.load(f)
        os.unlink(out)
        runs.append(row)
        print({k: v for k, v in row.items() if k != "auto_plan"}, flush=True)
    payload = {"benchmark": "sip_chunks (step)" if args.step else "sip_chunks",
               "description": __doc__.split("\n\n")[3 if args.step else 2].replace("\n", " "),
               "frames": args.frames, "machine": machine(), "runs": runs}  # fmt: skip
    if not args.step:  # a step run solves nothing: no sequences or iterations
        payload.update(sequences=args.sequences, lm_iterations=args.iters)
    name = f"sip_chunks_step_{args.suffix}.json" if args.step else f"sip_chunks_{args.suffix}.json"
    print("wrote", write_json(name, payload))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
