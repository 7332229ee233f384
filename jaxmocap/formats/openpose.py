"""OpenPose keypoints per camera folder and frame, and the calibration they belong to.

OpenPose's ``--write_json`` writes one file per frame, ``<name>_<frame:012d>_keypoints.json``:

    {"version": 1.3, "people": [{"person_id": [-1], "pose_keypoints_2d": [u0, v0, c0, u1, ...],
                                 "face_keypoints_2d": [], "hand_left_keypoints_2d": [], ...}]}

with K (u, v, confidence) triples per person in the model's order (BODY_25, BODY_25B,
COCO-18; HALPE_26: RTMPose's, which Pose2Sim >= 0.9 writes in this format; counts in
`KEYPOINT_COUNTS`, names in `jaxmocap.geometry.keypoints.KEYPOINT_FORMATS`), pixel
centres at integers, undetected keypoints as (0, 0, 0). A recording is one folder per
camera under a root (Pose2Sim: ``pose/cam01_json/``; EasyMocap: ``openpose/01/``).

File names: labs rename these files, so any ``*.json`` file whose name holds a number is
read, and **the frame number is the last run of digits in the name** (``.json`` and a
trailing ``_keypoints`` aside): ``cam01_000000000012_keypoints.json`` (OpenPose),
``cam01_000012.json`` (Pose2Sim/RTMLib), ``cam01.0012.json``, ``frame_0012.json`` and
``0012.json`` are all frame 12. A name whose number comes before the camera's
(``0012_cam01.json``) is misread; two files giving one frame number are refused.

A camera's frames share one naming pattern (the name with its frame number taken out:
``cam01.#.json``). Files of another pattern in a camera folder are strays (Pose2Sim's
demo holds ``del_000000_0.json`` beside ``cam03.0000.json``): the pattern with the most
files is read, the others are listed in `KeypointRecording.ignored` (a tie is refused).
All cameras' files in one folder (OpenPose run on every video with one ``--write_json``
folder: ``video1_000000000012_keypoints.json``, ``video2_...``) are told apart the same
way: there, every pattern with at least half as many files as the largest is a camera,
named by the name before its number (``video1``).

`read_openpose` gathers every view into padded arrays over the union of frame numbers,
matching frames across cameras by their numbers: a frame whose file is missing in one
view (`KeypointRecording.present`), or whose "people" list is empty, has no people there
(confidence 0). Cameras that share no frame number with any other camera are refused (an
unsynchronised or misnamed folder, not a longer recording). People are kept in the
file's order; which one is the subject is decided later across views
(`jaxmocap.geometry.triangulation.select_person`).

BODY_25 and BODY_25B both have 25 keypoints and cannot be told apart from the numbers:
`layout=None` reads 25-point files with `KeypointRecording.layout` None, to be decided
from the data (`jaxmocap.app.layout.detect_layout`).
"""

from __future__ import annotations

import dataclasses
import json
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .._files import natural_key
from .calibration import CalibratedCamera

__all__ = [
    "KEYPOINT_COUNTS",
    "KeypointFileError",
    "KeypointRecording",
    "align_views",
    "normalise_view_name",
    "read_openpose",
    "write_openpose",
]

KEYPOINT_COUNTS = {
    "body25": 25,
    "body25b": 25,
    "coco18": 18,
    "halpe26": 26,
    "mediapipe33": 33,
}  # mediapipe33: formats.video
# the last digit run of the stem (module docstring)
_FRAME = re.compile(r"(\d+)\D*\.json$", re.IGNORECASE)
_EMPTY_PARTS = (
    "face_keypoints_2d", "hand_left_keypoints_2d", "hand_right_keypoints_2d", "pose_keypoints_3d",
    "face_keypoints_3d", "hand_left_keypoints_3d", "hand_right_keypoints_3d",
)  # fmt: skip


class KeypointFileError(ValueError):
    """A keypoint folder or file is missing, unreadable or of another layout."""


