"""Multi-view SMPLify on a lab recording: OpenPose folders + calibration → SMPL, pictures, report.

`fit_recording` is the pipeline behind ``jaxmocap multiview``:

    read_openpose → load_calibration → align_views → select_person → camera_data
    → MuVS stage 1 (per frame) → stage 2 (temporal, DCT) → files in `out_dir`

Pixel convention: `select_person` returns undistorted pixels with OpenCV's centres at
integers, while the camera energies project with jaxmocap's centres at integer + 0.5
(`geometry.camera.project`). We follow `geometry.camera.pinhole_camera`: the principal
point of every K is moved by +0.5 and the detections by +0.5, so residuals are the
same and masks (`read_masks`, pixel centres at +0.5) line up too. Overlays
are drawn back in the video's own (distorted, integer-centred) pixels.

World frame: the fit happens in the calibration's world (Qualisys and Pose2Sim scenes are
usually z up). The outputs meant for other tools are re-expressed in jaxmocap's y-up
world first: the world axis closest to the cameras' mean "up" (-y of every camera) is
taken as up. `smpl.npz` then goes through `motion.amass.save_amass` (z up, as AMASS) and
the meshes are written y up (glTF's convention).

Outputs (`out_dir`):
    smpl.npz            AMASS layout: poses (T, 72) SMPL axis-angle (all 24 joints; the
                        hands 22/23 are not SMPL-H's), trans (T, 3), betas (16,) (the fit's
                        10, zero-padded), gender "neutral", mocap_framerate.
    overlays/<view>.png detections (coloured by confidence) vs the model's reprojected
                        keypoints and its projected mesh, first/middle/last frame.
    meshes/frame_XXXX.ply, meshes/sequence.glb   posed meshes (y up, metres).
    report.json, report.md   reprojection error per view and keypoint, jitter, timings.

Masks (optional, `masks_dir`): one folder per camera named like the keypoint folders,
PNG files whose last number is the frame number (``cam01_000000000042.png``), white (or
opaque) = person, in the video's pixels; `read_masks` undistorts them onto the fit's
pixels. A missing file is a frame without an observation. Stage 1 then adds the
silhouette term (eq. 4.5-4.6); the distance transforms are held for every frame and view
at full resolution, so long recordings are refused above `MAX_MASK_BYTES` (fit them in
pieces with `frames=`).
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
import time
from pathlib import Path

import numpy as np

from .._checks import output_folder

__all__ = ["fit_recording", "jitter", "read_masks", "reprojection_errors", "world_to_y_up"]

#: Detections with at least this confidence count in the reprojection statistics.
MIN_CONFIDENCE = 0.2
#: Frame rate assumed when neither fps= nor the project's Config.toml gives one.
DEFAULT_FPS = 30.0
#: At most this many PLY files (every n-th frame beyond) and GLB nodes are written.
MAX_PLY, MAX_GLB_NODES = 300, 30
#: Masks are refused when their distance transforms (float32, every frame and view) exceed this.
MAX_MASK_BYTES = 2 << 30
_AXES = {"+x": (0, 1), "-x": (0, -1), "+y": (1, 1), "-y": (1, -1), "+z": (2, 1), "-z": (2, -1)}
# World rotations taking each axis to +y with the smallest turn (+z: AMASS's rot_x(-90°)).
_TO_Y_UP = {
    "+y": np.eye(3),
    "-y": np.diag([1.0, -1.0, -1.0]),
    "+z": np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]]),
    "-z": np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]),
    "+x": np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]),
    "-x": np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]),
}


def world_to_y_up(cameras) -> tuple[str, np.ndarray]:
    """The calibration world's up axis ("+z", ...) and the rotation taking it to +y.

    Up is the world axis nearest to the mean of the cameras' up directions (their -y axes
    in the world): cameras are mounted roughly upright, even when tilted down.
    """
    up = sum(c.R.T @ np.array([0.0, -1.0, 0.0]) for c in cameras)
    i = int(np.argmax(np.abs(up)))
    name = ("+" if up[i] > 0 else "-") + "xyz"[i]
    return name, _TO_Y_UP[name]


def jitter(joints, fps: float) -> float:
    """Mean ‖second difference‖ · fps² of 3-D joints (T, J, 3) in metres, as mm/s²."""
    joints = np.asarray(joints, np.float64)
    if len(joints) < 3:
        return float("nan")
    acc = np.linalg.norm(joints[2:] - 2 * joints[1:-1] + joints[:-2], axis=-1) * fps**2
    return float(1000.0 * acc.mean())


def reprojection_errors(uv_model, keypoints, min_confidence: float = MIN_CONFIDENCE) -> np.ndarray:
    """Pixel distances (T, V, K) of model keypoints (T, V, K, 2) to detections (T, V, K, 3);
    NaN where the detection's confidence is below `min_confidence`."""
    err = np.linalg.norm(np.asarray(uv_model) - keypoints[..., :2], axis=-1)
    return np.where(keypoints[..., 2] >= min_confidence, err, np.nan)


_LAST_NUMBER = re.compile(r"(\d+)(?!.*\d)")


def _mask_image(path: Path) -> np.ndarray:
    from PIL import Image

    try:
        with Image.open(path) as im:
            if im.mode in ("RGBA", "LA", "PA") and im.getchannel("A").getextrema()[0] < 255:
                return np.asarray(im.getchannel("A")) > 127  # transparent background
            return np.asarray(im.convert("L")) > 127
    except OSError as e:
        raise ValueError(f"{path}: not a readable PNG mask ({e}).") from None


