"""Acclaim ASF (skeleton) / AMC (motion) files, as used by the CMU motion capture database.

What the files say (Acclaim spec, as implemented by CMU's own tools):

* ASF ``:units``: ``length L`` means one file length unit is 1/L inch, so
  metres = value x 0.0254 / L (CMU: L = 0.45, a femur of 7.59 units is 0.43 m);
  ``angle deg|rad``. AMC root translations use the same length unit.
* ASF ``:root``: ``order`` lists the root's AMC channels (e.g. TX TY TZ RX RY RZ),
  ``axis`` the Euler order of ``orientation``; ``position`` is ignored (AMC gives the
  absolute root position every frame).
* ASF bone: ``direction`` (unit vector in the *world* frame of the rest pose),
  ``length``, ``axis ax ay az ORDER`` (the bone's local frame C relative to the world),
  ``dof`` (the AMC channels of the bone, in order), ``limits`` (kept, not enforced).
* ``:hierarchy``: ``parent child child ...`` lines; every bone starts where its parent
  ends (bones below ``root`` start at the root position).
* AMC: an integer frame number line, then ``bone v1 v2 ...`` lines with the values of
  that bone's DOFs in the ASF order (angles in the ASF angle unit).

Rotations. The spec writes (row vectors) ``L = C⁻¹ M C B``; with column vectors, as
everywhere in jaxmocap, a bone's global rotation (rest-world → posed-world) is

    G_b = G_parent(b) · C_b · M_b · C_b⁻¹,   G_root = C_r · M_r · C_r⁻¹,

where C is the ``axis`` rotation and M the AMC motion rotation. Both are Euler
rotations applied in the listed order about *fixed* axes ("XYZ": X first, i.e.
R = Rz·Ry·Rx), which is scipy's lower-case (extrinsic) sequence ``"xyz"``. Positions:
``end_b = start_b + G_b · direction_b · length_b``. Translation DOFs of non-root bones
(``tx ty tz l``, absent in CMU data) are read and ignored.

CMU data are y up; the subjects' rest pose faces +z with their left side at +x — the
same frame as SMPL's, so no axis change is needed (see `retarget`).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from ..rotation import host_euler
from .skeleton import MotionFileError, SkeletonMotion, check_file

__all__ = ["AsfBone", "AsfSkeleton", "load_asf_amc", "read_amc", "read_asf"]

_ROT = ("rx", "ry", "rz")


@dataclasses.dataclass(frozen=True)
class AsfBone:
    """One ASF bone (lengths in file units; angles in degrees)."""

    id: int
    name: str
    direction: np.ndarray  # (3,) unit, rest world frame
    length: float
    axis: np.ndarray  # (3,) degrees
    axis_order: str  # e.g. "XYZ"
    dof: tuple[str, ...]  # e.g. ("rx", "ry", "rz")
    limits: tuple[tuple[float, float], ...]


@dataclasses.dataclass(frozen=True)
class AsfSkeleton:
    """A parsed ASF file.

    Attributes:
        name: the ``:name`` entry.
        length_unit: metres per file length unit (0.0254 / L).
        angle_unit: "deg" or "rad".
        root_order: root AMC channels, e.g. ("tx", "ty", "tz", "rx", "ry", "rz").
        root_axis: Euler order of the root orientation, e.g. "XYZ".
        root_orientation: (3,) in the angle unit.
        bones: bones in hierarchy order (every parent before its children).
        parents: parent name of each bone in `bones` ("root" for the root's children).
        path: the file.
    """

    name: str
    length_unit: float
    angle_unit: str
    root_order: tuple[str, ...]
    root_axis: str
    root_orientation: np.ndarray
    bones: tuple[AsfBone, ...]
    parents: tuple[str, ...]
    path: str = ""

    def bone(self, name: str) -> AsfBone:
        for b in self.bones:
            if b.name == name:
                return b
        raise KeyError(f"{self.path}: no bone {name!r}.")


def _lines(path: Path) -> list[tuple[int, str]]:
    """(1-based line number, stripped content) for non-empty non-comment lines."""
    try:
        text = path.read_text(errors="replace")
    except OSError as e:
        raise MotionFileError(f"Cannot read {path}: {e}") from e
    out = []
    for i, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if line:
            out.append((i, line))
    return out


def _floats(path, lineno, tokens, n=None) -> np.ndarray:
    try:
        values = np.array([float(t) for t in tokens], np.float64)
    except ValueError:
        raise MotionFileError(f"{path}, line {lineno}: non-numeric value in {' '.join(tokens)!r}.") from None
    if n is not None and values.size != n:
        raise MotionFileError(f"{path}, line {lineno}: expected {n} numbers, got {values.size}.")
    if not np.isfinite(values).all():
        raise MotionFileError(f"{path}, line {lineno}: NaN or inf value.")
    return values


def _euler_order(path, lineno, token: str) -> str:
    token = token.upper()
    if len(token) != 3 or sorted(token) != ["X", "Y", "Z"]:
        raise MotionFileError(f"{path}, line {lineno}: bad Euler axis order {token!r}.")
    return token


def read_asf(path) -> AsfSkeleton:
    """Parse an ASF skeleton file (see the module docstring for the conventions)."""
    path = check_file(path)
    lines = _lines(path)
    name, length_scale, angle = "", 1.0, "deg"
    root_order = ("tx", "ty", "tz", "rx", "ry", "rz")
    root_axis, root_orient = "XYZ", np.zeros(3)
    bones: list[AsfBone] = []
    children: dict[str, list[str]] = {}
    section = None
    current: dict | None = None
    in_limits = False

    for lineno, line in lines:
        tok = line.split()
        if line.startswith(":"):
            section = tok[0][1:].lower()
            if section == "name" and len(tok) > 1:
                name = tok[1]
            elif section in ("units", "root", "bonedata", "hierarchy", "documentation", "version"):
                pass
            current, in_limits = None, False
            continue
        key = tok[0].lower()
        if section == "units":
            if key == "length":
                length_scale = float(_floats(path, lineno, tok[1:2], 1)[0])
                if length_scale <= 0:
                    raise MotionFileError(f"{path}, line {lineno}: length unit must be positive.")
            elif key == "angle":
                angle = tok[1].lower()[:3] if len(tok) > 1 else "deg"
                if angle not in ("deg", "rad"):
                    raise MotionFileError(f"{path}, line {lineno}: unknown angle unit {tok[1]!r}.")
        elif section == "root":
            if key == "order":
                root_order = tuple(t.lower() for t in tok[1:])
                bad = [t for t in root_order if t not in ("tx", "ty", "tz", "rx", "ry", "rz")]
                if bad:
                    raise MotionFileError(f"{path}, line {lineno}: unknown root channels {bad}.")
            elif key == "axis":
                root_axis = _euler_order(path, lineno, tok[1])
            elif key == "orientation":
                root_orient = _floats(path, lineno, tok[1:4], 3)
        elif section == "bonedata":
            if key == "begin":
                current, in_limits = (
                    {"dof": (), "limits": [], "axis": np.zeros(3), "order": "XYZ"},
                    False,
                )
                continue
            if current is None:
                raise MotionFileError(f"{path}, line {lineno}: bone data outside begin/end.")
            if key == "end":
                missing = [k for k in ("name", "direction", "length") if k not in current]
                if missing:
                    raise MotionFileError(f"{path}, line {lineno}: bone block misses {missing}.")
                d = current["direction"]
                norm = np.linalg.norm(d)
                bones.append(
                    AsfBone(
                        id=int(current.get("id", len(bones) + 1)),
                        name=current["name"],
                        direction=d / norm if norm > 0 else d,
                        length=current["length"],
                        axis=current["axis"],
                        axis_order=current["order"],
                        dof=current["dof"],
                        limits=tuple(current["limits"]),
                    )
                )
                current = None
                continue
            if line.startswith("("):
                if in_limits:
                    current["limits"].append(_limit(path, lineno, line))
                continue
            in_limits = False
            if key == "id":
                current["id"] = int(_floats(path, lineno, tok[1:2], 1)[0])
            elif key == "name":
                current["name"] = tok[1]
            elif key == "direction":
                current["direction"] = _floats(path, lineno, tok[1:4], 3)
            elif key == "length":
                current["length"] = float(_floats(path, lineno, tok[1:2], 1)[0])
            elif key == "axis":
                current["axis"] = _floats(path, lineno, tok[1:4], 3)
                current["order"] = _euler_order(path, lineno, tok[4]) if len(tok) > 4 else "XYZ"
            elif key == "dof":
                dof = tuple(t.lower() for t in tok[1:])
                bad = [t for t in dof if t not in ("rx", "ry", "rz", "tx", "ty", "tz", "l")]
                if bad:
                    raise MotionFileError(f"{path}, line {lineno}: unknown dof {bad}.")
                current["dof"] = dof
            elif key == "limits":
                in_limits = True
                current["limits"].append(_limit(path, lineno, line[len(tok[0]) :].strip()))
        elif section == "hierarchy":
            if key in ("begin", "end"):
                continue
            children.setdefault(tok[0], []).extend(tok[1:])

    if not bones:
        raise MotionFileError(f"{path}: no :bonedata bones; is this an ASF file?")
    by_name = {b.name: b for b in bones}
    if len(by_name) != len(bones):
        raise MotionFileError(f"{path}: duplicate bone names.")
    # Hierarchy order: breadth first from the root.
    ordered, parents, queue, seen = [], [], ["root"], {"root"}
    while queue:
        p = queue.pop(0)
        for c in children.get(p, []):
            if c not in by_name:
                raise MotionFileError(f"{path}: :hierarchy names unknown bone {c!r} (child of {p!r}).")
            if c in seen:
                raise MotionFileError(f"{path}: bone {c!r} appears twice in :hierarchy.")
            seen.add(c)
            ordered.append(by_name[c])
            parents.append(p)
            queue.append(c)
    unplaced = [b.name for b in bones if b.name not in seen]
    if unplaced:
        raise MotionFileError(f"{path}: bones {unplaced} are not connected to the root in :hierarchy.")
    return AsfSkeleton(
        name=name,
        length_unit=0.0254 / length_scale,
        angle_unit=angle,
        root_order=root_order,
        root_axis=root_axis,
        root_orientation=root_orient,
        bones=tuple(ordered),
        parents=tuple(parents),
        path=str(path),
    )


def _limit(path, lineno, text: str) -> tuple[float, float]:
    inner = text.strip().strip("()").replace("inf", "1e300").split()
    try:
        lo, hi = (float(t) for t in inner[:2])
    except ValueError:
        raise MotionFileError(f"{path}, line {lineno}: bad limits {text!r}.") from None
    return lo, hi


def read_amc(path, skeleton: AsfSkeleton) -> tuple[dict[str, np.ndarray], float | None]:
    """Parse an AMC file against `skeleton`.

    Returns:
        ({bone name or "root": (T, ndof) values in file units}, fps or None). The frame
        rate is not stored in AMC files (CMU: 120 Hz); a ``:samples-per-second N``
        header, if present, is returned.
    Raises:
        MotionFileError naming the file and line for non-numeric values, wrong value
        counts, unknown bones, and frames that do not list the same bones as the first
        frame (a truncated file).
    """
    path = check_file(path)
    dof = {b.name: b.dof for b in skeleton.bones}
    dof["root"] = skeleton.root_order
    frames: list[dict[str, np.ndarray]] = []
    frame_line: list[int] = []
    fps = None
    for lineno, line in _lines(path):
        if line.startswith(":"):
            tok = line.split()
            if tok[0].lower() in (":samples-per-second", ":sample-rate") and len(tok) > 1:
                fps = float(_floats(path, lineno, tok[1:2], 1)[0])
            continue
        tok = line.split()
        if len(tok) == 1 and tok[0].isdigit():
            frames.append({})
            frame_line.append(lineno)
            continue
        if not frames:
            raise MotionFileError(f"{path}, line {lineno}: bone values before the first frame number.")
        name = tok[0]
        if name not in dof:
            raise MotionFileError(f"{path}, line {lineno}: bone {name!r} is not in {skeleton.path}.")
        if len(tok) - 1 != len(dof[name]):
            # Either file may be at fault: name both.
            raise MotionFileError(
                f"{path}, line {lineno}: expected {len(dof[name])} numbers for bone {name!r} (its "
                f"degrees of freedom in the skeleton {skeleton.path}), got {len(tok) - 1}."
            )
        frames[-1][name] = _floats(path, lineno, tok[1:], len(dof[name]))
    if not frames:
        raise MotionFileError(f"{path}: no frames; is this an AMC file?")
    listed = list(frames[0])
    if not listed:
        raise MotionFileError(f"{path}, line {frame_line[0]}: frame 1 lists no bone values.")
    for k, frame in enumerate(frames):
        if list(frame) != listed and set(frame) != set(listed):
            missing = sorted(set(listed) - set(frame))
            extra = sorted(set(frame) - set(listed))
            raise MotionFileError(
                f"{path}, line {frame_line[k]}: frame {k + 1} lists different bones than frame 1 "
                f"(missing {missing}, extra {extra}); the file is truncated or corrupt."
            )
    values = {name: np.stack([f[name] for f in frames]) for name in listed}
    return values, fps


def _euler(order: str, angles: np.ndarray, degrees: bool) -> np.ndarray:
    """Fixed-axis Euler rotation(s): the first listed axis is applied first."""
    return host_euler(order.lower(), angles, degrees=degrees)


def _motion_rotation(channels, values: np.ndarray, degrees: bool) -> np.ndarray | None:
    """(T, 3, 3) rotation from the rotation channels among `channels`, None if none."""
    cols = [i for i, c in enumerate(channels) if c in _ROT]
    if not cols:
        return None
    order = "".join(channels[i][1] for i in cols)
    return _euler(order, values[:, cols], degrees)


def skeleton_motion(skeleton: AsfSkeleton, values: dict[str, np.ndarray], fps: float, name: str = "") -> SkeletonMotion:
    """Forward kinematics of AMC `values` on `skeleton` (see the module docstring)."""
    T = next(iter(values.values())).shape[0]
    deg = skeleton.angle_unit == "deg"
    unit = skeleton.length_unit
    names = ["root"] + [b.name for b in skeleton.bones]
    parent_idx = [-1] + [names.index(p) for p in skeleton.parents]
    N = len(names)
    rot = np.zeros((T, N, 3, 3))
    pos = np.zeros((T, N, 3))
    end = np.zeros((T, N, 3))
    rest = np.zeros((N, 3))
    rest_end = np.zeros((N, 3))
    tips = np.zeros((N, 3))

    # Root: translation channels (file units) and C·M·C⁻¹.
    rv = values.get("root", np.zeros((T, len(skeleton.root_order))))
    root_t = np.zeros((T, 3))
    for i, c in enumerate(skeleton.root_order):
        if c[0] == "t":
            root_t[:, "xyz".index(c[1])] = rv[:, i] * unit
    C = _euler(skeleton.root_axis, skeleton.root_orientation, deg)
    M = _motion_rotation(skeleton.root_order, rv, deg)
    rot[:, 0] = C if M is None else C @ M @ C.T
    pos[:, 0] = end[:, 0] = root_t

    for k, bone in enumerate(skeleton.bones, 1):
        p = parent_idx[k]
        C = _euler(bone.axis_order, bone.axis, deg)
        bv = values.get(bone.name)
        M = None if bv is None else _motion_rotation(bone.dof, bv, deg)
        local = np.broadcast_to(np.eye(3), (T, 3, 3)) if M is None else C @ M @ C.T
        rot[:, k] = rot[:, p] @ local
        vec = bone.direction * bone.length * unit
        tips[k] = vec
        rest[k] = rest_end[p]
        rest_end[k] = rest[k] + vec
        pos[:, k] = end[:, p]
        end[:, k] = pos[:, k] + rot[:, k] @ vec
    return SkeletonMotion(
        names=tuple(names),
        parents=tuple(parent_idx),
        rest_positions=rest,
        tips=tips,
        rotations=rot,
        positions=pos,
        fps=float(fps),
        name=name,
    )


def load_asf_amc(amc_path, asf_path=None, fps: float | None = None) -> SkeletonMotion:
    """Read an AMC motion with its ASF skeleton and run the ASF/AMC forward kinematics.

    Args:
        amc_path: the .amc file.
        asf_path: the .asf file; default ``<subject>.asf`` next to the AMC, where the
            subject is the part of the AMC name before the first underscore
            (02_01.amc → 02.asf), else the only .asf in that folder.
        fps: frame rate of the AMC (not stored in the file; default: a
            ``:samples-per-second`` header if present, else 120, CMU's rate).
    Returns:
        SkeletonMotion with joints "root" then the ASF bones; joint = bone start.
    """
    amc_path = check_file(amc_path)
    asf_path = check_file(find_asf(amc_path) if asf_path is None else asf_path)
    skeleton = _named(asf_path, read_asf, asf_path)
    values, file_fps = _named(amc_path, read_amc, amc_path, skeleton)
    rate = fps if fps is not None else (file_fps if file_fps else 120.0)
    if not (np.isfinite(rate) and rate > 0):
        raise MotionFileError(f"{amc_path}: frame rate must be a finite number > 0, got {rate}.")
    return _named(f"{amc_path} (with {asf_path})", skeleton_motion, skeleton, values, rate, name=str(amc_path))


def _named(what, fn, *args, **kwargs):
    """fn(...), with any error of a damaged file re-raised as a MotionFileError naming it."""
    try:
        return fn(*args, **kwargs)
    except MotionFileError:
        raise
    except (
        ValueError,
        KeyError,
        IndexError,
        TypeError,
        ZeroDivisionError,
        OverflowError,
        StopIteration,
        np.linalg.LinAlgError,
    ) as e:
        raise MotionFileError(f"{what}: inconsistent content ({type(e).__name__}: {e}).") from e


def find_asf(amc_path) -> Path:
    """The ASF skeleton for an AMC file (see `load_asf_amc`); FileNotFoundError if none."""
    amc_path = Path(amc_path)
    folder = amc_path.parent
    subject = amc_path.stem.split("_")[0]
    candidates = [
        folder / f"{subject}.asf",
        folder / f"{subject}.ASF",
        folder / f"{amc_path.stem}.asf",
    ]
    for c in candidates:
        if c.is_file():
            return c
    asfs = sorted(folder.glob("*.asf")) + sorted(folder.glob("*.ASF"))
    if len(asfs) == 1:
        return asfs[0]
    raise FileNotFoundError(
        f"No ASF skeleton for {amc_path}: looked for {candidates[0].name} in {folder}"
        + (f" (found several .asf: {[a.name for a in asfs]})" if asfs else "")
        + "; pass asf=<path>."
    )