@dataclasses.dataclass(frozen=True, eq=False)
class KeypointRecording:
    """OpenPose detections of several synchronised cameras.

    views: camera folder names, one per view.
    layout: "body25" | "body25b" | "coco18" | "halpe26", or None when the files fit
        several layouts (25 points: BODY_25 or BODY_25B) and none was named.
    frames: (T,) int frame numbers (union over views, increasing).
    keypoints: per view (T, P_v, K, 3) rows (u, v, confidence) in pixels, people in file
        order padded with zeros to P_v = max(1, most people in any frame of that view).
    present: per view (T,) bool, whether that view has a file for the frame (None: all).
    ignored: files that look like frames but were not read (another naming pattern than
        their camera's: module docstring), as paths relative to the keypoint folder.
    """

    views: tuple[str, ...]
    layout: str | None
    frames: np.ndarray
    keypoints: tuple[np.ndarray, ...]
    present: tuple[np.ndarray, ...] | None = None
    ignored: tuple[str, ...] = ()

    @property
    def num_frames(self) -> int:
        return len(self.frames)


def _keypoint_files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.is_file() and _FRAME.search(p.name))


def _pattern(name: str) -> str:
    """The file name with its frame number taken out: "cam01.0012.json" -> "cam01.#.json"."""
    m = _FRAME.search(name)
    return name[: m.start(1)] + "#" + name[m.end(1) :]


def _by_pattern(files: list[Path]) -> list[tuple[str, list[Path]]]:
    """Files grouped by naming pattern, most files first (then by pattern, natural order)."""
    groups: dict[str, list[Path]] = {}
    for f in files:
        groups.setdefault(_pattern(f.name), []).append(f)
    return sorted(groups.items(), key=lambda g: (-len(g[1]), natural_key(g[0])))


def _camera_name(pattern: str, fallback: str) -> str:
    return pattern[: pattern.index("#")].rstrip("._- ") or fallback


def _frame_map(folder: Path, files: list[Path]) -> dict[int, Path]:
    by_frame: dict[int, Path] = {}
    for f in files:
        frame = int(_FRAME.search(f.name).group(1))
        if frame in by_frame:
            raise KeypointFileError(f"{folder}: frame {frame} appears twice: {by_frame[frame].name} and {f.name}.")
        by_frame[frame] = f
    return by_frame


def _cameras_in(folder: Path, several: bool) -> tuple[list[tuple[str, dict[int, Path]]], list[Path]]:
    """The cameras (name, frame -> file) of `folder`'s files and the files left out
    (module docstring). several: the folder may hold several cameras (a flat folder);
    otherwise it is one camera, named after the folder."""
    groups = _by_pattern(_keypoint_files(folder))
    if not groups:
        return [], []
    if several:
        cameras = [g for g in groups if 2 * len(g[1]) >= len(groups[0][1])]
    else:
        if len(groups) > 1 and len(groups[1][1]) == len(groups[0][1]):
            raise KeypointFileError(
                f"{folder}: frame files named in two ways, {len(groups[0][1])} like {groups[0][1][0].name!r} and "
                f"{len(groups[1][1])} like {groups[1][1][0].name!r}; a camera folder holds one camera's frames "
                "(move the others into their own folder, or delete the stray files)."
            )
        cameras = groups[:1]
    names = [_camera_name(p, folder.name) for p, _ in cameras] if len(cameras) > 1 else [folder.name]
    if len(set(names)) < len(names):
        names = [p for p, _ in cameras]
    ignored = [f for g in groups if g not in cameras for f in g[1]]
    return [(n, _frame_map(folder, files)) for n, (_, files) in zip(names, cameras)], ignored


def _layouts_for(count: int) -> list[str]:
    return [name for name, k in KEYPOINT_COUNTS.items() if 3 * k == count]


def _pose_lists(path: Path) -> list:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise KeypointFileError(f"{path}: not valid JSON, truncated or corrupt ({e}).") from None
    if not isinstance(data, dict) or not isinstance(data.get("people"), list):
        raise KeypointFileError(f"{path}: no 'people' list; not an OpenPose --write_json file.")
    out = []
    for i, person in enumerate(data["people"]):
        flat = person.get("pose_keypoints_2d", []) if isinstance(person, dict) else None
        if not isinstance(flat, list):
            raise KeypointFileError(f"{path}: people[{i}] has no 'pose_keypoints_2d' list.")
        out.append(flat)
    return out


def _layout_of(files: Sequence[Path]) -> str | None:
    """The one layout whose count the first detection in `files` has; None when it fits
    several (BODY_25 / BODY_25B)."""
    for path in files:
        for i, flat in enumerate(_pose_lists(path)):
            if flat:
                fits = _layouts_for(len(flat))
                if not fits:
                    raise KeypointFileError(
                        f"{path}: people[{i}] has {len(flat)} numbers in pose_keypoints_2d; no known "
                        "layout has that many (" + ", ".join(f"{n}: {3 * k}" for n, k in KEYPOINT_COUNTS.items()) + ")."
                    )
                return fits[0] if len(fits) == 1 else None
    return None


