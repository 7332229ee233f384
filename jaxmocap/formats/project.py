"""Pose2Sim-style project folders: where the keypoints, the calibration and the settings are.

A Pose2Sim project (https://github.com/perfanalytics/pose2sim, its ``Demo_*`` folders) is

    project/
        Config.toml              [project] frame_rate = 60 | 'auto'; [pose] pose_model = 'BODY_25B'
        calibration/Calib*.toml  (often beside the lab's own Calib.qca.txt it was converted from)
        pose/cam01_json/...      one OpenPose JSON folder per camera (pose-sync/ once
                                 synchronised, pose-associated/ once one person is chosen)

and a batch session puts several trials, each with its own Config.toml, under a session
folder holding the shared calibration/ and a Config.toml the trials' values override
(pose2sim 0.8: session/participant/trial, three Config.toml; the calibration folder is
the session's, e.g. S00_Calibration/). Pose2Sim up to 0.4 kept the settings in
``project/User/Config.toml``.

`read_project` finds these pieces with Pose2Sim's rules: the keypoint folder is the first
of pose-associated/, pose-sync/, pose/ that holds any; the calibration is in a folder
whose name contains "calib" (the trial's, else the nearest level above holding a
Config.toml): its one .toml, else its one calibration of another format
(`load_calibration`'s folder rule). `read_config` reads the settings jaxmocap uses:
``pose_model`` (Pose2Sim's names, any case; OpenPose's BODY_25, BODY_25B and COCO, and
HALPE_26 alias Body_with_feet, map to jaxmocap's layouts), ``frame_rate`` ('auto': as
Pose2Sim, the rate of the first video in the project's videos/, read from its MP4 /
QuickTime header; None when there is none) and ``frame_range`` ([start, stop): positions in the frame order, as
Pose2Sim indexes its sorted files; 'auto', 'all' and [] mean every frame).
"""

from __future__ import annotations

import dataclasses
import struct
import tomllib
from pathlib import Path

from .._files import natural_key

__all__ = ["POSE_MODELS", "Project", "ProjectConfig", "ProjectError", "read_config", "read_project", "video_frame_rate"]

#: Pose2Sim ``pose_model`` names (upper case) of the models jaxmocap reads: OpenPose's, and
#: HALPE_26 (Pose2Sim >= 0.9's default, RTMPose's, named "Body_with_feet" there; its
#: "Lower_body" runs the same model), and BLAZEPOSE (MediaPipe's: `formats.video`).
POSE_MODELS = {
    "BODY_25": "body25", "BODY_25B": "body25b", "COCO": "coco18", "COCO_18": "coco18",
    "HALPE_26": "halpe26", "BODY_WITH_FEET": "halpe26", "LOWER_BODY": "halpe26", "BLAZEPOSE": "mediapipe33",
}  # fmt: skip
_KEYPOINT_FOLDERS = ("pose-associated", "pose-sync", "pose")


class ProjectError(ValueError):
    """A project folder lacks a piece, or its Config.toml holds a value jaxmocap cannot use."""


@dataclasses.dataclass(frozen=True)
class ProjectConfig:
    """What Config.toml says. files: the Config.toml files read, session first (the last
    wins); pose_model: as written (None: not set); fps: frame_rate (None: not set, or
    'auto' without a readable video); fps_from: the file fps was read from (a Config.toml,
    or with 'auto' the video); frame_range: (start, stop) positions (None: every frame);
    sources: the Config.toml that set each of "pose_model", "frame_rate", "frame_range"."""

    files: tuple[Path, ...] = ()
    pose_model: str | None = None
    fps: float | None = None
    frame_range: tuple[int, int] | None = None
    fps_from: Path | None = None
    sources: dict = dataclasses.field(default_factory=dict)

    @property
    def layout(self) -> str | None:
        """jaxmocap's layout of `pose_model` (None when not set); ProjectError for a model
        jaxmocap has no layout for."""
        if self.pose_model is None:
            return None
        layout = POSE_MODELS.get(self.pose_model.upper())
        if layout is None:
            raise ProjectError(
                f"{self.sources.get('pose_model', self.files[-1])}: pose_model = {self.pose_model!r} has no "
                "jaxmocap layout; jaxmocap "
                f"reads {', '.join(sorted(POSE_MODELS))} detections. Run the pose estimation with "
                "one of those (Pose2Sim: pose_model = 'Body_with_feet'), or pass --layout if the files hold one."
            )
        return layout


