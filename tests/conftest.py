"""Shared fixtures: float64 on, and small random models in SMPL's exact file layout."""

import os
from pathlib import Path

# The suite is compile-bound: LLVM at -O1 compiled its cases 5-20 % faster here at about
# the same steady speed (benchmarks/results/compile_time_llvm_o1.json; the suite 15:29 ->
# 14:21). Set before JAX starts its backend; subprocesses inherit it.
# XLA's legacy LLVM IR emitters for fusions instead of the MLIR fusion emitters (each of
# those builds and lowers an MLIR module per kernel; with the passes below off there is a
# kernel per operation): test_solve's structured-step program compiled in 12.1 -> 3.9
# CPU-s, the 8-frame chain's LM solve 8.2 -> 3.5, results equal to round-off.
os.environ["XLA_FLAGS"] = " ".join(
    filter(
        None, [os.environ.get("XLA_FLAGS"), "--xla_backend_optimization_level=1", "--xla_cpu_use_fusion_emitters=false"]
    )
)
# Most of XLA's optimisation passes off (JAX_DISABLE_MOST_OPTIMIZATIONS): the suite's programs
# run for milliseconds after compiling for seconds. Measured with JAXMOCAP_COMPILE_REPORT's
# cpu_s on test_rotation + test_metrics + test_body + test_solve's structured step (85 tests,
# cold cache): 509 -> 394 CPU-s. Same arithmetic, unfused.
os.environ.setdefault("JAX_DISABLE_MOST_OPTIMIZATIONS", "1")
# One OpenBLAS thread (before numpy loads it): XLA already spreads jaxlib's batched LAPACK
# kernels (Cholesky, triangular solves, which call scipy's OpenBLAS) over its own threads,
# and OpenBLAS's threads inside each small call only spin. Measured on this 2-core machine:
# one batched triangular solve (39 x 75x75) 0.35 -> 0.013 CPU-s, MuVS stage 2 on a 39-frame
# walk 64 -> 14 CPU-s, test_multiview's short-window test 56.7 -> 15.5.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
# Compiled programs on disk (jaxmocap/_cache.py), shared by the two test processes, by the
# modules after `jax.clear_caches()` below, and by the next run; one folder per checkout.
os.environ.setdefault("JAXMOCAP_CACHE", str(Path(__file__).resolve().parents[1] / ".pytest_cache" / "xla"))

import jax  # noqa: E402
import numpy as np
import pytest

jax.config.update("jax_enable_x64", True)


def central_difference(f, x, eps=1e-6) -> np.ndarray:
    """Jacobian of f at x by central differences, shaped f(x).shape + (x.size,)."""
    x = np.asarray(x, np.float64)
    cols = []
    for i in range(x.size):
        dx = np.zeros_like(x)
        dx.flat[i] = eps
        cols.append((np.asarray(f(x + dx)) - np.asarray(f(x - dx))) / (2 * eps))
    return np.stack(cols, -1)


def random_smpl_dict(num_vertices: int = 120, num_betas: int = 10, seed: int = 0) -> dict:
    """A random model with SMPL's keys, shapes and dtypes (kintree_table root = 2**32-1).

    The rest joints sit at SMPL-like places so that poses behave like a body.
    """
    rng = np.random.default_rng(seed)
    from jaxmocap.body import SMPL_PARENTS

    V = num_vertices
    v_template = rng.normal(scale=0.3, size=(V, 3))
    weights = rng.random((V, 24)) ** 4
    weights /= weights.sum(1, keepdims=True)
    J_regressor = rng.random((24, V)) * (rng.random((24, V)) < 0.1)
    J_regressor[:, 0] += 1e-3
    J_regressor /= J_regressor.sum(1, keepdims=True)
    parents = np.array(SMPL_PARENTS, np.int64)
    parents[0] = 4294967295
    return {
        "v_template": v_template,
        "f": rng.integers(0, V, size=(2 * V, 3)).astype(np.uint32),
        "shapedirs": rng.normal(scale=0.02, size=(V, 3, num_betas)),
        "posedirs": rng.normal(scale=0.02, size=(V, 3, 207)),
        "J_regressor": J_regressor,
        "weights": weights,
        "kintree_table": np.stack([parents, np.arange(24)]).astype(np.int64),
    }


@pytest.fixture(scope="session")
def smpl_dict():
    return random_smpl_dict()


