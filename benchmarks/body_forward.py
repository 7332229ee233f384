"""Forward passes per second (vertices + joints) of `jaxmocap.forward`.

Measures the bundled default body and a 6890-vertex model in SMPL's layout at several
batch sizes, compile time reported separately, against a baseline in the same process:
a plain JAX transcription of SMPL's reference code (4x4 homogeneous transforms,
separate shape/pose products, `vmap` over the batch). Writes
benchmarks/results/body_forward[_<suffix>].json.

    python benchmarks/body_forward.py                      # CPU: batches 1, 64, 1024
    python benchmarks/body_forward.py --models smpl6890 --batches 1024 16384 --suffix gpu
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from _common import machine, peak_memory_bytes, time_call, write_json  # noqa: E402

import jaxmocap  # noqa: E402
from jaxmocap.body import SMPL_PARENTS, make_body  # noqa: E402
from jaxmocap.rotation import axis_angle_to_matrix  # noqa: E402


def smpl_layout_model(num_vertices: int = 6890, seed: int = 0):
    """A random model with SMPL's sizes and sparsity (weights on <= 4 joints per vertex)."""
    rng = np.random.default_rng(seed)
    V = num_vertices
    weights = np.zeros((V, 24), np.float32)
    for _ in range(4):
        weights[np.arange(V), rng.integers(0, 24, V)] += rng.random(V)
    weights /= weights.sum(1, keepdims=True)
    reg = np.zeros((24, V), np.float32)
    for j in range(24):
        reg[j, rng.choice(V, 30, replace=False)] = 1 / 30
    return make_body(
        rng.normal(scale=0.3, size=(V, 3)), rng.integers(0, V, (13776, 3)),
        rng.normal(scale=0.01, size=(V, 3, 10)), rng.normal(scale=0.01, size=(V, 3, 207)), reg, weights,
    )


def baseline_forward(body, pose, betas, trans):
    """SMPL's reference algorithm written plainly in JAX, one sample, 4x4 transforms."""
    v_shaped = body.v_template + jnp.einsum("kvc,k->vc", body.shapedirs[: len(betas)], betas)
    J = body.J_regressor @ v_shaped
    R = axis_angle_to_matrix(pose)
    v_posed = v_shaped + jnp.einsum("pvc,p->vc", body.posedirs, (R[1:] - jnp.eye(3)).ravel())

    def homogeneous(rot, t):
        return jnp.concatenate([jnp.concatenate([rot, t[:, None]], 1), jnp.array([[0.0, 0, 0, 1]])], 0)

    G = [homogeneous(R[0], J[0])]
    for i in range(1, 24):
        p = SMPL_PARENTS[i]
        G.append(G[p] @ homogeneous(R[i], J[i] - J[p]))
    G = jnp.stack(G)
    A = G - jnp.concatenate([jnp.zeros((24, 4, 3)), (G @ jnp.concatenate([J, jnp.zeros((24, 1))], 1)[..., None])], -1)
    T = jnp.einsum("vj,jab->vab", body.weights, A)
    v = jnp.einsum("vab,vb->va", T[:, :3], jnp.concatenate([v_posed, jnp.ones((len(v_posed), 1))], 1))
    return v + trans, G[:, :3, 3] + trans


def run(models: list[str], batches: list[int], min_seconds: float) -> dict:
    bodies = {
        "default_low": lambda: jaxmocap.default_body("low"),
        "default_full": lambda: jaxmocap.default_body("full"),
        "smpl6890": smpl_layout_model,
    }
    ours = jax.jit(lambda b, p, s, t: (lambda o: (o.vertices, o.joints))(jaxmocap.forward(b, p, s, t)))
    base = jax.jit(jax.vmap(baseline_forward, in_axes=(None, 0, 0, 0)))
    rows = []
    for name in models:
        body = bodies[name]()
        for batch in batches:
            rng = np.random.default_rng(batch)
            args = (
                body,
                jnp.asarray(rng.normal(scale=0.4, size=(batch, 24, 3)), jnp.float32),
                jnp.asarray(rng.normal(size=(batch, 10)), jnp.float32),
                jnp.asarray(rng.normal(size=(batch, 3)), jnp.float32),
            )
            t_ours = time_call(ours, *args, min_seconds=min_seconds)
            # Accuracy of the default matmul precision (TF32 on GPUs) against full float32.
            sub = (body, args[1][:64], args[2][:64], args[3][:64])
            with jax.default_matmul_precision("highest"):
                exact = jax.jit(lambda *a: ours(*a))(*sub)[0]
            error = float(jnp.abs(ours(*sub)[0] - exact).max())
            t_base = time_call(base, *args, min_seconds=min_seconds)
            row = {
                "model": name,
                "vertices": body.num_vertices,
                "batch": batch,
                "passes_per_s": batch / t_ours["median_s"],
                "baseline_passes_per_s": batch / t_base["median_s"],
                "speedup_vs_baseline": t_base["median_s"] / t_ours["median_s"],
                "max_abs_error_vs_highest_precision_m": error,
                "ours": t_ours,
                "baseline": t_base,
            }
            rows.append(row)
            print(
                f"{name:13s} V={body.num_vertices:5d} batch={batch:6d}  "
                f"{row['passes_per_s']:12.4g} passes/s  (baseline {row['baseline_passes_per_s']:.4g}, "
                f"x{row['speedup_vs_baseline']:.2f})  compile {t_ours['compile_and_first_call_s']:.2f}s  "
                f"err {error:.1e} m",
                flush=True,
            )
    return {"rows": rows, "peak_memory_bytes": peak_memory_bytes()}


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--models", nargs="+", default=["default_low", "smpl6890"])
    parser.add_argument("--batches", nargs="+", type=int, default=[1, 64, 1024])
    parser.add_argument("--min-seconds", type=float, default=1.0)
    parser.add_argument("--suffix", default="", help="results file suffix, e.g. 'gpu'")
    args = parser.parse_args()
    result = {"benchmark": "body_forward", "machine": machine(), "dtype": "float32"}
    result.update(run(args.models, args.batches, args.min_seconds))
    name = "body_forward" + (f"_{args.suffix}" if args.suffix else "") + ".json"
    print("wrote", write_json(name, result))


if __name__ == "__main__":
    main()
