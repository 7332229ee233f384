"""Video Inertial Poser speed: the whole pipeline (IT, association + fusion, twice) by stage.

    python benchmarks/vip_speed.py                              # CPU -> results/vip_speed.json
    python benchmarks/vip_speed.py --frames 300                 # a shorter CPU run
    python benchmarks/vip_speed.py --gpu-batch 16 --frames 300  # on a GPU -> results/vip_speed_gpu.json
    python benchmarks/vip_speed.py --gpu-batch 2 --frames 30    # smoke test of the GPU mode (any machine)

Data: `app.vip.demo_inputs`-like scenes (`sensors.vip_config`, low body, Xsens-like IMU
errors, OpenPose-like detections, a hand-held camera with an IMU) of the procedural walk
(arm raises, squats for the others): one wearer with 13 IMUs and two bystanders on the CPU;
`--gpu-batch N` scenes of two wearers and one bystander on a GPU. float64, `--steps` LM
steps per fusion (the thesis's rounds: 2).

Every run happens twice in the same process: the first includes tracing and XLA
compilation (`*_first_call_s`), the second is the steady state (`cpu_stage_s`, ...);
compile = first - second. `cpu_1000_frames_s` is the steady-state time of the full pipeline
scaled to 1000 frames (measured at `frames`; 1000 by default), `cpu_frames_per_s` =
frames / steady seconds. Baseline in the same process: the Inertial Tracker alone (eq.
4.10, the start of VIP) on the same wearer, steady state.

GPU mode: the N scenes run one after another through `video_inertial_scene` (each
scene's wearers as one batch): `gpu_frames_per_s` = wearer-frames / s of the full
pipeline; `gpu_fusion_batched_frames_per_s` solves the first-round fusion of all N x 2
wearers as one `solve_batch` (what a batch of recordings costs on one device).
"""

from __future__ import annotations

import argparse
import os
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from _common import machine, peak_memory_bytes, write_json  # noqa: E402

from jaxmocap.app.scenarios import vip_sequence  # noqa: E402
from jaxmocap.body import default_body  # noqa: E402
from jaxmocap.methods import visual_inertial as vip  # noqa: E402
from jaxmocap.methods.association import load_model  # noqa: E402
from jaxmocap.motion import library  # noqa: E402
from jaxmocap.sensors import make_scenario  # noqa: E402
from jaxmocap.sensors.scenario import vip_config  # noqa: E402
from jaxmocap.solve import solve_batch  # noqa: E402

MOTIONS = ("walk", "arm_raises", "squats")


def scene(body, frames, wearers, bystanders, seed):
    """(datas, bones, detections) of one simulated VIP scene."""
    motions = [library.MOTIONS[m](num_frames=frames, fps=30.0, body=body) for m in MOTIONS[: wearers + bystanders]]
    sc = make_scenario(motions, vip_config(bystanders=wearers + bystanders - 1, max_frames=frames), seed=seed, body=body,
                       num_sequences=1)  # fmt: skip
    datas = []
    for p in range(wearers):
        data, _, bones = vip_sequence(sc, 0, body, person=p)
        datas.append(data)
    return datas, bones, np.asarray(sc.sequence(0)["det_keypoints"][0])


def twice(fn):
    """(output of the second call, seconds of the first call, seconds of the second)."""
    t0 = time.perf_counter()
    fn()
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    out = fn()
    return out, first, time.perf_counter() - t0


def pipeline(scenes, steps):
    """Every scene through `video_inertial_scene`; -> (results, seconds per stage)."""
    out, seconds = [], {"tracker": 0.0, "association": 0.0, "fusion": 0.0}
    for datas, bones, det in scenes:
        r = vip.video_inertial_scene(datas, bones, det, max_steps=steps)
        jax.block_until_ready(r.people[-1].poses)
        out.append(r)
        seconds = {k: seconds[k] + r.seconds[k] for k in seconds}
    return out, seconds


