"""Multi-view SMPLify speed: stage 1 per frame, stage 2 per 30-frame window, batch throughput.

    python benchmarks/muvs_speed.py                          # CPU -> results/muvs_speed.json
    python benchmarks/muvs_speed.py --batch 16 --frames 120 --suffix gpu   # on a GPU

Data: one synthetic 4-view clip (CMU 02_01 on the default low body, 256 x 192 px, BODY_25
keypoints with OpenPose-like errors, silhouettes), `--batch` copies of it solved as one
batch. Every stage runs once to compile and once timed (times include the host work the
method does: initialisation, medians, DCT starting values). Stage 1 = the joint fit with
the annealed prior (3 solves) + the silhouette solve; stage 2 = the temporal solve.
The thesis (Huang §4.3.3): ~70 s per frame (stage 1) and ~12 min per 30-frame unit
(stage 2) on a 4-core PC with four 500 x 500 views; `*_vs_thesis` are our time / theirs.
`silhouette_images_per_s`: synthetic masks (256 x 192, the low body) rasterised per second,
after compilation. Baseline in the same process: one forward pass of the body (mesh + keypoints + projection
into all views) for the same frames, so `stage1_per_frame_in_forward_passes` says how many
residual evaluations' worth of time a frame costs.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from _common import machine, peak_memory_bytes, time_call, write_json

from jaxmocap.body import default_body
from jaxmocap.body.kinematics import forward
from jaxmocap.energies.camera import _views
from jaxmocap.methods import multiview as mv
from jaxmocap.sensors import CameraConfig, DetectorErrorModel, ScenarioConfig, make_scenario
from jaxmocap.sensors.keypoints import person_track, regress_keypoints
from jaxmocap.sensors.silhouette import rasterize_views

CLIP = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "cmu" / "02_01.amc"


def clip_data(body, frames):
    cfg = ScenarioConfig(
        max_frames=frames, imu_set=None, keypoints="body25", detector=DetectorErrorModel(
            pixel_noise=3.0, confidence_mean=0.8, confidence_std=0.1, miss_rate=0.03, swap_rate=0.02),
        cameras=CameraConfig(num_views=4), silhouettes=True,
    )  # fmt: skip
    s = make_scenario([CLIP], cfg, seed=0, body=body).sequence(0)
    kp = person_track(s["det_keypoints"], s["det_person"])
    masks = np.moveaxis(s["labels"] == 0, 0, 1)
    return mv.camera_data(body, s["cam_K"], s["cam_R"][:, 0], s["cam_t"][:, 0], kp, "body25", masks=masks)


def timed(fn, *args):
    fn(*args)  # compile
    t0 = time.perf_counter()
    out = fn(*args)
    return out, time.perf_counter() - t0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--batch", type=int, default=1)
    ap.add_argument("--suffix", default="")
    args = ap.parse_args(argv)
    body = default_body("low")
    one = clip_data(body, args.frames)
    data = one if args.batch == 1 else mv.stack([one] * args.batch)
    w = mv.MuVSWeights()
    n_frames = args.frames * args.batch
    windows = args.batch * -(-args.frames // w.window)

    p0 = mv.initialise(data, w.num_betas)
    (pj, _), t_joints = timed(lambda: mv.stage_one(data, p0, w, silhouettes=False))
    (ps, _), t_sil = timed(lambda: mv.stage_one(data, pj, w.replace(anneal=()), silhouettes=True))
    (pt, _), t_temporal = timed(lambda: mv.stage_two(data, ps, w))

    @jax.jit
    def residual_floor(pose, trans):
        verts = forward(one.body, pose, None, trans).vertices
        return _views(one, regress_keypoints(one.regressor, verts))[0]

    floor = time_call(residual_floor, jnp.asarray(p0["pose"] if args.batch == 1 else p0["pose"][0], jnp.float32),
                      jnp.asarray(p0["trans"] if args.batch == 1 else p0["trans"][0], jnp.float32))  # fmt: skip
    # Silhouette synthesis for benchmark sets (issue 17 item 5): views x frames per second.
    posed = forward(body, jnp.asarray(p0["pose"] if args.batch == 1 else p0["pose"][0], jnp.float32), None,
                    jnp.asarray(p0["trans"] if args.batch == 1 else p0["trans"][0], jnp.float32))  # fmt: skip
    V = 4
    Rb = np.repeat(np.asarray(one.R)[None], args.frames, 0).reshape(-1, 3, 3)
    tb = np.repeat(np.asarray(one.t)[None], args.frames, 0).reshape(-1, 3)
    vb = np.repeat(np.asarray(posed.vertices)[:, None], V, 1).reshape(args.frames * V, -1, 3)
    labels = np.zeros(len(body.faces), int)
    raster = lambda: rasterize_views(np.asarray(one.K[0]), Rb, tb, vb, body.faces, labels, 256, 192)  # noqa: E731
    _, t_raster = timed(lambda: jax.block_until_ready(raster()))
    stage1 = t_joints + t_sil
    result = {
        "frames": args.frames, "batch": args.batch, "views": 4, "image": [256, 192],
        "stage1_joints_s": t_joints, "stage1_silhouettes_s": t_sil, "stage2_s": t_temporal,
        "stage1_s_per_frame": stage1 / n_frames,
        "stage2_s_per_window": t_temporal / windows,
        "frames_per_s_stage1": n_frames / stage1,
        "frames_per_s_total": n_frames / (stage1 + t_temporal),
        "stage1_vs_thesis": stage1 / n_frames / 70.0,
        "stage2_vs_thesis": t_temporal / windows / 720.0,
        "baseline_forward_pass_s": floor["median_s"],
        "stage1_per_frame_in_forward_passes": stage1 / args.batch / floor["median_s"],
        "targets": {"stage1_s_per_frame": 0.05, "stage2_s_per_window": 1.0},
        "silhouette_images_per_s": args.frames * V / t_raster,
        "peak_memory_bytes": peak_memory_bytes(),
        "machine": machine(),
    }  # fmt: skip
    name = "muvs_speed" + (f"_{args.suffix}" if args.suffix else "") + ".json"
    print(write_json(name, result))
    for k in ("stage1_s_per_frame", "stage2_s_per_window", "frames_per_s_total", "stage1_per_frame_in_forward_passes"):
        print(f"{k}: {result[k]:.4g}")


if __name__ == "__main__":
    main()
