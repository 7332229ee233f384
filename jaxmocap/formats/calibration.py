"""Multi-camera calibrations from the files labs have: Pose2Sim TOML, Qualisys, EasyMocap, npz.

Every reader returns `CalibratedCamera`s in one convention: OpenCV camera axes (x right,
y down, z forward), world-to-camera p_c = R p_w + t in metres, K in pixels with pixel
centres at integers (OpenCV's and OpenPose's convention, so detections need no half-pixel
shift), distortion in OpenCV's order (k1, k2, p1, p2, k3) on normalised coordinates.

Formats (`format=` or inferred from the path):

- "pose2sim": Pose2Sim / OpenCV-style TOML. One table per camera ([cam_01] or [<name>])
  with ``name``, ``size = [width, height]``, ``matrix`` (3x3), ``distortions`` (k1, k2,
  p1, p2[, k3]), ``rotation`` (Rodrigues vector, world-to-camera), ``translation`` (m),
  ``fisheye``; a [metadata] table is skipped. Fisheye cameras are refused.
- "qualisys": QTM's ``.qca.txt`` XML. Per <camera>: ``serial`` (the name);
  <transform> x, y, z = camera centre in the world (mm) and r11..r33 with rows i = the
  camera's axes in world coordinates (p_q = M (p_w - c), M[i, j] = r_ij); the Qualisys
  camera looks down its -z axis with y up, so the OpenCV camera is diag(1, -1, -1) of it
  (the convention Pose2Sim's converter uses). Checked on Pose2Sim's demo scene: every
  camera then looks at the capture volume, and its .qca.txt agrees with the scene's
  independent checkerboard TOML to ~0.03 rad, ~6 cm and ~1 % in focal length, with the
  distortion coefficients unscaled (k1 -0.046 vs -0.053, k2 0.140 vs 0.151). <intrinsic> focal lengths and centre point are in 1/64 sensor
  pixels; the centre point is shifted by <fov_video>'s left/top (the video is a crop of
  the sensor) and the size is that window's (right - left + 1, bottom - top + 1), or the
  whole sensor without it. A ``video_resolution="540p"``/``"720p"`` attribute means the
  video was scaled from the 1080-row mode: K and the size are scaled by N/1080.
  Distortion coefficients are dimensionless and read unscaled (Pose2Sim divides them by
  64, which cancels most of the lens model). ``viewrotation`` is QTM's display rotation
  and is not applied: pixels are in the sensor's frame, as QTM exports the video.
  Cameras with nonzero skew are refused (its unit is undocumented).
- "easymocap": EasyMocap's ``intri.yml`` (names, K_<name>, dist_<name>, optional
  H_<name>, W_<name>) and ``extri.yml`` (names, R_<name> Rodrigues, optional Rot_<name>
  3x3, T_<name> metres), both OpenCV FileStorage YAML with ``!!opencv-matrix``; read by a
  small parser (PyYAML does not accept ``%YAML:1.0`` or the OpenCV tag). Without H_/W_
  the image size is unknown and `width` = `height` = 0.
- "npz": jaxmocap's own: arrays ``names`` (V,), ``K`` (V, 3, 3), ``dist`` (V, 5),
  ``R`` (V, 3, 3), ``t`` (V, 3), ``width`` (V,), ``height`` (V,).

Checks common to all: shapes, K upper-triangular with positive focal lengths, R a
rotation, and, when the size is known, the principal point inside the image and not
far off-centre where exchanging width and height would centre it (catches sizes given
the wrong way round or a calibration of another video mode).
"""

from __future__ import annotations

import dataclasses
import io
import re
import tomllib
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from ..rotation import host_exp, host_log

__all__ = [
    "FORMATS",
    "CalibratedCamera",
    "CalibrationError",
    "load_calibration",
    "save_calibration",
]

FORMATS = ("pose2sim", "qualisys", "easymocap", "npz")

# Qualisys camera axes (x right, y up, looking down -z) -> OpenCV axes (y down, z forward).
_QUALISYS_TO_OPENCV = np.diag([1.0, -1.0, -1.0])
_SUBPIXELS = 64.0  # QTM stores intrinsics in 1/64 pixel