def batched_fusion(scenes, results, steps):
    """The first-round fusion of every wearer of every scene as one `solve_batch`."""
    setups = [vip._fusion_setup(vip.with_keypoints(d, r.associations[0].keypoints[k]), bones, vip.VIPWeights(), True,
                                True, None, True, None, None, 100.0, None)
              for (datas, bones, _), r in zip(scenes, results) for k, d in enumerate(datas)]  # fmt: skip
    stack = lambda *xs: jnp.stack(xs)  # noqa: E731
    params = jax.tree.map(stack, *[s[1] for s in setups])
    data = jax.tree.map(stack, *[s[2] for s in setups])
    return lambda: jax.block_until_ready(solve_batch(setups[0][0], params, data, max_steps=steps).value["pose"])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=1000)
    ap.add_argument("--steps", type=int, default=30, help="LM steps per fusion (default: 30)")
    ap.add_argument("--gpu-batch", type=int, default=0, metavar="N", help="N scenes of 2 wearers (GPU mode)")
    args = ap.parse_args(argv)
    body = default_body("low")
    T = args.frames
    t0 = time.perf_counter()
    if args.gpu_batch:
        scenes = [scene(body, T, 2, 1, seed) for seed in range(args.gpu_batch)]
    else:
        scenes = [scene(body, T, 1, 2, 0)]
    setup_s = time.perf_counter() - t0
    wearer_frames = T * sum(len(s[0]) for s in scenes)
    t0 = time.perf_counter()
    first_results, first = pipeline(scenes, args.steps)
    first_total = time.perf_counter() - t0
    t0 = time.perf_counter()
    results, steady = pipeline(scenes, args.steps)
    total = time.perf_counter() - t0
    stage = {k: round(v, 3) for k, v in steady.items()}
    result = {
        "benchmark": "vip_speed", "frames": T, "imus": len(scenes[0][1]), "lm_steps": args.steps, "rounds": 2,
        "scene_setup_s": setup_s, "dtype": "float64", "association_model": load_model().tag,
        "first_call_stage_s": {k: round(v, 3) for k, v in first.items()}, "first_call_total_s": first_total,
        "compile_stage_s": {k: round(max(0.0, first[k] - steady[k]), 3) for k in steady},
        "detections_per_frame": int(scenes[0][2].shape[1]),
        "final_costs": [float(x.solution.cost) for r in results for x in r.people],
    }  # fmt: skip
    if args.gpu_batch:
        _, f_first, f_steady = twice(batched_fusion(scenes, results, args.steps))
        result.update({
            "scenes": args.gpu_batch, "wearers_per_scene": 2, "bystanders_per_scene": 1, "gpu_stage_s": stage,
            "gpu_total_s": total, "gpu_frames_per_s": wearer_frames / total,
            "gpu_fusion_batched_s": f_steady, "gpu_fusion_batched_first_call_s": f_first,
            "gpu_fusion_batched_frames_per_s": wearer_frames / f_steady,
        })  # fmt: skip
        name = "vip_speed_gpu.json"
    else:
        datas, bones, _ = scenes[0]
        it = lambda: jax.block_until_ready(vip.inertial_tracker(datas[0], bones))  # noqa: E731
        _, it_first, it_steady = twice(it)
        result.update({
            "wearers": 1, "bystanders": 2, "cpu_stage_s": stage, "cpu_total_s": total,
            "cpu_1000_frames_s": total * 1000.0 / T, "cpu_frames_per_s": T / total,
            "cpu_1000_frames_measured": T == 1000,  # else scaled linearly from T frames
            "baseline_inertial_tracker_s": it_steady, "baseline_inertial_tracker_first_call_s": it_first,
            "pipeline_in_tracker_runs": total / it_steady,
        })  # fmt: skip
        name = "vip_speed.json"
    result["peak_memory_bytes"] = peak_memory_bytes()
    result["load_average_1_5_15min_at_end"] = list(os.getloadavg())
    result["machine"] = machine()
    print(write_json(name, result))
    for k, v in result.items():
        if k.endswith(("_s", "_per_s")) and isinstance(v, (int, float)):
            print(f"{k}: {v:.4g}")
        elif k.endswith("stage_s"):
            print(f"{k}: {v}")


if __name__ == "__main__":
    main()