def _read_people(path: Path, layout: str) -> list[np.ndarray]:
    K = KEYPOINT_COUNTS[layout]
    people = []
    for i, flat in enumerate(_pose_lists(path)):
        if len(flat) == 0:  # e.g. a face- or hand-only detection
            continue
        if len(flat) != 3 * K:
            fits = _layouts_for(len(flat))
            hint = (
                f"the layout that fits is {' or '.join(map(repr, fits))}"
                if fits
                else (
                    f"no known layout has {len(flat)} numbers ("
                    + ", ".join(f"{n}: {3 * k}" for n, k in KEYPOINT_COUNTS.items())
                    + ")"
                )
            )
            raise KeypointFileError(
                f"{path}: people[{i}] has {len(flat)} numbers in pose_keypoints_2d, but layout "
                f"{layout!r} expects {3 * K} ({K} keypoints x (u, v, c)); {hint}."
            )
        try:
            rows = np.asarray(flat, np.float64).reshape(K, 3)
        except (TypeError, ValueError):
            raise KeypointFileError(f"{path}: people[{i}].pose_keypoints_2d holds non-numbers.") from None
        if not np.all(np.isfinite(rows)):
            raise KeypointFileError(f"{path}: people[{i}].pose_keypoints_2d holds NaN or infinity.")
        people.append(rows)
    return people


def read_openpose(root, layout: str | None = "body25", views: Sequence[str] | None = None) -> KeypointRecording:
    """Read OpenPose JSON from one folder per camera under `root`.

    Args:
        root: folder holding one sub-folder per camera (or, for one camera, the JSON files).
        layout: "body25" | "body25b" | "coco18" | "halpe26", the model the detector ran
            with; None takes the count from the files (module docstring).
        views: camera folder names to read, in this order (in one flat folder: the camera
            names, module docstring); None reads every sub-folder holding numbered
            ``*.json`` files, in natural order (cam2 before cam10).
    Raises:
        KeypointFileError naming the folder or file: missing camera folder, no keypoint
        files, a camera folder whose files are named in two ways as often, truncated JSON,
        a keypoint count of another layout, cameras whose frame numbers do not overlap.
    """
    root = Path(root)
    if layout is not None and layout not in KEYPOINT_COUNTS:
        raise KeypointFileError(f"layout={layout!r} is not known; choose from {sorted(KEYPOINT_COUNTS)}.")
    if not root.is_dir():
        raise KeypointFileError(f"{root}: no such folder; give the folder holding one keypoint folder per camera.")
    if views is not None:
        views = [views] if isinstance(views, str) else list(views)
    subfolders = sorted(
        (p for p in root.iterdir() if p.is_dir() and _keypoint_files(p)), key=lambda p: natural_key(p.name)
    )
    cameras: list[tuple[str, dict[int, Path]]] = []
    ignored: list[Path] = []
    for folder in subfolders if views is None else [f for f in subfolders if f.name in views]:
        found_here, left = _cameras_in(folder, several=False)
        cameras += found_here
        ignored += left
    if not subfolders:
        cameras, ignored = _cameras_in(root, several=True)  # one folder: one camera, or all
    if views is None:
        if not cameras:
            raise KeypointFileError(
                f"{root}: no camera folders with numbered OpenPose '*.json' files (e.g. "
                "cam01/cam01_000000000012_keypoints.json); give the folder that holds one such "
                "folder per camera"
                + (f" ({root / 'pose'}; or the project folder itself as `jaxmocap multiview {root}`)."
                   if (root / "pose").is_dir() else ".")
            )  # fmt: skip
    else:
        named = dict(cameras)
        present = sorted(set(named) | {p.name for p in root.iterdir() if p.is_dir()}, key=natural_key)
        for v in views:
            if v in named:
                continue
            if (root / v).is_dir():
                raise KeypointFileError(
                    f"{root / v}: no OpenPose JSON files with a frame number in their name "
                    "('<name>_<frame>_keypoints.json', 'cam01.0012.json', ...)."
                )
            raise KeypointFileError(f"{root / v}: missing camera folder; cameras present in {root}: {present}.")
        cameras = [(v, named[v]) for v in views]
    names = [name for name, _ in cameras]
    per_view = [by_frame for _, by_frame in cameras]
    _check_overlap(names, per_view)
    found = layout or _layout_of([f for by_frame in per_view for f in by_frame.values()])
    # undecided (25 points, none named): read as BODY_25, whose count is the same
    per_view = [{frame: _read_people(f, found or "body25") for frame, f in by_frame.items()} for by_frame in per_view]
    frames = np.array(sorted(set().union(*per_view)), np.int64)
    index = {int(f): i for i, f in enumerate(frames)}
    K = KEYPOINT_COUNTS[found or "body25"]
    keypoints = []
    for people in per_view:
        P = max([1] + [len(p) for p in people.values()])
        out = np.zeros((len(frames), P, K, 3))
        for frame, rows in people.items():
            if rows:
                out[index[frame], : len(rows)] = np.stack(rows)
        keypoints.append(out)
    present = tuple(np.isin(frames, list(people)) for people in per_view)
    left_out = tuple(sorted((str(f.relative_to(root)) for f in ignored), key=natural_key))
    return KeypointRecording(tuple(names), found, frames, tuple(keypoints), present, left_out)