def read_masks(masks_dir, views, frame_numbers, cameras) -> np.ndarray:
    """Person masks (T, V, H, W) on the fit's undistorted pixels (module docstring).

    Mask pixel (row i, column j) is the undistorted OpenCV pixel (j, i), i.e. jaxmocap's
    (j + 0.5, i + 0.5), the convention of `energies.camera.silhouette_data`; each is looked
    up at its distorted position in the PNG (nearest pixel). Cameras of different sizes
    are padded to the largest with "no person".
    """
    masks_dir = Path(masks_dir)
    if not masks_dir.is_dir():
        raise ValueError(f"{masks_dir}: no such folder (masks_dir: one folder of PNG masks per camera).")
    frame_numbers = [int(f) for f in frame_numbers]
    if any(c.width <= 0 for c in cameras):
        raise ValueError(
            "masks need the image size of every camera; the calibration gives none for "
            f"{[c.name for c in cameras if c.width <= 0]}."
        )
    T, V = len(frame_numbers), len(cameras)
    H, W = max(c.height for c in cameras), max(c.width for c in cameras)
    if T * V * H * W * 4 > MAX_MASK_BYTES:
        raise ValueError(
            f"masks of {T} frames x {V} views at {W} x {H} need {T * V * H * W * 4 / 2**30:.1f} GiB of distance "
            f"transforms (limit {MAX_MASK_BYTES / 2**30:.0f} GiB); fit fewer frames at a time (frames=/--frames)."
        )
    from ..geometry.camera import to_pixels, distort_points

    out = np.zeros((T, V, H, W), bool)
    index = {f: i for i, f in enumerate(frame_numbers)}
    for v, (view, cam) in enumerate(zip(views, cameras)):
        folder = masks_dir / view
        if not folder.is_dir():
            present = sorted(p.name for p in masks_dir.iterdir() if p.is_dir())
            raise ValueError(f"{folder}: missing mask folder for camera {view!r}; folders present: {present}.")
        files = {}
        for p in sorted(folder.glob("*.png")):
            m = _LAST_NUMBER.search(p.stem)
            frame = int(m.group(1)) if m else None
            if frame in index:
                if frame in files:
                    raise ValueError(f"{folder}: frame {frame} has two masks, {files[frame].name} and {p.name}.")
                files[frame] = p
        # where every undistorted pixel centre lies in the video (the same for all frames)
        j, i = np.meshgrid(np.arange(cam.width, dtype=np.float64), np.arange(cam.height, dtype=np.float64))
        y = (i - cam.K[1, 2]) / cam.K[1, 1]
        x = (j - cam.K[0, 2] - cam.K[0, 1] * y) / cam.K[0, 0]
        src = np.rint(to_pixels(cam.K, distort_points(np.stack([x, y], -1), cam.dist))).astype(np.int64)
        inside = (src[..., 0] >= 0) & (src[..., 0] < cam.width) & (src[..., 1] >= 0) & (src[..., 1] < cam.height)
        su, sv = np.where(inside, src[..., 0], 0), np.where(inside, src[..., 1], 0)
        for frame, path in files.items():
            image = _mask_image(path)
            if image.shape != (cam.height, cam.width):
                raise ValueError(
                    f"{path}: mask is {image.shape[1]} x {image.shape[0]} px but camera {cam.name!r} "
                    f"records {cam.width} x {cam.height}."
                )
            out[index[frame], v, : cam.height, : cam.width] = image[sv, su] & inside
    return out


def _stats(err) -> dict:
    err = err[np.isfinite(err)]
    if err.size == 0:
        return {"median_px": None, "mean_px": None, "count": 0}
    return {"median_px": float(np.median(err)), "mean_px": float(err.mean()), "count": int(err.size)}


def _frame_filter(frames: np.ndarray, selection: slice | None) -> np.ndarray:
    """Positions of the frame numbers that `selection` keeps (start <= n < stop, step)."""
    if selection is None:
        return np.arange(len(frames))
    if not isinstance(selection, slice):
        raise ValueError(f"frames must be a slice of frame numbers (e.g. slice(0, 100)), got {selection!r}.")
    start = frames.min() if selection.start is None else selection.start
    stop = frames.max() + 1 if selection.stop is None else selection.stop
    step = 1 if selection.step is None else selection.step
    if step < 1:
        raise ValueError(f"frames: the step must be a positive integer, got {step}.")
    keep = (frames >= start) & (frames < stop) & ((frames - start) % step == 0)
    if not keep.any():
        raise ValueError(
            f"frames {start}:{stop}"
            + (f":{step}" if step != 1 else "")
            + f" selects no frame; the recording has frame numbers {frames.min()}..{frames.max()}."
        )
    return np.flatnonzero(keep)


