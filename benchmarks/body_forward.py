"""Forward passes per second (vertices + joints) of `jaxmocap.forward`.

Measures the bundled default body and a 6890-vertex model in SMPL's layout at several
batch sizes, compile time reported separately, against baselines in the same process:

- plain JAX: a transcription of SMPL's reference code (4x4 homogeneous transforms,
  separate shape/pose products, `vmap` over the batch);
- smplx (PyTorch, float32, no_grad, one torch thread per core) built from the same arrays
  through its own loader, timed on CPU runs when `import smplx, torch` works; its vertices
  are checked against ours. Install with `pip install -e '.[bench]'`, or, to keep PyPI's
  CUDA builds of torch out: `pip install torch==2.13.0 --index-url
  https://download.pytorch.org/whl/cpu` then `pip install --no-deps smplx` (smplx needs
  only torch and numpy).

Variants of our forward are timed in the same run (`--variants`, `--variant-batches`):
skinning dense (`_skin_dense`) or over each vertex's non-zero weights (`_skin_sparse`),
shape and pose blend shapes as one product or two, bfloat16 blend-shape bases (with
their error against full float32, in mm), and the stacked product without the zero
columns that accelerators add (`unpadded_blend`, the path before 2026-11-26); and the
library forward with the body closed over by jit (`closure_body`, how users write it).
`passes_per_s_6890` is the library forward's best over the batches on the 6890-vertex
model. A batch that does not fit in memory is recorded as such, not fatal. Writes
benchmarks/results/body_forward[_<suffix>].json.

    python benchmarks/body_forward.py                      # CPU: batches 1, 64, 1024
    python benchmarks/body_forward.py --models smpl6890 default_full --batches 1024 4096 16384 65536 --suffix gpu
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import pickle
import sys
import tempfile
import time
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from _common import machine, peak_memory_bytes, time_call, write_json  # noqa: E402

import jaxmocap  # noqa: E402
from jaxmocap.body import SMPL_PARENTS, make_body  # noqa: E402
from jaxmocap.body import kinematics  # noqa: E402
from jaxmocap.body.kinematics import forward_rotations_unchecked  # noqa: E402
from jaxmocap.rotation import axis_angle_to_matrix  # noqa: E402

#: Variants of our forward: options of `forward_rotations_unchecked`. "bf16_blend" also stores the
#: blend-shape bases in bfloat16 (the body's other leaves stay float32).
VARIANTS = {
    "dense": {"skinning": "dense"},
    "sparse": {"skinning": "sparse"},
    "split_blend": {"joint_blend": False},
    "joint_blend": {"joint_blend": True},
    "bf16_blend": {"blend_dtype": jnp.bfloat16},
    "unpadded_blend": {"pad_columns": False},
}
# The library's own choices are not repeated: on accelerators it skins sparsely with one
# blend product (from 256 samples), on the CPU densely.
GPU_VARIANTS = ["dense", "split_blend", "bf16_blend", "unpadded_blend", "closure_body"]
CPU_VARIANTS = ["sparse"]
ERROR_SAMPLES = 64


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
        rng.normal(scale=0.3, size=(V, 3)),
        rng.integers(0, V, (13776, 3)),
        rng.normal(scale=0.01, size=(V, 3, 10)),
        rng.normal(scale=0.01, size=(V, 3, 207)),
        reg,
        weights,
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


def _variant(options: dict):
    def run(body, pose, betas, trans):
        out = forward_rotations_unchecked(body, axis_angle_to_matrix(pose), betas, trans, **options)
        return out.vertices, out.joints

    return jax.jit(run)


def _closure_variant():
    """The library forward jitted with the body closed over (a constant of the program), as
    users write it; one compiled function per body."""
    compiled = {}

    def run(body, pose, betas, trans):
        if id(body) not in compiled:
            compiled[id(body)] = jax.jit(
                lambda p, s, t: (lambda o: (o.vertices, o.joints))(jaxmocap.forward(body, p, s, t))
            )
        return compiled[id(body)](pose, betas, trans)

    return run


def _bf16_bases(body):
    """The body with its blend-shape bases stored in bfloat16."""
    return eqx.tree_at(
        lambda b: (b.shapedirs, b.posedirs),
        body,
        (body.shapedirs.astype(jnp.bfloat16), body.posedirs.astype(jnp.bfloat16)),
    )


def _is_out_of_memory(error: Exception) -> bool:
    text = str(error)
    return "RESOURCE_EXHAUSTED" in text or "out of memory" in text.lower() or "Out of memory" in text


def _timed(fn, *args, min_seconds: float) -> dict:
    """`time_call`, with an out-of-memory failure recorded instead of raised."""
    try:
        return time_call(fn, *args, min_seconds=min_seconds)
    except Exception as e:  # XlaRuntimeError and friends; anything else is re-raised
        if not _is_out_of_memory(e):
            raise
        return {"error": "out of memory", "detail": str(e).splitlines()[0][:300]}


class Smplx:
    """smplx.SMPL built from a body's arrays through smplx's own loader (a temporary
    SMPL-layout .pkl), float32 on the CPU."""

    def __init__(self, body):
        import smplx
        import torch
        from smplx.vertex_ids import vertex_ids

        self.torch = torch
        torch.set_num_threads(os.cpu_count() or 1)
        arrays = {
            "v_template": np.asarray(body.v_template, np.float64),
            "shapedirs": np.moveaxis(np.asarray(body.shapedirs, np.float64), 0, -1),  # (V, 3, B)
            "posedirs": np.moveaxis(np.asarray(body.posedirs, np.float64), 0, -1),  # (V, 3, 207)
            "J_regressor": np.asarray(body.J_regressor, np.float64),
            "weights": np.asarray(body.weights, np.float64),
            "kintree_table": np.stack([np.array(body.parents), np.arange(body.num_joints)]),
            "f": body.faces.astype(np.int64),
        }
        # smplx appends 21 vertex-picked keypoints (SMPL-H vertex ids); on other meshes
        # point them at vertex 0 so that they exist (their cost is the same).
        ids = vertex_ids["smplh"] if body.num_vertices == 6890 else {k: 0 for k in vertex_ids["smplh"]}
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "SMPL_NEUTRAL.pkl"
            path.write_bytes(pickle.dumps(arrays))
            with contextlib.redirect_stdout(io.StringIO()):  # its "only 10 shape coefficients" note
                self.model = smplx.SMPL(str(path), num_betas=body.num_betas, vertex_ids=ids, dtype=torch.float32)
        self.model.eval()

    def __call__(self, pose, betas, trans):
        t = self.torch
        with t.no_grad():
            p = t.from_numpy(np.array(pose, np.float32).reshape(len(pose), -1))
            out = self.model(
                betas=t.from_numpy(np.array(betas, np.float32)),
                global_orient=p[:, :3],
                body_pose=p[:, 3:],
                transl=t.from_numpy(np.array(trans, np.float32)),
            )
            return out.vertices, out.joints

    def time(self, pose, betas, trans, min_seconds: float) -> dict:
        start = time.perf_counter()
        self(pose, betas, trans)
        first = time.perf_counter() - start
        times = []
        while sum(times) < min_seconds and len(times) < 1000:
            t0 = time.perf_counter()
            self(pose, betas, trans)
            times.append(time.perf_counter() - t0)
        times.sort()
        return {
            "compile_and_first_call_s": first,
            "median_s": times[len(times) // 2],
            "min_s": times[0],
            "repeats": len(times),
        }


def _smplx_status(backend: str) -> tuple[bool, str | None, dict]:
    if backend != "cpu":
        return False, "smplx is timed on CPU runs only (run this script on the CPU for that comparison)", {}
    try:
        import smplx
        import torch
    except ImportError as e:
        return False, f"smplx/torch not importable ({e}); pip install -e '.[bench]'", {}
    return (
        True,
        None,
        {"torch": torch.__version__, "smplx": getattr(smplx, "__version__", None) or _dist_version("smplx")},
    )


def _dist_version(name: str) -> str | None:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(name)
    except PackageNotFoundError:
        return None


def run(
    models: list[str],
    batches: list[int],
    min_seconds: float,
    variant_seconds: float,
    variants: list[str],
    variant_batches: list[int],
) -> dict:
    bodies = {
        "default_low": lambda: jaxmocap.default_body("low"),
        "default_full": lambda: jaxmocap.default_body("full"),
        "smpl6890": smpl_layout_model,
    }
    backend = jax.default_backend()
    use_smplx, smplx_reason, smplx_versions = _smplx_status(backend)
    ours = jax.jit(lambda b, p, s, t: (lambda o: (o.vertices, o.joints))(jaxmocap.forward(b, p, s, t)))
    base = jax.jit(jax.vmap(baseline_forward, in_axes=(None, 0, 0, 0)))
    exact_fn = _variant({"skinning": "dense"})  # compiled once per model (ERROR_SAMPLES shapes)
    variant_fns = {name: _variant(VARIANTS[name]) for name in VARIANTS} | {"closure_body": _closure_variant()}
    rows = []
    for name in models:
        body = bodies[name]()
        bf16_body = _bf16_bases(body)
        reference = Smplx(body) if use_smplx else None
        for batch in batches:
            rng = np.random.default_rng(batch)
            args = (
                body,
                jnp.asarray(rng.normal(scale=0.4, size=(batch, 24, 3)), jnp.float32),
                jnp.asarray(rng.normal(size=(batch, 10)), jnp.float32),
                jnp.asarray(rng.normal(size=(batch, 3)), jnp.float32),
            )
            sub = (body, *(a[:ERROR_SAMPLES] for a in args[1:]))
            with jax.default_matmul_precision("highest"):
                # Full float32 everywhere: the reference for the errors below.
                exact = exact_fn(*sub)[0]
            t_ours = _timed(ours, *args, min_seconds=min_seconds)
            # Accuracy of the default matmul precision (TF32 on GPUs) against full float32.
            error = float(jnp.abs(ours(*sub)[0] - exact).max())
            t_base = _timed(base, *args, min_seconds=min_seconds)
            row = {
                "model": name,
                "vertices": body.num_vertices,
                "max_influences": body.max_influences,
                "batch": batch,
                "passes_per_s": batch / t_ours["median_s"] if "median_s" in t_ours else None,
                "baseline_passes_per_s": batch / t_base["median_s"] if "median_s" in t_base else None,
                "max_abs_error_vs_highest_precision_m": error,
                "ours": t_ours,
                "baseline": t_base,
            }
            if row["passes_per_s"] and row["baseline_passes_per_s"]:
                row["speedup_vs_baseline"] = t_base["median_s"] / t_ours["median_s"]
            if reference is not None:
                host = [np.asarray(a) for a in args[1:]]
                t_smplx = reference.time(*host, min_seconds=min_seconds)
                v_smplx, j_smplx = reference(*(a[:ERROR_SAMPLES] for a in host))
                v_ours, j_ours = ours(*sub)
                row["smplx_passes_per_s"] = batch / t_smplx["median_s"]
                row["speedup_vs_smplx"] = t_smplx["median_s"] / t_ours["median_s"] if "median_s" in t_ours else None
                row["smplx_max_abs_vertex_diff_m"] = float(np.abs(v_smplx.numpy() - np.asarray(v_ours)).max())
                row["smplx_max_abs_joint_diff_m"] = float(np.abs(j_smplx.numpy()[:, :24] - np.asarray(j_ours)).max())
                row["smplx"] = t_smplx
            row["variants"] = {}
            for variant in variants if batch in variant_batches else ():
                vbody = bf16_body if variant == "bf16_blend" else body
                vargs = (vbody, *args[1:])
                timing = _timed(variant_fns[variant], *vargs, min_seconds=variant_seconds)
                err = float(jnp.abs(variant_fns[variant](vbody, *sub[1:])[0] - exact).max())
                row["variants"][variant] = {
                    "passes_per_s": batch / timing["median_s"] if "median_s" in timing else None,
                    "max_abs_error_vs_highest_precision_mm": 1e3 * err,
                    **timing,
                }
            if "bf16_blend" not in row["variants"]:
                # Its error alone (XLA-CPU's bfloat16 products are slow, not worth timing).
                err = float(jnp.abs(variant_fns["bf16_blend"](bf16_body, *sub[1:])[0] - exact).max())
                row["bf16_blend_max_abs_error_mm"] = 1e3 * err
            rows.append(row)
            fmt = lambda x: f"{x:10.4g}" if x else "      None"  # noqa: E731
            line = (
                f"{name:13s} V={body.num_vertices:5d} batch={batch:6d}  {fmt(row['passes_per_s'])} passes/s  "
                f"(plain JAX {fmt(row['baseline_passes_per_s'])}"
            )
            if "smplx_passes_per_s" in row:
                line += f", smplx {fmt(row['smplx_passes_per_s'])}, diff {row['smplx_max_abs_vertex_diff_m']:.1e} m"
            line += f")  compile {t_ours.get('compile_and_first_call_s', float('nan')):.2f}s  err {error:.1e} m"
            for variant, v in row["variants"].items():
                line += f"\n    {variant:12s} {fmt(v['passes_per_s'])} passes/s  err {v['max_abs_error_vs_highest_precision_mm']:.1e} mm"
            print(line, flush=True)
    result = {"rows": rows, "peak_memory_bytes": peak_memory_bytes()}
    result.update(_summary(rows, smplx_reason))
    result["library_path"] = {
        "skinning": "dense" if backend == "cpu" else "sparse (each vertex's max_influences non-zero weights)",
        "blend_shapes": f"one product [betas, pose feature] @ stacked bases from {kinematics._JOINT_BLEND_MIN_BATCH} samples, two below",
    }
    result["versions"] = {
        "jax": jax.__version__,
        "jaxlib": _dist_version("jaxlib"),
        "equinox": eqx.__version__,
        "numpy": np.__version__,
        **smplx_versions,
    }
    return result


def _summary(rows: list[dict], smplx_reason: str | None) -> dict:
    """Top-level numbers on the 6890-vertex model: best batch of the library forward."""
    timed = [r for r in rows if r["model"] == "smpl6890" and r["passes_per_s"]]
    if not timed:
        return {"passes_per_s_6890": None, "best_batch_6890": None}
    best = max(timed, key=lambda r: r["passes_per_s"])
    out = {
        "passes_per_s_6890": best["passes_per_s"],
        "best_batch_6890": best["batch"],
        "baseline_plain_jax_passes_per_s_6890": best["baseline_passes_per_s"],
        "smplx_passes_per_s_6890": best.get("smplx_passes_per_s"),
        "speedup_vs_smplx": best.get("speedup_vs_smplx"),
    }
    if smplx_reason:
        out["smplx_unavailable_reason"] = smplx_reason
    else:
        # smplx at its own best batch too: the ratio above is at our best batch.
        best_smplx = max(timed, key=lambda r: r["smplx_passes_per_s"])
        out["smplx_best_passes_per_s_6890"] = best_smplx["smplx_passes_per_s"]
        out["smplx_best_batch_6890"] = best_smplx["batch"]
        out["speedup_vs_smplx_each_batch_6890"] = {str(r["batch"]): r["speedup_vs_smplx"] for r in timed}
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--models", nargs="+", default=["default_low", "smpl6890"])
    parser.add_argument(
        "--batches",
        nargs="+",
        type=int,
        default=None,
        help="batch sizes (default: 1 64 1024 on the CPU, 1024 4096 16384 65536 131072 on accelerators)",
    )
    parser.add_argument("--min-seconds", type=float, default=1.0)
    parser.add_argument("--variant-seconds", type=float, default=0.3, help="timing per variant (after its compile)")
    parser.add_argument(
        "--variants",
        nargs="*",
        choices=[*VARIANTS, "closure_body"],
        default=None,
        help=f"variants to time (default: {' '.join(GPU_VARIANTS)} on accelerators, {' '.join(CPU_VARIANTS)} on the CPU)",
    )
    parser.add_argument(
        "--variant-batches",
        nargs="*",
        type=int,
        default=None,
        help="batches at which variants are timed (default: the two largest on accelerators, all on the CPU)",
    )
    parser.add_argument("--suffix", default="", help="results file suffix, e.g. 'gpu'")
    args = parser.parse_args()
    cpu = jax.default_backend() == "cpu"
    batches = args.batches or ([1, 64, 1024] if cpu else [1024, 4096, 16384, 65536, 131072])
    variants = args.variants
    if variants is None:
        variants = CPU_VARIANTS if cpu else GPU_VARIANTS
    variant_batches = args.variant_batches
    if variant_batches is None:
        variant_batches = batches if cpu else sorted(batches)[-2:]
    result = {"benchmark": "body_forward", "machine": machine(), "dtype": "float32"}
    result.update(run(args.models, batches, args.min_seconds, args.variant_seconds, variants, variant_batches))
    name = "body_forward" + (f"_{args.suffix}" if args.suffix else "") + ".json"
    print("wrote", write_json(name, result))


if __name__ == "__main__":
    main()