def _check_overlap(names: list[str], per_view: list[dict]) -> None:
    """Refuse a camera that shares no frame number with any other: its frames would be
    other instants, fitted as if they were more frames of the same recording."""
    if len(per_view) < 2:
        return
    for v, frames in enumerate(per_view):
        others = set().union(*(f for w, f in enumerate(per_view) if w != v))
        if not others & set(frames):
            ranges = ", ".join(f"{n} {min(f)}..{max(f)}" for n, f in zip(names, per_view))
            raise KeypointFileError(
                f"camera folder {names[v]!r} shares no frame number with the other cameras "
                f"(frame numbers: {ranges}); frames are matched by the number in the file "
                "names, so the cameras must be synchronised and numbered alike (Pose2Sim's "
                "synchronization writes pose-sync/), or leave it out with views=/--views."
            )


OPENPOSE_NAME = "{view}_{frame:012d}_keypoints.json"
#: `align_views` refuses a view with a detection further outside its image than this
#: share of the image's width (height).
OUTSIDE_IMAGE = 0.1


def write_openpose(root, views, keypoints, layout, frames=None, name: str = OPENPOSE_NAME) -> None:
    """Write detections as OpenPose's ``--write_json`` output, one folder per view.

    Args:
        root: output folder; view v goes to ``root/views[v]/<view>_<frame:012d>_keypoints.json``.
        views: camera folder names; keypoints: per view (T, P, K, 3) rows (u, v, c);
        layout: "body25" | "body25b" | "coco18" | "halpe26"; frames: (T,) frame numbers
            (default 0..T-1).
        name: file name pattern with {view} and {frame} (a lab's renaming, e.g.
            "{view}.{frame:04d}.json"; `read_openpose` takes the last number as the frame).
    A slot whose confidences are all 0 is padding and not written, so a frame with no one
    gets ``"people": []``.
    """
    root = Path(root)
    if layout not in KEYPOINT_COUNTS:
        raise KeypointFileError(f"layout={layout!r} is not known; choose from {sorted(KEYPOINT_COUNTS)}.")
    views = [views] if isinstance(views, str) else list(views)
    if len(views) != len(keypoints):
        raise ValueError(f"write_openpose: {len(views)} views but {len(keypoints)} keypoint arrays.")
    K = KEYPOINT_COUNTS[layout]
    for view, kp in zip(views, keypoints):
        kp = np.asarray(kp, np.float64)
        if kp.ndim != 4 or kp.shape[2:] != (K, 3):
            raise ValueError(
                f"write_openpose: view {view!r} keypoints must be (T, P, {K}, 3) for {layout!r}; got {kp.shape}."
            )
        T = kp.shape[0]
        frame_numbers = np.arange(T) if frames is None else np.asarray(frames, np.int64)
        if frame_numbers.shape != (T,):
            raise ValueError(f"write_openpose: frames must be ({T},), got {frame_numbers.shape}.")
        folder = root / view
        folder.mkdir(parents=True, exist_ok=True)
        for t, frame in enumerate(frame_numbers):
            people = [
                {
                    "person_id": [-1],
                    "pose_keypoints_2d": person.reshape(-1).tolist(),
                    **{k: [] for k in _EMPTY_PARTS},
                }
                for person in kp[t]
                if np.any(person[:, 2] > 0)
            ]
            text = json.dumps({"version": 1.3, "people": people})
            (folder / name.format(view=view, frame=int(frame))).write_text(text, encoding="utf-8")