def _complete_frames(recording):
    """Frame numbers missing from every camera inserted as frames without detections, so
    that frames stay equally spaced in time for the temporal stage and the jitter; the
    step is the numbers' greatest common difference (every 2nd frame written: step 2)."""
    frames = recording.frames
    if len(frames) < 2:
        return recording
    step = int(np.gcd.reduce(np.diff(frames)))
    full = np.arange(frames[0], frames[-1] + 1, step)
    if len(full) == len(frames):
        return recording
    if len(full) > 2 * len(frames) + 10:
        jump = int(np.argmax(np.diff(frames)))
        raise ValueError(
            f"frame numbers jump from {frames[jump]} to {frames[jump + 1]} ({len(frames)} frames spread over "
            f"{len(full)} numbers): several takes in one folder? Fit them one at a time (frames=/--frames START:STOP)."
        )
    rows = np.searchsorted(full, frames)

    def spread(a):
        out = np.zeros((len(full), *a.shape[1:]), a.dtype)
        out[rows] = a
        return out

    present = recording.present or tuple(np.ones(len(frames), bool) for _ in recording.views)
    return dataclasses.replace(recording, frames=full, keypoints=tuple(spread(k) for k in recording.keypoints),
                               present=tuple(spread(p) for p in present))  # fmt: skip


def _ranges(numbers) -> str:
    """[1, 2, 3, 7, 9, 10] -> "1..3, 7, 9..10"."""
    parts, start = [], None
    for i, n in enumerate(numbers):
        start = n if start is None else start
        if i + 1 == len(numbers) or numbers[i + 1] != n + 1:
            parts.append(f"{start}" if start == n else f"{start}..{n}")
            start = None
    return ", ".join(parts)


def _one_view_warning(keypoints, frames) -> str | None:
    """The frames of a multi-camera fit whose subject only one camera sees (T, V, K, 3)."""
    one = frames[(keypoints[..., 2] > 0).any(-1).sum(1) == 1]
    if keypoints.shape[1] < 2 or not len(one):
        return None
    return (
        f"warning: {len(one)} of {len(frames)} frames have the subject in one camera only (frame numbers "
        f"{_ranges(one)}): depth there is not observed, it follows the neighbouring frames and the body's size."
    )


def _blind_view_warning(keypoints, views) -> str | None:
    """The cameras that never see the subject (T, V, K, 3): fitted without them."""
    blind = [v for v, seen in zip(views, (keypoints[..., 2] > 0).any((0, 2))) if not seen]
    if not blind or len(blind) == len(views):
        return None
    folders = f"camera folder {blind[0]!r} never shows" if len(blind) == 1 else \
        f"camera folders {', '.join(map(repr, blind))} never show"  # fmt: skip
    return (
        f"warning: {folders} the "
        "subject the other cameras agree on (no one detected, another person, or a wrong camera in the "
        "calibration); fitted without them."
    )


def _overlap_warnings(recording) -> list[str]:
    """Cameras most of whose frame numbers no other camera has: unsynchronised, or
    numbered from another start, yet sharing a few numbers by chance."""
    if recording.present is None or len(recording.views) < 2:
        return []
    present = np.array(recording.present)  # (V, T)
    out = []
    for view, have in zip(recording.views, present):
        shared = int((have & (present.sum(0) >= 2)).sum())
        if shared < 0.5 * have.sum():
            out.append(f"warning: camera folder {view!r} shares only {shared} of its {int(have.sum())} frame numbers "
                       "with the other cameras; are the cameras synchronised and numbered alike?")  # fmt: skip
    return out


def _ignored_warning(recording) -> list[str]:
    """The JSON files left unread because their camera's frames are named otherwise."""
    ignored = recording.ignored
    if not ignored:
        return []
    shown = ", ".join(ignored[:4]) + (f", ... ({len(ignored)} in all)" if len(ignored) > 4 else "")
    return [
        f"warning: not read, named unlike the other frames of their camera: {shown}; rename them like "
        "the others if they are frames of this recording."
    ]


def _read_summary(recording) -> str:
    present = recording.present or tuple(np.ones(recording.num_frames, bool) for _ in recording.views)
    parts = []
    for view, have in zip(recording.views, present):
        numbers = recording.frames[have]
        parts.append(f"{view} {len(numbers)} frames" + (f" ({numbers[0]}..{numbers[-1]})" if len(numbers) else ""))
    line = f"read     {len(recording.views)} cameras: " + ", ".join(parts)
    if len(present) > 1:
        missing = int((np.sum(present, 0) < len(present)).sum())
        if missing:
            line += f"; {missing} of {recording.num_frames} frames lack a file in some camera (masked there)"
    return line


def ground_depth(camera, detections, model_keypoints, names, up: str) -> dict | None:
    """A second, independent depth with one camera: where the feet meet the floor.

    Assumes the floor is the calibration world's 0 plane across `up` (Qualisys and
    Pose2Sim calibrations put their origin on the floor). Per frame, the ray of every
    detected foot point (ankles, heels, toes; undistorted OpenCV pixels) is cut with the
    floor, and the point whose cut is nearest relative to its fitted depth is kept: a
    lifted foot's ray meets the floor behind the foot, the standing foot's at the foot.
    Returns the medians of those cut depths, of the fitted depths of the same points and
    of their ratio (cut / fitted; 1 when the fitted size is right), or None (camera not
    above the floor, no feet seen).
    """
    axis, sign = _AXES[up]
    centre = camera.center
    if sign * centre[axis] <= 0:
        return None
    feet = [k for k, n in enumerate(names) if n.endswith(("ankle", "heel", "big_toe", "small_toe"))]
    ground, fitted = [], []
    for det, model in zip(detections, model_keypoints):
        best = None
        for k in feet:
            if det[k, 2] <= 0:
                continue
            ray = camera.R.T @ np.linalg.solve(camera.K, np.array([det[k, 0], det[k, 1], 1.0]))  # depth 1
            fit = (camera.R @ model[k] + camera.t)[2]
            if sign * ray[axis] >= 0 or fit <= 0:  # at or above the horizon: never meets the floor
                continue
            cut = -centre[axis] / ray[axis]
            if best is None or cut / fit < best[0] / best[1]:
                best = (cut, fit)
        if best is not None:
            ground.append(best[0])
            fitted.append(best[1])
    if not ground:
        return None
    ground, fitted = np.array(ground), np.array(fitted)
    return {"ground_depth_m": float(np.median(ground)), "fitted_depth_m": float(np.median(fitted)),
            "ratio": float(np.median(ground / fitted))}  # fmt: skip


