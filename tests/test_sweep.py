"""Sweeps (issue 19): chunked and sharded batches, one compile per grid, resume, bad configs.

The sweep machinery is exercised with a toy method (`tests/sweep_toy.py`: smoothing
noisy 3-D tracks, compiles in about a second); the SIP method runs on the GPU in
benchmarks/sweep_scale.py. Subprocesses get the repository and tests/ on PYTHONPATH.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxmocap.app import SweepConfigError, run_sweep, validate_config, variants
from jaxmocap.app.sweep import Store
from jaxmocap.solve import Problem, Term, solve_batch
from jaxmocap.solve.batch import length_buckets, plan_batch
from jaxmocap.timeseries import second_difference

ROOT = Path(__file__).resolve().parent.parent
ENV = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), str(ROOT / "tests")]), "JAX_PLATFORMS": "cpu"}


def toy_config(**sweep) -> dict:
    return {
        "sweep": {"name": "toy", "methods": ["sweep_toy:ToyMethod"], "datasets": ["tracks"],
                  "sensor_errors": ["low", "high"], "metric": "rmse", "batch_size": 8, **sweep},
        "grid": {"weights": {"smooth": [0.1, 1.0, 10.0], "data": [0.0, 1.0]}, "terms": {"smooth": [True, False]}},
        "datasets": {"tracks": {"motions": ["walk"], "sequences": 3, "frames": 8}},
        "sensor_errors": {"low": {"acc_noise": 0.05}, "high": {"acc_noise": 0.2}},
    }  # fmt: skip


def toml(config: dict) -> str:
    """A minimal TOML writer for the configs above (tomllib reads, nothing writes)."""

    def value(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, list):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return repr(v)

    lines = []

    def table(name, d):
        scalars = {k: v for k, v in d.items() if not isinstance(v, dict)}
        if scalars or not d:
            lines.append(f"[{name}]")
            lines.extend(f"{json.dumps(k)} = {value(v)}" for k, v in scalars.items())
        for k, v in d.items():
            if isinstance(v, dict):
                table(f"{name}.{k}", v)

    for name, d in config.items():
        table(name, d)
    return "\n".join(lines) + "\n"


# --- solve_batch: chunks, compile count, devices -------------------------------------------

COMPILES = []
jax.monitoring.register_event_duration_secs_listener(
    lambda name, *a, **k: COMPILES.append(name) if name == "/jax/core/compile/backend_compile_duration" else None
)
COUNTED = Problem(
    [Term("data", lambda p, d: p["x"] - d["y"]), Term("smooth", lambda p, d: second_difference(p["x"]), bandwidth=1)]
)


def test_chunks_equal_one_batch_and_one_compile_serves_every_weight_setting():
    rng = np.random.default_rng(0)
    B, T = 5, 12
    y = jnp.asarray(rng.normal(size=(B, T, 3)))
    mask = jnp.arange(T)[None] < jnp.asarray([12, 12, 10, 8, 12])[:, None]
    whole = solve_batch(COUNTED, {"x": y}, {"y": y}, mask, weights={"smooth": jnp.full(B, 2.0)}, chunk_size=None)
    costs = []
    for k in range(10):  # 10 weight settings, each in 3 chunks (2 + 2 + 1 padded)
        w = {"smooth": jnp.full(B, 0.1 * (k + 1)).at[0].set(2.0), "data": jnp.full(B, 1.0 + k)}
        if k == 1:
            COMPILES.clear()
        sol = solve_batch(COUNTED, {"x": y}, {"y": y}, mask, weights=w, chunk_size=2)
        costs.append(float(sol.cost[1]))
        if k == 0:
            # Member 0 has the same weights as in `whole`: chunking changes nothing.
            np.testing.assert_allclose(sol.value["x"][0], whole.value["x"][0], atol=1e-12)
            assert sol.value["x"].shape == (B, T, 3) and sol.result.shape == (B,)
    assert COMPILES == [], f"{len(COMPILES)} compilations after the first weight setting"
    assert len(set(costs)) == 10


def test_plan_fits_the_free_memory(monkeypatch):
    y = jnp.zeros((10, 20, 3))
    per = plan_batch(COUNTED, {"x": y}, {"y": y}).bytes_per_sequence
    per_long = plan_batch(COUNTED, {"x": jnp.zeros((10, 40, 3))}, {"y": jnp.zeros((10, 40, 3))}).bytes_per_sequence
    assert per > 0 and 1.8 < per_long / per < 2.2  # linear in T
    monkeypatch.setattr("jaxmocap.solve.batch.free_memory_bytes", lambda d=None: 4 * per)
    plan = plan_batch(COUNTED, {"x": y}, {"y": y}, memory_fraction=0.5)
    assert (plan.chunk_size, plan.num_chunks) == (2, 5)
    plan = plan_batch(COUNTED, {"x": y}, {"y": y}, memory_fraction=1.0)  # 4 fit: 3 chunks of 4, 4, 2 -> 4
    assert plan.chunk_size * plan.num_chunks >= 10 and plan.chunk_size <= 4
    with pytest.raises(ValueError, match="chunk_size"):
        plan_batch(COUNTED, {"x": y}, {"y": y}, chunk_size=0)


def test_length_buckets_minimise_padding():
    b = length_buckets([10, 12, 30, 31, 100, 99, 50], max_buckets=2, multiple=8)
    assert [L for L, _ in b] == [32, 104]
    assert sorted(np.concatenate([m for _, m in b]).tolist()) == list(range(7))
    assert length_buckets([120] * 3)[0][0] == 120
    with pytest.raises(ValueError, match="positive"):
        length_buckets([])


SHARDED = """
import jax, jax.numpy as jnp, numpy as np
jax.config.update("jax_enable_x64", True)
from sweep_toy import PROBLEM
from jaxmocap.solve import solve_batch
from jaxmocap.solve.batch import plan_batch
devs = jax.devices()
assert len(devs) == 2, devs
rng = np.random.default_rng(1)
y = jnp.asarray(rng.normal(size=(5, 14, 3)))
w = {"smooth": jnp.asarray([0.1, 1.0, 3.0, 10.0, 0.5])}
one = solve_batch(PROBLEM, {"x": y}, {"y": y}, weights=w, devices=devs[:1], chunk_size=None)
two_chunked = solve_batch(PROBLEM, {"x": y}, {"y": y}, weights=w, devices=devs, chunk_size=2)
plan = plan_batch(PROBLEM, {"x": y}, {"y": y}, devices=devs, chunk_size=3)
for s in (two_chunked,):
    assert s.value["x"].shape == (5, 14, 3)
    np.testing.assert_allclose(s.value["x"], one.value["x"], atol=1e-12)
    np.testing.assert_array_equal(s.result, one.result)
