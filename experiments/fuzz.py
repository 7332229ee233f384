"""Fuzz every file reader with many spoiled files (issue 50, goal 4).

The property of `tests/test_fuzz_readers.py`, at scale: each reader gets small valid
seed files (the same seeds as the tests) truncated, with bytes overwritten, with bytes
spliced in, or replaced by random bytes, and (text formats) with values swapped for
others of the wrong type or range, and must either read the file or raise its own
error (MotionFileError, BodyFileError, CalibrationError, KeypointFileError,
SweepConfigError: all ValueErrors) naming the file, within `--timeout` seconds. Anything
else is an unexpected exception; a reader past the timeout is a hang. The spoiled bytes
of the first few failures of each reader are kept for a regression test.

    nice -n 19 python experiments/fuzz.py                   # 10^4 examples per reader
    python experiments/fuzz.py --examples 200 --only bvh    # a quick look at one reader

Writes experiments/results/fuzz.json (counts per reader, updated after each reader, so an
interrupted run leaves what it did) and experiments/results/fuzz_failures/ (inputs that
failed, if any).
"""

from __future__ import annotations

import sys as _sys
from pathlib import Path as _Path

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import _provenance  # noqa: E402,F401  (its commit is taken now, at the start of the run)

import argparse
import json
import re
import sys
import time
import traceback
import uuid
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))  # the seeds live with the property tests
sys.path.insert(0, str(ROOT / "experiments"))

import test_fuzz_readers as F  # noqa: E402

from jaxmocap.app.sweep import SweepConfigError  # noqa: E402
from jaxmocap.body.io import BodyFileError  # noqa: E402
from jaxmocap.formats import CalibrationError, KeypointFileError  # noqa: E402
from jaxmocap.motion import MotionFileError  # noqa: E402

RESULTS = ROOT / "experiments" / "results"


def _easymocap(folder: Path, data: bytes, which: str) -> Path:
    """An EasyMocap pair with `data` as intri.yml or extri.yml; the path the error must name."""
    intri, extri = F.CALIB["easymocap"][1], F.CALIB["extri"]
    (folder / "intri.yml").write_bytes(data if which == "intri" else intri)
    (folder / "extri.yml").write_bytes(data if which == "extri" else extri)
    return folder / f"{which}.yml"


def _openpose(folder: Path, data: bytes) -> Path:
    (folder / "cam01").mkdir()
    path = folder / "cam01" / "cam01_000000000000_keypoints.json"
    path.write_bytes(data)
    return path


def _amc_for_asf(folder: Path, data: bytes) -> Path:
    (folder / "seed.amc").write_bytes(F._amc_seed())
    path = folder / "fuzz.asf"
    path.write_bytes(data)
    return path


def _plain(suffix: str):
    def write(folder: Path, data: bytes) -> Path:
        path = folder / f"fuzz{suffix}"
        path.write_bytes(data)
        return path

    return write


def _calibration(name: str):
    def write(folder: Path, data: bytes) -> Path:
        path = folder / name
        path.write_bytes(data)
        return path

    return write


# name: (seed bytes, write(folder, data) -> the path the error must name, read(path), error type)
READERS = {
    "bvh": (F.BVH_SEED, _plain(".bvh"), F.load_bvh, MotionFileError),
    "amc": (F._amc_seed(), _plain(".amc"), lambda p: F.load_asf_amc(p, asf_path=F.CMU / "02.asf"), MotionFileError),
    "asf": (
        (F.CMU / "02.asf").read_bytes(),
        _amc_for_asf,
        lambda p: F.load_asf_amc(p.parent / "seed.amc", asf_path=p),
        MotionFileError,
    ),  # fmt: skip
    "amass_npz": (F.AMASS_SEED, _plain(".npz"), F.load_amass, MotionFileError),
    "own_motion_npz": (F.OWN_MOTION_SEED, _plain(".npz"), F.load_motion, MotionFileError),
    "scenario_npz": (F.SCENARIO_SEED, _plain(".npz"), F.load_scenario, MotionFileError),
    "body_pkl": (F.SMPL_PKL_SEED, _plain(".pkl"), F.load_body, BodyFileError),
    "body_npz": (F.SMPL_NPZ_SEED, _plain(".npz"), F.load_body, BodyFileError),
    "dip_pkl": (F.DIP_SEED, _plain(".pkl"), F.load_dip, MotionFileError),
    "threedpw_pkl": (F.THREEDPW_SEED, _plain(".pkl"), F.load_threedpw, MotionFileError),
    "pose_prior_npz": (F.PRIOR_SEED, _plain(".npz"), F.load_pose_prior, ValueError),
    "calibration_pose2sim": (
        F.CALIB["pose2sim"][1],
        _calibration("calib.toml"),
        lambda p: F.load_calibration(p, format="pose2sim"),
        CalibrationError,
    ),  # fmt: skip
    "calibration_qualisys": (
        F.CALIB["qualisys"][1],
        _calibration("calib.qca.txt"),
        lambda p: F.load_calibration(p, format="qualisys"),
        CalibrationError,
    ),  # fmt: skip
    "calibration_npz": (
        F.CALIB["npz"][1],
        _calibration("calib.npz"),
        lambda p: F.load_calibration(p, format="npz"),
        CalibrationError,
    ),  # fmt: skip
    "calibration_easymocap_intri": (
        F.CALIB["easymocap"][1],
        lambda f, d: _easymocap(f, d, "intri"),
        lambda p: F.load_calibration(p.parent / "intri.yml", format="easymocap"),
        CalibrationError,
    ),  # fmt: skip
    "calibration_easymocap_extri": (
        F.CALIB["extri"],
        lambda f, d: _easymocap(f, d, "extri"),
        lambda p: F.load_calibration(p.parent / "intri.yml", format="easymocap"),
        CalibrationError,
    ),  # fmt: skip
    "openpose_json": (
        F.CALIB["openpose"],
        _openpose,
        lambda p: F.read_openpose(p.parent.parent, "body25"),
        KeypointFileError,
    ),  # fmt: skip
    "sweep_toml": (F.SWEEP_SEED, _plain(".toml"), F.load_config, SweepConfigError),
}