def _fill_empty_frames(params: dict, empty: np.ndarray) -> dict:
    """Starting values of frames no view sees copied from the nearest frame that is seen
    (the fit then leaves them to the priors and, in stage 2, to their neighbours)."""
    if not empty.any():
        return params
    seen = np.flatnonzero(~empty)
    nearest = seen[np.abs(np.arange(len(empty))[:, None] - seen[None]).argmin(1)]
    return {k: np.asarray(v)[nearest] for k, v in params.items()}


def _distorted_pixels(cam, uv_undistorted):
    """Undistorted OpenCV pixels (..., 2) → the video's distorted pixels (same K)."""
    from ..geometry.camera import to_pixels, distort_points

    K = cam.K
    y = (uv_undistorted[..., 1] - K[1, 2]) / K[1, 1]
    x = (uv_undistorted[..., 0] - K[0, 2] - K[0, 1] * y) / K[0, 0]
    return to_pixels(K, distort_points(np.stack([x, y], -1), cam.dist))


def _overlay(path, cam, view, frame_numbers, picks, detections, model_kp, vertices, faces):
    """One PNG per view, a column per picked frame: the image-size canvas (no images are
    read) on top, the same zoomed onto the person below; pixels are the video's own."""
    from matplotlib import colormaps
    from matplotlib.collections import LineCollection
    from matplotlib.colors import Normalize
    from matplotlib.figure import Figure
    from matplotlib.patches import Rectangle
    from PIL import Image, ImageDraw

    from ..geometry.camera import project_points
    from ..viz.plot import save_figure

    W, H = (cam.width, cam.height) if cam.width > 0 else (int(2 * cam.K[0, 2]) + 1, int(2 * cam.K[1, 2]) + 1)
    fig = Figure(figsize=(4.2 * len(picks) + 1.0, 4.2 * H / W + 4.6), dpi=110, layout="constrained")
    axes = fig.subplots(2, len(picks), squeeze=False, height_ratios=[H / W, 1.0])
    norm = Normalize(0.0, 1.0)
    sc = None
    for col, t in enumerate(picks):
        uv, z = project_points(cam.K, cam.dist, cam.R, cam.t, vertices[t])
        front = (z[faces] > 0).all(1)
        model, zk = project_points(cam.K, cam.dist, cam.R, cam.t, model_kp[t])
        det = detections[t]
        seen = det[:, 2] > 0
        duv = _distorted_pixels(cam, det[:, :2])
        err = np.linalg.norm(model - duv, axis=-1)[seen]
        # the mesh's silhouette, drawn as an image (one artist instead of thousands of triangles)
        sil = Image.new("L", (W, H))
        draw = ImageDraw.Draw(sil)
        for tri in uv[faces[front]]:
            draw.polygon(tri.ravel().tolist(), fill=255)
        rgba = np.zeros((H, W, 4))
        rgba[..., :3] = (0.79, 0.64, 0.49)
        rgba[..., 3] = 0.55 * (np.asarray(sil) > 0)
        box = np.concatenate([uv[z > 0], duv[seen]])
        if len(box) == 0:  # nothing to zoom onto: the whole image
            box = np.array([[-0.5, -0.5], [W - 0.5, H - 0.5]])
        lo, hi = box.min(0), box.max(0)
        centre, half = 0.5 * (lo + hi), 0.6 * max(hi - lo) + 10.0
        for row, ax in enumerate(axes[:, col]):
            ax.add_patch(Rectangle((-0.5, -0.5), W, H, facecolor="#f4f4f4", edgecolor="#888888", lw=0.8, zorder=0))
            ax.imshow(rgba, extent=(-0.5, W - 0.5, H - 0.5, -0.5), interpolation="nearest", zorder=0.5)
            ax.add_collection(
                LineCollection([np.stack([a, b]) for a, b in zip(duv[seen], model[seen])], colors="#c53030", lw=0.8)
            )
            ax.scatter(*model[zk > 0].T, marker="x", s=22, c="#c53030", lw=1.2, label="model keypoint")
            sc = ax.scatter(
                *duv[seen].T,
                s=16,
                c=det[seen, 2],
                cmap=colormaps["viridis"],
                norm=norm,
                edgecolors="k",
                linewidths=0.3,
                label="detection",
            )
            if row == 0:
                ax.set_xlim(-0.5, W - 0.5)
                ax.set_ylim(H - 0.5, -0.5)  # image rows grow downwards
                ax.set_title(
                    f"{view}, frame {frame_numbers[t]}: "
                    + (f"median {np.median(err):.1f} px" if seen.any() else "no detection"),
                    fontsize=9,
                )
            else:
                ax.set_xlim(centre[0] - half, centre[0] + half)
                ax.set_ylim(centre[1] + half, centre[1] - half)
                ax.set_title("zoomed", fontsize=8)
            ax.set_aspect("equal")
            ax.tick_params(labelsize=7)
    axes[0, 0].legend(loc="lower left", fontsize=7, framealpha=0.8)
    fig.colorbar(sc, ax=axes.ravel().tolist(), shrink=0.6, label="detection confidence")
    return save_figure(fig, path)