class CalibrationError(ValueError):
    """A calibration file is missing, unreadable, of an unknown format or inconsistent."""


@dataclasses.dataclass(frozen=True, eq=False)
class CalibratedCamera:
    """One calibrated camera in OpenCV's convention (see the module docstring).

    name: the camera's name in the file (matched to keypoint folders by `align_views`).
    K: (3, 3) intrinsics in pixels; dist: (5,) k1, k2, p1, p2, k3 (zeros = none).
    R: (3, 3) world-to-camera rotation (the nearest exact rotation to the one given, which
        must be orthonormal to 1e-4); t: (3,) metres; p_c = R p_w + t.
    width, height: image size in pixels (0 when the file does not say).
    """

    name: str
    K: np.ndarray
    dist: np.ndarray
    R: np.ndarray
    t: np.ndarray
    width: int
    height: int

    def __post_init__(self):
        K = np.asarray(self.K, np.float64)
        dist = np.asarray(self.dist, np.float64).reshape(-1)
        R = np.asarray(self.R, np.float64)
        t = np.asarray(self.t, np.float64).reshape(-1)
        where = f"camera {self.name!r}"
        if K.shape != (3, 3) or R.shape != (3, 3) or t.shape != (3,):
            raise ValueError(f"{where}: K and R must be (3, 3) and t (3,); got {K.shape}, {R.shape}, {t.shape}.")
        if dist.size in (4, 5):
            dist = np.concatenate([dist, np.zeros(5 - dist.size)])
        elif dist.size == 0:
            dist = np.zeros(5)
        elif dist.size > 5 and np.all(dist[5:] == 0):
            dist = dist[:5]
        else:
            raise ValueError(
                f"{where}: distortion must have 4 or 5 OpenCV coefficients (k1, k2, p1, p2[, k3]); "
                f"got {dist.size}: {dist.tolist()} (rational/thin-prism models are not supported)."
            )
        if not all(np.isfinite(a).all() for a in (K, R, t, dist)):
            raise ValueError(f"{where}: K, dist, R and t must be finite.")
        if K[0, 0] <= 0 or K[1, 1] <= 0 or np.any(K[1:, 0] != 0) or K[2, 1] != 0 or not np.isclose(K[2, 2], 1.0):
            raise ValueError(
                f"{where}: K must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0; got {K.tolist()}."
            )
        if np.abs(R @ R.T - np.eye(3)).max() > 1e-4 or np.linalg.det(R) < 0:
            raise ValueError(f"{where}: R is not a rotation matrix (RRᵀ ≠ I or det < 0): {R.tolist()}.")
        # files round R to ~6 decimals (QTM, EasyMocap's Rot_): use the nearest rotation
        U, _, Vt = np.linalg.svd(R)
        R = U @ Vt
        width, height = int(self.width), int(self.height)
        if width < 0 or height < 0 or (width == 0) != (height == 0):
            raise ValueError(
                f"{where}: width and height must both be positive (or both 0 = unknown); got {width} x {height}."
            )
        # The principal point sits near the image centre (a cropped sensor window can move
        # it, never out of the image); far off-centre but central with the sides exchanged
        # means width and height were given the wrong way round.
        off = width > 0 and max(abs(K[0, 2] / width - 0.5), abs(K[1, 2] / height - 0.5)) > 0.35
        swapped = width > 0 and max(abs(K[0, 2] / height - 0.5), abs(K[1, 2] / width - 0.5)) < 0.1
        outside = width > 0 and not (0.0 <= K[0, 2] <= width and 0.0 <= K[1, 2] <= height)
        if outside or (off and swapped):
            raise ValueError(
                f"{where}: principal point ({K[0, 2]:.1f}, {K[1, 2]:.1f}) lies outside the "
                f"{width} x {height} (width x height) image"
                + ("; width and height look swapped." if swapped else "; is the image size right?")
            )
        for field, value in (
            ("K", K),
            ("dist", dist),
            ("R", R),
            ("t", t),
            ("width", width),
            ("height", height),
        ):
            object.__setattr__(self, field, value)
        object.__setattr__(self, "name", str(self.name))

    @property
    def center(self) -> np.ndarray:
        """Camera centre -Rᵀ t in the world (m)."""
        return -self.R.T @ self.t


