"""Frames per second of sensor synthesis on this machine: IMU, 2D keypoints, silhouettes.

    python benchmarks/synthesis.py   ->  benchmarks/results/synthesis.json

One 240-frame motion (walk, 60 Hz) on the low-resolution default body, float32:
  imu:        forward pass + 13 virtual IMUs (orientation, FD acceleration, gyro), jitted;
  keypoints:  forward pass + COCO-18 regressor + projection into 4 views, jitted;
  silhouette: z-buffer rasterisation of the posed mesh into 4 views of 256 x 192 px
              (label + depth images), per frame (all 4 views);
  combined:   1 / (sum of the three per-frame times).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from _common import machine, time_call, write_json

import jaxmocap
from jaxmocap.geometry import camera, keypoints, raster
from jaxmocap.motion import library
from jaxmocap.sensors import imu


def main():
    body = jaxmocap.default_body("low")
    T, fps, C, W, H = 240, 60.0, 4, 256, 192
    m = library.walk(num_frames=T, fps=fps, body=body)
    poses, trans = jnp.asarray(m.poses, jnp.float32), jnp.asarray(m.trans, jnp.float32)
    placement = imu.imu_placement(body, "totalcapture13")
    reg = jnp.asarray(keypoints.keypoint_regressor(body, "coco18"), jnp.float32)
    K = jnp.asarray(camera.intrinsics(W, H, 55.0), jnp.float32)
    R, t = camera.ring_cameras(C, 4.0, 1.4, [0.0, 0.9, 1.0])
    R, t = jnp.asarray(R, jnp.float32), jnp.asarray(t, jnp.float32)

    imu_fn = eqx.filter_jit(lambda p, tr: imu.synthesize_imu(body, placement, p, None, tr, fps))

    @jax.jit
    def kp_fn(p, tr):
        out = jaxmocap.forward(body, p, trans=tr)
        kp = keypoints.regress_keypoints(reg, out.vertices, out.joints)
        return camera.project(K, R[:, None], t[:, None], kp[None])

    verts = np.asarray(jax.jit(lambda p, tr: jaxmocap.forward(body, p, trans=tr).vertices)(poses, trans))
    Rb = jnp.repeat(R[None], T, 0).reshape(-1, 3, 3)
    tb = jnp.repeat(t[None], T, 0).reshape(-1, 3)
    Vb = jnp.repeat(jnp.asarray(verts)[:, None], C, 1).reshape(-1, *verts.shape[1:])
    window = raster.window_for(np.asarray(K), np.asarray(Rb), np.asarray(tb), np.asarray(Vb), body.faces)
    labels = np.zeros(len(body.faces), int)
    sil_fn = lambda: raster.rasterize_views(K, Rb, tb, Vb, body.faces, labels, W, H, window=window)  # noqa: E731

    results = {}
    for name, fn, args in (
        ("imu", imu_fn, (poses, trans)),
        ("keypoints", kp_fn, (poses, trans)),
        ("silhouette", sil_fn, ()),
    ):
        r = time_call(fn, *args, min_seconds=2.0)
        r["frames_per_second"] = T / r["median_s"]
        results[name] = r
        print(
            f"{name:10s} {r['frames_per_second']:10.0f} frames/s (compile+first {r['compile_and_first_call_s']:.1f} s)"
        )
    per_frame = sum(1 / results[k]["frames_per_second"] for k in results)
    results["combined_frames_per_second"] = 1 / per_frame
    print(f"combined   {1 / per_frame:10.0f} frames/s")
    payload = {
        "benchmark": "synthesis",
        "setup": {"frames": T, "fps": fps, "body": "default low (1229 vertices)", "imu_sensors": 13,
                  "keypoints": "coco18", "views": C, "image": [W, H], "raster_window": window, "dtype": "float32"},
        "results": results,
        "machine": machine(),
    }  # fmt: skip
    print(write_json("synthesis.json", payload))


if __name__ == "__main__":
    main()
