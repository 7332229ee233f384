"""Compile time of representative solves, against the engine at an earlier commit.

Each engine runs in its own subprocess (a fresh JAX: no compiled program is shared), the
same cases in the same order, on the same machine:

- `sip`: SIP (analytic Jacobians, the method's terms), 100 frames x 10 LM steps;
- `sip_ad`: the same terms with their Jacobians by AD colouring (two bandwidths: the
  orientation and prior terms per frame, the acceleration term over three frames);
- `sip_gradient`: d(final cost)/d(acceleration weight) through the SIP solve (the
  implicit adjoint with the structured Hessian), jitted whole;
- `vip`: the Video Inertial Poser's fusion (AD-coloured terms, per-sensor headings and
  the camera as sequence unknowns), 24 frames of walking x 30 LM steps.

`compile_s` is the first call (trace, XLA compile and one run) minus the median of three
more, the least over `--repeats` fresh processes per engine (run alternately: this
machine's compile times vary by tens of percent); `ratio` = now / before. float32, the
default body "low", SOP start given.

    python benchmarks/compile_time.py --before 82c9f8a     # writes results/compile_time.json

`--xla-flags FLAGS` times this engine a second way, its processes run with FLAGS added to
XLA_FLAGS (key `with_flags`, and `flags_ratio`: compile and steady time with / without),
e.g. LLVM's optimisation level, which the test suite lowers (tests/conftest.py):

    python benchmarks/compile_time.py --xla-flags=--xla_backend_optimization_level=1 --suffix llvm_o1
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from _common import machine, write_json  # noqa: E402
from _v1 import ROOT, v1_path  # noqa: E402

CASES = ("sip", "sip_ad", "sip_gradient", "vip")


def _cases(frames: int, steps: int) -> dict:
    import jax
    import jax.numpy as jnp
    from sip_speed import _setup

    from jaxmocap.app.scenarios import vip_sequence
    from jaxmocap.body.io import default_body
    from jaxmocap.methods import inertial
    from jaxmocap.methods import visual_inertial as vip
    from jaxmocap.sensors import DetectorErrorModel, IMUErrorModel, make_scenario
    from jaxmocap.sensors.scenario import vip_config
    from jaxmocap.solve import Problem, Term, VonMarcardLM, solve
    from jaxmocap.solve.batch import with_weights

    setup = _setup(frames)
    sop = inertial.sparse_orientation_poser(setup)[0]
    params = {"pose": sop, "trans": jnp.broadcast_to(setup.trans0, (frames, 3))}
    it = dict(max_steps=steps, solver=VonMarcardLM(rtol=0.0, atol=0.0), progress=False)
    problem = inertial.inertial_problem(setup)
    plain = Problem(
        [Term(t.name, t.fn, t.weight, t.bandwidth, t.loss, t.mask) for t in problem.terms], rotations=("pose",)
    )
    weight = jnp.asarray(next(t.weight for t in problem.terms if t.name == "acc"), jnp.float32)
    cost = lambda w: solve(with_weights(problem, {"acc": w}), params, setup.data, **it).cost  # noqa: E731
    grad = jax.jit(jax.grad(cost))
    body = default_body("low")
    cfg = vip_config(max_frames=24, imu_errors=IMUErrorModel.off(), detector=DetectorErrorModel.off())
    vdata, _, bones = vip_sequence(make_scenario(["walk"], cfg, seed=3, body=body), 0, body)
    tracked = vip.inertial_tracker(vdata, bones)
    return {
        "sip": lambda: solve(problem, params, setup.data, **it).value["pose"],
        "sip_ad": lambda: solve(plain, params, setup.data, **it).value["pose"],
        "sip_gradient": lambda: grad(weight),
        "vip": lambda: vip.video_inertial_poser(vdata, bones, init=tracked, max_steps=30).poses,
    }


def _child(args) -> int:
    """Time every case with whichever jaxmocap is importable; write JSON to --json-out."""
    import jax

    import jaxmocap

    where = Path(jaxmocap.__file__).resolve().parent.parent
    out = {"jaxmocap": str(where), "cases": {}}
    for name, fn in _cases(args.frames, args.steps).items():
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        first = time.perf_counter() - t0
        runs = []
        for _ in range(3):
            t0 = time.perf_counter()
            jax.block_until_ready(fn())
            runs.append(time.perf_counter() - t0)
        steady = sorted(runs)[1]
        out["cases"][name] = {"first_call_s": first, "steady_s": steady, "compile_s": first - steady}
        print(f"[{where.name}] {name}: first call {first:.2f} s, steady {steady:.3f} s", flush=True)
    Path(args.json_out).write_text(json.dumps(out))
    return 0


def _run_child(package: Path, args, flags: str | None = None) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out.json"
        env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(package), str(Path(__file__).parent)]))
        if flags:
            env["XLA_FLAGS"] = " ".join(filter(None, [os.environ.get("XLA_FLAGS"), flags]))
        cmd = [sys.executable, __file__, "--child", "--json-out", str(out), "--frames", str(args.frames),
               "--steps", str(args.steps)]  # fmt: skip
        subprocess.run(cmd, env=env, check=True)
        result = json.loads(out.read_text())
    if Path(result["jaxmocap"]).resolve() != package.resolve():
        raise SystemExit(f"the child imported jaxmocap from {result['jaxmocap']}, expected {package}")
    return result


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--before", help="the engine at this commit (build/engine_<commit>, extracted from git or carried)")
    p.add_argument("--frames", type=int, default=100)
    p.add_argument("--steps", type=int, default=10)
    p.add_argument("--repeats", type=int, default=2, help="fresh processes per engine (the least compile time counts)")
    p.add_argument("--xla-flags", help="also time this engine with these flags added to XLA_FLAGS (key with_flags)")
    p.add_argument("--suffix", default="", help="results/compile_time_<suffix>.json")
    p.add_argument("--child", action="store_true", help="internal: time the cases in this process")
    p.add_argument("--json-out", help="internal (--child): where to write the timings")
    args = p.parse_args(argv)
    if args.child:
        return _child(args)

    engines = {"now": (ROOT, None)}
    if args.before:
        engines["before"] = (v1_path(args.before, ROOT / "build" / f"engine_{args.before}"), None)
    if args.xla_flags:
        engines["with_flags"] = (ROOT, args.xla_flags)
    runs = {name: [] for name in engines}
    for _ in range(args.repeats):
        for name, (package, flags) in engines.items():
            runs[name].append(_run_child(package, args, flags))
    summary = {
        name: {"jaxmocap": rs[0]["jaxmocap"], "runs": rs,
               "cases": {k: min((r["cases"][k] for r in rs), key=lambda c: c["compile_s"]) for k in CASES}}
        for name, rs in runs.items()
    }  # fmt: skip
    now = summary["now"]
    result = {"benchmark": "compile_time", "machine": machine(), "frames": args.frames, "lm_steps": args.steps,
              "repeats": args.repeats, "now": now}  # fmt: skip
    if args.before:
        before = summary["before"]
        result["before"] = dict(before, commit=args.before)
        result["ratio"] = {k: now["cases"][k]["compile_s"] / before["cases"][k]["compile_s"] for k in CASES}
        for k in CASES:
            print(f"{k}: compile {now['cases'][k]['compile_s']:.2f} s against {before['cases'][k]['compile_s']:.2f} s "
                  f"at {args.before} (ratio {result['ratio'][k]:.3f})")  # fmt: skip
    if args.xla_flags:
        flagged = summary["with_flags"]
        result["with_flags"] = dict(flagged, xla_flags=args.xla_flags)
        result["flags_ratio"] = {
            k: {t: flagged["cases"][k][t] / now["cases"][k][t] for t in ("compile_s", "steady_s")} for k in CASES
        }
        for k in CASES:
            r = result["flags_ratio"][k]
            print(f"{k} with {args.xla_flags}: compile {r['compile_s']:.3f}x, steady {r['steady_s']:.3f}x")
    path = write_json(f"compile_time{'_' + args.suffix if args.suffix else ''}.json", result)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
