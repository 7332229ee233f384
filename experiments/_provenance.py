"""Where every published result came from: one entry a file in `experiments/results/provenance.json`.

Each experiment writes its results through `write_json` / `write_text` (or calls `record`
after writing a file itself, e.g. a figure): the file is written atomically and its entry
in the provenance file of its results folder is updated, under the lock of that file:

    files.<path relative to the repository>:
        commit   git HEAD when the experiment started, "+dirty" if tracked files other
                 than results differed from it then
        command  the exact command line (python and argv)
        split    the `Split.record()` its numbers obey (`jaxmocap.motion.splits`)
        data     which clips / subjects / scenes it read (the experiment says)
        date     UTC, ISO 8601, when the file was written
        machine  platform, processor, CPU count, JAX backend and device when JAX is loaded

The provenance file is `provenance.json` in the nearest folder named `results` above the
written file (so `experiments/results/sip_ablation/summary.json` is recorded in
`experiments/results/provenance.json`), else in the file's own folder: a run into
`out/` never touches the committed provenance.

    from _provenance import write_json
    write_json(out / "muvs_tables.json", result, split=SPLIT, data={"clips": names})
"""

from __future__ import annotations

import datetime
import fcntl
import hashlib
import json
import os
import platform
import shlex
import subprocess
import sys
import tempfile
from pathlib import Path

from jaxmocap._files import atomic_write

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "experiments" / "results"
PROVENANCE = "provenance.json"

__all__ = ["write_json", "write_text", "record", "commit", "command", "machine", "subjects_of"]


def _git(*args: str) -> str:
    try:
        return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, timeout=30).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return ""


def _commit_now() -> str:
    head = _git("rev-parse", "HEAD") or "unknown"
    # Results are this script's outputs: a tree dirty only there is still the commit's code.
    dirty = _git("status", "--porcelain", "--untracked-files=no", "--", ".", ":(exclude)experiments/results")
    return head + ("+dirty" if dirty else "")


#: The commit when the experiment started (this module is imported at the start of a run):
#: results written later, by this run, do not make it "+dirty".
_START_COMMIT = _commit_now()


def commit() -> str:
    """git HEAD when this process started, with "+dirty" if tracked code differed from it."""
    return _START_COMMIT


def command(argv=None) -> str:
    """The command line that ran this process ("python experiments/x.py --out ..."); `argv`:
    the arguments a `main(argv)` got when it was called from Python rather than a shell."""
    args = list(sys.argv[1:] if argv is None else argv)
    script = sys.argv[0] if sys.argv and sys.argv[0] else "-c"
    try:
        script = str(Path(script).resolve().relative_to(ROOT))
    except ValueError:
        pass
    return shlex.join(["python", script, *map(str, args)])


def machine() -> dict:
    """The machine, and JAX's backend and first device when this process has loaded JAX."""
    out = {"platform": platform.platform(), "processor": platform.processor() or platform.machine(),
           "cpus": os.cpu_count(), "python": platform.python_version()}  # fmt: skip
    jax = sys.modules.get("jax")
    if jax is not None:
        try:
            out.update(jax=jax.__version__, backend=jax.default_backend(), device=str(jax.devices()[0]))
        except Exception:  # noqa: BLE001 (a broken backend must not lose a result)
            pass
    return out


def subjects_of(names) -> list[str]:
    """The CMU subjects of clip names or paths ('02_01.amc', '005_03.bvh' -> '02', '05'), sorted."""
    from jaxmocap.motion.corpus import subject_of

    out = set()
    for n in names:
        try:
            out.add(subject_of(n))
        except ValueError:
            out.add(Path(str(n)).stem)  # a procedural motion: its own "subject"
    return sorted(out)


def _provenance_file(path: Path) -> Path:
    for parent in path.parents:
        if parent.name == "results":
            return parent / PROVENANCE
    return path.parent / PROVENANCE


def _key(path: Path) -> str:
    try:
        return str(path.relative_to(ROOT))
    except ValueError:
        return str(path)


def _atomic_write(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, text)


def _split_record(split) -> dict | None:
    if split is None:
        return None
    record = split.record() if hasattr(split, "record") else dict(split)
    from jaxmocap.motion.splits import check_record

    check_record(record)  # a result is never written under a split that leaks
    return record


def record(path, *, split, data, argv=None, extra: dict | None = None, provenance: Path | None = None) -> dict:
    """Enter the written file `path` in its provenance file (atomically, under a lock).

    split: the `Split` (or its record) the numbers obey; None only for files that measure
        no data (a fuzzer, a timing). data: what was read (clips, subjects, scenes).
    provenance: the provenance file (default: see the module's docstring), e.g.
        experiments/results/provenance.json for a model file written into the package.
    Returns the entry.
    """
    path = Path(path).resolve()
    entry = {"commit": commit(), "command": command(argv), "split": _split_record(split), "data": data,
             "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
             "machine": machine(), **(extra or {})}  # fmt: skip
    prov = Path(provenance) if provenance is not None else _provenance_file(path)
    prov.parent.mkdir(parents=True, exist_ok=True)
    # The lock lives outside the repository (nothing to commit or ignore), one per provenance file.
    digest = hashlib.sha1(str(prov.resolve()).encode()).hexdigest()[:16]  # hash() differs between processes
    lock_path = Path(tempfile.gettempdir()) / f"jaxmocap-provenance-{digest}.lock"
    with open(lock_path, "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # several experiments may finish at once
        try:
            table = json.loads(prov.read_text()) if prov.exists() else {}
        except json.JSONDecodeError as e:
            raise RuntimeError(f"{prov} is not valid JSON ({e}); fix or remove it, nothing was recorded") from e
        table.setdefault("files", {})[_key(path)] = entry
        table["files"] = dict(sorted(table["files"].items()))
        table["about"] = ("One entry a result file: the commit and command that wrote it, the split its numbers "
                          "obey, the data it read. Written by experiments/_provenance.py; regenerate with "
                          "`make tables`.")  # fmt: skip
        _atomic_write(prov, json.dumps(table, indent=1, default=str) + "\n")
    return entry


def write_json(path, obj: dict, *, split, data, argv=None, indent: int = 1, **dump) -> Path:
    """Write `obj` (with "split": split.record() added) atomically as JSON and record it."""
    path = Path(path)
    rec = _split_record(split)
    if rec is not None:
        obj = {**obj, "split": rec}
    _atomic_write(path, json.dumps(obj, indent=indent, **dump) + "\n")
    record(path, split=rec, data=data, argv=argv)
    return path


def write_text(path, text: str, *, split, data, argv=None) -> Path:
    """Write a generated text (a table's .md) atomically and record it."""
    path = Path(path)
    _atomic_write(path, text)
    record(path, split=split, data=data, argv=argv)
    return path