def _camera(path, **fields) -> CalibratedCamera:
    try:
        return CalibratedCamera(**fields)
    except ValueError as e:
        raise CalibrationError(f"{path}: {e}") from None


# ------------------------------------------------------------------------------- dispatch


def _infer_format(path: Path) -> str:
    name = path.name.lower()
    if path.is_dir():
        if (path / "intri.yml").exists() or (path / "extri.yml").exists():
            return "easymocap"
        raise CalibrationError(
            f"{path}: a folder is read as an EasyMocap calibration, but it holds no "
            "intri.yml/extri.yml; give the calibration file itself."
        )
    if name.endswith(".toml"):
        return "pose2sim"
    if name.endswith(".npz"):
        return "npz"
    if name.endswith((".yml", ".yaml")):
        return "easymocap"
    if name.endswith((".qca.txt", ".qca", ".xml")):
        return "qualisys"
    head = path.read_bytes()[:512].lstrip().decode("utf-8", "replace")
    if head.startswith("<?xml") or "<calibration" in head:
        return "qualisys"
    if head.startswith("%YAML"):
        return "easymocap"
    raise CalibrationError(
        f"{path}: cannot tell the calibration format from the name or the contents; pass format= one of {FORMATS}."
    )


_CALIBRATION_SUFFIXES = (".toml", ".qca.txt", ".npz")


def load_calibration(path, format: str | None = None) -> list[CalibratedCamera]:
    """Cameras of a calibration file, in the file's order (module docstring: formats).

    Args:
        path: the file (EasyMocap: intri.yml, extri.yml or their folder), or a folder
            holding exactly one .toml / .qca.txt / .npz calibration.
        format: "pose2sim" | "qualisys" | "easymocap" | "npz"; None infers it.
    Raises:
        CalibrationError naming the file and what is wrong.
    """
    path = Path(path)
    if format is not None and format not in FORMATS:
        raise CalibrationError(f"{path}: unknown calibration format {format!r}; choose from {FORMATS}.")
    if not path.exists():
        raise CalibrationError(f"{path}: no such file or folder.")
    if path.is_dir() and format != "easymocap" and not (path / "intri.yml").exists():
        # a calibration folder (Pose2Sim's calibration/) holding a single calibration file
        found = [p for p in sorted(path.iterdir()) if p.name.lower().endswith(_CALIBRATION_SUFFIXES)]
        if len(found) != 1:
            raise CalibrationError(
                f"{path}: a folder needs intri.yml + extri.yml (EasyMocap) or exactly one "
                f"calibration file ({', '.join(_CALIBRATION_SUFFIXES)}); found {[p.name for p in found]}."
            )
        path = found[0]
    format = format or _infer_format(path)
    cameras = {
        "pose2sim": _read_toml,
        "qualisys": _read_qualisys,
        "easymocap": _read_easymocap,
        "npz": _read_npz,
    }[format](path)
    if not cameras:
        raise CalibrationError(f"{path}: no cameras found (read as {format!r}).")
    names = [c.name for c in cameras]
    if len(set(names)) != len(names):
        raise CalibrationError(f"{path}: camera names are not unique: {names}.")
    return cameras


def save_calibration(path, cameras, format: str) -> None:
    """Write `cameras` in one of the real layouts.

    `path` is the file; for EasyMocap the folder that gets intri.yml and extri.yml (or
    either of those two files' path).
    """
    path = Path(path)
    if format not in FORMATS:
        raise CalibrationError(f"{path}: unknown calibration format {format!r}; choose from {FORMATS}.")
    cameras = list(cameras)
    if not cameras or not all(isinstance(c, CalibratedCamera) for c in cameras):
        raise ValueError("save_calibration: `cameras` must be a non-empty sequence of CalibratedCamera.")
    {
        "pose2sim": _write_toml,
        "qualisys": _write_qualisys,
        "easymocap": _write_easymocap,
        "npz": _write_npz,
    }[format](path, cameras)


