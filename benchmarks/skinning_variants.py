"""Which linear-blend-skinning formulation is fastest, per backend (a design record).

Blending the J joint transforms densely is a (V, J) x (J, 12N) product; SMPL-family
weights have at most a handful of non-zero joints per vertex, so an exact alternative
gathers only those K joints per vertex (`jaxmocap.forward` does this on accelerators and
the dense product on CPUs). This script times both on a 6890-vertex SMPL-layout model at
several batch sizes and writes benchmarks/results/skinning_variants[_<suffix>].json.

Beside them, in the same run: the library's sparse loop (`kinematics._blend_sparse`) on
the random model's weights and on the default body's (its first 6890 vertices: spatially
coherent, as a scanned body's are, so neighbouring vertices gather the same joints), and
the memory floor: one elementwise pass that reads the posed vertices and writes as many
(`floor_s`). On one H100 (skinning_variants_gpu.json) the library loop took 8.37 ms at
65536 samples with either weights, 2.2x the floor's 3.85 ms (2.08 against 1.08 ms at
16384): gather coherence does not matter, and in a probe neither did a planar (N, 3, V)
layout nor half-width inputs (8.2-8.8 ms). The loop issues about 27 loads per output
coordinate (16 of them gathered transform entries), which at the L1's rate is its time;
only a kernel that keeps a vertex's joints and a sample's transforms in registers could
reach the floor (`fused_skinning.py`).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from _common import machine, time_call, write_json  # noqa: E402
from body_forward import smpl_layout_model  # noqa: E402

from jaxmocap.body import kinematics  # noqa: E402
from jaxmocap.body.io import default_body  # noqa: E402


def dense(weights, transforms, v_posed):
    N, J = transforms.shape[:2]
    blended = (weights @ transforms.reshape(N, J, 12)).reshape(N, -1, 3, 4)
    return jnp.einsum("nvab,nvb->nva", blended[..., :3], v_posed) + blended[..., 3]


def make_sparse(weights_np):
    nonzero = weights_np != 0
    K = int(nonzero.sum(1).max())
    support = np.argsort(~nonzero, axis=1, kind="stable")[:, :K]

    def sparse(weights, transforms, v_posed):
        w = jnp.take_along_axis(weights, jnp.asarray(support), axis=1)
        g = transforms[:, support]  # (N, V, K, 3, 4)
        rotated = jnp.sum(g[..., :3] * v_posed[:, :, None, None, :], axis=-1) + g[..., 3]
        return jnp.einsum("vk,nvka->nva", w, rotated)

    return sparse, K


def library(weights, influences: int):
    """The library's sparse loop over each vertex's `influences` largest weights."""
    return lambda T, v: kinematics._blend_sparse(weights, T, v, influences)


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--batches", nargs="+", type=int, default=[1, 64, 1024])
    parser.add_argument("--suffix", default="")
    args = parser.parse_args()
    body = smpl_layout_model()
    sparse, K = make_sparse(np.asarray(body.weights))
    coherent = default_body("full").weights[: body.num_vertices]
    coherent = coherent / coherent.sum(1, keepdims=True)
    variants = {"library_random_weights": library(body.weights, K), "library_default_body_weights": library(coherent, K),
                "floor": lambda T, v: v * 1.0001 + 1.0}  # fmt: skip
    rows = []
    for N in args.batches:
        rng = np.random.default_rng(N)
        R = jnp.asarray(np.linalg.qr(rng.normal(size=(N, 24, 3, 3)))[0], jnp.float32)
        T = jnp.concatenate([R, jnp.asarray(rng.normal(size=(N, 24, 3, 1)), jnp.float32)], -1)
        v = jnp.asarray(rng.normal(size=(N, body.num_vertices, 3)), jnp.float32)
        td = time_call(jax.jit(dense), body.weights, T, v)
        ts = time_call(jax.jit(sparse), body.weights, T, v)
        err = float(jnp.abs(jax.jit(dense)(body.weights, T, v) - jax.jit(sparse)(body.weights, T, v)).max())
        row = {"batch": N, "dense_s": td["median_s"], "sparse_s": ts["median_s"],
               "sparse_over_dense": ts["median_s"] / td["median_s"], "max_abs_diff": err}  # fmt: skip
        for name, fn in variants.items():
            row[f"{name}_s"] = time_call(jax.jit(fn), T, v)["median_s"]
        for name in variants:
            row[f"{name}_over_floor"] = row[f"{name}_s"] / row["floor_s"]
        rows.append(row)
        print(
            f"batch {N:6d}: dense {td['median_s'] * 1e3:9.3f} ms  sparse(K={K}) {ts['median_s'] * 1e3:9.3f} ms  "
            f"ratio {row['sparse_over_dense']:.2f}  diff {err:.1e}",
            flush=True,
        )
        print("    " + "  ".join(f"{name} {row[f'{name}_s']*1e3:.3f} ms ({row[f'{name}_over_floor']:.2f}x floor)"
                                 for name in variants), flush=True)  # fmt: skip
    name = "skinning_variants" + (f"_{args.suffix}" if args.suffix else "") + ".json"
    print("wrote", write_json(name, {"benchmark": "skinning_variants", "machine": machine(), "K": K, "rows": rows}))


if __name__ == "__main__":
    main()
