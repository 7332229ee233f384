"""Write jaxmocap's standard benchmark sets into a cache folder (issue 3).

    python experiments/make_datasets.py [--out out/datasets] [--force] [--only imu6,...]
                                        [--scale 1.0] [--cmu PATH]

Sets (real CMU motion when available + the procedural library; default low-res body):

    imu6        SIP/DIP setting: 6 IMUs (von Marcard §3.2.2), Xsens-like errors, 60 Hz
    imu13       TotalCapture setting: 13 IMUs, Xsens-like errors, 60 Hz
    cam_imu     VIP/3DPW setting: 2 people with 13 IMUs each, one hand-held camera with an
                IMU, COCO-18 detections with OpenPose-like errors and distractors, 30 Hz
    multiview   HumanEva/H3.6M setting: 4 static views, BODY_25 detections + silhouettes
    rgbd        InterCap setting: 4 static RGB-D views, depth point clouds, silhouettes,
                BODY_25 detections, a box carried by the right hand over marked frames

Each set is one `<name>.npz` (jaxmocap scenario format, `jaxmocap.sensors.load_scenario`)
plus `<name>.png`, a summary picture. Resumable: finished sets are skipped (unless
--force); files are written to a temporary name and renamed, so an interrupted run never
leaves a half-written set behind; `summary.json` is merged after every set, and a set
whose picture is missing gets it redrawn from its data. A set's seed is `--seed` plus its
place in the list above, whatever `--only` selects. CMU clips come from $JAXMOCAP_CMU or ../shared/data/cmu.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def cmu_clips(folder: Path | None) -> list[str]:
    if folder is None:
        env = os.environ.get("JAXMOCAP_CMU")
        folder = Path(env) if env else ROOT.parent / "shared" / "data" / "cmu"
    if not folder.is_dir():
        return []
    return sorted(str(p) for p in folder.iterdir() if p.suffix in (".amc", ".bvh"))


def set_specs(scale: float, cmu: list[str]) -> dict:
    from jaxmocap.sensors import CameraConfig, DepthNoiseModel, DetectorErrorModel, IMUErrorModel
    from jaxmocap.sensors import ScenarioConfig

    library = ["walk", "run", "jumping_jacks", "arm_raises", "leg_raises", "squats", "sit_stand", "static_hold"]
    n = lambda k: max(1, int(round(k * scale)))  # noqa: E731
    # Alternate real and procedural motion so that every set gets both.
    mixed = [m for pair in zip(cmu, library) for m in pair] + cmu[len(library) :] + library[len(cmu) :]
    return {
        "imu6": (mixed, n(len(mixed)), ScenarioConfig(
            fps=60.0, max_frames=n(300), imu_set="sip6", imu_errors=IMUErrorModel.xsens())),
        "imu13": (mixed, n(len(mixed)), ScenarioConfig(
            fps=60.0, max_frames=n(300), imu_set="totalcapture13", imu_errors=IMUErrorModel.xsens())),
        "cam_imu": (mixed, n(6), ScenarioConfig(
            fps=30.0, max_frames=n(120), people=2, imu_set="totalcapture13",
            imu_errors=IMUErrorModel.xsens(),
            cameras=CameraConfig(num_views=1, moving=True, camera_imu=True, width=320, height=240),
            keypoints="coco18", detector=DetectorErrorModel.openpose())),
        "multiview": (mixed, n(6), ScenarioConfig(
            fps=30.0, max_frames=n(90), imu_set=None,
            cameras=CameraConfig(num_views=4, width=256, height=192),
            keypoints="body25", detector=DetectorErrorModel.openpose(), silhouettes=True)),
        "rgbd": (["squats", "arm_raises", "walk", "sit_stand"], n(4), ScenarioConfig(
            fps=30.0, max_frames=n(60), imu_set=None,
            cameras=CameraConfig(num_views=4, width=160, height=120, distance=3.0),
            keypoints="body25", detector=DetectorErrorModel.openpose(), silhouettes=True,
            depth_points=1024, depth_noise=DepthNoiseModel(), object="box")),
    }  # fmt: skip


def summary_png(name: str, s, path: Path) -> None:
    """A picture of one set: IMU signals, an image with keypoints, depth points."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    a = s.arrays
    panels = []
    if "imu_acc" in a:
        panels.append("imu")
    if "labels" in a or "det_keypoints" in a:
        panels.append("image")
    if "depth_points" in a:
        panels.append("depth")
    panels.append("lengths")
    fig, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 3.6))
    axes = np.atleast_1d(axes)
    i = int(np.argmax(a["length"]))
    n = int(a["length"][i])
    for ax, kind in zip(axes, panels):
        if kind == "imu":
            t = np.arange(n) / s.meta["config"]["fps"]
            acc = a["imu_acc"][i, 0, :n, 0]
            for c, col in enumerate("rgb"):
                ax.plot(t, acc[:, c], col, lw=0.8, label="xyz"[c])
            ax.plot(t, a["imu_acc_true"][i, 0, :n, 0, 1], "k--", lw=0.6, label="y, no errors")
            ax.set(title=f"{s.meta['sensor_names'][0]} accelerometer (seq {i})", xlabel="s", ylabel="m/s²")
            ax.legend(fontsize=6)
        elif kind == "image":
            f = n // 2
            cfg = s.meta["config"]["cameras"]
            if "labels" in a:
                ax.imshow(a["labels"][i, 0, f], cmap="tab10", vmin=-2, vmax=7, interpolation="nearest")
            else:
                ax.imshow(np.zeros((cfg["height"], cfg["width"])), cmap="gray")
            det = a["det_keypoints"][i, 0, f]
            for d in range(det.shape[0]):
                ok = det[d, :, 2] > 0
                pid = a["det_person"][i, 0, f, d]
                if pid == -2:
                    continue
                ax.scatter(det[d, ok, 0], det[d, ok, 1], s=6, c="w" if pid >= 0 else "r")
            ax.set(title=f"view 0, frame {f}: mask + detections (red: distractors)")
            ax.set_xlim(0, cfg["width"]), ax.set_ylim(cfg["height"], 0)
        elif kind == "depth":
            f = n // 2
            for c in range(a["depth_points"].shape[1]):
                ok = a["depth_valid"][i, c, f]
                p = a["depth_points"][i, c, f][ok]
                ax.scatter(p[:, 0], p[:, 1], s=0.5, label=f"view {c}")
            ax.set(title=f"depth points, frame {f} (x-y)", aspect="equal")
            ax.legend(fontsize=6, markerscale=8)
        else:
            ax.barh(range(len(a["length"])), a["length"])
            ax.set_yticks(range(len(a["length"])))
            ax.set_yticklabels([Path(x).name[:28] for x in s.meta["names"]], fontsize=6)
            ax.set(title=f"{name}: frames per sequence", xlabel="frames")
    fig.tight_layout()
    tmp = path.with_name(path.name + ".tmp.png")
    fig.savefig(tmp, dpi=90)
    plt.close(fig)
    os.replace(tmp, path)