def _rodrigues(rvec, where) -> np.ndarray:
    try:
        rvec = np.asarray(rvec, np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise CalibrationError(f"{where}: a Rodrigues rotation needs 3 numbers, got {str(rvec)[:40]!r}.") from None
    if rvec.shape != (3,) or not np.isfinite(rvec).all():
        raise CalibrationError(f"{where}: a Rodrigues rotation needs 3 finite numbers, got {rvec.tolist()}.")
    return host_exp(rvec)


def _num(x: float) -> str:
    return repr(float(x))  # shortest round-tripping decimal


# ---------------------------------------------------------------------------- Pose2Sim TOML


def _read_toml(path: Path) -> list[CalibratedCamera]:
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise CalibrationError(f"{path}: not valid TOML ({e}).") from None
    cameras = []
    for key, table in data.items():
        if not isinstance(table, dict) or key == "metadata":
            continue
        where = f"{path} [{key}]"
        missing = [k for k in ("size", "matrix", "rotation", "translation") if k not in table]
        if missing:
            raise CalibrationError(
                f"{where}: missing {missing}; a Pose2Sim camera table needs size, matrix, "
                "distortions, rotation (Rodrigues) and translation."
            )
        if table.get("fisheye", False):
            raise CalibrationError(f"{where}: fisheye cameras are not supported (OpenCV pinhole model only).")
        try:
            size = np.asarray(table["size"], np.float64).reshape(-1)
            K = np.asarray(table["matrix"], np.float64)
            dist = np.asarray(table.get("distortions", []), np.float64)
            t = np.asarray(table["translation"], np.float64)
        except (TypeError, ValueError) as e:
            raise CalibrationError(f"{where}: numbers expected ({e}).") from None
        if size.shape != (2,) or np.any(size != np.round(size)):
            raise CalibrationError(f"{where}: size must be [width, height] in whole pixels, got {table['size']}.")
        cameras.append(_camera(
            where, name=str(table.get("name", key)), K=K, dist=dist, R=_rodrigues(table["rotation"], where),
            t=t, width=int(size[0]), height=int(size[1]),
        ))  # fmt: skip
    return cameras


_BARE_KEY = re.compile(r"^[A-Za-z0-9_-]+$")


def _write_toml(path: Path, cameras) -> None:
    lines = []
    for cam in cameras:
        key = cam.name if _BARE_KEY.match(cam.name) else '"' + cam.name.replace('"', '\\"') + '"'
        K, d = cam.K, cam.dist
        dist = d if d[4] != 0 else d[:4]  # Pose2Sim writes four coefficients
        lines += [
            f"[{key}]",
            'name = "' + cam.name.replace('"', '\\"') + '"',
            f"size = [ {float(cam.width)}, {float(cam.height)}]",
            "matrix = [ " + ", ".join("[ " + ", ".join(_num(v) for v in row) + "]" for row in K) + "]",
            "distortions = [ " + ", ".join(_num(v) for v in dist) + "]",
            "rotation = [ " + ", ".join(_num(v) for v in host_log(cam.R)) + "]",
            "translation = [ " + ", ".join(_num(v) for v in cam.t) + "]",
            "fisheye = false",
            "",
        ]
    lines += ["[metadata]", "adjusted = false", "error = 0.0", ""]
    path.write_text("\n".join(lines), encoding="utf-8")


# ---------------------------------------------------------------------------- Qualisys XML


def _attr(element, key, where) -> float:
    value = element.get(key)
    if value is None:
        raise CalibrationError(f"{where}: <{element.tag}> has no attribute {key!r}.")
    try:
        return float(value)
    except ValueError:
        raise CalibrationError(f"{where}: <{element.tag} {key}={value!r}> is not a number.") from None


def _read_qualisys(path: Path) -> list[CalibratedCamera]:
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, LookupError, ValueError) as e:  # LookupError: an unknown encoding= in the header
        raise CalibrationError(f"{path}: not valid XML ({e}); expected a QTM .qca.txt calibration.") from None
    elements = root.findall("cameras/camera") or root.findall(".//calibration/cameras/camera")
    if root.tag != "calibration" and not elements:
        raise CalibrationError(f"{path}: no <calibration><cameras><camera> elements; not a QTM calibration.")
    cameras = []
    for i, el in enumerate(elements):
        name = el.get("serial") or f"camera_{i + 1}"
        where = f"{path} (camera {name})"
        transform, intrinsic = el.find("transform"), el.find("intrinsic")
        if transform is None or intrinsic is None:
            raise CalibrationError(f"{where}: missing <transform> or <intrinsic>.")
        M = np.array([[_attr(transform, f"r{a}{b}", where) for b in (1, 2, 3)] for a in (1, 2, 3)])
        centre = np.array([_attr(transform, k, where) for k in ("x", "y", "z")]) / 1000.0  # mm -> m
        R = _QUALISYS_TO_OPENCV @ M
        if _attr_or(intrinsic, "skew", 0.0, where) != 0.0:
            raise CalibrationError(f"{where}: nonzero skew is not supported (its unit is undocumented).")
        fu, fv = (_attr(intrinsic, k, where) / _SUBPIXELS for k in ("focalLengthU", "focalLengthV"))
        cu, cv = (_attr(intrinsic, k, where) / _SUBPIXELS for k in ("centerPointU", "centerPointV"))
        fov = el.find("fov_video")
        if fov is not None:
            left, top, right, bottom = (_attr(fov, k, where) for k in ("left", "top", "right", "bottom"))
        else:  # the whole sensor
            left = _attr(intrinsic, "sensorMinU", where) / _SUBPIXELS
            top = _attr(intrinsic, "sensorMinV", where) / _SUBPIXELS
            right = _attr(intrinsic, "sensorMaxU", where) / _SUBPIXELS
            bottom = _attr(intrinsic, "sensorMaxV", where) / _SUBPIXELS
        width, height = right - left + 1, bottom - top + 1
        cu, cv = cu - left, cv - top
        scale = _video_scale(el.get("video_resolution", ""), where)
        if scale != 1.0:  # pixel centres at integers: u' = (u + 1/2) s - 1/2
            fu, fv, cu, cv = (
                fu * scale,
                fv * scale,
                (cu + 0.5) * scale - 0.5,
                (cv + 0.5) * scale - 0.5,
            )
            width, height = width * scale, height * scale
        dist = [_attr_or(intrinsic, k, 0.0, where) for k in (
            "radialDistortion1", "radialDistortion2", "tangentalDistortion1", "tangentalDistortion2",
            "radialDistortion3",
        )]  # fmt: skip
        cameras.append(_camera(
            where, name=name, K=[[fu, 0.0, cu], [0.0, fv, cv], [0.0, 0.0, 1.0]], dist=dist, R=R,
            t=-R @ centre, width=round(width), height=round(height),
        ))  # fmt: skip
    return cameras


