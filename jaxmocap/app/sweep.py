"""Sweeps: grids of methods × weights × terms on/off × sensor errors × datasets, resumable.

    jaxmocap sweep CONFIG.toml [--out DIR] [--prepare-only] [--no-summary]

or, from Python, `run_sweep(load_config(path))`. A config (TOML) names the methods, the
datasets, the sensor-error presets and the grid (`[grid.weights]`, `[grid.terms]`);
README "Running a sweep" shows one and `experiments/sweeps/sip_ablation.toml` is a full
example. Everything the config says is checked before any compute: unknown weight or
term names, an empty grid axis, missing dataset files, and on resume a config that
differs from the interrupted one (the message names each changed entry).

Work is cut into cells, one (variant, dataset, sensor errors, sequence) each. Cells of
one method and one padded length are solved together, every variant's weights a traced
(B,) array, so one compiled program serves the whole grid (`solve_batch`, which chunks
to the device's memory and splits the batch over the local devices). Each finished
cell is written to `DIR/cells/` atomically (temp file + rename) with the config's hash;
a killed sweep resumes with the cells on disk and repeats none of them; a cell whose
solve raises records the error and the sweep goes on.

Several processes (`jax.distributed.initialize()`, which reads SLURM's and similar
launchers' variables, or `--distributed`) share the cells: process p of P takes every
P-th batch of cells (cut from the whole grid, so any P solves the same batches and gets
the same numbers), all write to the same DIR (a shared file system), and process 0
waits for the others and writes the summary. The cells are independent, so no process
waits for another during the solves.
"""

from __future__ import annotations

import hashlib
import json
import math
import shutil
import sys
import time
import tomllib
import traceback
from pathlib import Path

import numpy as np

from .._files import atomic_write
from .sweep_methods import Cell, resolve_method

__all__ = [
    "SweepConfigError", "load_config", "validate_config", "config_hash", "variants", "run_sweep", "Store",
    "join_distributed", "atomic_write",
]  # fmt: skip

_SWEEP_KEYS = {
    "name", "methods", "datasets", "sensor_errors", "metric", "batch_size", "max_steps", "rtol", "atol",
    "memory_fraction", "out", "baseline",
}  # fmt: skip
_DATASET_KEYS = {"motions", "scenario", "sequences", "frames", "fps", "imu_set", "seed", "betas_std", "vary", "prior"}


class SweepConfigError(ValueError):
    """A sweep config that cannot run (raised before any compute)."""


def load_config(path) -> dict:
    """Read and validate a sweep config (TOML). Relative paths are taken from the cwd."""
    path = Path(path)
    if not path.is_file():
        raise SweepConfigError(f"sweep config {str(path)!r} does not exist.")
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise SweepConfigError(f"{path}: not valid TOML ({e}).") from None
    return validate_config(raw, source=str(path))


def _fail(source, msg):
    raise SweepConfigError(f"{source}: {msg}")


