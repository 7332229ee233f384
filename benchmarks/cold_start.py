"""Time to first result: each entry point's compile cold, compile with a warm disk cache, and run.

Every measurement is a fresh process, so nothing compiled is shared but what the
persistent compilation cache (jaxmocap/_cache.py) keeps on disk:

- cold: an empty cache folder; warm: a second process on the folder the cold one filled;
- in each process the entry runs twice on the same inputs: `compile_s` = first call -
  second call (tracing, lowering, compiling or loading from disk), `run_s` = second call;
  inputs (a simulated scene) are built before the clock starts;
- `sop_batched`: SOP with every frame solved at once from x₀ (`sequential=False`);
- `sip_batch`: `--batch` SIP sequences in one `solve_batch` (20 steps forced), as sweeps and
  `sweep_scale.py` run them;
- `make_demo` is the whole `jaxmocap demo` command's wall time (`cold_wall_s`, `warm_wall_s`).

The same entries run, cold, on jaxmocap at `--before` (default: the last commit without the
persistent cache, `BEFORE`) in the same run, as the baseline (`before.<name>`; that
version has no disk cache, so its every run is cold). `--test` also times `make test`'s
pytest on this tree (key `make_test_s`; minutes).

    python benchmarks/cold_start.py                  # results/cold_start.json (this CPU)
    python benchmarks/cold_start.py --suffix gpu     # results/cold_start_gpu.json
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from _common import RESULTS, machine, write_json  # noqa: E402
from _v1 import ROOT, v1_path  # noqa: E402

BEFORE = "de0bea7"  # main before the persistent cache
ENTRIES = ("sip", "sop", "sop_batched", "sip_batch", "vip", "multiview", "interaction", "sweep_cell")


def _inputs(name: str, frames: int, batch: int = 8):
    """A zero-argument callable running entry `name` on inputs built here (untimed)."""
    import jax
    import numpy as np

    from jaxmocap.body.io import default_body

    body = default_body("low")
    if name in ("sip", "sop", "sop_batched"):
        from jaxmocap.app.scenarios import inertial_setup
        from jaxmocap.methods import inertial
        from jaxmocap.motion import library
        from jaxmocap.sensors import IMUErrorModel, ScenarioConfig, make_scenario

        motion = library.walk(num_frames=frames, fps=30.0, body=body)  # procedural: no data folder needed
        cfg = ScenarioConfig(fps=30.0, max_frames=frames, imu_set="sip6", imu_errors=IMUErrorModel.xsens())
        setup = inertial_setup(make_scenario([motion], cfg, seed=0, body=body), 0, body)
        if name == "sop":
            return lambda: inertial.sparse_orientation_poser(setup)[0]
        if name == "sop_batched":  # every frame from x0, all at once (experiments/sop_start.py)
            return lambda: inertial.orientation_poser(setup, sequential=False)[0]
        sop = jax.block_until_ready(inertial.sparse_orientation_poser(setup)[0])
        return lambda: inertial.sparse_inertial_poser(setup, init=sop).poses
    if name == "sip_batch":  # `--batch` sequences through solve_batch, as sweeps run them
        from sweep_scale import _pool, _solve, _tile

        pool, pool_init = _pool(frames, min(8, batch))
        stacked, init = _tile(pool, batch), _tile(pool_init, batch)
        return lambda: _solve(stacked, init, 20).value["pose"]
    if name == "vip":
        from jaxmocap.app.scenarios import vip_sequence
        from jaxmocap.methods import visual_inertial as vip
        from jaxmocap.sensors import DetectorErrorModel, IMUErrorModel, make_scenario
        from jaxmocap.sensors.scenario import vip_config

        cfg = vip_config(max_frames=frames, imu_errors=IMUErrorModel.off(), detector=DetectorErrorModel.off())
        data, _, bones = vip_sequence(make_scenario(["walk"], cfg, seed=3, body=body), 0, body)
        tracked = jax.block_until_ready(vip.inertial_tracker(data, bones))
        return lambda: vip.video_inertial_poser(data, bones, init=tracked, max_steps=30).poses
    if name == "multiview":
        from muvs_speed import clip_data

        from jaxmocap.methods import multiview as mv

        data = clip_data(body, frames)
        return lambda: mv.multiview_smplify(data).poses
    if name == "interaction":
        from jaxmocap.app.scenarios import interaction_observations
        from jaxmocap.methods.interaction import fit_human, fit_joint, track_object
        from jaxmocap.sensors import make_scenario
        from jaxmocap.sensors.scenario import interaction_config

        cfg = interaction_config(object="box", num_views=2, max_frames=frames, width=128, height=96, depth_points=256)
        scenario = make_scenario(["walk"], cfg, seed=0, body=body)
        obs = interaction_observations(scenario, 0)
        obj = track_object(obs, body=body)
        human = fit_human(obs, body)
        contact = np.asarray(scenario.sequence(0)["contact"], np.float64)
        part = scenario.config.contact_part
        return lambda: fit_joint(obs, human, obj, contact, body, parts=(part,))["pose"]
    if name == "sweep_cell":
        from jaxmocap.app.sweep import run_sweep, validate_config

        raw = {
            "sweep": {"name": "cold", "methods": ["sip"], "datasets": ["lib"], "sensor_errors": ["xsens"],
                      "max_steps": 20},
            "grid": {"weights": {"acc": [0.05]}},
            "datasets": {"lib": {"motions": ["walk"], "sequences": 2, "frames": frames, "fps": 30, "imu_set": "sip6"}},
            "sensor_errors": {"xsens": {"preset": "xsens"}},
        }  # fmt: skip
        config = validate_config(raw)
        work = Path(tempfile.mkdtemp())
        run_sweep(config, work / "prepare", prepare_only=True, progress=False)  # datasets (untimed)
        calls = iter(range(10))
        return lambda: run_sweep(config, work / f"run{next(calls)}", summary=False, progress=False)
    raise ValueError(f"unknown entry {name!r}; expected one of {ENTRIES}")


def _child(args) -> int:
    import jax

    import jaxmocap

    fn = _inputs(args.entry, args.frames, args.batch)
    t0 = time.perf_counter()
    jax.block_until_ready(fn())
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    jax.block_until_ready(fn())
    run = time.perf_counter() - t0
    out = {"jaxmocap": str(Path(jaxmocap.__file__).resolve().parent.parent), "first_call_s": first, "run_s": run,
           "compile_s": max(first - run, 0.0)}  # fmt: skip
    Path(args.json_out).write_text(json.dumps(out))
    return 0


def _run(package: Path, entry: str, cache: Path | None, frames: int, batch: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out.json"
        env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(package), str(Path(__file__).parent)]),
                   JAXMOCAP_CACHE=str(cache) if cache else "off", PYTHONUNBUFFERED="1")  # fmt: skip
        cmd = [sys.executable, __file__, "--child", entry, "--json-out", str(out), "--frames", str(frames),
               "--batch", str(batch)]  # fmt: skip
        subprocess.run(cmd, env=env, check=True, cwd=ROOT)
        return json.loads(out.read_text())


def _demo(cache: Path) -> float:
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, JAXMOCAP_CACHE=str(cache), PYTHONPATH=str(ROOT))
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "jaxmocap.cli", "demo", "--out", tmp], env=env, check=True, cwd=ROOT,
                       stdout=subprocess.DEVNULL)  # fmt: skip
        return time.perf_counter() - t0


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--entries", nargs="+", default=list(ENTRIES), choices=ENTRIES)
    p.add_argument("--frames", type=int, default=60, help="frames of each entry's sequence (default 60)")
    p.add_argument("--batch", type=int, default=8, help="sequences of the sip_batch entry (default 8)")
    p.add_argument("--before", default=BEFORE, help="baseline commit (cold runs only); 'none' skips it")
    p.add_argument("--no-demo", action="store_true", help="skip the `jaxmocap demo` rows")
    p.add_argument("--test", action="store_true", help="also time the test suite (make_test_s)")
    p.add_argument("--suffix", default="")
    p.add_argument("--merge", action="store_true", help="keep the other entries of an existing results file")
    p.add_argument("--child", metavar="ENTRY", help=argparse.SUPPRESS)
    p.add_argument("--json-out", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.child:
        args.entry = args.child
        return _child(args)

    before = None if args.before == "none" else v1_path(args.before, ROOT / "build" / f"engine_{args.before}")
    commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    result = {"benchmark": "cold_start", "machine": machine(), "commit": commit.stdout.strip() or None,
              "frames": args.frames, "batch": args.batch, "entries": {}}  # fmt: skip
    if before:
        result["before"] = {"commit": args.before, "entries": {}}
    name = f"cold_start{'_' + args.suffix if args.suffix else ''}.json"
    earlier = json.loads((RESULTS / name).read_text()) if args.merge and (RESULTS / name).exists() else {}

    def save():
        """Write what is measured so far (after every entry: a stopped run keeps its rows)."""
        out = json.loads(json.dumps(result))
        if earlier:  # entries measured by an earlier call (the GPU's time limit)
            out["entries"] = {**earlier.get("entries", {}), **out["entries"]}
            if "before" in earlier:  # an earlier call's baseline rows stay, under their own commit
                if before and earlier["before"]["commit"] == args.before:
                    out["before"]["entries"] = {**earlier["before"]["entries"], **out["before"]["entries"]}
                elif not before:
                    out["before"] = earlier["before"]
        return write_json(name, out)

    root = Path(tempfile.mkdtemp(prefix="jaxmocap-cold-"))
    try:
        for entry in args.entries:
            cache = root / entry
            cold = _run(ROOT, entry, cache, args.frames, args.batch)
            warm = _run(ROOT, entry, cache, args.frames, args.batch)
            row = {"cold_compile_s": cold["compile_s"], "warm_compile_s": warm["compile_s"], "run_s": warm["run_s"],
                   "cold_first_call_s": cold["first_call_s"], "warm_first_call_s": warm["first_call_s"]}  # fmt: skip
            result["entries"][entry] = row
            line = f"{entry:12s} cold compile {row['cold_compile_s']:6.1f} s  warm {row['warm_compile_s']:5.2f} s  run {row['run_s']:6.3f} s"
            if before:
                old = _run(before, entry, None, args.frames, args.batch)
                result["before"]["entries"][entry] = {"cold_compile_s": old["compile_s"], "run_s": old["run_s"]}
                row["warm_compile_ratio_vs_before"] = row["warm_compile_s"] / old["compile_s"]
                line += f"  (before: compile {old['compile_s']:6.1f} s every run, run {old['run_s']:6.3f} s)"
            print(line, flush=True)
            save()
        if not args.no_demo:
            cache = root / "demo"
            cold, warm = _demo(cache), _demo(cache)
            result["entries"]["make_demo"] = {"cold_wall_s": cold, "warm_wall_s": warm}
            print(f"make_demo    cold {cold:6.1f} s  warm {warm:6.1f} s (whole command)", flush=True)
        if args.test:
            env = dict(os.environ, PYTHONPATH=str(ROOT))
            t0 = time.perf_counter()
            subprocess.run([sys.executable, "-m", "pytest", "-q", "-n", "2", "--dist", "loadfile"], env=env, cwd=ROOT,
                           check=False, stdout=subprocess.DEVNULL)  # fmt: skip
            result["make_test_s"] = time.perf_counter() - t0
            print(f"make test    {result['make_test_s']:.0f} s")
    finally:
        shutil.rmtree(root, ignore_errors=True)
    print(f"wrote {save()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