def _attr_or(element, key, default, where) -> float:
    value = element.get(key)
    try:
        return default if value in (None, "", "none") else float(value)
    except ValueError:
        raise CalibrationError(f"{where}: <{element.tag} {key}={value!r}> is not a number.") from None


def _video_scale(resolution: str, where) -> float:
    resolution = resolution.strip().lower()
    if resolution in ("", "none", "1080p"):
        return 1.0
    m = re.fullmatch(r"(\d+)p", resolution)
    if not m:
        raise CalibrationError(f"{where}: unknown video_resolution {resolution!r} (expected e.g. '1080p', '540p').")
    return int(m.group(1)) / 1080.0


def _write_qualisys(path: Path, cameras) -> None:
    root = ET.Element("calibration", {"source": "jaxmocap", "type": "regular"})
    ET.SubElement(root, "results", {"std-dev": "0.", "min-max-diff": "0."})
    group = ET.SubElement(root, "cameras")
    for cam in cameras:
        if cam.width <= 0:
            raise CalibrationError(f"{path}: camera {cam.name!r} has no image size; QTM files need one.")
        if cam.K[0, 1] != 0:
            raise CalibrationError(f"{path}: camera {cam.name!r} has skew; the QTM writer does not store it.")
        el = ET.SubElement(group, "camera", {
            "active": "1", "avg-residual": "0.0", "model": "Miqus Video", "point-count": "0",
            "serial": cam.name, "viewrotation": "0", "video_resolution": "",
        })  # fmt: skip
        box = {"left": "0", "top": "0", "right": str(cam.width - 1), "bottom": str(cam.height - 1)}
        for tag in ("fov_marker", "fov_marker_max", "fov_video", "fov_video_max"):
            ET.SubElement(el, tag, box)
        M = _QUALISYS_TO_OPENCV @ cam.R  # diag(1,-1,-1) is its own inverse
        centre_mm = cam.center * 1000.0
        attrs = {k: _num(v) for k, v in zip("xyz", centre_mm)}
        attrs.update({f"r{a + 1}{b + 1}": _num(M[a, b]) for a in range(3) for b in range(3)})
        ET.SubElement(el, "transform", attrs)
        K, d = cam.K, cam.dist
        ET.SubElement(el, "intrinsic", {
            "focallength": "0", "sensorMinU": "0", "sensorMaxU": _num((cam.width - 1) * _SUBPIXELS),
            "sensorMinV": "0", "sensorMaxV": _num((cam.height - 1) * _SUBPIXELS),
            "focalLengthU": _num(K[0, 0] * _SUBPIXELS), "focalLengthV": _num(K[1, 1] * _SUBPIXELS),
            "centerPointU": _num(K[0, 2] * _SUBPIXELS), "centerPointV": _num(K[1, 2] * _SUBPIXELS),
            "skew": "0", "radialDistortion1": _num(d[0]), "radialDistortion2": _num(d[1]),
            "radialDistortion3": _num(d[4]), "tangentalDistortion1": _num(d[2]),
            "tangentalDistortion2": _num(d[3]),
        })  # fmt: skip
    ET.indent(root)
    # us-ascii: no declaration from ElementTree, non-ASCII names become character references
    path.write_bytes(b"<?xml version='1.0' encoding='ASCII'?>\n" + ET.tostring(root, encoding="us-ascii") + b"\n")


