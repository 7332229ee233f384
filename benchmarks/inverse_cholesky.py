"""Inverse Cholesky factors of batched SPD blocks: recursive halving against LAPACK-style.

    python benchmarks/inverse_cholesky.py                 # CPU: results/inverse_cholesky.json
    python benchmarks/inverse_cholesky.py --suffix gpu    # on a GPU

`jaxmocap.solve.tridiagonal.inverse_cholesky` forms L⁻¹ (S = L Lᵀ) by halving down to a
base size, so nearly all flops are matrix products; the baseline (same process, same
blocks) is a Cholesky and one triangular solve against I, what the engine did before.
Shapes are those of SIP's solve (T = 1000): blocks of 102 (two frames of 51 coupled
unknowns) batched as in the first level of cyclic reduction, 24 × 24 per-frame
elimination blocks, and, on the CPU, the sequential scan's one block per step (500
steps). Keys per case: `baseline_ms`, `recursive_ms` (per base), `ratio` (recursive at
the engine's base / baseline), `max_abs_diff`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jaxmocap  # noqa: F401 - before JAX's CPU backend starts (jaxmocap._threads)
import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl

sys.path.insert(0, str(Path(__file__).parent))
from _common import machine, time_call, write_json  # noqa: E402

from jaxmocap.solve.tridiagonal import CYCLIC_BASE, SCAN_BASE, inverse_cholesky  # noqa: E402


def _baseline(S):
    eye = jnp.broadcast_to(jnp.eye(S.shape[-1], dtype=S.dtype), S.shape)
    return jsl.solve_triangular(jnp.linalg.cholesky(S), eye, lower=True)


def _spd(batch: int, n: int, seed: int = 0):
    A = jax.random.normal(jax.random.PRNGKey(seed), (batch, n, n), jnp.float32)
    return A @ jnp.swapaxes(A, -1, -2) / n + jnp.eye(n, dtype=jnp.float32)


def _scan(inv):
    """One factor per step of a `lax.scan`, as in the sequential block Cholesky."""
    return jax.jit(lambda S: jax.lax.scan(lambda c, s: (c, inv(s)), 0.0, S)[1])


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--suffix", default="")
    p.add_argument("--min-seconds", type=float, default=1.0)
    args = p.parse_args(argv)
    gpu = jax.default_backend() != "cpu"
    cases = [
        ("batched", 31250 if gpu else 250, 102, CYCLIC_BASE),
        ("batched", 125000 if gpu else 1000, 24, CYCLIC_BASE),
    ]
    if not gpu:
        cases.append(("scan", 500, 102, SCAN_BASE))
    out = {"benchmark": "inverse_cholesky", "machine": machine(), "dtype": "float32", "cases": {}}
    for mode, batch, n, engine_base in cases:
        S = _spd(batch, n)
        wrap = _scan if mode == "scan" else jax.jit
        base = time_call(wrap(_baseline), S, min_seconds=args.min_seconds)
        ref = wrap(_baseline)(S)
        rec = {}
        for b in sorted({8, 16, 32, engine_base}):
            if b < n:
                fn = wrap(lambda S, b=b: inverse_cholesky(S, b))
                rec[str(b)] = time_call(fn, S, min_seconds=args.min_seconds)["median_s"] * 1e3
        diff = float(jnp.max(jnp.abs(wrap(lambda S, b=engine_base: inverse_cholesky(S, b))(S) - ref)))
        key = f"{mode}_{batch}x{n}"
        out["cases"][key] = {
            "baseline_ms": base["median_s"] * 1e3, "recursive_ms": rec, "engine_base": engine_base,
            "ratio": rec[str(engine_base)] / (base["median_s"] * 1e3), "max_abs_diff": diff,
        }  # fmt: skip
        print(f"{key}: baseline {base['median_s'] * 1e3:.2f} ms, recursive {rec} ms, max |diff| {diff:.2e}", flush=True)
    name = "inverse_cholesky" + (f"_{args.suffix}" if args.suffix else "") + ".json"
    print(f"wrote {write_json(name, out)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
