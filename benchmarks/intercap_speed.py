"""InterCap speed: the joint fit over all frames (Huang eq. 5.6-5.7) against the per-frame
human fit (eq. 5.2-5.5) on the same scene, in the same process.

    python benchmarks/intercap_speed.py                        # CPU -> results/intercap_speed.json
    python benchmarks/intercap_speed.py --suffix gpu           # on a GPU -> results/intercap_speed_gpu.json
    python benchmarks/intercap_speed.py --frames 12 --suffix small   # a quick check

Data: one synthetic scene of `sensors.scenario.interaction_config` (the library walk on the
default low body carrying `--object`, `--views` static RGB-D cameras of `--size` pixels,
`--depth-points` per view and frame; seed 0). The object is tracked once (`track_object`,
not timed: it is the joint fit's input). `fit_human` and `fit_joint` (contact frames Q_t:
the scene's true ones, E_C on the scene's contact part) each run once to compile and once
timed; the times include the host work the methods do between solves (visible-vertex
rasterisation and closest-vertex matching of every ICP round, data assembly).

Keys: `joint_fit_frames_per_s` and `human_fit_frames_per_s` (frames / timed seconds),
`ratio_joint_to_human` (joint / human frames per second: > 1 means the joint fit of all
frames costs less per frame than the per-frame human fit), the first-call (compile + run)
times, the joint fit's final cost, settings, peak memory, machine and versions.
"""

from __future__ import annotations

import argparse
import time

import jax
import numpy as np
from _common import machine, peak_memory_bytes, write_json

from jaxmocap.app.scenarios import interaction_observations
from jaxmocap.body import default_body
from jaxmocap.methods.interaction import fit_human, fit_joint, track_object
from jaxmocap.sensors.scenario import interaction_config, make_scenario


def versions() -> dict:
    import equinox
    import jaxlib
    import scipy
    import trimesh

    import jaxmocap

    return {"jaxmocap": jaxmocap.__version__, "jax": jax.__version__, "jaxlib": jaxlib.__version__,
            "numpy": np.__version__, "scipy": scipy.__version__, "equinox": equinox.__version__,
            "trimesh": trimesh.__version__}  # fmt: skip


def twice(fn):
    """(result of the timed second call, first-call seconds, second-call seconds)."""
    t0 = time.perf_counter()
    jax.block_until_ready(jax.tree_util.tree_leaves(fn()))
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    out = fn()
    jax.block_until_ready(jax.tree_util.tree_leaves(out))
    return out, first, time.perf_counter() - t0


def _size(text: str) -> tuple[int, int]:
    w, _, h = text.lower().partition("x")
    return int(w), int(h)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--views", type=int, default=4)
    ap.add_argument("--size", type=_size, default=(256, 192), metavar="WxH", help="image size (default: 256x192)")
    ap.add_argument("--depth-points", type=int, default=768)
    ap.add_argument("--object", default="box", choices=("box", "ball", "bottle", "chair"))
    ap.add_argument("--suffix", default="", help="results file suffix, e.g. gpu")
    args = ap.parse_args(argv)
    body = default_body("low")
    W, H = args.size
    cfg = interaction_config(object=args.object, num_views=args.views, max_frames=args.frames, width=W, height=H,
                             depth_points=args.depth_points)  # fmt: skip
    t0 = time.perf_counter()
    scenario = make_scenario(["walk"], cfg, seed=0, body=body)
    truth = scenario.sequence(0)
    obs = interaction_observations(scenario, 0)
    T = obs.num_frames
    print(f"scene: {T} frames, {args.views} views of {W} x {H} px, {args.object} ({time.perf_counter() - t0:.1f} s)")
    t0 = time.perf_counter()
    obj = track_object(obs, body=body)
    track_s = time.perf_counter() - t0
    print(f"object tracked ({track_s:.1f} s, not timed)")

    human, human_first, human_s = twice(lambda: fit_human(obs, body))
    print(f"fit_human: first call {human_first:.1f} s, timed {human_s:.2f} s")
    contact, part = np.asarray(truth["contact"], np.float64), scenario.config.contact_part
    joint, joint_first, joint_s = twice(lambda: fit_joint(obs, human, obj, contact, body, parts=(part,)))
    print(f"fit_joint: first call {joint_first:.1f} s, timed {joint_s:.2f} s")

    last = list(joint["costs"])[-1]
    result = {
        "benchmark": "intercap_speed",
        "frames": T, "views": args.views, "image": [W, H], "depth_points": args.depth_points, "object": args.object,
        "body": "default low", "body_vertices": body.num_vertices, "contact_part": part,
        "contact_frames": int(contact.sum()), "dtype": "float32",
        "joint_fit_frames_per_s": T / joint_s,
        "human_fit_frames_per_s": T / human_s,
        "ratio_joint_to_human": (T / joint_s) / (T / human_s),
        "joint_fit_s": joint_s, "human_fit_s": human_s,
        "joint_fit_first_call_s": joint_first, "human_fit_first_call_s": human_first,
        "object_track_s_untimed_first_call": track_s,
        "joint_fit_final_cost": float(sum(joint["costs"][last].values())),
        "peak_memory_bytes": peak_memory_bytes(),
        "machine": machine(),
        "versions": versions(),
    }  # fmt: skip
    name = "intercap_speed" + (f"_{args.suffix}" if args.suffix else "") + ".json"
    print(write_json(name, result))
    for k in ("joint_fit_frames_per_s", "human_fit_frames_per_s", "ratio_joint_to_human"):
        print(f"{k}: {result[k]:.4g}")


if __name__ == "__main__":
    main()
