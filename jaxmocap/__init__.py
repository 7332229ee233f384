"""jaxmocap: human motion capture by model-based optimisation, in JAX."""

import os as _os

# jaxlib 0.10's CPU LAPACK kernels (batched Cholesky, triangular solves) cut a large batch
# into tasks on XLA's intra-op thread pool and block their own pool thread until the tasks
# are done. When every pool thread blocks so (two concurrent solves on a 2-core machine),
# no thread is left to run the tasks and the process hangs for ever (measured: the
# 1000-frame VIP fusion; tests/test_cpu_threads.py). The pool has one thread per usable
# core unless PJRT_NPROC says otherwise; with at least `MIN_CPU_THREADS` a hang needs that
# many such kernels at once, and SIP's CPU time is unchanged (4.8 s with 4 threads against
# 5.1-5.4 s with 2, same process layout). It only acts before JAX's CPU backend starts
# (import jaxmocap before running JAX code) and never overrides a user's PJRT_NPROC.
MIN_CPU_THREADS = 4
_cores = len(_os.sched_getaffinity(0)) if hasattr(_os, "sched_getaffinity") else (_os.cpu_count() or 1)
if _cores < MIN_CPU_THREADS:
    _os.environ.setdefault("PJRT_NPROC", str(MIN_CPU_THREADS))

from . import motion as motion
from . import rotation as rotation
from .body import SMPL_JOINT_NAMES as SMPL_JOINT_NAMES
from .body import SMPL_PARENTS as SMPL_PARENTS
from .body import Body as Body
from .body import BodyFileError as BodyFileError
from .body import BodyOutput as BodyOutput
from .body import default_body as default_body
from .body import forward as forward
from .body import load_body as load_body
from .body import save_body as save_body

__version__ = "0.1.0"

# Heavier subpackages (MuJoCo, trimesh, matplotlib) load on first use: `jaxmocap.physics`.
_LAZY = ("energies", "formats", "learned", "methods", "metrics", "objects", "physics", "priors", "sensors", "solve", "viz")


def __getattr__(name):
    if name in _LAZY:
        import importlib

        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module 'jaxmocap' has no attribute {name!r}")