@dataclasses.dataclass(frozen=True)
class Project:
    """The pieces of a project folder: root, keypoints (folder of per-camera JSON folders),
    calibration (file, or folder for `load_calibration`), config."""

    root: Path
    keypoints: Path | None
    calibration: Path | None
    config: ProjectConfig


def _merge(base: dict, top: dict) -> dict:
    out = dict(base)
    for k, v in top.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


#: At most this many levels above a trial hold Config.toml files it inherits (session, participant).
_LEVELS_ABOVE = 2


def _config_file(folder: Path) -> Path | None:
    for path in (folder / "Config.toml", folder / "User" / "Config.toml"):  # User/: Pose2Sim <= 0.4
        if path.is_file():
            return path
    return None


def _levels_above(folder: Path) -> list[Path]:
    """The folders above `folder` whose Config.toml it inherits, nearest first."""
    out: list[Path] = []
    folder = folder.resolve()
    while len(out) < _LEVELS_ABOVE and (folder.parent / "Config.toml").is_file() and folder.parent != folder:
        folder = folder.parent
        out.append(folder)
    return out


def read_config(folder) -> ProjectConfig:
    """The settings of the project holding `folder` (the project, or its keypoint folder).

    Config.toml (or User/Config.toml) is looked for in `folder`, then its parent (`folder`
    = project/pose), and those of the levels above (session, participant) are read first,
    outermost first, each overridden by the next; none found gives an empty ProjectConfig.
    """
    folder = Path(folder).resolve()
    start = next((f for f in (folder, folder.parent) if _config_file(f) is not None), None)
    if start is None:
        return ProjectConfig()
    files = [_config_file(start)] + [level / "Config.toml" for level in _levels_above(start)]
    files.reverse()
    data: dict = {}
    sources: dict[str, Path] = {}  # which file set each value: the one errors name
    for path in files:
        try:
            level = tomllib.loads(path.read_text(encoding="utf-8"))
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
            raise ProjectError(f"{path}: not valid TOML ({e}).") from None
        for section, key in (("pose", "pose_model"), ("project", "frame_rate"), ("project", "frame_range")):
            if isinstance(level.get(section), dict) and key in level[section]:
                sources[key] = path
        data = _merge(data, level)
    pose, project = data.get("pose", {}), data.get("project", {})
    model = pose.get("pose_model") if isinstance(pose, dict) else None
    rate = project.get("frame_rate") if isinstance(project, dict) else None
    if model is not None and not isinstance(model, str):
        raise ProjectError(
            f"{sources['pose_model']}: [pose] pose_model must be a name such as 'BODY_25B', got {model!r}."
        )
    fps, fps_from = None, sources.get("frame_rate")
    if isinstance(rate, str) and rate.strip().lower() == "auto":
        videos = sorted((p for p in (start / "videos").glob("*") if p.suffix.lower() in VIDEO_SUFFIXES),
                        key=lambda p: natural_key(p.name)) if (start / "videos").is_dir() else []  # fmt: skip
        fps_from = videos[0] if videos else None
        fps = video_frame_rate(videos[0]) if videos else None
    elif rate is not None:
        if isinstance(rate, bool) or not isinstance(rate, int | float) or not rate > 0:
            raise ProjectError(
                f"{sources['frame_rate']}: [project] frame_rate must be a positive number of frames per second "
                f"or 'auto', got {rate!r}."
            )
        fps = float(rate)
    span = project.get("frame_range") if isinstance(project, dict) else None
    frame_range = None
    if isinstance(span, list) and span:
        if len(span) != 2 or not all(isinstance(x, int) and not isinstance(x, bool) and x >= 0 for x in span) \
                or span[0] >= span[1]:  # fmt: skip
            raise ProjectError(
                f"{sources['frame_range']}: [project] frame_range must be [start, stop] with 0 <= start < stop (frame "
                f"positions), 'auto' or 'all'; got {span!r}."
            )
        frame_range = (span[0], span[1])
    elif span is not None and not (isinstance(span, str) and span.strip().lower() in ("auto", "all")) and span != []:
        raise ProjectError(
            f"{sources['frame_range']}: [project] frame_range must be [start, stop], 'auto' or 'all'; got {span!r}."
        )
    return ProjectConfig(tuple(files), model, fps, frame_range, fps_from if fps is not None else None, sources)


#: Videos whose frame rate `video_frame_rate` reads (the ISO base media file format).
VIDEO_SUFFIXES = (".mp4", ".mov", ".m4v")


