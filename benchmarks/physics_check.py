"""Frames per second of the batched MJX checker (`jaxmocap.physics.check`).

Batch 1, 1000 and 100,000 frames of random poses (low-res default body, capsules, one
box object); CPU by default, the GPU with `--suffix gpu` on a GPU machine. Writes
results/physics_check[_<suffix>].json.

    python benchmarks/physics_check.py [--sizes 1 1000 100000] [--chunk 4096] [--suffix gpu]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from _common import machine, peak_memory_bytes, time_call, write_json  # noqa: E402


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[1, 1000, 100_000])
    p.add_argument("--chunk", type=int, default=4096, help="frames vmapped at once")
    p.add_argument("--suffix", default="", help="results file suffix, e.g. gpu")
    p.add_argument("--min-seconds", type=float, default=2.0)
    args = p.parse_args(argv)

    import jax
    import trimesh

    from jaxmocap.body import default_body
    from jaxmocap.objects import RigidObject
    from jaxmocap.physics import Ground, check, make_scene

    body = default_body("low")
    box = RigidObject.from_trimesh(trimesh.creation.box(extents=(0.3, 0.2, 0.3)), "box")
    scene = make_scene(body, ground=Ground(-0.9), objects=[box])
    rng = np.random.default_rng(0)
    fn = jax.jit(lambda s, q, t, o: check(s, q, t, object_positions=o, chunk=args.chunk))
    rows = []
    for n in args.sizes:
        poses = jax.device_put(rng.normal(scale=0.3, size=(n, 24, 3)).astype(np.float32))
        trans = jax.device_put(np.zeros((n, 3), np.float32))
        objs = jax.device_put(rng.normal(scale=0.1, size=(n, 1, 3)).astype(np.float32))
        t = time_call(fn, scene, poses, trans, objs, min_seconds=args.min_seconds, max_repeats=20)
        row = {"frames": n, **t, "frames_per_s": n / t["median_s"], "us_per_frame": 1e6 * t["median_s"] / n}
        print(
            f"batch {n:>7d}: {row['frames_per_s']:>12,.0f} frames/s  ({row['us_per_frame']:.1f} µs/frame, "
            f"compile+first {t['compile_and_first_call_s']:.1f} s)",
            flush=True,
        )
        rows.append(row)
    payload = {
        "benchmark": "physics_check",
        "what": "jaxmocap.physics.check: FK + mjx.kinematics + mjx.collision per frame, "
        f"{scene.geometry.num_geoms} capsules vs plane and a 12-triangle box (convex mesh); "
        f"vmapped in chunks of {args.chunk}",
        "machine": machine(),
        "peak_memory_bytes": peak_memory_bytes(),
        "results": rows,
    }
    name = f"physics_check{'_' + args.suffix if args.suffix else ''}.json"
    print(f"wrote {write_json(name, payload)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
