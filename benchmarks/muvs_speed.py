"""Multi-view SMPLify speed: stage 1 per frame, stage 2 per 30-frame window, batch throughput.

    python benchmarks/muvs_speed.py                          # CPU -> results/muvs_speed.json
    python benchmarks/muvs_speed.py --batch 16 --frames 120 --suffix gpu   # on a GPU

Data: one synthetic 4-view clip (CMU 02_01 on the default low body, 256 x 192 px, BODY_25
keypoints with OpenPose-like errors, silhouettes), `--batch` copies of it solved as one
batch. Every stage runs twice: the first call includes tracing and XLA compilation
(`*_first_call_s`), the second is the steady state (`stage1_joints_s`, ...; times include
the host work the method does: initialisation, medians, DCT starting values). Stage 1 =
the joint fit with the annealed prior (3 solves) + the silhouette solve; stage 2 = the
temporal solve. `stage1_s_per_frame` and `stage2_s_per_window` are the steady state on
`--frames`; `*_steady` the steady state on a `--long` clip (default 300 frames), where
fixed costs per call are spread over many frames: what a long sequence costs per frame.
`resolve_swaps_s_per_frame(_steady)`: the check for views that swapped the legs, which
`multiview_smplify` runs before stage 1 (`resolve_left_right`, NumPy on the host; not in
the stage-1 times). `baseline_engine_stage2_s_per_window`: the same stage-2 steps through the generic
structured engine (E_T as a plain window term, not a basis term: `_generic_stage_two`), in the same process.
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
from jaxmocap.energies import camera as ec
from jaxmocap.energies.camera import project_to_views
from jaxmocap.geometry.keypoints import regress_keypoints
from jaxmocap.geometry.raster import rasterize_views
from jaxmocap.methods import multiview as mv
from jaxmocap.sensors import CameraConfig, DetectorErrorModel, ScenarioConfig, make_scenario
from jaxmocap.sensors.detector import person_track

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
    """(output, steady-state seconds, first-call seconds incl. compilation)."""
    t0 = time.perf_counter()
    fn(*args)
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    out = fn(*args)
    return out, time.perf_counter() - t0, first


def run_stages(data, w):
    """The swap check, stage 1 (joints, silhouettes) and stage 2 timed: {name: (steady s, first-call s)}."""
    _, t_resolve, f_resolve = timed(lambda: mv.resolve_left_right(data))
    p0 = mv.initialise(data, w.num_betas)
    (pj, _), t_joints, f_joints = timed(lambda: mv.stage_one(data, p0, w, silhouettes=False))
    (ps, _), t_sil, f_sil = timed(lambda: mv.stage_one(data, pj, w.replace(anneal=()), silhouettes=True))
    (pt, _), t_temporal, f_temporal = timed(lambda: mv.stage_two(data, ps, w))
    times = {"joints": (t_joints, f_joints), "silhouettes": (t_sil, f_sil), "temporal": (t_temporal, f_temporal),
             "resolve": (t_resolve, f_resolve)}  # fmt: skip
    return p0, ps, times


def _generic_stage_two(data, params1, w):
    """`mv.stage_two` with E_T as an ordinary window term: the engine's generic window
    elimination (by K·Q Jacobian-vector products) instead of `jaxmocap.solve.basis`."""
    from unittest import mock

    from jaxmocap.solve import Term

    def plain(*args, **kwargs):
        t = ec.temporal_term(*args, **kwargs)
        return Term(t.name, t.fn, t.weight, loss=t.loss, reads=t.reads)

    with mock.patch.object(mv, "temporal_term", plain):  # problems are built per call: no cache to clear
        return mv.stage_two(data, params1, w)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--batch", type=int, default=1)
    ap.add_argument("--long", type=int, default=300, help="frames of the steady-state run (0: skip)")
    ap.add_argument("--suffix", default="")
    args = ap.parse_args(argv)
    body = default_body("low")
    one = clip_data(body, args.frames)
    data = one if args.batch == 1 else mv.stack([one] * args.batch)
    w = mv.MuVSWeights()
    n_frames = args.frames * args.batch
    windows = args.batch * -(-args.frames // w.window)

    p0, ps, times = run_stages(data, w)
    (t_joints, f_joints), (t_sil, f_sil), (t_temporal, f_temporal), (t_resolve, _) = times.values()
    _, t_engine, _ = timed(lambda: _generic_stage_two(data, ps, w))
    steady = {}
    if args.long:
        long = clip_data(body, args.long)
        long = long if args.batch == 1 else mv.stack([long] * args.batch)
        _, _, ltimes = run_stages(long, w)
        n_long = args.long * args.batch
        steady = {
            "long_frames": args.long,
            "stage1_s_per_frame_steady": (ltimes["joints"][0] + ltimes["silhouettes"][0]) / n_long,
            "stage1_joints_s_per_frame_steady": ltimes["joints"][0] / n_long,
            "stage1_silhouettes_s_per_frame_steady": ltimes["silhouettes"][0] / n_long,
            "stage2_s_per_window_steady": ltimes["temporal"][0] / (args.batch * -(-args.long // w.window)),
            "resolve_swaps_s_per_frame_steady": ltimes["resolve"][0] / n_long,
            "long_first_call_s": {k: v[1] for k, v in ltimes.items()},
        }  # fmt: skip

    @jax.jit
    def residual_floor(pose, trans):
        out = forward(one.body, pose, None, trans)
        return project_to_views(one, regress_keypoints(one.regressor, out.vertices, out.joints))[0]

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
    _, t_raster, _ = timed(lambda: jax.block_until_ready(raster()))
    stage1 = t_joints + t_sil
    result = {
        "frames": args.frames, "batch": args.batch, "views": 4, "image": [256, 192],
        "stage1_joints_s": t_joints, "stage1_silhouettes_s": t_sil, "stage2_s": t_temporal,
        "stage1_joints_first_call_s": f_joints, "stage1_silhouettes_first_call_s": f_sil,
        "stage2_first_call_s": f_temporal,
        "stage1_compile_s": max(0.0, f_joints + f_sil - t_joints - t_sil), "stage2_compile_s": max(0.0, f_temporal - t_temporal),
        "steps": list(w.steps), "silhouette_points": w.silhouette_points,
        "stage1_s_per_frame": stage1 / n_frames,
        "stage2_s_per_window": t_temporal / windows,
        "resolve_swaps_s_per_frame": t_resolve / n_frames,
        "baseline_engine_stage2_s_per_window": t_engine / windows,
        **steady,
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
    for k in (
        "stage1_s_per_frame",
        "stage2_s_per_window",
        "stage1_s_per_frame_steady",
        "stage2_s_per_window_steady",
        "stage1_compile_s",
        "stage2_compile_s",
        "baseline_engine_stage2_s_per_window",
        "frames_per_s_total",
    ):
        if k in result:
            print(f"{k}: {result[k]:.4g}")


if __name__ == "__main__":
    main()