print("OK", plan.num_devices, plan.chunk_size, len(two_chunked.value["x"].sharding.device_set))
"""


def test_sharded_over_two_devices_equals_one_device():
    env = {**ENV, "XLA_FLAGS": "--xla_force_host_platform_device_count=2"}
    out = subprocess.run([sys.executable, "-c", SHARDED], env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    # Chunks are a multiple of the device count; the result is split over both devices.
    assert out.stdout.split() == ["OK", "2", "4", "2"], out.stdout


# --- configs --------------------------------------------------------------------------------


def test_variants_collapse_switched_off_terms():
    config = validate_config(toy_config())
    v = variants(config)
    # 3 smooth x 2 data with smooth on, + 2 data with smooth off (smooth's weight moot).
    assert len(v) == 8
    off = [x for x in v.values() if not x["terms"]["smooth"]]
    assert len(off) == 2 and all(x["weights"]["smooth"] == 0.0 for x in off)


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda c: c["grid"]["weights"].update(smoth=[1.0]), "'smoth' is not a weight of method"),
        (lambda c: c["grid"]["terms"].update(data=[True, False]), "'data' is not a switchable term"),
        (lambda c: c["grid"]["weights"].update(smooth=[]), "smooth is an empty grid axis"),
        (lambda c: c["datasets"]["tracks"].update(motions=["/no/such/clip.bvh"]), "'/no/such/clip.bvh' is neither"),
        (
            lambda c: c["datasets"].update(tracks={"scenario": "/no/such.npz"}),
            "scenario file '/no/such.npz' does not exist",
        ),
        (lambda c: c["sweep"].update(sensor_errors=["medium"]), "preset 'medium' has no"),
        (lambda c: c["sweep"].update(methods=["nope"]), "unknown method 'nope'"),
        (lambda c: c["sweep"].update(metric="mpjpe"), "metric 'mpjpe' is not reported"),
        (lambda c: c["sensor_errors"]["low"].update(acc_nois=1.0), "unknown IMU error field"),
        (lambda c: c["datasets"]["tracks"].update(prior="heldout"), "prior must be 'bundled', 'held_out'"),
    ],
)
def test_bad_config_is_refused_naming_the_problem(edit, message):
    config = toy_config()
    edit(config)
    with pytest.raises(SweepConfigError, match=message.replace("(", r"\(").replace("[", r"\[")):
        validate_config(config)


def test_changed_config_refuses_to_resume_naming_the_change(tmp_path):
    config = validate_config(toy_config())
    store = Store(tmp_path, config)
    store.open()
    # One solved cell: results to protect (a folder that solved none is taken over instead).
    (store.cells / "solved.json").write_text(
        json.dumps({"config_hash": store.hash, "cell": "c", "metrics": {"rmse": 1.0}})
    )
    changed = toy_config()
    changed["grid"]["weights"]["smooth"] = [0.1, 1.0, 30.0]
    changed["sensor_errors"]["high"]["acc_noise"] = 0.3
    with pytest.raises(SweepConfigError, match=r"grid\.weights\.smooth.*sensor_errors\.high\.acc_noise"):
        run_sweep(validate_config(changed), tmp_path, progress=False)
    # The batch size and the output folder are not part of the results' identity.
    Store(tmp_path / "elsewhere", validate_config(toy_config(batch_size=16))).open()
    Store(tmp_path, validate_config(toy_config(batch_size=16))).open()


# --- the runner: failures, kill and resume, several processes ---------------------------------


def _cells(root: Path) -> dict[str, str]:
    return {p.name: p.read_text() for p in (root / "cells").glob("*.json")}


def _solved(root: Path) -> int:
    return sum('"metrics"' in t for t in _cells(root).values()) if (root / "cells").exists() else 0


def test_killed_sweep_resumes_losing_and_repeating_nothing(tmp_path):
    cfg = tmp_path / "toy.toml"
    cfg.write_text(toml(toy_config(batch_size=4)))
    out, log1, log2 = tmp_path / "out", tmp_path / "solved1.log", tmp_path / "solved2.log"
    cmd = [sys.executable, "-m", "jaxmocap.cli", "sweep", str(cfg), "--out", str(out), "--no-progress"]
    err = open(tmp_path / "stderr1", "w")
    proc = subprocess.Popen(cmd, env={**ENV, "SWEEP_TOY_LOG": str(log1), "SWEEP_TOY_SLEEP": "0.15"},
                            stdout=subprocess.DEVNULL, stderr=err)  # fmt: skip
    deadline = time.monotonic() + 120
    while _solved(out) < 6:
        assert proc.poll() is None, (tmp_path / "stderr1").read_text()[-2000:]
        assert time.monotonic() < deadline, "the sweep wrote too few cells"
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    err.close()
    before = _cells(out)
    total = 8 * 2 * 3  # variants x presets x sequences
    assert 6 <= len(before) < total
    assert all(json.loads(t)["cell"] for t in before.values())  # no half-written cell
    done = subprocess.run(cmd, env={**ENV, "SWEEP_TOY_LOG": str(log2)}, capture_output=True, text=True, timeout=300)
    # 28 cells fail (below): status 1 and a line saying so, so that scripts notice.
    assert done.returncode == 1, done.stderr[-3000:]
    assert "jaxmocap sweep: 28 of 48 cells failed" in done.stderr
    after = _cells(out)
    assert len(after) == total
    assert all(after[k] == v for k, v in before.items()), "a finished cell was rewritten"
    # Nothing finished before the kill was solved again: compare (sequence, noise, weights).
    finished = set()
    for text in before.values():
        r = json.loads(text)
        if "metrics" in r:
            finished.add((r["index"], r["errors"], r["weights"]["data"], r["weights"]["smooth"]))
    noise = {0.05: "low", 0.2: "high"}
    again = set()
    for line in log2.read_text().split("\n") if log2.exists() else []:
        if line:
            i, n, wd, ws = line.split()
            again.add((int(i), noise[float(n)], float(wd), float(ws)))
    assert finished and not (finished & again)
    records = [json.loads(t) for t in after.values()]
    failed = [r for r in records if "error" in r]
    # w_data = 0 (4 variants x 2 presets x 3 sequences) raises in the solve; sequence 2 at
    # the high noise fails to prepare (its 4 other variants).
    assert sum("undetermined" in r["error"] for r in failed) + sum("prepare" in r["error"] for r in failed) == 28
    assert len(failed) == 28
    assert all(
        json.loads(t)["config_hash"] == json.loads((out / "sweep.json").read_text())["hash"] for t in after.values()
    )
    summary = (out / "summary.md").read_text()
    assert "paired" in summary.lower() and (out / "boxplot.png").stat().st_size > 0 and (out / "weights.png").exists()


def test_refused_config_writes_nothing_and_a_failed_sweep_locks_nothing(tmp_path, capsys):
    """max_steps = 0 is refused before the folder exists (status 2, naming the key); a
    sweep whose every cell failed does not keep its folder from the corrected config."""
    from jaxmocap.cli import main

    out, cfg = tmp_path / "out", tmp_path / "toy.toml"
    cfg.write_text(toml(toy_config(max_steps=0)))
    assert main(["sweep", str(cfg), "--out", str(out), "--no-progress"]) == 2
    assert "[sweep] max_steps must be an integer >= 1" in capsys.readouterr().err
    assert not out.exists()
    failing = toy_config()
    failing["grid"]["weights"]["data"] = [0.0]  # every cell raises in the solve
    run_sweep(validate_config(failing), out, progress=False, summary=False)
    assert _solved(out) == 0 and len(_cells(out)) == 24  # 4 variants x 2 presets x 3
    (out / "datasets" / "stale.npz").write_bytes(b"")
    config = toy_config()
    config["grid"] = {"weights": {"smooth": [1.0]}}
    messages = []
    run_sweep(validate_config(config), out, progress=False, summary=False, log=messages.append)
    assert len(_cells(out)) == 6 and _solved(out) == 5  # sequence 2 at high noise fails to prepare
    assert "earlier sweep solved no cell" in messages[0]
    assert not (out / "datasets" / "stale.npz").exists()  # generated data is cached by name: gone too
    assert "loading dataset 'tracks' with sensor errors 'high' for 'sweep_toy:ToyMethod' (2 of 2)" in messages


def test_damaged_cell_files_are_run_again(tmp_path):
    config = toy_config()
    config["grid"] = {"weights": {"smooth": [1.0]}}
    config = validate_config(config)
    run_sweep(config, tmp_path, progress=False, summary=False)
    before = _cells(tmp_path)
    solved = sorted(k for k, t in before.items() if '"metrics"' in t)
    (tmp_path / "cells" / solved[0]).write_text(before[solved[0]][:25])  # cut short
    (tmp_path / "cells" / solved[1]).write_text("")
    run_sweep(config, tmp_path, progress=False, summary=False)
    timeless = lambda cells: {k: {**json.loads(t), "seconds": 0} for k, t in cells.items()}  # noqa: E731
    assert timeless(_cells(tmp_path)) == timeless(before)  # the two redone, the others kept
    assert all(_cells(tmp_path)[k] == before[k] for k in before if k not in solved[:2])
    (tmp_path / "sweep.json").write_text('{"hash": ')
    with pytest.raises(SweepConfigError, match=r"sweep\.json: damaged, not JSON"):
        run_sweep(config, tmp_path, progress=False, summary=False)


DISTRIBUTED = """
import sys
from jaxmocap.app.sweep import join_distributed
join_distributed(dict(coordinator_address=sys.argv[1], num_processes=2, process_id=int(sys.argv[2])))
import jax
jax.config.update("jax_enable_x64", True)  # as this test process (conftest)
assert jax.process_count() == 2
from jaxmocap.app import load_config, run_sweep
run_sweep(load_config(sys.argv[3]), sys.argv[4], progress=False)
"""


def test_two_processes_joined_by_jax_distributed_equal_one_process(tmp_path):
    cfg = tmp_path / "toy.toml"
    cfg.write_text(toml(toy_config(batch_size=4)))
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    two = tmp_path / "two"
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", DISTRIBUTED, f"127.0.0.1:{port}", str(i), str(cfg), str(two)],
            env=ENV,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
        )  # fmt: skip
        for i in range(2)
    ]
    outs = [p.communicate(timeout=300) for p in procs]
    for p, (_, err) in zip(procs, outs):
        assert p.returncode == 0, err.decode()[-3000:]
    logs = [out.decode() for out, _ in outs]
    assert "on process 0 of 2" in logs[0] and "on process 1 of 2" in logs[1]
    one = tmp_path / "one"
    from jaxmocap.app import load_config

    run_sweep(load_config(cfg), one, progress=False, summary=False)
    a = {json.loads(t)["cell"]: json.loads(t) for t in _cells(two).values()}
    b = {json.loads(t)["cell"]: json.loads(t) for t in _cells(one).values()}
    assert a.keys() == b.keys() and len(a) == 48
    for k in a:
        assert ("error" in a[k]) == ("error" in b[k])
        if "metrics" in a[k]:
            np.testing.assert_allclose(a[k]["metrics"]["rmse"], b[k]["metrics"]["rmse"], rtol=1e-12)
    assert (two / "summary.md").exists()


def test_summary_plots_label_units_and_ticks_at_the_swept_weights(tmp_path, monkeypatch):
    """Ticks only at the grid's weights (log axes labelled their minor ticks over each
    other), the metric's unit on the y axis, readable variant labels, legends off the curves."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from jaxmocap.app import sweep_report as R

    figures = []
    monkeypatch.setattr(plt, "close", figures.append)
    config = validate_config(toy_config())  # smooth [0.1, 1, 10], data [0, 1], smooth on/off
    var = variants(config)
    key = ("sweep_toy:ToyMethod", "tracks", "low")
    values = {key: {v: {0: float(i), 1: i + 0.5} for i, v in enumerate(var)}}
    R._weight_plot(plt, tmp_path / "weights.png", config, [key], values, var, "mpjpe")
    data_ax, smooth_ax = figures[0].axes[:2]
    assert [t.get_text() for t in smooth_ax.get_xticklabels()] == ["0.1", "1", "10"]
    assert [t.get_text() for t in data_ax.get_xticklabels()] == ["0", "1"]
    assert not [t for t in smooth_ax.get_xticklabels(minor=True) if t.get_text()]
    assert smooth_ax.get_ylabel() == "mean MPJPE (mm, Procrustes-aligned)"
    assert "-smooth" in [t.get_text() for t in data_ax.get_legend().get_texts()]
    renderer = figures[0].canvas.get_renderer()
    assert data_ax.get_legend().get_window_extent(renderer).x0 >= data_ax.get_window_extent(renderer).x1
    analysis = {"|".join(key): {"baseline": next(iter(var))}}
    R._boxplot(plt, tmp_path, [key], values, "mpjae", analysis)
    ax = figures[1].axes[0]
    assert ax.get_ylabel() == "MPJAE (degrees)"
    labels = ax.get_xticklabels()
    assert min(t.get_fontsize() for t in labels) >= 8 and "data=1 smooth=10" in [t.get_text() for t in labels]
