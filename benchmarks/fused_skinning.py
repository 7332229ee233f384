"""Can one Pallas (Triton) GPU kernel beat XLA at the body forward? (a design record)

`jaxmocap.forward` on a GPU is a cuBLAS product for the blend shapes, T̄ + [β, vec(R − I)]
· [𝒮; 𝒫] (Huang eq. 2.2-2.3), that writes the rest-pose vertices, then an XLA loop that
reads them back and skins them over each vertex's K non-zero weights (eq. 2.4, gathering
the joint transforms). This script times those two stages apart and against Pallas
kernels that fuse them, on the 6890-vertex SMPL-layout model of body_forward.py:

- `input_*`: a skinning kernel on the cuBLAS product's output (saves XLA's loop only);
- `gemm_*`: the blend product inside the kernel as well (tensor-core TF32 tiles), so the
  rest-pose vertices never reach memory;
- `*_gather`: skinning over the K largest weights, the transforms gathered per vertex;
  `*_dense`: skinning as products against all J weights in three bfloat16 products
  (hi·hi + hi·lo + lo·hi, float32-accurate); `gemm_none`: the blend product alone.

Each kernel is timed over a few tile shapes (samples x vertices, warps, launch order);
the best is reported with its error against full float32. XLA's `blend_product_alone` is
the 217-deep product as the "input" kernels get it (the library pads the depth to 224,
about 1.35x faster on an H200; a probe on one H100 ran that one at 2.07e7 passes/s).

Measured on one H100 (batch 65536, results/fused_skinning_gpu.json): the library forward
5.39e6 passes/s, XLA's skinning loop alone 7.35e6; the best kernel (`input_dense`)
3.68e6, 0.68x the library; the kernel's own TF32 blend tiles alone 6.19e6. Not adopted:
XLA's gather loop and cuBLAS outrun these Triton tiles, and the skinning loop (about
three quarters of the forward's time) stays where the forward's time goes. Writes
benchmarks/results/fused_skinning_gpu.json. Needs a CUDA GPU; `--check` runs every
kernel in Pallas's interpreter on a small model instead (any machine).

    python benchmarks/fused_skinning.py            # CUDA GPU
    python benchmarks/fused_skinning.py --check    # correctness, CPU
"""

from __future__ import annotations

import argparse
import functools
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from _common import machine, time_call, write_json  # noqa: E402
from body_forward import smpl_layout_model  # noqa: E402

from jaxmocap.body import kinematics as K  # noqa: E402
from jaxmocap.rotation import axis_angle_to_matrix  # noqa: E402

K_STEP = 32  # coefficients per tensor-core product in the kernel's blend loop
INFLUENCES = 4  # smpl_layout_model's most non-zero weights per vertex
VARIANTS = [("input", "gather"), ("input", "dense"), ("gemm", "gather"), ("gemm", "dense"), ("gemm", "none")]
# (samples, vertices, warps, launch order) per tile; the first probes on one H100 kept these.
TILES = [(16, 128, 4, "samples"), (32, 64, 4, "samples"), (32, 128, 4, "vertices"), (64, 64, 4, "samples"),
         (64, 64, 4, "vertices"), (128, 64, 8, "samples")]  # fmt: skip