def validate_config(raw: dict, source: str = "config") -> dict:
    """The config normalised (defaults filled in, lists sorted where order is meaningless).

    Raises `SweepConfigError` naming the offending entry for anything that would fail
    later: unknown sections or keys, unknown methods, weights or terms, empty grid
    axes, non-positive weights, missing dataset files, undefined presets.
    """
    raw = dict(raw)
    # No [options] table: its keys live in [sweep] (max_steps, rtol, ...); one would be ignored.
    unknown = sorted(set(raw) - {"sweep", "grid", "datasets", "sensor_errors"})
    if unknown:
        _fail(source, f"unknown section(s) {unknown}; a sweep config has [sweep], [grid], [datasets], [sensor_errors].")
    # Types first: a value of the wrong kind (methods = [1], [datasets] tracks = 3) would
    # otherwise surface as a TypeError deep in the checks below.
    for section in ("sweep", "grid", "datasets", "sensor_errors"):
        if not isinstance(raw.get(section, {}), dict):
            _fail(source, f"{section} must be a [{section}] table, got {raw[section]!r}.")
    sw = dict(raw.get("sweep", {}))
    for key in ("methods", "datasets", "sensor_errors"):
        if isinstance(sw.get(key), list) and not all(isinstance(x, str) for x in sw[key]):
            _fail(source, f"[sweep] {key} must be a list of names (strings), got {sw[key]!r}.")
    for key in ("name", "metric", "out"):
        if key in sw and not isinstance(sw[key], str):
            _fail(source, f"[sweep] {key} must be a string, got {sw[key]!r}.")
    if not isinstance(sw.get("baseline", {}), dict):
        _fail(
            source,
            f"[sweep] baseline must be a table of weights, e.g. baseline = {{acc = 2.0}}; got {sw['baseline']!r}.",
        )
    for k, v in dict(sw.get("baseline", {})).items():
        _check_number(source, f"[sweep] baseline.{k}", v, 0.0, None, "a weight")
    for d, spec in dict(raw.get("datasets", {})).items():
        if not isinstance(spec, dict):
            _fail(source, f"[datasets.{d}] must be a table (motions = [...], sequences = ..., ...), got {spec!r}.")
        for key in ("scenario", "prior"):
            if key in spec and not isinstance(spec[key], str):
                _fail(source, f"[datasets.{d}] {key} must be a string, got {spec[key]!r}.")
        if isinstance(spec.get("motions"), list) and not all(isinstance(m, str) for m in spec["motions"]):
            _fail(source, f"[datasets.{d}] motions must be a list of library names or paths, got {spec['motions']!r}.")
    for e, spec in dict(raw.get("sensor_errors", {})).items():
        if not isinstance(spec, dict):
            _fail(source, f"[sensor_errors.{e}] must be a table of IMU error fields, got {spec!r}.")
    bad = sorted(set(sw) - _SWEEP_KEYS)
    if bad:
        _fail(source, f"unknown key(s) {bad} in [sweep]; allowed: {sorted(_SWEEP_KEYS)}.")
    for key in ("methods", "datasets"):
        if not isinstance(sw.get(key), list) or not sw[key]:
            _fail(source, f"[sweep] {key} must be a non-empty list, got {sw.get(key)!r}.")
    methods = {}
    for name in sw["methods"]:
        try:
            methods[name] = resolve_method(name)
        except ValueError as e:
            _fail(source, str(e))
    grid = dict(raw.get("grid", {}))
    bad = sorted(set(grid) - {"weights", "terms"})
    if bad:
        _fail(source, f"unknown [grid] table(s) {bad}; use [grid.weights] and [grid.terms].")
    for axis in ("weights", "terms"):
        if not isinstance(grid.get(axis, {}), dict):
            _fail(source, f"[grid.{axis}] must be a table (name = [values]), got {grid[axis]!r}.")
    gw, gt = dict(grid.get("weights", {})), dict(grid.get("terms", {}))
    for name, m in methods.items():
        for w in gw:
            if w not in m.defaults:
                _fail(
                    source,
                    f"[grid.weights] {w!r} is not a weight of method {name!r}; its weights are {sorted(m.defaults)}.",
                )
        for t in gt:
            if t not in m.terms:
                _fail(
                    source,
                    f"[grid.terms] {t!r} is not a switchable term of method {name!r}; its terms are {sorted(m.terms)}.",
                )
    for axis, table, ok in (("weights", gw, lambda v: isinstance(v, (int, float)) and not isinstance(v, bool) and 0 <= v < math.inf),
                            ("terms", gt, lambda v: isinstance(v, bool))):  # fmt: skip
        for k, vals in table.items():
            if not isinstance(vals, list) or not vals:
                _fail(source, f"[grid.{axis}] {k} is an empty grid axis; give at least one value.")
            if not all(ok(v) for v in vals):
                kind = "weights >= 0" if axis == "weights" else "true/false"
                _fail(source, f"[grid.{axis}] {k} must be a list of {kind}, got {vals!r}.")
            if len(set(vals)) != len(vals):
                _fail(source, f"[grid.{axis}] {k} repeats a value: {vals!r}.")
    datasets = dict(raw.get("datasets", {}))
    for d in sw["datasets"]:
        if d not in datasets:
            _fail(source, f"dataset {d!r} is listed in [sweep] datasets but has no [datasets.{d}] table.")
    for d, spec in datasets.items():
        bad = sorted(set(spec) - _DATASET_KEYS)
        if bad:
            _fail(source, f"unknown key(s) {bad} in [datasets.{d}]; allowed: {sorted(_DATASET_KEYS)}.")
        if ("scenario" in spec) == ("motions" in spec):
            _fail(source, f"[datasets.{d}] needs exactly one of 'scenario' (a saved .npz) or 'motions'.")
        prior = spec.get("prior", "bundled")
        if prior not in ("bundled", "held_out") and not Path(str(prior)).is_file():
            _fail(source, f"[datasets.{d}] prior must be 'bundled', 'held_out' (leave-subject-out, for corpus "
                          f"clips) or a prior .npz file; {prior!r} is none of these.")  # fmt: skip
        if "scenario" in spec and not Path(spec["scenario"]).is_file():
            _fail(source, f"[datasets.{d}] scenario file {spec['scenario']!r} does not exist.")
        if "motions" in spec:
            from ..motion import library

            if not isinstance(spec["motions"], list) or not spec["motions"]:
                _fail(source, f"[datasets.{d}] motions must be a non-empty list.")
            for m in spec["motions"]:
                if m not in library.MOTIONS and not Path(m).exists():
                    _fail(source, f"[datasets.{d}] motion {m!r} is neither a library motion "
                                  f"({sorted(library.MOTIONS)}) nor an existing file or folder.")  # fmt: skip
    presets = dict(raw.get("sensor_errors", {}))
    chosen = sw.get("sensor_errors", ["as_recorded"] if not presets else None)
    if not isinstance(chosen, list) or not chosen:
        _fail(source, "[sweep] sensor_errors must be a non-empty list of [sensor_errors.NAME] presets.")
    for e in chosen:
        if e != "as_recorded" and e not in presets:
            _fail(source, f"sensor-error preset {e!r} has no [sensor_errors.{e}] table.")
    from .sweep_methods import error_model

    for e, spec in presets.items():
        try:
            error_model(spec)
        except (ValueError, TypeError) as err:
            _fail(source, f"[sensor_errors.{e}]: {err}")
    for d in sw["datasets"]:
        for e in chosen:
            if "scenario" in datasets[d] and e != "as_recorded":
                _fail(source, f"dataset {d!r} is a saved scenario with its sensor errors baked in; "
                              "use sensor_errors = ['as_recorded'] or generate it from 'motions'.")  # fmt: skip
            if "motions" in datasets[d] and e == "as_recorded":
                _fail(source, f"dataset {d!r} is generated from motions: name a [sensor_errors] preset.")
    baseline = dict(sw.get("baseline", {}))
    for name, m in methods.items():
        for k in baseline:
            if k not in m.defaults:
                _fail(source, f"[sweep] baseline weight {k!r} is not a weight of method {name!r}.")
    metric = sw.get("metric", "mpjae")
    for name, m in methods.items():
        if metric not in getattr(m, "metrics", (metric,)):
            _fail(
                source, f"[sweep] metric {metric!r} is not reported by method {name!r}; it reports {list(m.metrics)}."
            )
    bs = sw.get("batch_size", 256)
    if not isinstance(bs, int) or bs < 1:
        _fail(source, f"[sweep] batch_size must be a positive integer, got {bs!r}.")
    # Numbers that pass TOML but fail every cell (max_steps = 0) or build no dataset
    # (fps = -30) are refused here, before the output folder is written.
    _check_int(source, "[sweep] max_steps", sw.get("max_steps", 20), 1, "e.g. max_steps = 20")
    for key, default in (("rtol", 1e-6), ("atol", 1e-10)):
        _check_number(source, f"[sweep] {key}", sw.get(key, default), 0.0, None, f"e.g. {key} = {default:g}")
    _check_number(source, "[sweep] memory_fraction", sw.get("memory_fraction", 0.6), 0.0, 1.0,
                  "a fraction of the device's free memory in (0, 1], e.g. memory_fraction = 0.6", open_low=True)  # fmt: skip
    for d, spec in datasets.items():
        where = f"[datasets.{d}]"
        if "fps" in spec:
            _check_number(
                source, f"{where} fps", spec["fps"], 0.0, None, "frames per second, e.g. fps = 30", open_low=True
            )
        if "frames" in spec:
            _check_int(source, f"{where} frames", spec["frames"], 1, "the most frames per sequence, e.g. frames = 120")
        if "sequences" in spec:
            _check_int(source, f"{where} sequences", spec["sequences"], 1, "e.g. sequences = 8")
        if "seed" in spec:
            _check_int(source, f"{where} seed", spec["seed"], 0, "e.g. seed = 0")
        if "betas_std" in spec:
            _check_number(source, f"{where} betas_std", spec["betas_std"], 0.0, None, "e.g. betas_std = 1.0")
        if "vary" in spec and not isinstance(spec["vary"], bool):
            _fail(source, f"{where} vary must be true or false, got {spec['vary']!r}.")
        if "imu_set" in spec:
            from ..sensors.imu import SENSOR_SETS

            if spec["imu_set"] not in SENSOR_SETS:
                _fail(source, f"{where} imu_set must be one of {sorted(SENSOR_SETS)}, got {spec['imu_set']!r}.")
    return {
        "name": str(sw.get("name", Path(source).stem)),
        "methods": list(sw["methods"]),
        "datasets": {d: {k: datasets[d][k] for k in sorted(datasets[d])} for d in sw["datasets"]},
        "sensor_errors": {e: dict(sorted(presets.get(e, {}).items())) if e != "as_recorded" else None for e in chosen},
        "grid": {"weights": {k: [float(v) for v in vals] for k, vals in sorted(gw.items())},
                 "terms": {k: list(vals) for k, vals in sorted(gt.items())}},  # fmt: skip
        "baseline": {k: float(v) for k, v in sorted(baseline.items())},
        "metric": str(metric),
        "options": {"max_steps": int(sw.get("max_steps", 20)), "rtol": float(sw.get("rtol", 1e-6)),
                    "atol": float(sw.get("atol", 1e-10)), "memory_fraction": float(sw.get("memory_fraction", 0.6))},
        "batch_size": bs,  # how many cells per solve call; not part of the results' identity
        "out": sw.get("out"),
    }  # fmt: skip