# Values that a text file may hold where another value was: type and range confusions
# (a string for a number, a table for a list, inf, an empty list) that random bytes
# rarely produce as valid syntax.
TOKENS = ["0", "-1", "1", "1e400", "-1e400", "nan", "inf", '"x"', '""', "true", "[]", "[1]", "{a = 1}", "{}",
          "null", "[[1, 2], [3]]", "999999999999", "-0.5", "'", ":", "\n", " "]  # fmt: skip
_TOKEN = re.compile(rb'-?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?|"[^"\n]*"|\btrue\b|\bfalse\b|\[[^\[\]\n]*\]')


def spoil(seed: bytes, rng: np.random.Generator) -> bytes:
    """The test's four ways (truncate, overwrite, splice, random bytes) and, for text
    seeds, a fifth: a few numbers, strings, booleans or lists replaced by `TOKENS`."""
    text = not seed[:512].count(b"\0")
    how = rng.integers(5 if text else 4)
    if how == 4:
        spans = [m.span() for m in _TOKEN.finditer(seed)]
        if spans:
            data = seed
            for k in sorted(rng.choice(len(spans), size=min(len(spans), int(rng.integers(1, 4))), replace=False))[::-1]:
                a, b = spans[k]
                data = data[:a] + TOKENS[int(rng.integers(len(TOKENS)))].encode() + data[b:]
            return data
        how = 1
    if how == 0:
        return seed[: rng.integers(0, max(len(seed), 1))]
    if how == 3:
        return rng.bytes(int(rng.integers(0, 513)))
    data = bytearray(seed)
    for _ in range(int(rng.integers(1, 7))):
        at = int(rng.integers(0, len(data) + 1))
        chunk = rng.bytes(int(rng.integers(1, 9)))
        data[at : at + (len(chunk) if how == 1 else 0)] = chunk
    return bytes(data)


def _example(name: str, seed: int, i: int) -> bytes:
    """Example i of a reader: its own generator, so a restarted worker resumes exactly."""
    return spoil(READERS[name][0], np.random.default_rng([seed, list(READERS).index(name), i]))


def _outcome(name: str, data: bytes, folder: Path) -> tuple[str, str]:
    """("read" | "own_error" | "unexpected_exceptions", detail) of one spoiled file."""
    _, write, read, error = READERS[name]
    folder.mkdir()
    path = write(folder, data)
    try:
        with np.errstate(all="ignore"):  # overflow in absurd numbers is the data's problem
            read(path)
        return "read", ""
    except error as e:
        if path.name in str(e):
            return "own_error", ""
        return "unexpected_exceptions", f"{type(e).__name__} not naming {path.name}: {e}"
    except Exception as e:  # noqa: BLE001 - what the property forbids: record it
        return "unexpected_exceptions", f"{type(e).__name__}: {e}\n{traceback.format_exc(limit=-3)}"
    finally:
        for p in sorted(folder.rglob("*"), reverse=True):
            p.rmdir() if p.is_dir() else p.unlink()
        folder.rmdir()


