"""Shared helpers for benchmark scripts: timing, machine description, atomic JSON output."""

from __future__ import annotations

import json
import os
import platform
import subprocess
import time
from pathlib import Path

import jax

RESULTS = Path(__file__).parent / "results"


def time_call(fn, *args, min_seconds: float = 1.0, max_repeats: int = 1000) -> dict:
    """Compile once (timed separately), then repeat until `min_seconds` have passed."""
    start = time.perf_counter()
    jax.block_until_ready(fn(*args))
    compile_and_first = time.perf_counter() - start
    times = []
    total = 0.0
    while total < min_seconds and len(times) < max_repeats:
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - t0)
        total += times[-1]
    times.sort()
    return {
        "compile_and_first_call_s": compile_and_first,
        "median_s": times[len(times) // 2],
        "min_s": times[0],
        "repeats": len(times),
    }


def machine() -> dict:
    devices = jax.devices()
    info = {
        "platform": platform.platform(),
        "python": platform.python_version(),
        "cpu_count": os.cpu_count(),
        "jax": jax.__version__,
        "backend": jax.default_backend(),
        "devices": [d.device_kind for d in devices],
    }
    try:
        import numpy

        info["numpy"] = numpy.__version__
        model = subprocess.run(["sh", "-c", "grep -m1 'model name' /proc/cpuinfo"], capture_output=True, text=True)
        info["cpu"] = model.stdout.split(":", 1)[-1].strip()
    except Exception:
        pass
    return info


def peak_memory_bytes() -> int | None:
    """Peak device memory on accelerators; peak resident set size on the CPU."""
    device = jax.devices()[0]
    if device.platform != "cpu":
        stats = device.memory_stats() or {}
        return stats.get("peak_bytes_in_use")
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def write_json(name: str, payload: dict) -> Path:
    """Write results/<name> atomically (temp file + rename) and return its path."""
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / name
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(payload, indent=2) + "\n")
    os.replace(tmp, path)
    return path