def _check_int(source, key: str, v, low: int, example: str) -> None:
    if isinstance(v, bool) or not isinstance(v, int) or v < low:
        _fail(source, f"{key} must be an integer >= {low}, got {v!r}; {example}.")


def _check_number(source, key: str, v, low: float, high: float | None, example: str, open_low: bool = False) -> None:
    ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
    ok = ok and (v > low if open_low else v >= low) and (high is None or v <= high)
    if not ok:
        bound = f"> {low:g}" if open_low else f">= {low:g}"
        bound += f" and <= {high:g}" if high is not None else ""
        _fail(source, f"{key} must be a finite number {bound}, got {v!r}; {example}.")


def _identity(config: dict) -> dict:
    """The parts of a config that decide its results (batch size and output folder do not)."""
    return {k: v for k, v in config.items() if k not in ("batch_size", "out")}


def config_hash(config: dict) -> str:
    text = json.dumps(_identity(config), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _diff(old, new, prefix="") -> list[str]:
    if isinstance(old, dict) and isinstance(new, dict):
        out = []
        for k in sorted(set(old) | set(new)):
            where = f"{prefix}.{k}" if prefix else str(k)
            if k not in old:
                out.append(f"{where} added ({new[k]!r})")
            elif k not in new:
                out.append(f"{where} removed (was {old[k]!r})")
            else:
                out += _diff(old[k], new[k], where)
        return out
    return [] if old == new else [f"{prefix}: {old!r} -> {new!r}"]


def _fmt(v: float) -> str:
    return f"{v:g}"


def variants(config: dict) -> dict[str, dict]:
    """Every variant of the grid: {variant id: {method, weights (all of them), terms}}.

    A term switched off zeroes its weights, so variants that differ only in the weight
    of a switched-off term are one variant (listed once).
    """
    import itertools

    out = {}
    gw, gt = config["grid"]["weights"], config["grid"]["terms"]
    for name in config["methods"]:
        m = resolve_method(name)
        for wvals in itertools.product(*gw.values()) if gw else [()]:
            for tvals in itertools.product(*gt.values()) if gt else [()]:
                weights = {**m.defaults, **config["baseline"], **dict(zip(gw, wvals))}
                terms = dict(zip(gt, tvals))
                for t, on in terms.items():
                    if not on:
                        weights.update({w: 0.0 for w in m.terms[t]})
                shown = {k: weights[k] for k in gw if all(terms.get(t, True) or k not in m.terms[t] for t in terms)}
                label = ",".join(f"{k}={_fmt(v)}" for k, v in shown.items())
                off = ",".join(f"-{t}" for t, on in terms.items() if not on)
                vid = name + (f"[{label}]" if label else "") + (f"[{off}]" if off else "")
                out.setdefault(vid, {"method": name, "weights": weights, "terms": terms, "grid": shown})
    return out


class Store:
    """The sweep's folder: `sweep.json` (config + hash) and one JSON file per finished cell."""

    def __init__(self, root, config: dict):
        self.root = Path(root)
        self.cells = self.root / "cells"
        self.config = config
        self.hash = config_hash(config)

    def open(self, log=print) -> None:
        """Create the folder, or check that the one there belongs to this config.

        A folder whose sweep solved no cell (every cell failed, or none ran) holds no
        results to protect: it is taken over by the new config rather than locked.
        """
        manifest = self.root / "sweep.json"
        if manifest.exists():
            old = _read_json(manifest, "delete it to start again (the cells keep their config hash)")
            if not isinstance(old, dict) or "hash" not in old or "config" not in old:
                raise SweepConfigError(f"{manifest}: not a sweep manifest (no 'hash' and 'config'); "
                                       "delete it or use another --out.")  # fmt: skip
            if old["hash"] == self.hash:
                self.cells.mkdir(parents=True, exist_ok=True)
                return
            if self._solved_any():
                changes = _diff(old["config"], _identity(self.config))
                raise SweepConfigError(
                    f"{self.root} holds an interrupted sweep of a different config; refusing to mix results. "
                    f"Changed: {'; '.join(changes) or 'unknown'}. Restore the config, or use another --out."
                )
            log(f"{self.root}: its earlier sweep solved no cell; starting over with this config")
            for p in self.cells.glob("*.json"):
                p.unlink()
            # Its generated datasets too: they are cached by name, not by their settings.
            shutil.rmtree(self.root / "datasets", ignore_errors=True)
        self.cells.mkdir(parents=True, exist_ok=True)
        atomic_write(manifest, json.dumps({"hash": self.hash, "config": _identity(self.config)}, indent=1))

    def _solved_any(self) -> bool:
        for p in self.cells.glob("*.json"):
            r = _read_cell(p)
            if r is not None and "metrics" in r:
                return True
        return False

    def path(self, cell: Cell) -> Path:
        digest = hashlib.sha1(cell.key.encode()).hexdigest()[:20]
        return self.cells / f"{digest}.json"

    def done(self, cell: Cell) -> bool:
        """Whether the cell's file holds this cell's complete record: a truncated or
        otherwise damaged file (a full disk, a copy cut short) is run again."""
        r = _read_cell(self.path(cell))
        return r is not None and r.get("cell") == cell.key and r.get("config_hash") == self.hash

    def write(self, cell: Cell, record: dict) -> None:
        atomic_write(self.path(cell), json.dumps({"config_hash": self.hash, "cell": cell.key, **record}))

    def records(self) -> list[dict]:
        out = []
        for p in sorted(self.cells.glob("*.json")):
            r = _read_cell(p)
            if r is None:
                raise SweepConfigError(f"{p}: a damaged cell file (not a complete JSON record); run the sweep "
                                       "again to redo that cell, or delete the file.")  # fmt: skip
            if r.get("config_hash") != self.hash:
                raise SweepConfigError(f"{p} belongs to config {r.get('config_hash')}, not {self.hash}.")
            out.append(r)
        return out

    def failed(self) -> int:
        """How many cells recorded an error."""
        return sum("error" in r for r in self.records())


def _read_json(path: Path, fix: str):
    try:
        return json.loads(path.read_text())
    except (ValueError, UnicodeDecodeError) as e:
        raise SweepConfigError(f"{path}: damaged, not JSON ({e}); {fix}.") from None


def _try_json(path: Path):
    """The JSON in `path`, or None if it is missing or not JSON."""
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError, UnicodeDecodeError):
        return None