def _worker(conn, name: str, seed: int, start: int, stop: int, work: str) -> None:
    """Examples start .. stop-1 of one reader, each announced before it runs (so that the
    parent knows which one hung) and answered after."""
    work = Path(work)
    # Warm-up, untimed: the first successful read compiles the body model (seconds).
    _outcome(name, READERS[name][0], work / f"warm_{uuid.uuid4().hex[:8]}")
    conn.send(("ready",))
    for i in range(start, stop):
        data = _example(name, seed, i)
        conn.send(("start", i))
        conn.send(("done", i, *_outcome(name, data, work / uuid.uuid4().hex[:10])))


def fuzz_reader(name: str, examples: int, seed: int, timeout: float, work: Path, keep: Path) -> dict:
    """Run `examples` spoiled files through one reader in a worker process; a worker that
    gives no answer within `timeout` is killed (a hang) and a new one resumes after it.
    (A signal raised into the reader instead left NumPy's internals broken.)"""
    import multiprocessing as mp

    ctx = mp.get_context("spawn")  # JAX runs threads: no fork
    counts = {"examples": 0, "read": 0, "own_error": 0, "unexpected_exceptions": 0, "hangs": 0}
    failures = []
    started = time.perf_counter()

    def record(i, outcome, detail):
        counts["examples"] += 1
        counts[outcome] += 1
        if outcome in ("unexpected_exceptions", "hangs") and len(failures) < 5:
            keep.mkdir(parents=True, exist_ok=True)
            kept = keep / f"{name}_{i}.bin"
            kept.write_bytes(_example(name, seed, i))
            failures.append(
                {"example": i, "kind": outcome, "detail": detail[:600], "input": str(kept.relative_to(ROOT))}
            )

    i = 0
    while i < examples:
        parent, child = ctx.Pipe()
        proc = ctx.Process(target=_worker, args=(child, name, seed, i, examples, str(work)), daemon=True)
        proc.start()
        if not parent.poll(600) or parent.recv() != ("ready",):
            raise RuntimeError(f"the {name} worker did not start (its seed file does not read?)")
        current = i
        while i < examples:
            if not parent.poll(timeout):
                proc.kill()
                record(current, "hangs", f"no answer within {timeout:g} s")
                i = current + 1
                break
            try:
                msg = parent.recv()
            except EOFError:
                proc.join()
                record(current, "unexpected_exceptions", f"the worker died (exit code {proc.exitcode})")
                i = current + 1
                break
            if msg[0] == "start":
                current = msg[1]
            else:
                record(msg[1], msg[2], msg[3])
                i = msg[1] + 1
        proc.join(5)
        if proc.is_alive():
            proc.kill()
    counts["seconds"] = round(time.perf_counter() - started, 1)
    return {**counts, "failures": failures}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--examples", type=int, default=10_000, help="spoiled files per reader (default 10^4)")
    ap.add_argument("--only", nargs="*", choices=sorted(READERS), help="these readers only")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--timeout", type=float, default=10.0, help="seconds before a read counts as a hang")
    ap.add_argument("--out", type=Path, default=RESULTS / "fuzz.json")
    args = ap.parse_args()
    import tempfile

    names = args.only or list(READERS)
    report = json.loads(args.out.read_text()) if args.out.is_file() else {}
    report.setdefault("readers", {})
    keep = RESULTS / "fuzz_failures"
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            r = fuzz_reader(name, args.examples, args.seed, args.timeout, Path(tmp), keep)
            report["readers"][name] = r
            print(f"{name:30s} {r['examples']:6d} examples: {r['read']} read, {r['own_error']} own errors, "
                  f"{r['unexpected_exceptions']} unexpected, {r['hangs']} hangs ({r['seconds']} s)", flush=True)  # fmt: skip
            done = report["readers"]
            report.update({
                "description": "Spoiled files per reader (truncated, overwritten, spliced, random bytes; the seeds "
                               "of tests/test_fuzz_readers.py): each must read or raise the reader's own error "
                               "naming the file, within the timeout (experiments/fuzz.py).",
                "seed": args.seed, "timeout_s": args.timeout,
                "examples_per_reader": {k: v["examples"] for k, v in done.items()},
                "unexpected_exceptions": sum(v["unexpected_exceptions"] for v in done.values()),
                "hangs": sum(v["hangs"] for v in done.values()),
            })  # fmt: skip
            from _provenance import write_json

            from jaxmocap.motion.splits import Split

            # Reads no motion: spoiled seed files only.
            write_json(
                args.out,
                {k: v for k, v in report.items() if k != "split"},
                data={"readers": names},
                split=Split("fuzz", tuning=(), training=(), evaluation=()),
            )


if __name__ == "__main__":
    main()