# ------------------------------------------------------------------- EasyMocap (OpenCV YAML)


def _yaml_string(text: str) -> str:
    """A list item as written ("01" stays "01": camera names are not numbers)."""
    text = text.strip()
    quoted = len(text) >= 2 and text[0] == text[-1] and text[0] in "\"'"
    return text[1:-1] if quoted else text


def _yaml_scalar(text: str):
    text = text.strip()
    if len(text) >= 2 and text[0] == text[-1] and text[0] in "\"'":
        return text[1:-1]
    for cast in (int, float):
        try:
            return cast(text)
        except ValueError:
            pass
    return text


def _flow_items(text: str) -> list[str]:
    inner = text.strip()[1:-1]
    return [s for s in (x.strip() for x in inner.split(",")) if s]


def _parse_opencv_yaml(path: Path) -> dict:
    """Top-level keys of an OpenCV FileStorage YAML file: scalars, lists, matrices (NumPy).

    Covers what OpenCV and EasyMocap write: ``%YAML:1.0``, ``---``, ``key: scalar``,
    ``key:`` + ``- item`` lines or ``key: [a, b]``, and ``key: !!opencv-matrix`` with
    indented rows, cols, dt and ``data: [ ... ]`` over one or more lines.
    """
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except UnicodeDecodeError as e:
        raise CalibrationError(f"{path}: not a text file ({e}).") from None
    out: dict = {}
    i = 0
    while i < len(lines):
        raw = lines[i]
        line = raw.rstrip()
        i += 1
        if not line.strip() or line.lstrip().startswith(("#", "%", "---", "...")):
            continue
        if line[0] in " \t-":
            raise CalibrationError(f"{path}:{i}: unexpected indented line {line.strip()!r} outside a key.")
        key, sep, rest = line.partition(":")
        if not sep:
            raise CalibrationError(f"{path}:{i}: expected 'key: value', got {line!r}.")
        key, rest = key.strip(), rest.strip()
        if rest.startswith("!!opencv-matrix"):
            fields: dict = {}
            while i < len(lines) and (lines[i][:1] in (" ", "\t")) and lines[i].strip():
                sub = lines[i].strip()
                i += 1
                name, _, value = sub.partition(":")
                value = value.strip()
                if name.strip() == "data":
                    while "]" not in value and i < len(lines):
                        value += " " + lines[i].strip()
                        i += 1
                    if not (value.startswith("[") and value.endswith("]")):
                        raise CalibrationError(f"{path}: matrix {key!r} has unterminated data {value[:40]!r}.")
                    try:
                        fields["data"] = [float(x) for x in _flow_items(value)]
                    except ValueError as e:
                        raise CalibrationError(f"{path}: matrix {key!r} data is not numeric ({e}).") from None
                else:
                    fields[name.strip()] = _yaml_scalar(value)
            try:
                rows, cols, data = int(fields["rows"]), int(fields["cols"]), fields["data"]
            except (KeyError, ValueError, TypeError, OverflowError):  # OverflowError: rows: inf
                raise CalibrationError(
                    f"{path}: matrix {key!r} needs rows, cols and data; got {sorted(fields)}."
                ) from None
            if len(data) != rows * cols:
                raise CalibrationError(f"{path}: matrix {key!r} is {rows}x{cols} but has {len(data)} numbers.")
            out[key] = np.asarray(data, np.float64).reshape(rows, cols)
        elif rest == "":
            items = []
            while i < len(lines) and lines[i].strip().startswith("-"):
                items.append(_yaml_string(lines[i].strip()[1:]))
                i += 1
            out[key] = items
        elif rest.startswith("["):
            while "]" not in rest and i < len(lines):
                rest += " " + lines[i].strip()
                i += 1
            out[key] = [_yaml_string(x) for x in _flow_items(rest)]
        else:
            out[key] = _yaml_scalar(rest)
    return out