@pytest.fixture(scope="session")
def random_body(smpl_dict):
    from jaxmocap.body import make_body

    d = smpl_dict
    return make_body(
        d["v_template"],
        d["f"],
        d["shapedirs"],
        d["posedirs"],
        d["J_regressor"],
        d["weights"],
        dtype=np.float64,
    )


#: A worker drops JAX's compiled programs after a test module once it holds this much memory
#: (JAXMOCAP_TEST_RELEASE_GB; 0: after every module).
_RELEASE_ABOVE = float(os.environ.get("JAXMOCAP_TEST_RELEASE_GB", "3")) * 2**30


def _resident_bytes() -> float:
    """This process's resident memory (Linux); elsewhere +inf, so that every module releases."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return float("inf")


@pytest.fixture(scope="module", autouse=True)
def _release_compiled_programs():
    """Drop JAX's compiled programs after a test module when the worker holds more than
    `_RELEASE_ABOVE`: a process that kept every module's executables grew to several GB and
    a late compile crashed once under that memory pressure; releasing after *every* module
    made each one trace, lower and load from disk again the programs the modules share
    (the body, the solves at the test shapes, hundreds of small eager operations)."""
    yield
    if _resident_bytes() > _RELEASE_ABOVE:
        import gc

        jax.clear_caches()
        gc.collect()


# `JAXMOCAP_COMPILE_REPORT=FILE make test` appends one JSON line per test: seconds spent
# tracing, lowering and compiling (XLA), and persistent-cache hits and misses. The suite is
# compile-bound; this says which tests pay for it (tests/compile_report.py sums it up).
_COMPILE_REPORT = os.environ.get("JAXMOCAP_COMPILE_REPORT")
_compile_totals: dict = {}

if _COMPILE_REPORT:
    from jax import monitoring as _monitoring

    _EVENTS = {"/jax/core/compile/jaxpr_trace_duration": "trace_s",
               "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower_s",
               "/jax/core/compile/backend_compile_duration": "compile_s"}  # fmt: skip

    def _on_duration(event, seconds, **_):
        key = _EVENTS.get(event)
        if key:
            _compile_totals[key] = _compile_totals.get(key, 0.0) + seconds
            if key == "compile_s":
                _compile_totals["programs"] = _compile_totals.get("programs", 0) + 1

    def _on_event(event, **_):
        if event.startswith("/jax/compilation_cache/cache_"):
            key = event.rsplit("/", 1)[1]
            _compile_totals[key] = _compile_totals.get(key, 0) + 1

    _monitoring.register_event_duration_secs_listener(_on_duration)
    _monitoring.register_event_listener(_on_event)

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_protocol(item, nextitem):
        import json
        import resource
        import time

        _compile_totals.clear()
        t0, c0 = time.perf_counter(), resource.getrusage(resource.RUSAGE_SELF).ru_utime
        yield
        cpu = resource.getrusage(resource.RUSAGE_SELF).ru_utime - c0  # what a busy machine does not inflate
        row = {"test": item.nodeid, "wall_s": round(time.perf_counter() - t0, 3), "cpu_s": round(cpu, 3),
               **{k: round(v, 3) if isinstance(v, float) else v for k, v in _compile_totals.items()}}  # fmt: skip
        with open(_COMPILE_REPORT, "a") as f:
            f.write(json.dumps(row) + "\n")


def assert_picture(path, min_bytes=10_000, min_colour_fraction=0.0, min_drawn_fraction=0.0):
    """A PNG with content: not blank, some dark ink, and (if asked) enough drawn pixels
    (anything not page-white) and enough coloured ones.

    Coloured: saturation (max - min over RGB) above 0.3, i.e. plotted data rather than the
    black, grey and white of axes, text and page.
    """
    import matplotlib.image

    path = Path(path)
    assert path.is_file() and path.suffix == ".png", path
    assert path.stat().st_size > min_bytes, (path, path.stat().st_size)
    image = matplotlib.image.imread(path)[..., :3]
    assert image.std() > 0.05, f"{path} is blank"
    assert (image < 0.5).mean() > 0.001, f"{path} has no dark ink"
    drawn = (image.min(-1) < 0.9).mean()
    assert drawn >= min_drawn_fraction, f"{path}: {drawn:.4f} of its pixels drawn, expected >= {min_drawn_fraction}"
    colour = (image.max(-1) - image.min(-1) > 0.3).mean()
    assert colour >= min_colour_fraction, (
        f"{path}: {colour:.4f} of its pixels coloured, expected >= {min_colour_fraction}"
    )
