"""`jaxmocap multiview demo`: a small synthetic recording in a lab's layout, then its fit.

The recording is what a Pose2Sim user hands over (`formats.project`):

    recording/Config.toml                 [project] frame_rate = 60; [pose] pose_model = 'BODY_25B'
    recording/calibration/Calib_demo.toml Pose2Sim TOML, z-up world, lens distortion
    recording/pose/camNN_json/camNN.FFFF.json   OpenPose BODY_25B, frames numbered from 1

with the default body walking in front of four cameras: its BODY_25B keypoints projected
through the lenses with 1 px noise, the off-image ones missed, and one frame that camera
4 did not write (a dropped frame, kept as a gap). `run_demo` writes it, then fits the
project folder as `jaxmocap multiview recording/` would (layout and frame rate from
Config.toml, the layout checked against the skeleton) into ``fit/``.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

__all__ = ["run_demo", "write_demo_recording"]

_CONFIG = """# Written by `jaxmocap multiview demo`, in Pose2Sim's Config.toml layout (the keys jaxmocap reads).
[project]
frame_rate = {fps:g} # fps, int or 'auto'
frame_range = 'all'

[pose]
pose_model = 'BODY_25B'
"""


def write_demo_recording(root, frames: int = 16, fps: float = 60.0, views: int = 4, seed: int = 0,
                         body="default-low") -> dict:  # fmt: skip
    """Write the demo recording (module docstring) under `root`; returns its truth:
    {"joints": (T, 24, 3) in jaxmocap's y-up world, "frames": (T,) numbers, "dropped": (view, frame)}."""
    from ..body import posed_vertices
    from ..body.io import resolve_body
    from ..formats import CalibratedCamera, save_calibration, write_openpose
    from ..motion.amass import Z_UP_TO_Y_UP
    from ..motion.library import walk
    from ..geometry.camera import project_points, ring_cameras
    from ..geometry.keypoints import keypoint_regressor, regress_keypoints

    root = Path(root)
    W, H = 1280, 720
    body = resolve_body(body)
    motion = walk(frames, fps=fps, body=body)
    verts, joints = posed_vertices(body, motion)
    z_up = Z_UP_TO_Y_UP  # Pose2Sim and Qualisys worlds are z up: x_y = Z x_z
    keypoints = regress_keypoints(
        keypoint_regressor(body, "body25b"), *(np.asarray(a, np.float64) for a in (verts, joints))
    )
    keypoints = keypoints @ z_up
    R, t = ring_cameras(views, 4.5, 1.6, [0.0, 0.9, 0.4], start_angle=0.4)
    rng = np.random.default_rng(seed)
    numbers = np.arange(1, frames + 1)
    dropped = (views - 1, int(numbers[frames // 2]))
    cameras = []
    for v in range(views):
        f = 1000.0 + 30.0 * v
        K = [[f, 0.0, W / 2 - 3.0 + 2 * v], [0.0, f, H / 2 + 2.0 - v], [0.0, 0.0, 1.0]]
        cam = CalibratedCamera(f"cam{v + 1:02d}", K, [-0.1 + 0.02 * v, 0.03, 0.0, 0.0, 0.0], R[v] @ z_up, t[v], W, H)
        cameras.append(cam)
        uv, z = project_points(cam.K, cam.dist, cam.R, cam.t, keypoints.reshape(-1, 3))
        uv = uv.reshape(frames, -1, 2) + rng.normal(scale=1.0, size=(frames, keypoints.shape[1], 2))
        z = z.reshape(frames, -1)
        inside = (z > 0) & (uv >= -0.5).all(-1) & (uv[..., 0] < W - 0.5) & (uv[..., 1] < H - 0.5)
        rows = np.where(inside[..., None], np.concatenate([uv, np.full(z.shape + (1,), 0.85)], -1), 0.0)
        write_openpose(root / "pose", [f"{cam.name}_json"], [rows[:, None]], "body25b", frames=numbers,
                       name=cam.name + ".{frame:04d}.json")  # fmt: skip
    (root / "pose" / f"cam{dropped[0] + 1:02d}_json" / f"cam{dropped[0] + 1:02d}.{dropped[1]:04d}.json").unlink()
    (root / "calibration").mkdir(parents=True, exist_ok=True)
    save_calibration(root / "calibration" / "Calib_demo.toml", cameras, "pose2sim")
    (root / "Config.toml").write_text(_CONFIG.format(fps=fps))
    return {"joints": np.asarray(joints, np.float64), "frames": numbers, "dropped": dropped}


def run_demo(out, frames: int = 16, body="default-low", temporal: bool = True, log=print,
             progress: bool = False, weights=None) -> dict:  # fmt: skip
    """Write the demo recording into ``out/recording`` and fit it into ``out/fit``; returns
    the fit's report with "demo": {"mpjpe_mm", "seconds"} added. progress: a bar over the
    fit's stages on stderr; weights: `fit_recording`'s (None: the "validated" preset)."""
    from ..formats import read_project
    from .._checks import output_folder
    from .multiview import fit_recording

    out = output_folder(out, create=False)
    start = time.perf_counter()
    log(f"demo     writing a synthetic 4-camera recording ({frames} frames, Pose2Sim layout) to {out / 'recording'}")
    truth = write_demo_recording(out / "recording", frames=frames, body=body)
    project = read_project(out / "recording")
    log(f"demo     fitting it as `jaxmocap multiview {out / 'recording'}` would (keypoints {project.keypoints}, "
        f"calibration {project.calibration}, settings {project.config.files[-1]})")  # fmt: skip
    log("demo     stage 1 (per frame)" + (", stage 2 (temporal)" if temporal else "") + "; the first run compiles "
        "the solvers, a few minutes on a laptop CPU")  # fmt: skip
    report = fit_recording(project.keypoints, project.calibration, out / "fit", body=body, temporal=temporal,
                           weights=weights, progress=progress, log=log)  # fmt: skip
    from ..body import posed_vertices
    from ..body.io import resolve_body
    from ..motion.amass import load_amass

    model = resolve_body(body)  # the AMASS file reads back y up, as the truth is
    _, joints = posed_vertices(model, load_amass(out / "fit" / report["outputs"]["smpl"], body=model))
    mpjpe = float(1000 * np.linalg.norm(np.asarray(joints, np.float64) - truth["joints"], axis=-1).mean())
    report["demo"] = {"mpjpe_mm": mpjpe, "seconds": time.perf_counter() - start}
    return report
