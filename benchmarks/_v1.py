"""The "v1" least-squares engine (jaxmocap at commit d67d910, its own hand-written LM) as
a package folder, for in-run baselines after that engine left the codebase.

`v1_path()` returns `build/v1`, a folder that holds `jaxmocap/` as it was at `V1_COMMIT`;
put it first on PYTHONPATH in a subprocess to import that package instead of the current
one. Where git and the commit are at hand it extracts the folder from history
(`git archive d67d910 jaxmocap | tar -x -C build/v1`, once; a stamp file records the
commit); elsewhere (the GPU machine gets no .git) it uses a `build/v1` made earlier and
carried along. `/build/` is git-ignored.

    python benchmarks/_v1.py        # make build/v1 here, before carrying it
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

V1_COMMIT = "d67d910"
ROOT = Path(__file__).resolve().parent.parent
V1_DIR = ROOT / "build" / "v1"
_STAMP = ".v1-commit"  # inside V1_DIR: the full hash the folder was extracted from


def _git(*args: str) -> str | None:
    """stdout of `git -C ROOT args`, or None when git, the repository or the object is missing."""
    try:
        out = subprocess.run(["git", "-C", str(ROOT), *args], capture_output=True, text=True, check=False)
    except OSError:
        return None
    return out.stdout.strip() if out.returncode == 0 else None


def _complete(path: Path) -> bool:
    return (path / "jaxmocap" / "__init__.py").is_file() and (path / "jaxmocap" / "solve" / "solver.py").is_file()


def v1_path(commit: str = V1_COMMIT, dest: Path = V1_DIR) -> Path:
    """The folder to put on PYTHONPATH for the v1 package (extracted from git if needed)."""
    dest = Path(dest)
    full = _git("rev-parse", "--verify", "--quiet", f"{commit}^{{commit}}")
    if full is not None:
        stamp = dest / _STAMP
        if _complete(dest) and stamp.is_file() and stamp.read_text().strip() == full:
            return dest
        tmp = dest.with_name(dest.name + ".tmp")
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir(parents=True)
        archive = subprocess.Popen(["git", "-C", str(ROOT), "archive", full, "jaxmocap"], stdout=subprocess.PIPE)
        untar = subprocess.run(["tar", "-x", "-C", str(tmp)], stdin=archive.stdout, check=False)
        archive.stdout.close()
        if archive.wait() != 0 or untar.returncode != 0 or not _complete(tmp):
            shutil.rmtree(tmp, ignore_errors=True)
            raise RuntimeError(f"`git archive {commit} jaxmocap | tar -x -C {tmp}` failed")
        (tmp / _STAMP).write_text(full + "\n")
        shutil.rmtree(dest, ignore_errors=True)
        tmp.rename(dest)
        return dest
    if _complete(dest):
        return dest
    raise RuntimeError(
        f"The v1 engine (jaxmocap at commit {commit}) is not available: no git history with that "
        f"commit here and no extracted copy at {dest}. Fix: in a git checkout that has the commit, "
        f"run `python benchmarks/_v1.py` (or `mkdir -p build/v1 && git archive {commit} jaxmocap | "
        f"tar -x -C build/v1`), then carry `build/v1` to this machine (device run: carry=['build/v1'])."
    )


if __name__ == "__main__":
    path = v1_path()
    stamp = path / _STAMP
    print(f"{path} ({stamp.read_text().strip() if stamp.is_file() else 'carried copy, no stamp'})")
    sys.exit(0)