def _read_summary(log: Path) -> dict:
    return json.loads(log.read_text()) if log.exists() else {}


def _update_summary(log: Path, name: str, stats: dict) -> None:
    """Merge one set's statistics into summary.json (atomic: temp file + rename)."""
    merged = {**_read_summary(log), name: stats}
    tmp = log.with_name("summary.json.tmp")
    tmp.write_text(json.dumps(dict(sorted(merged.items())), indent=2) + "\n")
    os.replace(tmp, log)


def _stats(s, path: Path, seconds: float | None, cmu_clips: int, seed: int | None = None) -> dict:
    stats = {
        "sequences": s.num_sequences, "frames": int(s["length"].sum()),
        "seconds": None if seconds is None else round(seconds, 1),
        "megabytes": round(path.stat().st_size / 1e6, 2), "cmu_clips": cmu_clips,
    }  # fmt: skip
    if seed is not None:
        stats["seed"] = seed
    return stats


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default="out/datasets", help="cache folder (default out/datasets)")
    parser.add_argument("--force", action="store_true", help="rebuild sets that exist")
    parser.add_argument("--only", default="", help="comma-separated set names")
    parser.add_argument("--scale", type=float, default=1.0, help="scale sequence counts and lengths")
    parser.add_argument("--cmu", type=Path, default=None, help="folder with CMU .amc/.bvh clips")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    from tqdm import tqdm

    from jaxmocap.sensors import load_scenario, make_scenario, save_scenario

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    cmu = cmu_clips(args.cmu)
    specs = set_specs(args.scale, cmu)
    names = [n for n in args.only.split(",") if n] or list(specs)
    unknown = set(names) - set(specs)
    if unknown:
        parser.error(f"unknown set(s) {sorted(unknown)}; choose from {sorted(specs)}")
    log = out / "summary.json"
    for name in tqdm(names, desc="datasets"):
        path, png = out / f"{name}.npz", out / f"{name}.png"
        motions, count, config = specs[name]
        if path.exists() and not args.force:
            # Finished before: keep the data; redraw a picture a kill may have cut off, and
            # record statistics an interrupted run never wrote.
            s = None
            if not png.exists():
                s = load_scenario(path)
                summary_png(name, s, png)
                tqdm.write(f"{name}: exists, picture redrawn")
            else:
                tqdm.write(f"{name}: exists, skipped")
            if name not in _read_summary(log):
                s = load_scenario(path) if s is None else s
                _update_summary(log, name, _stats(s, path, None, len(cmu)))
            continue
        # A set's seed depends on the set, not on --only: `--only imu13` and a full run
        # build the same standard set (seed + the set's place in the full list).
        seed = args.seed + list(specs).index(name)
        start = time.perf_counter()
        s = make_scenario(motions, config, seed=seed, num_sequences=count, progress=True)
        # The old picture goes first, so a kill between the two files leaves data without a
        # picture (redrawn on the next run), never a picture of other data.
        png.unlink(missing_ok=True)
        save_scenario(s, path)
        summary_png(name, s, png)
        stats = _stats(s, path, time.perf_counter() - start, len(cmu), seed)
        _update_summary(log, name, stats)  # after every set: an interruption loses nothing
        tqdm.write(f"{name}: {stats}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
