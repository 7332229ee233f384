"""Files written so that nothing half-written is ever read, pickles read without running
code, and file names sorted as people number them."""

from __future__ import annotations

import io
import os
import pickle
import re
from pathlib import Path

__all__ = ["atomic_write", "load_array_pickle", "natural_key"]


def atomic_write(path: Path, text: str) -> None:
    """Write `text` to a temporary file of this process, then rename it onto `path`:
    readers (and a resumed run) never see half a file, even with writers in parallel."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "w") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:  # a failed or interrupted write leaves no temporary file behind
        tmp.unlink(missing_ok=True)
        raise


class _ArrayUnpickler(pickle._Unpickler):
    """Unpickles numpy arrays and containers only: a pickle naming anything else would run code.

    The pure-Python unpickler keeps its memo in a dict; the C one grows an array to the
    largest memo index in the file, so one damaged byte could ask for gigabytes."""

    def find_class(self, module, name):
        if module.split(".")[0] == "numpy" or (module, name) in (
            ("copyreg", "_reconstructor"),
            ("_codecs", "encode"),
            ("builtins", "object"),
        ):
            return super().find_class(module, name)
        raise pickle.UnpicklingError(f"refusing to load {module}.{name}")


def load_array_pickle(path: Path):
    """The object pickled in `path`, numpy arrays and plain containers only (latin1 for
    Python-2 pickles, as DIP-IMU's and 3DPW's files are). A non-pickle or a damaged one can
    raise almost anything: callers wrap the error with what the file should have been."""
    return _ArrayUnpickler(io.BytesIO(Path(path).read_bytes()), encoding="latin1").load()


def natural_key(name: str) -> list:
    """Sort key that orders the numbers in file names by value, "cam2" before "cam10": the
    order of views and frames for every reader that lists a folder."""
    return [int(s) if s.isdigit() else s.lower() for s in re.split(r"(\d+)", name)]
