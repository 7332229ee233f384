"""XLA's CPU thread pool, widened on import where jaxlib's LAPACK kernels could deadlock it."""

import os
import sys
import warnings

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
_USER_POOL = "PJRT_NPROC" in os.environ  # set by the user, before the default below
cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
if cores < MIN_CPU_THREADS:
    os.environ.setdefault("PJRT_NPROC", str(MIN_CPU_THREADS))


def _cpu_backend_started() -> bool:
    """Whether JAX's CPU backend already runs; False before JAX is imported."""
    if "jax" not in sys.modules:
        return False
    from ._compat import cpu_backend_started  # imports optimistix, which starts no backend

    return cpu_backend_started()


if cores < MIN_CPU_THREADS and not _USER_POOL and _cpu_backend_started():
    warnings.warn(
        f"JAX's CPU backend started before `import jaxmocap` on a machine with {cores} usable core(s): its thread "
        f"pool has {cores} thread(s), and two concurrent batched solves can hang it (jaxmocap/_threads.py). Import "
        f"jaxmocap before running JAX code, or set PJRT_NPROC={MIN_CPU_THREADS} in the environment before starting.",
        RuntimeWarning, stacklevel=2,
    )  # fmt: skip