def _easymocap_paths(path: Path) -> tuple[Path, Path]:
    folder = path if path.is_dir() else path.parent
    intri, extri = folder / "intri.yml", folder / "extri.yml"
    if not path.is_dir() and path.name not in ("intri.yml", "extri.yml"):
        # Custom names: the other file is the one with the other prefix.
        other = path.name.replace("intri", "extri") if "intri" in path.name else path.name.replace("extri", "intri")
        intri, extri = (path, folder / other) if "intri" in path.name else (folder / other, path)
    for p in (intri, extri):
        if not p.exists():
            raise CalibrationError(
                f"{p}: no such file; an EasyMocap calibration is intri.yml + extri.yml in one folder."
            )
    return intri, extri


def _numeric(value, path: Path, key: str, sizes: tuple[int, ...]) -> np.ndarray:
    """`value` as a float array of one of `sizes` entries, or a CalibrationError naming the key."""
    try:
        a = np.asarray(value, np.float64)
    except (TypeError, ValueError):
        raise CalibrationError(f"{path}: {key} is not numeric, got {str(value)[:40]!r}.") from None
    if a.size not in sizes:
        raise CalibrationError(f"{path}: {key} has {a.size} numbers; expected {' or '.join(map(str, sizes))}.")
    return a


def _read_easymocap(path: Path) -> list[CalibratedCamera]:
    intri_path, extri_path = _easymocap_paths(path)
    intri, extri = _parse_opencv_yaml(intri_path), _parse_opencv_yaml(extri_path)
    names = intri.get("names")
    if not isinstance(names, list) or not names:
        raise CalibrationError(f"{intri_path}: no 'names' list of cameras.")
    names = [str(n) for n in names if str(n) != "none"]
    cameras = []

    def need(store, key, file, name):
        if key not in store:
            raise CalibrationError(f"{file}: camera {name!r} has no {key!r}.")
        return store[key]

    for name in names:
        where = f"{intri_path} + {extri_path.name} (camera {name})"
        K = need(intri, f"K_{name}", intri_path, name)
        dist = intri.get(f"dist_{name}", intri.get(f"D_{name}", np.zeros(5)))
        width, height = intri.get(f"W_{name}", 0), intri.get(f"H_{name}", 0)
        if f"R_{name}" in extri:
            r = _numeric(extri[f"R_{name}"], extri_path, f"R_{name}", (3, 9))
            R = r.reshape(3, 3) if r.size == 9 else _rodrigues(r, f"{extri_path} R_{name}")
        else:
            R = _numeric(need(extri, f"Rot_{name}", extri_path, name), extri_path, f"Rot_{name}", (9,)).reshape(3, 3)
        both = f"R_{name}" in extri and f"Rot_{name}" in extri
        if (
            both
            and np.abs(_numeric(extri[f"Rot_{name}"], extri_path, f"Rot_{name}", (9,)).reshape(3, 3) - R).max() > 1e-3
        ):
            raise CalibrationError(f"{extri_path}: camera {name!r}: R_{name} (Rodrigues) and Rot_{name} disagree.")
        T = need(extri, f"T_{name}", extri_path, name)
        if not isinstance(width, int) or not isinstance(height, int):
            raise CalibrationError(f"{intri_path}: W_{name}/H_{name} must be integers, got {width!r}, {height!r}.")
        cameras.append(_camera(where, name=name, K=K, dist=dist, R=R, t=T, width=width, height=height))
    return cameras