def _round_up(n: int, m: int) -> int:
    return -(-n // m) * m


def _split(x):
    """x = hi + lo + O(2⁻¹⁶|x|), both bfloat16. The high part by masking the low mantissa
    bits: XLA and Triton may drop a float32 → bfloat16 → float32 round trip (excess
    precision), which made lo = 0 and cost 2.4 mm in a first probe."""
    hi = jax.lax.bitcast_convert_type(jax.lax.bitcast_convert_type(x, jnp.uint32) & jnp.uint32(0xFFFF0000), jnp.float32)
    return hi.astype(jnp.bfloat16), (x - hi).astype(jnp.bfloat16)


def _kernel(*refs, n, v, blend, skin, order):
    from jax.experimental import pallas as pl
    from jax.experimental.pallas import triton as plgpu

    refs, out_ref = list(refs[:-1]), refs[-1]
    bn, vb = out_ref.shape[0], out_ref.shape[1]
    i, j = (pl.program_id(0), pl.program_id(1)) if order == "samples" else (pl.program_id(1), pl.program_id(0))
    mask = (((i * bn + jnp.arange(bn)) < n)[:, None] & ((j * vb + jnp.arange(vb)) < v)[None, :])[:, :, None]
    template_ref = refs.pop(0)
    if blend == "gemm":
        coeff_ref, bases_ref = refs.pop(0), refs.pop(0)

        def step(k, accs):
            ks = pl.ds(pl.multiple_of(k * K_STEP, K_STEP), K_STEP)
            c = coeff_ref[:, ks]
            return tuple(acc + jnp.dot(c, bases_ref[b, ks, :], preferred_element_type=jnp.float32)
                         for b, acc in enumerate(accs))  # fmt: skip

        zero = jnp.zeros((bn, vb), jnp.float32)
        accs = jax.lax.fori_loop(0, coeff_ref.shape[1] // K_STEP, step, (zero,) * 3)
        rest = [template_ref[b, :][None, :] + accs[b] for b in range(3)]
    else:  # the cuBLAS product's (samples, 3 x vertices) rows, coordinates interleaved
        offsets_ref = refs.pop(0)
        rest = [template_ref[b, :][None, :] + offsets_ref[:, pl.ds(b, vb, stride=3)] for b in range(3)]
    if skin == "none":
        outs = rest
    elif skin == "dense":
        w_hi_ref, w_lo_ref, a_hi_ref, a_lo_ref, trans_ref = refs
        w_hi, w_lo = w_hi_ref[...], w_lo_ref[...]
        dot = functools.partial(jnp.dot, preferred_element_type=jnp.float32)

        def blended(e):  # transform entry e blended over all joints, (bn, vb)
            return dot(a_hi_ref[e], w_hi) + dot(a_hi_ref[e], w_lo) + dot(a_lo_ref[e], w_hi)

        outs = [trans_ref[a, :][:, None] + blended(4 * a + 3) + sum(blended(4 * a + b) * rest[b] for b in range(3))
                for a in range(3)]  # fmt: skip
    else:  # gather
        joints_ref, w_ref, a_ref, trans_ref = refs
        r = jnp.broadcast_to(jnp.arange(bn, dtype=jnp.int32)[:, None], (bn, vb))
        outs = [jnp.broadcast_to(trans_ref[a, :][:, None], (bn, vb)) for a in range(3)]
        for k in range(joints_ref.shape[0]):
            jk = jnp.broadcast_to(joints_ref[k, :][None, :], (bn, vb))
            wk = w_ref[k, :][None, :]
            for a in range(3):
                g = [a_ref[4 * a + b, r, jk] for b in range(4)]
                outs[a] = outs[a] + wk * (g[0] * rest[0] + g[1] * rest[1] + g[2] * rest[2] + g[3])
    for a in range(3):
        plgpu.store(out_ref.at[:, :, pl.ds(a, 1)], outs[a][:, :, None], mask=mask)


def posed(
    coeff_bases,
    template,
    weights,
    coeffs,
    offsets,
    transforms,
    trans,
    blend: str,
    skin: str,
    tile,
    interpret: bool = False,
):
    """Posed vertices (N, V, 3) by one kernel. coeff_bases (K, V, 3), template (V, 3),
    weights (V, J); coeffs (N, K) (blend "gemm") or offsets (N, 3Vp), the product's rows
    for Vp a multiple of the tile's vertices (blend "input"); transforms (N, J, 3, 4)."""
    from jax.experimental import pallas as pl
    from jax.experimental.pallas import triton as plgpu

    bs, bv, warps, order = tile
    N, J = transforms.shape[:2]
    V = template.shape[0]
    Vp, Jp, Np = _round_up(V, bv), _round_up(J, 16), _round_up(N, bs)
    pad_v = lambda x: jnp.pad(x, [(0, 0)] * (x.ndim - 1) + [(0, Vp - x.shape[-1])])  # noqa: E731
    ij = (lambda f: f) if order == "samples" else (lambda f: lambda j, i: f(i, j))  # noqa: E731
    spec = lambda shape, f: pl.BlockSpec(shape, ij(f))  # noqa: E731
    args, specs = [pad_v(template.T)], [spec((3, bv), lambda i, j: (0, j))]
    if blend == "gemm":
        Kp = _round_up(coeff_bases.shape[0], K_STEP)
        args += [
            jnp.pad(coeffs, ((0, Np - N), (0, Kp - coeffs.shape[1]))),
            pad_v(jnp.pad(jnp.moveaxis(coeff_bases, -1, 0), ((0, 0), (0, Kp - coeff_bases.shape[0]), (0, 0)))),
        ]
        specs += [spec((bs, Kp), lambda i, j: (i, 0)), spec((3, Kp, bv), lambda i, j: (0, 0, j))]
    else:
        args += [jnp.pad(offsets, ((0, Np - N), (0, 0)))]
        specs += [spec((bs, 3 * bv), lambda i, j: (i, j))]
    A = jnp.pad(transforms.reshape(N, J, 12).transpose(2, 0, 1), ((0, 0), (0, Np - N), (0, Jp - J)))
    tr = jnp.pad(trans.T, ((0, 0), (0, Np - N)))
    if skin == "dense":
        args += [*_split(pad_v(jnp.pad(weights.T, ((0, Jp - J), (0, 0))))), *_split(A), tr]
        specs += [spec((Jp, bv), lambda i, j: (0, j))] * 2 + [spec((12, bs, Jp), lambda i, j: (0, i, 0))] * 2
        specs += [spec((3, bs), lambda i, j: (0, i))]
    elif skin == "gather":
        w, joints = jax.lax.top_k(weights, INFLUENCES)
        args += [pad_v(joints.T.astype(jnp.int32)), pad_v(w.T), A, tr]
        specs += [spec((INFLUENCES, bv), lambda i, j: (0, j))] * 2
        specs += [spec((12, bs, Jp), lambda i, j: (0, i, 0)), spec((3, bs), lambda i, j: (0, i))]
    grid = (Np // bs, Vp // bv) if order == "samples" else (Vp // bv, Np // bs)
    return pl.pallas_call(
        functools.partial(_kernel, n=N, v=V, blend=blend, skin=skin, order=order),
        out_shape=jax.ShapeDtypeStruct((N, V, 3), jnp.float32), grid=grid,
        in_specs=specs, out_specs=spec((bs, bv, 3), lambda i, j: (i, j, 0)),
        compiler_params=plgpu.CompilerParams(num_warps=warps, num_stages=3), interpret=interpret,
    )(*args)  # fmt: skip


def _inputs(body, N: int, seed: int = 0) -> dict:
    """Coefficients, the blend product's padded rows, transforms and translations of N
    random poses (the body forward's own intermediate arrays)."""
    rng = np.random.default_rng(seed)
    pose = jnp.asarray(rng.normal(scale=0.4, size=(N, 24, 3)), jnp.float32)
    betas = jnp.asarray(rng.normal(size=(N, 10)), jnp.float32)
    R = axis_angle_to_matrix(pose)
    rest = K.shaped_joints(body, betas)
    G_R, G_t = K.forward_kinematics(body.parents, R, rest)
    return {"R": R, "betas": betas, "trans": jnp.asarray(rng.normal(size=(N, 3)), jnp.float32),
            "coeffs": jnp.concatenate([betas, (R[:, 1:] - jnp.eye(3)).reshape(N, -1)], -1),
            "transforms": jnp.concatenate([G_R, (G_t - K.mat3_apply(G_R, rest))[..., None]], -1)}  # fmt: skip


def _product(coeff_bases, coeffs, vertices_to: int):
    """The blend product as the library runs it on a GPU: rows (N, 3·vertices_to), zero
    columns past the real vertices."""
    bases = jnp.pad(coeff_bases, ((0, 0), (0, vertices_to - coeff_bases.shape[1]), (0, 0)))
    return coeffs @ bases.reshape(len(bases), -1)


def _kernel_fn(blend, skin, tile, interpret=False):
    def run(coeff_bases, template, weights, x):
        offsets = (
            _product(coeff_bases, x["coeffs"], _round_up(template.shape[0], tile[1])) if blend == "input" else None
        )
        return posed(coeff_bases, template, weights, x["coeffs"], offsets, x["transforms"], x["trans"], blend, skin,
                     tile, interpret)  # fmt: skip

    return run if interpret else jax.jit(run)


def _arrays(body):
    return jnp.concatenate([body.shapedirs[:10], body.posedirs]), body.v_template, body.weights


def check(num_vertices: int = 500, samples: int = 40) -> float:
    """Every kernel in Pallas's interpreter against the library forward; the largest error (m)."""
    body = smpl_layout_model(num_vertices)
    x = _inputs(body, samples)
    reference = K.forward_rotations_unchecked(body, x["R"], x["betas"], x["trans"]).vertices
    worst = 0.0
    for blend, skin in VARIANTS:
        if skin == "none":
            continue
        out = _kernel_fn(blend, skin, (32, 64, 4, "samples"), interpret=True)(*_arrays(body), x)
        err = float(jnp.abs(out - reference).max())
        print(f"{blend}_{skin}: max |error| {err:.2e} m", flush=True)
        worst = max(worst, err)
    return worst


def run(batch: int, min_seconds: float) -> dict:
    body = smpl_layout_model()
    arrays = _arrays(body)
    x = _inputs(body, batch)
    sub = {k: v[:1024] for k, v in x.items()}
    with jax.default_matmul_precision("highest"):
        exact = jax.jit(lambda b, R, s, t: K.forward_rotations_unchecked(b, R, s, t, skinning="dense").vertices)(
            body, sub["R"], sub["betas"], sub["trans"]
        )
    error_mm = lambda out: 1e3 * float(jnp.abs(out - exact).max())  # noqa: E731
    rate = lambda t: batch / t["median_s"]  # noqa: E731
    # XLA's stages, as the library runs them (the body an argument, as in body_forward.py)
    library = jax.jit(lambda b, R, s, t: K.forward_rotations_unchecked(b, R, s, t).vertices)
    Vp = _round_up(body.num_vertices, 128)
    product = jax.jit(functools.partial(_product, vertices_to=Vp))
    offsets = product(arrays[0], x["coeffs"])
    skin = jax.jit(lambda b, o, A, t: K._skin(K._unfolded(b), A, (b.v_template.reshape(-1) + o[:, : 3 * b.num_vertices])
                                                .reshape(len(o), -1, 3)) + t[:, None])  # fmt: skip
    xla = {
        "library_forward": rate(time_call(library, body, x["R"], x["betas"], x["trans"], min_seconds=min_seconds)),
        "blend_product_alone": rate(time_call(product, arrays[0], x["coeffs"], min_seconds=min_seconds)),
        "skinning_alone": rate(time_call(skin, body, offsets, x["transforms"], x["trans"], min_seconds=min_seconds)),
        "library_error_mm": error_mm(library(body, sub["R"], sub["betas"], sub["trans"])),
    }
    print("XLA:", {k: f"{v:.3e}" for k, v in xla.items()}, flush=True)
    kernels = {}
    for blend, skin in VARIANTS:
        rows = []
        for tile in TILES:
            fn = _kernel_fn(blend, skin, tile)
            try:
                t = time_call(fn, *arrays, x, min_seconds=min_seconds)
            except Exception as e:  # a tile that does not compile or fit is recorded, not fatal
                rows.append({"tile": list(tile), "error": str(e).splitlines()[0][:200]})
                continue
            rows.append({"tile": list(tile), "passes_per_s": rate(t), "compile_s": t["compile_and_first_call_s"]})
            print(f"{blend}_{skin} {tile}: {rate(t):.3e} passes/s", flush=True)
        timed = [r for r in rows if "passes_per_s" in r]
        best = max(timed, key=lambda r: r["passes_per_s"]) if timed else None
        entry = {"tiles": rows, "best_passes_per_s": best and best["passes_per_s"], "best_tile": best and best["tile"]}
        if best and skin != "none":
            entry["error_mm"] = error_mm(_kernel_fn(blend, skin, tuple(best["tile"]))(*arrays, sub))
        kernels[f"{blend}_{skin}"] = entry
    best_kernel = max((k for k in kernels if "_none" not in k and kernels[k]["best_passes_per_s"]),
                      key=lambda k: kernels[k]["best_passes_per_s"], default=None)  # fmt: skip
    return {
        "batch": batch,
        "xla_passes_per_s": xla,
        "kernels": kernels,
        "best_kernel": best_kernel,
        "best_kernel_vs_library": best_kernel and kernels[best_kernel]["best_passes_per_s"] / xla["library_forward"],
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--batch", type=int, default=65536)
    parser.add_argument("--min-seconds", type=float, default=0.3)
    parser.add_argument("--check", action="store_true", help="run the kernels in Pallas's interpreter (any machine)")
    args = parser.parse_args()
    if args.check:
        worst = check()
        raise SystemExit(0 if worst < 1e-4 else f"a kernel is off by {worst:.2e} m")
    if jax.default_backend() != "gpu":
        raise SystemExit("the kernels are Triton kernels: run this on a CUDA GPU, or pass --check for the interpreter.")
    result = {
        "benchmark": "fused_skinning",
        "machine": machine(),
        "dtype": "float32",
        **run(args.batch, args.min_seconds),
    }
    print("wrote", write_json("fused_skinning_gpu.json", result))


if __name__ == "__main__":
    main()