def _read_cell(path: Path) -> dict | None:
    """A cell file's record, or None if it is missing or damaged."""
    r = _try_json(path)
    ok = isinstance(r, dict) and isinstance(r.get("cell"), str) and ("metrics" in r or "error" in r)
    return r if ok else None


def join_distributed(distributed) -> None:
    """`jax.distributed.initialize(**kwargs)` once; True: no arguments (SLURM, Open MPI, ... env)."""
    import jax

    from .._compat import distributed_client

    if distributed and distributed_client() is None:
        jax.distributed.initialize(**(distributed if isinstance(distributed, dict) else {}))


def _process_info(distributed) -> tuple[int, int]:
    """(process index, process count); joins `jax.distributed` when asked."""
    import jax

    join_distributed(distributed)
    return jax.process_index(), jax.process_count()


def run_sweep(config: dict, out=None, *, prepare_only: bool = False, summary: bool = True,
              distributed: bool = False, progress: bool = True, log=print) -> Path:  # fmt: skip
    """Run (or resume) a validated sweep; returns its output folder.

    out: folder (default: the config's `out`, else out/sweeps/<name>).
    prepare_only: build and cache the datasets, solve nothing.
    distributed: join `jax.distributed` first: True (`initialize()` reads SLURM etc.) or the
        keyword arguments of `jax.distributed.initialize`. It must happen before JAX
        computes anything in this process, so call `join_distributed` before
        `load_config` when a method builds arrays as it is resolved (the CLI does).
    """
    root = Path(out or config.get("out") or Path("out") / "sweeps" / config["name"])
    store = Store(root, config)
    rank, nproc = _process_info(distributed)
    if rank == 0:
        store.open(log)
    else:
        # Process 0 alone writes (or takes over) the folder: wait for this config's manifest.
        _wait_for(
            root / "sweep.json", 600, lambda p: isinstance(m := _try_json(p), dict) and m.get("hash") == store.hash
        )
        store.open(log)
    var = variants(config)
    cache = root / "datasets"
    methods = {name: resolve_method(name) for name in config["methods"]}
    # Sequences per (method, dataset, preset); generated data is cached in DIR/datasets.
    groups = []
    for name, m in methods.items():
        for d, spec in config["datasets"].items():
            for e, errors in config["sensor_errors"].items():
                groups.append((name, m, d, {**spec, "_name": d, "_errors_name": e}, e, errors))
    prepared = []
    cache.mkdir(parents=True, exist_ok=True)
    if rank == 0 or prepare_only:
        for k, (_, m, d, spec, e, errors) in enumerate(groups):  # process 0 writes the cache first
            if hasattr(m, "prepare"):
                # Generating a dataset takes minutes; say what is going on.
                log(f"building dataset {d!r} with sensor errors {e!r} ({k + 1} of {len(groups)}) in {cache}")
                m.prepare(spec, errors, cache)
                prepared.append(cache / f".{d}__{e}.ready")
                atomic_write(prepared[-1], "")
    if prepare_only:
        log(f"prepared datasets in {cache}")
        return root
    if nproc > 1:
        for _, m, d, _spec, e, _ in groups:
            if hasattr(m, "prepare"):
                _wait_for(cache / f".{d}__{e}.ready", 1800)
    grid, errors_by_cell = [], {}
    items_of = {}
    for k, (name, m, d, spec, e, errors) in enumerate(groups):
        log(f"loading dataset {d!r} with sensor errors {e!r} for {name!r} ({k + 1} of {len(groups)})")
        try:
            items = m.sequences(spec, errors, cache)
        except Exception as err:  # noqa: BLE001 - the whole group fails, the sweep goes on
            log(f"dataset {d!r} / {e!r} for {name!r} failed: {type(err).__name__}: {err}")
            items = None
        items_of[(name, d, e)] = items
        n = len(items) if items is not None else int(spec.get("sequences", 1))
        for vid, v in var.items():
            if v["method"] != name:
                continue
            for i in range(n):
                cell = Cell(vid, d, e, i, tuple(sorted(v["weights"].items())))
                if items is None:
                    errors_by_cell[cell] = f"dataset {d!r} failed to load"
                elif hasattr(items[i], "error"):
                    errors_by_cell[cell] = f"sequence {i} failed to prepare: {items[i].error}"
                else:
                    grid.append(cell)
    if rank == 0:  # process 0 records them; a resume retries nothing that is recorded
        for cell, msg in errors_by_cell.items():
            if not store.done(cell):
                store.write(cell, {**_where(cell), "error": msg})
    # Cells of one method and one padded length go together (one compiled program). The
    # batches are cut from the whole grid, whatever is on disk, and batch b belongs to
    # process b mod P: every process count solves the same batches, so the results are
    # the same bit for bit; finished cells are dropped from their batch afterwards.
    from ..solve.batch import length_buckets

    batches = []
    for name in methods:
        cells_m = [c for c in grid if var[c.variant]["method"] == name]
        if not cells_m:
            continue
        lengths = [items_of[(name, c.dataset, c.errors)][c.index].length for c in cells_m]
        for _T, members in length_buckets(lengths):
            cells = [cells_m[i] for i in members]
            # Every call of a bucket has `size` cells (the last one padded): one shape.
            size = min(config["batch_size"], len(cells))
            for s in range(0, len(cells), size):
                batches.append((name, size, cells[s : s + size]))
    batches = [(name, size, [c for c in cells if not store.done(c)]) for name, size, cells in batches[rank::nproc]]
    batches = [b for b in batches if b[2]]
    total = sum(len(b[2]) for b in batches)
    log(f"sweep {config['name']!r}: {len(var)} variants, {len(grid) + len(errors_by_cell)} cells, "
        f"{total} to run" + (f" on process {rank} of {nproc}" if nproc > 1 else "") + f", results in {root}")  # fmt: skip
    bar = _progress(total, progress and rank == 0)
    for name, size, cells in batches:
        m = methods[name]
        _solve_cells(m, cells, size, items_of, name, config, store)
        bar.update(len(cells))
    bar.close()
    if nproc > 1:
        _barrier(f"jaxmocap-sweep-{store.hash}")
    if summary and rank == 0:
        from .sweep_report import write_summary

        write_summary(root, config, store.records(), var, log=log)
    return root