def fit_recording(
    keypoints_dir,
    calib_path,
    out_dir,
    layout: str | None = None,
    body="default-low",
    views=None,
    frames: slice | None = None,
    temporal: bool = True,
    masks_dir=None,
    fps: float | None = None,
    weights=None,
    progress: bool = True,
    resolve_swaps: bool = True,
    floor: float | None = None,
    log=None,
) -> dict:
    """Fit SMPL to a multi-camera OpenPose recording and write results to `out_dir`.

    Args:
        keypoints_dir: folder with one OpenPose ``--write_json`` folder per camera (any
            per-frame file naming: `formats.openpose`); a Pose2Sim Config.toml in it or
            its parent (project/pose) gives the layout and fps not passed here.
        calib_path: calibration file (Pose2Sim .toml, Qualisys .qca.txt, EasyMocap
            intri/extri.yml or their folder, jaxmocap .npz); cameras matched to the
            keypoint folders by name (`formats.align_views`).
        out_dir: output folder (created); see the module docstring for what is written.
        layout: "body25" | "body25b" | "coco18" | "halpe26", the model the detector ran with; None takes
            Config.toml's pose_model, else detects it (`app.layout.check_layout`). A named
            layout is checked against the skeleton too: a clearly worse fit is warned
            about, an absurd one refused.
        body: "default-low", "default-full", "mannequin" or a model file.
        views: camera folder names to use (default: all).
        frames: slice of frame numbers (as in the file names) to fit; default all, or
            Config.toml's frame_range (Pose2Sim's [start, stop) positions).
        temporal: run stage 2 (DCT temporal prior); otherwise stop after stage 1.
        resolve_swaps: flip back views whose detector swapped the legs before stage 1
            (`methods.multiview.resolve_left_right`); False is MuVS as written.
        masks_dir: optional folder of per-camera PNG person masks (module docstring);
            they add the silhouette term to stage 1.
        fps: the recording's frame rate (OpenPose files do not store it); None takes
            Config.toml's frame_rate, else `DEFAULT_FPS`.
        weights: `methods.multiview.MuVSWeights` or a preset name (`methods.multiview.PRESETS`);
            None: "validated", the weights chosen on the development subjects (λ_θ, λ_β).
        floor: the floor's height (m) along the calibration world's up axis (`world_to_y_up`;
            0 for Qualisys and Pose2Sim calibrations, whose origin is on the floor). Used
            when one camera sees the person: both stages hold the feet on it and the body is
            scaled about the camera by what it says of the body's size (the floor of
            `methods.multiview.multiview_smplify`); with several cameras triangulation
            measures depth and the floor is not used (a note says so). None: no floor.
        progress: show a tqdm bar over the stages on stderr.
        log: called with one line per finding before the fit (cameras and frames read,
            layout and fps and where they came from; lines starting "warning:" are
            warnings); None: silent (they are in the report's "notes").
    Returns:
        The report (also written as report.json): frames, views, layout check,
        reprojection errors, jitter, timings, output paths; "monocular" (one camera saw
        the person: depth is not observed, `MuVSResult.monocular`) with "depth" (the
        method's record, `MuVSResult.depth`: `methods.multiview.monocular_depth` of the final
        fit with stage 1's uncertainty, plus "camera" and "floor", `ground_depth`).
    Raises:
        ValueError (KeypointFileError, CalibrationError) naming the file or argument.
    """
    from ..formats import align_views, load_calibration, read_config, read_openpose
    from ..methods.multiview import (
        camera_data,
        final_depth,
        initialise,
        monocular_view,
        place_monocular,
        preset,
        resolve_left_right,
        stage_one,
        stage_two,
    )
    from ..geometry.keypoints import KEYPOINT_FORMATS, keypoint_regressor, regress_keypoints
    from ..geometry.triangulation import projection_matrices, select_person
    from ..body.io import resolve_body
    from ..body.posed import posed_arrays
    from .layout import check_layout

    notes: list[str] = []

    def say(line):
        notes.append(line)
        if log is not None:
            log(line)

    # every input is checked before any fitting: output folder, settings, files
    out_dir = output_folder(out_dir, create=False)  # created only once the inputs are good
    if floor is not None and not np.isfinite(floor):
        raise ValueError(f"floor must be a finite height in metres (0: the world's 0 plane), got {floor!r}.")
    config = read_config(keypoints_dir) if Path(keypoints_dir).is_dir() else None
    named, named_by = layout, "--layout"
    if named is None and config is not None and config.pose_model is not None:
        named, named_by = config.layout, f"{config.sources['pose_model']} (pose_model = {config.pose_model!r})"
    fps_note = None  # said once the files are read, so that a bad file is the only message
    if fps is None:
        if config is not None and config.fps is not None:
            fps = config.fps
            fps_note = f"fps      {fps:g}, from {config.fps_from}" + (
                " (frame_rate)" if config.fps_from.suffix == ".toml" else
                f" (its header; {config.sources['frame_rate']} says frame_rate = 'auto')")  # fmt: skip
        else:
            fps = DEFAULT_FPS
            fps_note = (f"warning: the frame rate is not known (no fps given, no frame_rate in a Config.toml, "
                        "no readable video in the project's videos/); "
                        f"assuming {fps:g} fps: give the recording's (--fps).")  # fmt: skip
    try:
        positive = not isinstance(fps, bool) and float(fps) > 0
    except (TypeError, ValueError):
        positive = False
    if not positive:
        raise ValueError(f"fps must be a positive number of frames per second, got {fps!r}.")
    fps = float(fps)
    if fps_note is None and config is not None and config.fps is not None and fps != config.fps:
        fps_note = (f"warning: fps {fps:g} as given, but {config.fps_from} says {config.fps:g}; "
                    "the given one is used.")  # fmt: skip
    weights = preset("validated" if weights is None else weights)
    timings: dict[str, float] = {}
    stages = ["read", "select person", "initialise", "stage 1", "stage 2", "write"]
    if not temporal:
        stages.remove("stage 2")
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=len(stages), unit="stage", leave=False)
    clock = [time.perf_counter()]

    def begin(name):
        if bar is not None:
            bar.set_description(f"multiview: {name}")

    def done(name):
        now = time.perf_counter()
        timings[name] = now - clock[0]
        clock[0] = now
        if bar is not None:
            bar.update()

    try:
        begin("read")
        recording = read_openpose(keypoints_dir, named, views)
        say(_read_summary(recording))
        for warning in _ignored_warning(recording) + _overlap_warnings(recording):
            say(warning)
        keep = _frame_filter(recording.frames, frames)
        if frames is None and config is not None and config.frame_range is not None:
            start, stop = config.frame_range  # Pose2Sim's: positions in the frame order
            keep = keep[start:stop]
            if not len(keep):
                raise ValueError(f"{config.sources['frame_range']}: frame_range = [{start}, {stop}] selects no frame; the "
                                 f"recording has {recording.num_frames}.")  # fmt: skip
            say(
                f"frames   positions {start}..{min(stop, recording.num_frames) - 1} (frame numbers "
                f"{recording.frames[keep[0]]}..{recording.frames[keep[-1]]}), from {config.sources['frame_range']} (frame_range)"
            )
        recording = _complete_frames(dataclasses.replace(
            recording, frames=recording.frames[keep], keypoints=tuple(k[keep] for k in recording.keypoints),
            present=None if recording.present is None else tuple(p[keep] for p in recording.present),
        ))  # fmt: skip
        calibration = load_calibration(calib_path)
        cameras = align_views(recording, calibration)
        if len(calibration) > len(cameras):
            unused = sorted({c.name for c in calibration} - {c.name for c in cameras})
            say(f"calib    {len(calibration)} cameras in {calib_path}; without keypoints, not used: {unused}")
        body_model = resolve_body(body)
        if fps_note:
            say(fps_note)
        done("read")

        begin("select person")
        subject = select_person(recording, cameras)  # (V, T, K, 3), undistorted, OpenCV centres
        check = check_layout(subject, projection_matrices(cameras), body_model, subject.shape[2], named, named_by)
        say(check.message)
        layout = check.layout
        recording = dataclasses.replace(recording, layout=layout)
        keypoints = np.moveaxis(subject, 0, 1).copy()  # (T, V, K, 3)
        # never NaN: a view without the subject in a frame is confidence 0 at (0, 0)
        bad = ~np.isfinite(keypoints).all(-1) | (keypoints[..., 2] <= 0)
        keypoints[bad] = 0.0
        empty = ~(keypoints[..., 2] > 0).any((1, 2))  # frames no view sees
        if empty.all():
            raise ValueError(
                f"{keypoints_dir}: no frame has the same person in two views consistently with "
                f"{calib_path}; check that the calibration belongs to this recording."
            )
        if (warning := _one_view_warning(keypoints, recording.frames)) is not None:
            say(warning)
        if (warning := _blind_view_warning(keypoints, recording.views)) is not None:
            say(warning)
        done("select person")

        begin("initialise")
        K = np.stack([c.K for c in cameras])
        K[:, :2, 2] += 0.5  # jaxmocap's pixel centres (module docstring), as pinhole_camera
        shifted = keypoints.copy()
        shifted[..., :2] += 0.5 * (keypoints[..., 2:] > 0)
        masks = None if masks_dir is None else read_masks(masks_dir, recording.views, recording.frames, cameras)
        data = camera_data(body_model, K, np.stack([c.R for c in cameras]), np.stack([c.t for c in cameras]),
                           shifted, layout, masks=masks)  # fmt: skip
        data = resolve_left_right(data) if resolve_swaps else data
        p0 = _fill_empty_frames(initialise(data, weights.num_betas), empty)
        done("initialise")

        up, _ = world_to_y_up(cameras)
        plane = None  # the floor term's (up (3,), height): with one camera only, as multiview_smplify
        if floor is not None:
            if monocular_view(data) is None:
                say(f"note: --floor {floor:g} is not used: {len(recording.views)} cameras see the person and "
                    "triangulation measures depth; the floor serves one camera.")  # fmt: skip
            else:
                axis, sign = _AXES[up]
                plane = (np.eye(3)[axis] * sign, float(floor))

        begin("stage 1")
        p1, costs = stage_one(data, p0, weights, silhouettes=masks is not None, floor=plane)
        p1, placed = place_monocular(data, p1, plane)  # one view seeing the person: its depth record
        done("stage 1")
        final = {"pose": p1["pose"], "trans": p1["trans"], "betas": np.median(p1["betas"], 0)}
        if temporal:
            begin("stage 2")
            p2, c2 = stage_two(data, p1, weights, silhouettes=False, floor=plane)
            costs.update(c2)
            final = {"pose": p2["pose"], "trans": p2["trans"], "betas": p2["betas"]}
            done("stage 2")

        begin("write")
        for name, p in (("stage 1", p1), ("final", final)):
            if not all(np.isfinite(v).all() for v in p.values()):
                raise FloatingPointError(f"the {name} fit produced NaN; please report this recording.")
        report = _write_outputs(
            out_dir, (keypoints_dir, calib_path), recording, cameras, body_model, layout, keypoints, empty,
            p1, final, costs, fps, regressor=keypoint_regressor(body_model, layout),
            names=KEYPOINT_FORMATS[layout], temporal=temporal, weights=weights, silhouettes=masks is not None,
        )  # fmt: skip
        done("write")
    finally:
        if bar is not None:
            bar.close()
    report["resolve_swaps"] = resolve_swaps
    report["floor"] = {"height_m": floor, "used": plane is not None}  # along report["world_up"]
    report["layout_check"] = {"verdict": check.verdict, "named": named, "named_by": named_by if named else None,
                              "scores": check.scores}  # fmt: skip
    report["monocular"] = placed is not None  # as `MuVSResult.monocular`: one camera saw the person
    if report["monocular"]:
        camera = cameras[placed["view"]]
        report["depth"] = {**final_depth(data, final, placed), "camera": camera.name}  # `MuVSResult.depth`
        d = report["depth"]
        say(f"warning: one camera ({camera.name}): depth along its line of sight is not observed; it comes from "
            f"{d['from']}: {d['depth_m']:.2f} m ± {d['depth_uncertainty_m']:.2f} m (1σ). Add a second camera to "
            "measure it.")  # fmt: skip
        model_kp = regress_keypoints(
            keypoint_regressor(body_model, layout),
            *posed_arrays(body_model, final["pose"], final["betas"], final["trans"], dtype=np.float64),
        )
        cut = ground_depth(camera, keypoints[:, placed["view"]], model_kp, KEYPOINT_FORMATS[layout],
                           report["world_up"])  # fmt: skip
        d["floor"] = cut
        if cut is not None and plane is None and abs(cut["ratio"] - 1) > 2 * d["relative"]:
            say(f"warning: the feet would meet the floor (the world's 0 plane) at {cut['ground_depth_m']:.2f} m from "
                f"the camera, but the fit puts them at {cut['fitted_depth_m']:.2f} m: the person is "
                f"{'smaller' if cut['ratio'] < 1 else 'larger'} than the mean body, "
                "or the floor is elsewhere. If the floor is the world's 0 plane, --floor 0 fits with it.")  # fmt: skip
    report["notes"] = notes
    report["timings_s"] = {k: round(v, 3) for k, v in timings.items()}
    report["timings_s"]["total"] = round(sum(timings.values()), 3)
    _save_reports(out_dir, report)
    return report