def _boxes(f, start: int, end: int):
    """(type, payload start, end) of the ISO-BMFF boxes between `start` and `end`."""
    pos = start
    while pos + 8 <= end:
        f.seek(pos)
        size, kind = struct.unpack(">I4s", f.read(8))
        header = 8
        if size == 1:
            size, header = struct.unpack(">Q", f.read(8))[0], 16
        elif size == 0:  # to the end
            size = end - pos
        if size < header or pos + size > end:
            return
        yield kind, pos + header, pos + size
        pos += size


def _inside(f, box, kind: bytes):
    return [b for b in _boxes(f, box[1], box[2]) if b[0] == kind]


def video_frame_rate(path) -> float | None:
    """Frames per second of the first video track of an MP4 / MOV file, from its header
    (moov/trak/mdia: mdhd's timescale, stbl/stts's frame durations: frames / duration, the
    mean rate); None when the file has no such header. No decoder is needed."""
    try:
        with open(path, "rb") as f:
            f.seek(0, 2)
            top = (b"", 0, f.tell())
            for moov in _inside(f, top, b"moov"):
                for trak in _inside(f, moov, b"trak"):
                    for mdia in _inside(f, trak, b"mdia"):
                        hdlr, mdhd = _inside(f, mdia, b"hdlr"), _inside(f, mdia, b"mdhd")
                        if not hdlr or not mdhd:
                            continue
                        f.seek(hdlr[0][1] + 8)
                        if f.read(4) != b"vide":
                            continue
                        f.seek(mdhd[0][1])
                        version = f.read(1)[0]
                        f.seek(mdhd[0][1] + (20 if version == 1 else 12))
                        timescale = struct.unpack(">I", f.read(4))[0]
                        stts = [b for minf in _inside(f, mdia, b"minf") for stbl in _inside(f, minf, b"stbl")
                                for b in _inside(f, stbl, b"stts")]  # fmt: skip
                        if not stts:
                            continue
                        f.seek(stts[0][1] + 4)
                        n = min(struct.unpack(">I", f.read(4))[0], (stts[0][2] - stts[0][1] - 8) // 8)
                        pairs = struct.unpack(f">{2 * n}I", f.read(8 * n))
                        frames, ticks = sum(pairs[0::2]), sum(c * d for c, d in zip(pairs[0::2], pairs[1::2]))
                        if timescale > 0 and frames > 0 and ticks > 0:
                            return timescale * frames / ticks
    except (OSError, struct.error, IndexError):
        return None
    return None


def _has_json(folder: Path) -> bool:
    """JSON in camera sub-folders, or directly inside (every camera's files in one folder)."""
    return folder.is_dir() and any(
        (p.is_dir() and any(f.suffix.lower() == ".json" for f in p.iterdir())) or p.suffix.lower() == ".json"
        for p in folder.iterdir()
    )


def _calibration(root: Path) -> Path | None:
    # a session's calibration serves its trials; elsewhere the parent is not ours to search
    for where in [root, *_levels_above(root)]:
        folders = sorted(p for p in where.iterdir() if p.is_dir() and "calib" in p.name.lower())
        for folder in folders:
            tomls = sorted(p for p in folder.iterdir() if p.suffix.lower() == ".toml")
            if len(tomls) > 1:
                raise ProjectError(
                    f"{folder}: several calibration files {[p.name for p in tomls]}; pass the one to use with --calib."
                )
            return tomls[0] if tomls else folder
    return None


def read_project(path, need_keypoints: bool = True, need_calibration: bool = True) -> Project:
    """The keypoints, calibration and settings of a Pose2Sim-style project (module docstring).

    need_keypoints, need_calibration: False when the caller has its own (`--keypoints`,
    `--calib`): that piece is not looked for (None).
    Raises:
        ProjectError naming the folder and the missing piece.
    """
    root = Path(path)
    if not root.is_dir():
        raise ProjectError(f"{root}: no such folder; give a project folder (Config.toml, calibration/, pose/).")
    keypoints = next((root / n for n in _KEYPOINT_FOLDERS if need_keypoints and _has_json(root / n)), None)
    if keypoints is None and need_keypoints:
        raise ProjectError(
            f"{root}: no keypoints; a project holds one OpenPose JSON folder per camera under "
            f"{' or '.join(n + '/' for n in reversed(_KEYPOINT_FOLDERS))} (e.g. pose/cam01_json/). "
            "Elsewhere, name them with --keypoints DIR."
        )
    calibration = _calibration(root) if need_calibration else None
    if calibration is None and need_calibration:
        raise ProjectError(
            f"{root}: no calibration folder (a folder named like 'calibration' here or in a session "
            "folder above holding a Config.toml); name the calibration file with --calib FILE."
        )
    return Project(root, keypoints, calibration, read_config(root))