def _yaml_matrix(key: str, value: np.ndarray) -> list[str]:
    value = np.atleast_2d(value)
    return [
        f"{key}: !!opencv-matrix",
        f"  rows: {value.shape[0]}",
        f"  cols: {value.shape[1]}",
        "  dt: d",
        "  data: [" + ", ".join(_num(v) for v in value.reshape(-1)) + "]",
    ]


def _write_easymocap(path: Path, cameras) -> None:
    folder = path.parent if path.suffix in (".yml", ".yaml") else path
    folder.mkdir(parents=True, exist_ok=True)
    names = ["names:"] + [f'  - "{c.name}"' for c in cameras]
    intri, extri = ["%YAML:1.0", "---", *names], ["%YAML:1.0", "---", *names]
    for c in cameras:
        intri += _yaml_matrix(f"K_{c.name}", c.K) + _yaml_matrix(f"dist_{c.name}", c.dist[None])
        if c.width > 0:
            intri += [f"H_{c.name}: {c.height}", f"W_{c.name}: {c.width}"]
        extri += _yaml_matrix(f"R_{c.name}", host_log(c.R)[:, None]) + _yaml_matrix(f"Rot_{c.name}", c.R)
        extri += _yaml_matrix(f"T_{c.name}", c.t[:, None])
    # EasyMocap writes CRLF line ends; keep them so its tools see the same bytes.
    (folder / "intri.yml").write_bytes(("\r\n".join(intri) + "\r\n").encode())
    (folder / "extri.yml").write_bytes(("\r\n".join(extri) + "\r\n").encode())


# ------------------------------------------------------------------------------------ npz

_NPZ_KEYS = ("names", "K", "dist", "R", "t", "width", "height")


def _read_npz(path: Path) -> list[CalibratedCamera]:
    try:
        # From memory: numpy leaks the file handle of a damaged zip it opened itself.
        with np.load(io.BytesIO(path.read_bytes()), allow_pickle=False) as f:
            missing = [k for k in _NPZ_KEYS if k not in f]
            if missing:
                raise CalibrationError(
                    f"{path}: missing arrays {missing}; a jaxmocap calibration npz has {list(_NPZ_KEYS)}."
                )
            data = {k: f[k] for k in _NPZ_KEYS}
    except CalibrationError:
        raise
    except Exception as e:  # a damaged archive fails in zipfile, numpy or zlib, in many types
        raise CalibrationError(f"{path}: not a readable npz ({type(e).__name__}: {e}).") from None
    V = len(data["names"])
    for k in _NPZ_KEYS[1:]:
        if len(data[k]) != V:
            raise CalibrationError(f"{path}: {k} has {len(data[k])} entries for {V} camera names.")
    return [
        _camera(path, name=str(data["names"][i]), K=data["K"][i], dist=data["dist"][i], R=data["R"][i],
                t=data["t"][i], width=int(data["width"][i]), height=int(data["height"][i]))
        for i in range(V)
    ]  # fmt: skip


def _write_npz(path: Path, cameras) -> None:
    with open(path, "wb") as f:  # keep the exact name (np.savez would append .npz)
        np.savez(
            f,
            names=np.array([c.name for c in cameras]),
            K=np.stack([c.K for c in cameras]),
            dist=np.stack([c.dist for c in cameras]),
            R=np.stack([c.R for c in cameras]),
            t=np.stack([c.t for c in cameras]),
            width=np.array([c.width for c in cameras]),
            height=np.array([c.height for c in cameras]),
        )
