"""XLA's CPU thread pool is wide enough that concurrent batched LAPACK kernels cannot hang.

jaxlib 0.10's batched Cholesky and triangular solves block a pool thread while their
sub-tasks wait for another; with one thread per core, two of them at once on a 2-core
machine deadlock (jaxmocap/__init__.py). This runs exactly that in a fresh process (the
pool is sized when JAX's CPU backend starts) and fails by timeout if it hangs. Without the
fix it hangs within the first few calls on a 2-core machine; with 4 or more usable cores the
pool was wide enough anyway and the test passes either way.
"""

import os
import subprocess
import sys

import pytest

import jaxmocap

SCRIPT = """
import jaxmocap, jax, jax.numpy as jnp, jax.scipy.linalg as jsl
jax.config.update("jax_enable_x64", True)
A = jax.random.normal(jax.random.PRNGKey(0), (256, 60, 60))
A = A @ jnp.swapaxes(A, -1, -2) + 60 * jnp.eye(60)
R = jnp.ones((256, 60, 100))

@jax.jit
def two_solves(A, R):  # independent: XLA runs them on two pool threads at once
    return (jsl.solve_triangular(jnp.linalg.cholesky(A), R, lower=True),
            jsl.solve_triangular(jnp.linalg.cholesky(2 * A), R + 1, lower=True))

for _ in range(40):
    jax.block_until_ready(two_solves(A, R))
print("pool", __import__("os").environ.get("PJRT_NPROC", "cores"))
"""


def test_concurrent_batched_solves_do_not_hang():
    env = {k: v for k, v in os.environ.items() if k != "PJRT_NPROC"}
    env["JAX_PLATFORMS"] = "cpu"
    try:
        out = subprocess.run([sys.executable, "-c", SCRIPT], env=env, capture_output=True, text=True, timeout=240)
    except subprocess.TimeoutExpired:
        pytest.fail("two concurrent batched LAPACK solves hung: XLA's CPU pool is too narrow (jaxmocap/__init__.py)")
    assert out.returncode == 0, out.stderr[-2000:]
    if len(os.sched_getaffinity(0)) < jaxmocap.MIN_CPU_THREADS:
        assert out.stdout.split()[-1] == str(jaxmocap.MIN_CPU_THREADS)


def test_a_users_pool_size_is_kept():
    env = dict(os.environ, PJRT_NPROC="3", JAX_PLATFORMS="cpu")
    code = "import jaxmocap, os; print(os.environ['PJRT_NPROC'])"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert out.stdout.strip() == "3", out.stderr[-2000:]


def test_a_backend_started_before_the_import_is_warned_about():
    env = {k: v for k, v in os.environ.items() if k != "PJRT_NPROC"}
    env["JAX_PLATFORMS"] = "cpu"
    small = f"import os; os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[:2]}); "  # also on a large machine

    def run(code):
        return subprocess.run([sys.executable, "-W", "always", "-c", small + code], env=env, capture_output=True,
                              text=True, timeout=120)  # fmt: skip

    out = run("import jax; jax.devices(); import jaxmocap")
    assert out.returncode == 0 and "Import jaxmocap before running JAX code" in out.stderr, out.stderr[-2000:]
    quiet = run("import jaxmocap, jax; jax.devices()")
    assert "Import jaxmocap before" not in quiet.stderr, quiet.stderr[-2000:]
