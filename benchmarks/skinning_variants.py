"""Which linear-blend-skinning formulation is fastest, per backend (a design record).

`jaxmocap.forward` blends the J joint transforms densely ((V, J) x (J, 12N) product).
SMPL-family weights have at most a handful of non-zero joints per vertex, so an exact
alternative gathers only those K joints per vertex. This script times both on a
6890-vertex SMPL-layout model at several batch sizes and writes
benchmarks/results/skinning_variants[_<suffix>].json.
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


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--batches", nargs="+", type=int, default=[1, 64, 1024])
    parser.add_argument("--suffix", default="")
    args = parser.parse_args()
    body = smpl_layout_model()
    sparse, K = make_sparse(np.asarray(body.weights))
    rows = []
    for N in args.batches:
        rng = np.random.default_rng(N)
        R = jnp.asarray(np.linalg.qr(rng.normal(size=(N, 24, 3, 3)))[0], jnp.float32)
        T = jnp.concatenate([R, jnp.asarray(rng.normal(size=(N, 24, 3, 1)), jnp.float32)], -1)
        v = jnp.asarray(rng.normal(size=(N, body.num_vertices, 3)), jnp.float32)
        td = time_call(jax.jit(dense), body.weights, T, v)
        ts = time_call(jax.jit(sparse), body.weights, T, v)
        err = float(jnp.abs(jax.jit(dense)(body.weights, T, v) - jax.jit(sparse)(body.weights, T, v)).max())
        rows.append({"batch": N, "dense_s": td["median_s"], "sparse_s": ts["median_s"],
                     "sparse_over_dense": ts["median_s"] / td["median_s"], "max_abs_diff": err})
        print(f"batch {N:6d}: dense {td['median_s']*1e3:9.3f} ms  sparse(K={K}) {ts['median_s']*1e3:9.3f} ms  "
              f"ratio {rows[-1]['sparse_over_dense']:.2f}  diff {err:.1e}", flush=True)
    name = "skinning_variants" + (f"_{args.suffix}" if args.suffix else "") + ".json"
    print("wrote", write_json(name, {"benchmark": "skinning_variants", "machine": machine(), "K": K, "rows": rows}))


if __name__ == "__main__":
    main()