def _solve_cells(method, cells, size, items_of, name, config, store) -> None:
    """Solve one batch of cells and write each; a failing batch is bisected down to its failing cells."""
    items = [items_of[(name, c.dataset, c.errors)][c.index] for c in cells]

    def run(idx):
        # Pad to `size` by repeating the last cell: every call has one shape, one program.
        full = list(idx) + [idx[-1]] * (size - len(idx))
        keys = list(method.defaults)
        w = {k: np.asarray([dict(cells[i].weights)[k] for i in full], np.float32) for k in keys}
        t0 = time.perf_counter()
        res = method.solve([items[i] for i in full], w, config["options"])
        dt = (time.perf_counter() - t0) / len(full)
        return res[: len(idx)], dt

    def attempt(idx):
        # A failing call is split in halves until the failing cells are alone: a rare
        # failure in a large batch costs O(log batch) extra calls, not one per cell.
        try:
            results, dt = run(idx)
        except Exception as err:  # noqa: BLE001 - isolate the failing cells, keep the others
            if len(idx) == 1:
                store.write(cells[idx[0]], {**_where(cells[idx[0]]), "error": f"{type(err).__name__}: {err}",
                                            "traceback": traceback.format_exc(limit=4)})  # fmt: skip
                return
            attempt(idx[: len(idx) // 2])
            attempt(idx[len(idx) // 2 :])
            return
        for i, r in zip(idx, results):
            store.write(cells[i], _record(cells[i], r, dt))

    attempt(list(range(len(cells))))


def _where(c: Cell) -> dict:
    return {"variant": c.variant, "dataset": c.dataset, "errors": c.errors, "index": c.index,
            "weights": dict(c.weights)}  # fmt: skip


def _record(c: Cell, metrics: dict, seconds: float) -> dict:
    return {**_where(c), "metrics": metrics, "seconds": seconds}


def _progress(total: int, enabled: bool):
    from tqdm import tqdm

    return tqdm(total=total, desc="cells", unit="cell", disable=not enabled, file=sys.stderr, smoothing=0.1)


def _wait_for(path: Path, timeout: float, ready=None) -> None:
    start = time.monotonic()
    while not path.exists() or (ready is not None and not ready(path)):
        if time.monotonic() - start > timeout:
            raise TimeoutError(f"waited {timeout:.0f} s for {path} (written by process 0).")
        time.sleep(0.2)


def _barrier(name: str) -> None:
    """All processes of `jax.distributed` meet here (the coordination service's barrier)."""
    from .._compat import distributed_client

    client = distributed_client()
    if client is not None:
        client.wait_at_barrier(name, 3_600_000)


def main_args(args) -> int:
    """The CLI verb's body (`jaxmocap sweep`)."""
    join_distributed(args.distributed)
    config = load_config(args.config)
    root = run_sweep(config, args.out, prepare_only=args.prepare_only, summary=not args.no_summary,
                     distributed=args.distributed, progress=not args.no_progress)  # fmt: skip
    if args.prepare_only:
        return 0
    store = Store(root, config)
    failed, total = store.failed(), len(store.records())
    if failed:
        # Non-zero so that scripts and schedulers notice; the cells keep their errors.
        print(f"jaxmocap sweep: {failed} of {total} cells failed (their errors are in {root / 'cells'}"
              f"{' and summary.md' if not args.no_summary else ''}).", file=sys.stderr)  # fmt: skip
        return 1
    return 0


def configure_parser(p) -> None:
    p.add_argument("config", help="sweep config (.toml); see README 'Running a sweep'")
    p.add_argument("--out", default=None, help="output folder (default: the config's out, else out/sweeps/NAME)")
    p.add_argument("--prepare-only", action="store_true", help="build and cache the datasets, solve nothing")
    p.add_argument("--no-summary", action="store_true", help="skip the summary tables and plots")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--distributed", action="store_true",
                   help="join jax.distributed first (SLURM etc.); processes share the cells")  # fmt: skip