def normalise_view_name(name: str) -> tuple[str, ...]:
    """The key `align_views` matches names by when they differ: case, separators, leading zeros
    and a "json" word are ignored ("cam01" == "Cam_1" == "cam1_json")."""
    tokens = re.findall(r"[a-z]+|\d+", name.lower())
    return tuple(str(int(t)) if t.isdigit() else t for t in tokens if t != "json")


def _camera_number(name: str) -> int | None:
    numbers = re.findall(r"\d+", name)
    return int(numbers[0]) if len(numbers) == 1 else None


def align_views(recording: KeypointRecording, cameras: Sequence[CalibratedCamera]) -> list[CalibratedCamera]:
    """The cameras of `recording.views`, in that order, matched by name.

    A view takes, in this order of rules: the camera of the same name; the one camera with
    an equal `normalise_view_name` key ("cam01" == "Cam_1" == "cam1_json"); the one camera
    with the same number, when every name on both sides carries exactly one number and no
    number repeats (Pose2Sim's "int_cam01_img" calibration for the "cam01_json" folder).
    Cameras without a view are left out. Raises ValueError listing both name sets when a
    view has no (or no unique) camera, or when a view's detections fall outside its
    camera's image by more than `OUTSIDE_IMAGE` of its size (a wrong image size or camera).
    """
    cameras = list(cameras)
    by_name = {c.name: c for c in cameras}
    out: list[CalibratedCamera | None] = [by_name.get(v) for v in recording.views]
    used = {c.name for c in out if c is not None}
    rules = [normalise_view_name]
    numbers = [_camera_number(n) for n in [*recording.views, *(c.name for c in cameras)]]
    unique = len(set(numbers[: len(recording.views)])) == len(recording.views) and len(
        set(numbers[len(recording.views) :])
    ) == len(cameras)
    if None not in numbers and unique:
        rules.append(_camera_number)
    problems: dict[int, str] = {}
    for rule in rules:
        keys: dict = {}
        for c in cameras:
            if c.name not in used:
                keys.setdefault(rule(c.name), []).append(c)
        for i, view in enumerate(recording.views):
            if out[i] is not None:
                continue
            match = keys.get(rule(view), [])
            if len(match) == 1 and match[0].name not in used:
                out[i] = match[0]
                used.add(match[0].name)
                problems.pop(i, None)
            else:
                names = [c.name for c in match]
                problems[i] = f"{view!r} ({f'ambiguous: {names}' if match else 'no camera'})"
    if problems:
        raise ValueError(
            f"align_views: keypoint views {list(recording.views)} do not match calibration cameras "
            f"{[c.name for c in cameras]}: {', '.join(problems.values())}. Rename the folders or "
            "the cameras (names match exactly, or ignoring case, separators, leading zeros and "
            "'json', or by their one camera number)."
        )
    for view, cam, kp in zip(recording.views, out, recording.keypoints):
        seen = kp[..., 2] > 0
        if cam.width <= 0 or not seen.any():
            continue
        u, v = kp[..., 0][seen], kp[..., 1][seen]
        # Detectors put a few occluded points past the border (RTMPose; Pose2Sim's
        # multi-person demo: 49 px on a 1088 px width), a wrong image size puts many far out
        mu, mv = OUTSIDE_IMAGE * cam.width, OUTSIDE_IMAGE * cam.height
        if (
            u.max() > cam.width - 0.5 + mu
            or v.max() > cam.height - 0.5 + mv
            or u.min() < -0.5 - mu
            or v.min() < -0.5 - mv
        ):
            raise ValueError(
                f"align_views: view {view!r} has detections in u {u.min():.0f}..{u.max():.0f}, "
                f"v {v.min():.0f}..{v.max():.0f} px, outside "
                f"camera {cam.name!r}'s {cam.width} x {cam.height} image; wrong image size in the calibration "
                "(another video resolution, width/height swapped) or the wrong camera."
            )
    return out  # type: ignore[return-value]