def _write_outputs(
    out_dir,
    sources,
    recording,
    cameras,
    body,
    layout,
    keypoints,
    empty,
    p1,
    final,
    costs,
    fps,
    regressor,
    names,
    temporal,
    weights,
    silhouettes,
) -> dict:
    from ..motion.amass import rotate_world, pelvis_rest, save_amass
    from ..motion.sequence import Motion
    from ..geometry.keypoints import regress_keypoints
    from ..geometry.triangulation import projection_matrices
    from ..viz.mesh import export_sequence
    from ..body.posed import posed_arrays

    out_dir.mkdir(parents=True, exist_ok=True)
    T, V = keypoints.shape[:2]
    verts1, joints1 = posed_arrays(body, p1["pose"], p1["betas"], p1["trans"], dtype=np.float64)
    verts, joints = posed_arrays(body, final["pose"], final["betas"], final["trans"], dtype=np.float64)

    # reprojection in undistorted OpenCV pixels (the detections' frame)
    P = projection_matrices(cameras)  # (V, 3, 4)
    errors = {}
    for name, v, j in (("stage1", verts1, joints1), ("final", verts, joints)):
        kp3 = regress_keypoints(regressor, v, j)
        x = np.einsum("vab,tkb->tvka", P[:, :, :3], kp3) + P[None, :, None, :, 3]
        errors[name] = reprojection_errors(x[..., :2] / x[..., 2:], keypoints)
    kp_final = regress_keypoints(regressor, verts, joints)

    # AMASS npz: calibration world → y up → (save_amass) z up
    up, to_y = world_to_y_up(cameras)
    betas16 = np.zeros(16)
    betas16[: len(final["betas"])] = final["betas"]
    j0 = pelvis_rest(body, betas16)
    poses_y, trans_y = rotate_world(final["pose"].astype(np.float64), final["trans"].astype(np.float64), to_y, j0)
    motion = Motion(poses_y, trans_y, fps, betas=betas16, gender="neutral", name="multiview")
    npz = save_amass(motion, out_dir / "smpl.npz", body=body, layout="smpl")

    # meshes, y up
    verts_y = verts @ to_y.T
    ply = export_sequence(verts_y, body.faces, out_dir / "meshes", fmt="ply", every=math.ceil(T / MAX_PLY))
    glb = export_sequence(verts_y, body.faces, out_dir / "meshes", fmt="glb", every=math.ceil(T / MAX_GLB_NODES))

    picks = sorted({0, T // 2, T - 1})
    faces = np.asarray(body.faces)
    overlays = [
        _overlay(out_dir / "overlays" / f"{view}.png", cam, view, recording.frames, picks, keypoints[:, v],
                 kp_final, verts, faces)
        for v, (view, cam) in enumerate(zip(recording.views, cameras))
    ]  # fmt: skip

    def table(err):
        return {
            "overall": _stats(err),
            "per_view": {view: _stats(err[:, v]) for v, view in enumerate(recording.views)},
            "per_keypoint": {n: _stats(err[:, :, k]) for k, n in enumerate(names)},
        }

    seen = keypoints[..., 2] > 0
    return {
        "keypoints": str(sources[0]),
        "calibration": str(sources[1]),
        "layout": layout,
        "body": body.kind,
        "frames": {
            "count": T, "first": int(recording.frames[0]), "last": int(recording.frames[-1]),
            "fps": fps, "without_subject": [int(f) for f in recording.frames[empty]],
        },
        "views": {
            view: {"camera": cam.name, "frames_with_subject": int(seen[:, v].any(-1).sum()),
                   "image_size": [cam.width, cam.height]}
            for v, (view, cam) in enumerate(zip(recording.views, cameras))
        },
        "world_up": up,
        "min_confidence": MIN_CONFIDENCE,
        "reprojection": {"stage1": table(errors["stage1"]), "final": table(errors["final"])},
        "jitter_mm_s2": {"stage1": jitter(joints1, fps), "final": jitter(joints, fps)},
        "temporal": temporal,
        "silhouettes": silhouettes,
        "betas": [float(b) for b in final["betas"]],
        "costs": {k: float(c) for k, c in costs.items()},
        "weights": {k: (list(v) if isinstance(v, tuple) else v) for k, v in dataclasses.asdict(weights).items()},
        "outputs": {
            "smpl": npz.name,
            "meshes": [str(p.relative_to(out_dir)) for p in ply + glb],
            "overlays": [str(p.relative_to(out_dir)) for p in overlays],
        },
    }  # fmt: skip


def _fmt(x, spec=".1f"):
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else format(x, spec)


def _finite(x):
    """The report with NaN/inf (e.g. jitter of fewer than 3 frames) as null: strict JSON."""
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_finite(v) for v in x]
    return None if isinstance(x, float) and not math.isfinite(x) else x


def _save_reports(out_dir: Path, report: dict) -> None:
    report.update(_finite(report))
    (out_dir / "report.json").write_text(json.dumps(report, indent=2, allow_nan=False) + "\n")
    r, f = report["reprojection"], report["frames"]
    lines = [
        "# Multi-view SMPLify report",
        "",
        f"{f['count']} frames ({f['first']}..{f['last']} at {f['fps']:g} fps), {len(report['views'])} views, "
        f"layout {report['layout']}, body {report['body']}, world up {report['world_up']}"
        + (f"; frames without the subject in any view: {f['without_subject']}" if f["without_subject"] else "")
        + ".",
        "",
        f"Reprojection error in pixels over detections with confidence ≥ {report['min_confidence']} "
        "(undistorted pixels):",
        "",
        "| view | frames with subject | stage 1 median | final median | final mean | detections |",
        "|---|---|---|---|---|---|",
    ]
    for view, info in report["views"].items():
        s1, fin = r["stage1"]["per_view"][view], r["final"]["per_view"][view]
        lines.append(
            f"| {view} | {info['frames_with_subject']} | {_fmt(s1['median_px'])} | "
            f"{_fmt(fin['median_px'])} | {_fmt(fin['mean_px'])} | {fin['count']} |"
        )
    s1, fin = r["stage1"]["overall"], r["final"]["overall"]
    lines += [
        f"| **all** | | {_fmt(s1['median_px'])} | {_fmt(fin['median_px'])} | {_fmt(fin['mean_px'])} | {fin['count']} |",
        "",
        "| keypoint | final median | final mean | detections |",
        "|---|---|---|---|",
    ]
    for name, s in r["final"]["per_keypoint"].items():
        lines.append(f"| {name} | {_fmt(s['median_px'])} | {_fmt(s['mean_px'])} | {s['count']} |")
    j = report["jitter_mm_s2"]
    lines += [
        "",
        "Jitter of the 24 SMPL joints, mean ‖second difference‖·fps² (mm/s²): "
        f"stage 1 {_fmt(j['stage1'], '.0f')}, final {_fmt(j['final'], '.0f')}"
        + ("" if report["temporal"] else " (stage 2 skipped: --no-temporal)")
        + ".",
        "",
        "Stage 1 "
        + (
            "fitted keypoints, then keypoints and silhouettes (person masks)."
            if report["silhouettes"]
            else "fitted keypoints only (no person masks given)."
        ),
        "",
        "Timings (s): " + ", ".join(f"{k} {v:.1f}" for k, v in report["timings_s"].items()) + ".",
        "",
        *[f"- {note}" for note in report.get("notes", [])],
        "",
        "Outputs: " + ", ".join([report["outputs"]["smpl"], *report["outputs"]["overlays"], "meshes/"]) + ".",
        "",
    ]
    (out_dir / "report.md").write_text("\n".join(lines))
