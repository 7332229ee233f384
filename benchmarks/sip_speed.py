"""SIP speed: one 1000-frame sequence × 20 LM iterations, and batch throughput.

    python benchmarks/sip_speed.py                   # CPU, writes results/sip_speed.json
    python benchmarks/sip_speed.py --suffix gpu --batches 1,64,1024   # on a GPU
    python benchmarks/sip_speed.py --frames 100 --iters 5 --batches 1 --suffix small   # a quick check
    python benchmarks/sip_speed.py --no-v1 --no-baseline --batches '' --long 5000,20000   # long sequences
    python benchmarks/sip_speed.py --suffix gpu --no-v1 --no-baseline --batches '' --big-batch 1000  # issue 20 on a GPU

Issue 20's keys: `sip_single.median_s` (this machine, default factorisation),
`sip_t5000_s`, `sip_t20000_s` (`--long`: one timed solve each after a compiling one, SOP
start given, with `linear_scaling`: time / ((T / frames) x the single-sequence time)),
`gpu_single_s` and `gpu_1000x1000_s` (from a GPU run: the single sequence, and
`--big-batch` sequences of `--frames` frames through `sparse_inertial_poser_batch`, which
chunks to fit memory). A GPU run also writes its two keys into results/sip_speed.json and
a CPU run copies them from results/sip_speed_gpu.json, so that one file holds them all.
The frame band's factorisation ("rows": in the acceleration rows' space, jaxmocap/solve/rows.py;
"scan":
block Cholesky of the band; "cyclic": cyclic reduction, jaxmocap/solve/tridiagonal.py)
is timed every way on the single sequence (`tridiagonal`, with `default_vs_scan_ratio`:
the default against the band scan, the CPU's default before "rows"); `--big-batch-tridiagonal`
times the big batch with others besides the default (`big_batch_by_tridiagonal`).

The thesis (von Marcard §3.4.1): 1000 frames, 20 cost evaluations, 7.5 minutes in
single-core MATLAB. Here "20 iterations" means 20 LM trial steps (each one cost
evaluation; accepted steps also rebuild the Jacobian), forced by rtol = atol = 0 so the
solver never stops early. The SOP initialisation is computed once and not timed (it is
reported separately). float32 (x64 off), the default of the methods.

float64 check (`float64_check`, `final_cost_rel_diff_float64`): float32 iterates of two
programs drift apart by rounding over 20 LM steps, so the same solve (200 frames x 10
steps) also runs in float64 under both engines, in subprocesses, to compare the algorithms.

v1 baseline (same run, same machine): the engine as it was at commit d67d910 (its own
hand-written LM), imported from `build/v1` (see `_v1.py`: extracted from git history, or
carried where there is no .git) in a subprocess that times the identical single-sequence
SIP solve (`--engine-only`): the same data arrays and SOP start (handed over in a file),
dtype, iteration count and timing loop. Keys: `v1_time_s`, `optx_default_time_s` (this
run's engine, `sip_single.median_s`), `optx_default_vs_v1_ratio` = current / v1,
`final_cost`, `v1_final_cost`, `final_cost_rel_diff` (and `v1_final_cost_by_current_costs`,
v1's end point under this engine's cost function; `v1`: the subprocess's own record).
`--no-v1` skips it.

`--before COMMIT`: the same single-sequence solve (and, with `--big-batch`, the same
batch) with the engine at COMMIT (extracted like v1 into build/engine_COMMIT, which a
machine without .git needs carried), key `before` (time, final cost, `ratio` = now /
before, `big_batch_s`, `big_batch_ratio`): a speed-up measured on one machine, whichever
card it is.

Baseline (same process, same problem and start): the engine without the SIP terms'
analytic Jacobians and `reads`, i.e. Jacobian blocks by forward-mode AD over all 75
unknowns per frame and no per-frame elimination (`--no-baseline` skips it).

GPU memory: unless XLA_PYTHON_CLIENT_PREALLOCATE is set, it is set to false here (and so
in the v1 subprocess), so that the two processes can share one GPU on equal terms.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

# Before JAX starts: the v1 subprocess needs GPU memory while this process holds its own.
os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
from _common import RESULTS, machine, peak_memory_bytes, time_call, write_json  # noqa: E402
from _v1 import V1_COMMIT, v1_path  # noqa: E402


def _setup(frames: int, seed: int = 0):
    from jaxmocap.app.scenarios import inertial_setup
    from jaxmocap.body import default_body
    from jaxmocap.motion import library
    from jaxmocap.sensors import IMUErrorModel, ScenarioConfig, make_scenario

    body = default_body("low")
    motion = library.jumping_jacks(num_frames=frames, fps=30.0, body=body)
    cfg = ScenarioConfig(fps=30.0, max_frames=frames, imu_set="sip6", imu_errors=IMUErrorModel.xsens(), betas_std=0.0)
    sc = make_scenario([motion], cfg, seed=seed, body=body)
    return inertial_setup(sc, 0, body)


def _time_sip(setup, init, iters: int, min_seconds: float, tridiagonal: str | None = None):
    """The single-sequence measurement (shared by this run and the v1 subprocess)."""
    from jaxmocap.methods import inertial

    it = dict(max_steps=iters, rtol=0.0, atol=0.0)

    def run_sip():
        if tridiagonal is None:  # the method's own entry point (also v1's)
            return inertial.sparse_inertial_poser(setup, init=init, **it).solution
        from jaxmocap.solve import VonMarcardLM, solve

        params = {"pose": init, "trans": jnp.broadcast_to(setup.trans0, (setup.num_frames, 3))}
        lm = VonMarcardLM(rtol=0.0, atol=0.0, tridiagonal=tridiagonal)
        return solve(inertial.inertial_problem(setup), params, setup.data, max_steps=iters, solver=lm)

    timing = time_call(run_sip, min_seconds=min_seconds, max_repeats=5)
    return timing, run_sip()


def _engine_only(args) -> int:
    """Child mode: time the single-sequence SIP solve of whichever jaxmocap is importable."""
    import jaxmocap

    where = Path(jaxmocap.__file__).resolve().parent.parent
    if args.expect_package and where != Path(args.expect_package).resolve():
        raise SystemExit(f"--engine-only: imported jaxmocap from {where}, expected {args.expect_package}")
    own = _setup(args.frames)
    leaves, treedef = jax.tree_util.tree_flatten(own)
    given = np.load(args.init)
    theirs = [given[f"leaf_{i}"] for i in range(int(given["num_leaves"]))]
    same_layout = len(theirs) == len(leaves) and all(np.shape(a) == np.shape(b) for a, b in zip(theirs, leaves))
    if not same_layout:
        raise SystemExit("--engine-only: this package's InertialSetup does not match the arrays handed over")
    identical = all(np.array_equal(np.asarray(a), np.asarray(b, np.asarray(a).dtype)) for a, b in zip(leaves, theirs))
    setup = jax.tree_util.tree_unflatten(treedef, [jnp.asarray(a) for a in theirs])
    timing, sol = _time_sip(setup, jnp.asarray(given["init"]), args.iters, args.min_seconds)
    out = {
        "jaxmocap": str(where),
        "time": timing,
        "final_cost": float(sol.cost),
        "num_steps": int(sol.num_steps),
        "frames": args.frames,
        "lm_iterations": args.iters,
        "x64": bool(jax.config.jax_enable_x64),
        "dtype": str(jnp.asarray(setup.pose0).dtype),
        "own_data_identical": bool(identical),  # its own data generation gave the same arrays
    }
    if args.engine_batch:  # the big batch too, once (compile + one timed call)
        from jaxmocap.methods import inertial

        stacked = inertial.stack_setups([setup] * args.engine_batch)
        init = jnp.broadcast_to(jnp.asarray(given["init"]), (args.engine_batch,) + given["init"].shape)

        def run():
            return inertial.sparse_inertial_poser_batch(stacked, init, max_steps=args.iters, rtol=0.0, atol=0.0).value[
                "pose"
            ]

        out["big_batch"] = dict(time_call(run, min_seconds=1e-9, max_repeats=1), sequences=args.engine_batch)
        print(f"[{where.name}] batch {args.engine_batch} x {args.frames} frames: {out['big_batch']['median_s']:.2f} s")
    np.savez(Path(args.json_out).with_suffix(".npz"), pose=np.asarray(sol.value["pose"]),
             trans=np.asarray(sol.value["trans"]))  # fmt: skip
    Path(args.json_out).write_text(json.dumps(out, indent=2) + "\n")
    print(
        f"[{where.name}] SIP {args.frames} frames x {args.iters} LM steps: {timing['median_s']:.3f} s "
        f"(compile + first {timing['compile_and_first_call_s']:.1f} s), final cost {out['final_cost']:.9g}"
    )
    return 0


def _run_v1(args, setup, sop, package=None, x64=None, frames=None, iters=None, batch=0) -> tuple[dict, dict]:
    """Run `--engine-only` under the v1 package (or `package`); returns its JSON and final values."""
    v1 = v1_path() if package is None else package
    x64 = jax.config.jax_enable_x64 if x64 is None else x64
    with tempfile.TemporaryDirectory(prefix="sip_v1_") as tmp:
        leaves = jax.tree_util.tree_leaves(setup)
        handed = Path(tmp) / "input.npz"
        np.savez(handed, init=np.asarray(sop), num_leaves=len(leaves),
                 **{f"leaf_{i}": np.asarray(a) for i, a in enumerate(leaves)})  # fmt: skip
        out = Path(tmp) / "v1.json"
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join([str(v1)] + [p for p in [env.get("PYTHONPATH")] if p])
        env["JAX_ENABLE_X64"] = "1" if x64 else "0"
        cmd = [sys.executable, str(Path(__file__).resolve()), "--engine-only", "--frames", str(frames or args.frames),
               "--iters", str(iters or args.iters), "--min-seconds", str(args.min_seconds), "--init", str(handed),
               "--json-out", str(out), "--expect-package", str(v1), "--engine-batch", str(batch)]  # fmt: skip
        subprocess.run(cmd, env=env, check=True)
        result = json.loads(out.read_text())
        with np.load(out.with_suffix(".npz")) as f:
            values = {k: f[k] for k in f.files}
    return result, values


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=1000)
    p.add_argument("--iters", "--steps", dest="iters", type=int, default=20, help="LM steps (rtol = atol = 0)")
    p.add_argument("--batches", default="1,16,64", help="batch sizes for the throughput test ('' skips it)")
    p.add_argument("--batch-frames", type=int, default=100, help="frames per sequence in the batch test")
    p.add_argument("--suffix", default="", help="results/sip_speed_<suffix>.json (e.g. gpu)")
    p.add_argument("--min-seconds", type=float, default=2.0)
    p.add_argument("--no-baseline", action="store_true", help="skip the AD-Jacobian baseline")
    p.add_argument("--no-v1", action="store_true", help="skip the v1-engine (commit d67d910) baseline")
    p.add_argument(
        "--long", default="", help="comma-separated long sequence lengths to time once each (e.g. 5000,20000)"
    )
    p.add_argument("--big-batch", type=int, default=0, help="time this many sequences of --frames frames at once")
    p.add_argument(
        "--big-batch-tridiagonal",
        default="",
        help="comma-separated factorisations to time the big batch "
        "with besides the default (key big_batch_by_tridiagonal)",
    )
    p.add_argument(
        "--before",
        help="also time the single sequence with the engine at this commit (subprocess, same "
        "machine; build/engine_<commit>, extracted from git or carried): key `before`",
    )
    p.add_argument("--engine-only", action="store_true", help="internal: time the single SIP solve only")
    p.add_argument("--init", help="internal (--engine-only): .npz with the setup's arrays and the SOP start")
    p.add_argument("--json-out", help="internal (--engine-only): where to write time and final cost")
    p.add_argument("--expect-package", help="internal (--engine-only): folder jaxmocap must come from")
    p.add_argument(
        "--engine-batch", type=int, default=0, help="internal (--engine-only): also time this many sequences at once"
    )
    args = p.parse_args(argv)
    if args.engine_only:
        if not (args.init and args.json_out):
            p.error("--engine-only needs --init and --json-out")
        return _engine_only(args)

    from jaxmocap.methods import inertial

    it = dict(max_steps=args.iters, rtol=0.0, atol=0.0)
    setup = _setup(args.frames)
    t0 = time.perf_counter()
    sop, _ = inertial.sparse_orientation_poser(setup)
    jax.block_until_ready(sop)
    sop_first = time.perf_counter() - t0
    sop_timing = time_call(lambda: inertial.sparse_orientation_poser(setup)[0], min_seconds=1e-9, max_repeats=1)
    sop_timing["compile_and_first_call_s"] = sop_first

    single, sol = _time_sip(setup, sop, args.iters, args.min_seconds)
    single.update(num_steps=int(sol.num_steps), frames=args.frames, lm_iterations=args.iters,
                  frames_per_second=args.frames / single["median_s"],
                  seconds_per_iteration=single["median_s"] / args.iters)  # fmt: skip
    final_cost = float(sol.cost)
    print(
        f"SIP {args.frames} frames x {args.iters} LM steps: {single['median_s']:.3f} s "
        f"(compile + first {single['compile_and_first_call_s']:.1f} s), final cost {final_cost:.9g}; "
        f"SOP {sop_timing['median_s']:.2f} s"
    )
    from jaxmocap.solve.tridiagonal import TRIDIAGONAL_METHODS, default_tridiagonal_method

    tridiagonal = {"default": default_tridiagonal_method()}
    for method in TRIDIAGONAL_METHODS:
        t, s = _time_sip(setup, sop, args.iters, args.min_seconds, tridiagonal=method)
        tridiagonal[method] = dict(t, final_cost=float(s.cost))
        print(f"  tridiagonal={method}: {t['median_s']:.3f} s, final cost {float(s.cost):.9g}")
    for method in TRIDIAGONAL_METHODS:
        if method != tridiagonal["default"]:
            tridiagonal[f"default_vs_{method}_ratio"] = (
                tridiagonal[tridiagonal["default"]]["median_s"] / tridiagonal[method]["median_s"]
            )

    long = {}
    for T in [int(x) for x in args.long.split(",") if x]:
        long_setup = _setup(T)
        t0 = time.perf_counter()
        long_sop, _ = inertial.sparse_orientation_poser(long_setup)
        jax.block_until_ready(long_sop)
        sop_s = time.perf_counter() - t0
        t, s = _time_sip(long_setup, long_sop, args.iters, 1e-9)  # compile + one timed solve
        long[T] = dict(t, sop_with_compile_s=sop_s, final_cost=float(s.cost),
                       linear_scaling=t["median_s"] / (T / args.frames * single["median_s"]))  # fmt: skip
        print(
            f"SIP {T} frames x {args.iters} LM steps: {t['median_s']:.2f} s "
            f"({long[T]['linear_scaling']:.2f} x linear from {args.frames} frames); SOP {sop_s:.1f} s"
        )

    v1 = {}
    if not args.no_v1:
        child, values = _run_v1(args, setup, sop)
        rel = abs(final_cost - child["final_cost"]) / abs(child["final_cost"])
        v1 = {
            "v1_commit": V1_COMMIT,
            "v1_time_s": child["time"]["median_s"],
            "optx_default_time_s": single["median_s"],
            "optx_default_vs_v1_ratio": single["median_s"] / child["time"]["median_s"],
            "v1_final_cost": child["final_cost"],
            "final_cost": final_cost,
            "final_cost_rel_diff": rel,
            "v1": child,
        }
        try:  # v1's end point under this run's cost function (same definition of "cost")
            problem = inertial.inertial_problem(setup)
            v1_value = {k: jnp.asarray(values[k]) for k in sol.value}
            costs = problem.costs(v1_value, setup.data)
            v1["v1_final_cost_by_current_costs"] = float(sum(jax.tree_util.tree_leaves(costs)))
        except Exception as e:  # noqa: BLE001 - a cross-check only
            v1["v1_final_cost_by_current_costs"] = None
            print(f"(v1 end point not re-evaluated with the current costs: {type(e).__name__}: {e})")
        print(
            f"v1 engine ({v1['v1_commit']}): {v1['v1_time_s']:.3f} s; current/v1 = "
            f"{v1['optx_default_vs_v1_ratio']:.3f}; final cost {v1['v1_final_cost']:.9g} "
            f"(relative difference {rel:.2e})"
        )
        # float32 iterates of two different programs drift apart by rounding over 20 steps;
        # the same solve in float64 (both engines, subprocesses) shows whether the
        # algorithms agree: 200 frames x 10 steps.
        small = _setup(min(args.frames, 200))
        small_sop, _ = inertial.sparse_orientation_poser(small)
        f64 = lambda x: np.asarray(x, np.float64) if np.issubdtype(np.asarray(x).dtype, np.floating) else x  # noqa: E731
        small, small_sop = jax.tree_util.tree_map(f64, small), f64(small_sop)
        here = Path(__file__).resolve().parent.parent
        runs = {name: _run_v1(args, small, small_sop, package=pkg, x64=True, frames=min(args.frames, 200), iters=10)[0]
                for name, pkg in (("current", here), ("v1", None))}  # fmt: skip
        a, b = runs["current"]["final_cost"], runs["v1"]["final_cost"]
        v1["float64_check"] = {"frames": min(args.frames, 200), "lm_iterations": 10, "final_cost": a,
                               "v1_final_cost": b, "final_cost_rel_diff": abs(a - b) / abs(b)}  # fmt: skip
        v1["final_cost_rel_diff_float64"] = abs(a - b) / abs(b)
        print(
            f"float64, {min(args.frames, 200)} frames x 10 steps: final cost {a!r} vs v1 {b!r} "
            f"(relative difference {v1['final_cost_rel_diff_float64']:.2e})"
        )

    baseline = None
    if not args.no_baseline:
        from jaxmocap.solve import VonMarcardLM, solve

        # The same problem with its terms' analytic Jacobians and `reads` removed. A
        # failure here (the engine's Problem/Term changed) is recorded, not fatal.
        try:
            analytic = inertial.inertial_problem(setup)
            plain = dataclasses.replace(
                analytic, terms=tuple(dataclasses.replace(t, jacobian=None, reads=None) for t in analytic.terms)
            )
            params = {"pose": sop, "trans": jnp.broadcast_to(setup.trans0, (args.frames, 3))}
            baseline = time_call(lambda: solve(plain, params, setup.data, max_steps=args.iters, solver=VonMarcardLM(rtol=0.0, atol=0.0)),
                                 min_seconds=1e-9, max_repeats=1)  # fmt: skip
        except Exception as e:  # noqa: BLE001
            baseline = {"skipped": f"{type(e).__name__}: {e}"}
            print(f"baseline (AD Jacobians) skipped: {baseline['skipped']}")
        else:
            single["ratio_to_baseline"] = single["median_s"] / baseline["median_s"]
            print(
                f"baseline (AD Jacobians, no elimination): {baseline['median_s']:.3f} s, "
                f"ratio {single['ratio_to_baseline']:.3f}"
            )

    before = None
    if args.before:  # an earlier engine on this machine: a ratio that survives a change of card
        # First, while this process holds little device memory (run with
        # XLA_PYTHON_CLIENT_PREALLOCATE=false on a GPU): the child's batch needs the card.
        from _v1 import ROOT, v1_path

        package = v1_path(args.before, ROOT / "build" / f"engine_{args.before}")
        child, _ = _run_v1(args, setup, sop, package=package, batch=args.big_batch)
        before = {"commit": args.before, "time_s": child["time"]["median_s"], "final_cost": child["final_cost"],
                  "ratio": single["median_s"] / child["time"]["median_s"], "run": child}  # fmt: skip
        print(f"engine at {args.before}: {before['time_s']:.3f} s; now/before = {before['ratio']:.3f}")

    big, big_by = None, {}
    if args.big_batch:
        stacked = inertial.stack_setups([setup] * args.big_batch)
        init = jnp.broadcast_to(sop, (args.big_batch,) + sop.shape)
        for method in [None] + [m for m in args.big_batch_tridiagonal.split(",") if m]:
            t = time_call(lambda m=method: inertial.sparse_inertial_poser_batch(stacked, init, tridiagonal=m, **it).value["pose"],
                          min_seconds=1e-9, max_repeats=1)  # fmt: skip
            t.update(sequences=args.big_batch, frames=args.frames, lm_iterations=args.iters,
                     frames_per_second=args.big_batch * args.frames / t["median_s"])  # fmt: skip
            print(
                f"batch {args.big_batch} x {args.frames} frames x {args.iters} steps ({method or 'default'}): "
                f"{t['median_s']:.2f} s (compile + first {t['compile_and_first_call_s']:.1f} s)"
            )
            if method is None:
                big = t
            else:
                big_by[method] = t

    if before and big and "big_batch" in before["run"]:
        before["big_batch_s"] = before["run"]["big_batch"]["median_s"]
        before["big_batch_ratio"] = big["median_s"] / before["big_batch_s"]
        print(
            f"batch {args.big_batch} at {args.before}: {before['big_batch_s']:.2f} s; now/before = {before['big_batch_ratio']:.3f}"
        )

    batches = {}
    if args.batches:
        short = _setup(args.batch_frames, seed=1)
        sop_short, _ = inertial.sparse_orientation_poser(short)
    for B in [int(b) for b in args.batches.split(",") if b]:
        stacked = inertial.stack_setups([short] * B)
        init = jnp.broadcast_to(sop_short, (B,) + sop_short.shape)

        def run_batch(stacked=stacked, init=init):
            return inertial.sparse_inertial_poser_batch(stacked, init, **it).value["pose"]

        t = time_call(run_batch, min_seconds=args.min_seconds, max_repeats=5)
        t["frames_per_second"] = B * args.batch_frames / t["median_s"]
        batches[str(B)] = t
        print(
            f"batch {B:5d} x {args.batch_frames} frames: {t['median_s']:.3f} s, {t['frames_per_second']:.0f} frames/s"
        )

    payload = {
        "benchmark": "sip_speed",
        "machine": machine(),
        "dtype": "float32",
        "thesis": {"frames": 1000, "cost_evaluations": 20, "seconds": 450.0, "setup": "single-core MATLAB, i7 3.5 GHz"},
        "sop_init": sop_timing,
        "sip_single": single,
        "tridiagonal": tridiagonal,
        **{f"sip_t{T}_s": v["median_s"] for T, v in long.items()},
        "long": {str(T): v for T, v in long.items()},
        "big_batch": big,
        "big_batch_by_tridiagonal": big_by or None,
        "before": before,
        **v1,
        "baseline_ad_jacobians": baseline,
        "batch_frames": args.batch_frames,
        "batch": batches,
        "peak_memory_bytes": peak_memory_bytes(),
        # The CPU is shared: a load above the core count means these times are inflated.
        "load_average_1_5_15min_at_end": list(os.getloadavg()),
    }
    gpu = jax.default_backend() == "gpu"
    if gpu:
        payload["gpu_single_s"] = single["median_s"]
        payload["gpu_1000x1000_s"] = big["median_s"] if big and big["sequences"] == 1000 == args.frames else None
        cpu_file = RESULTS / "sip_speed.json"
        if cpu_file.is_file():
            write_json(cpu_file.name, dict(json.loads(cpu_file.read_text()), **_gpu_keys(payload)))
    elif (RESULTS / "sip_speed_gpu.json").is_file():
        payload.update(_gpu_keys(json.loads((RESULTS / "sip_speed_gpu.json").read_text())))
    name = f"sip_speed{'_' + args.suffix if args.suffix else ''}.json"
    print(f"wrote {write_json(name, payload)}")
    return 0


def _gpu_keys(gpu_run: dict) -> dict:
    """A GPU run's issue-20 keys and, under "gpu", its machine and details."""
    keys = {k: gpu_run.get(k) for k in ("gpu_single_s", "gpu_1000x1000_s")}
    keys["gpu"] = {"machine": gpu_run["machine"], "tridiagonal": gpu_run.get("tridiagonal"),
                   "big_batch": gpu_run.get("big_batch"), "big_batch_by_tridiagonal": gpu_run.get("big_batch_by_tridiagonal"),
                   "before": gpu_run.get("before")}  # fmt: skip
    return keys


if __name__ == "__main__":
    raise SystemExit(main())
