"""Biovision BVH files: HIERARCHY (ROOT/JOINT/End Site, OFFSET, CHANNELS) and MOTION.

Conventions (standard BVH):
    * a joint's local transform is a translation by OFFSET (plus its position channels,
      if it has any) followed by its rotation channels, composed in the listed order
      about the joint's *moving* axes: ``CHANNELS 3 Zrotation Xrotation Yrotation``
      is R = Rz·Rx·Ry (scipy intrinsic, upper-case sequence "ZXY"); angles in degrees;
    * global rotation G_j = G_parent · R_j, position p_j = p_parent + G_parent·(OFFSET_j + t_j);
    * the rest pose is all channels zero, where every global rotation is the identity,
      so the rotations we return are already relative to the rest pose.

Units: BVH has no unit field. `scale` (metres per file unit) may be given; by default
it is chosen from the data (``scale="auto"``): among metres, centimetres, millimetres,
inches and ASF units (1/0.45 inch, the unit of CMU's ASF/AMC), the one that makes the
rest skeleton's estimated stature closest to 1.7 m. The CMU BVH conversions keep the
ASF/AMC length unit: 131_01.bvh has a hip height of 16.9 units and is read at
0.0254/0.45 = 0.0564 m per unit (hips at 0.95 m). Frame rate: 1 / Frame Time, rounded
to the nearest integer when within 0.01 Hz of it (CMU writes .0083333 for 120 Hz).
"""

from __future__ import annotations

import numpy as np

from ..rotation import host_euler
from .skeleton import MotionFileError, SkeletonMotion, check_file

__all__ = ["UNIT_CANDIDATES", "BvhSkeleton", "load_bvh", "read_bvh"]

#: metres per file unit, for ``scale="auto"``.
UNIT_CANDIDATES = {"m": 1.0, "cm": 0.01, "mm": 0.001, "inch": 0.0254, "asf": 0.0254 / 0.45}


class BvhSkeleton:
    """Parsed BVH hierarchy: joints (End Sites included, named ``<parent>_end``)."""

    def __init__(self, names, parents, offsets, channels, is_end):
        self.names = tuple(names)
        self.parents = tuple(parents)
        self.offsets = np.asarray(offsets, np.float64)  # (N, 3) file units
        self.channels = tuple(tuple(c) for c in channels)  # per joint, lower-case e.g. "xposition"
        self.is_end = tuple(is_end)

    @property
    def num_channels(self) -> int:
        return sum(len(c) for c in self.channels)


_CHANNELS = {"xposition", "yposition", "zposition", "xrotation", "yrotation", "zrotation"}


def read_bvh(path) -> tuple[BvhSkeleton, np.ndarray, float]:
    """Parse a BVH file: (skeleton, (T, C) channel values in file units/degrees, frame time)."""
    path = check_file(path)
    try:
        text = path.read_text(errors="replace")
    except OSError as e:
        raise MotionFileError(f"Cannot read {path}: {e}") from e
    # Tokens with line numbers; braces may touch other tokens.
    tokens: list[tuple[str, int]] = []
    for i, line in enumerate(text.splitlines(), 1):
        for t in line.replace("{", " { ").replace("}", " } ").split():
            tokens.append((t, i))
    if not tokens or tokens[0][0].upper() != "HIERARCHY":
        raise MotionFileError(f"{path}: does not start with HIERARCHY; is this a BVH file?")

    names, parents, offsets, channels, is_end = [], [], [], [], []
    stack: list[int] = []
    k = 1
    pending = None  # index of the joint whose '{' is expected

    def need(n):
        if k + n > len(tokens):
            raise MotionFileError(f"{path}: unexpected end of file in HIERARCHY.")

    def floats(start, n):
        try:
            return [float(tokens[start + m][0]) for m in range(n)]
        except ValueError:
            raise MotionFileError(
                f"{path}, line {tokens[start][1]}: expected {n} numbers, got "
                f"{' '.join(t for t, _ in tokens[start : start + n])!r}."
            ) from None

    while k < len(tokens):
        tok, line = tokens[k]
        key = tok.upper()
        if key in ("ROOT", "JOINT"):
            need(2)
            if key == "ROOT" and names:
                raise MotionFileError(f"{path}, line {line}: only one ROOT is supported.")
            parent = stack[-1] if stack else -1
            if key == "JOINT" and parent < 0:
                raise MotionFileError(f"{path}, line {line}: JOINT outside ROOT.")
            names.append(tokens[k + 1][0])
            parents.append(parent)
            offsets.append([0.0, 0.0, 0.0])
            channels.append(())
            is_end.append(False)
            pending = len(names) - 1
            k += 2
        elif key == "END":  # End Site
            need(2)
            if not stack:
                raise MotionFileError(f"{path}, line {line}: End Site outside a joint.")
            names.append(f"{names[stack[-1]]}_end")
            parents.append(stack[-1])
            offsets.append([0.0, 0.0, 0.0])
            channels.append(())
            is_end.append(True)
            pending = len(names) - 1
            k += 2
        elif key == "{":
            if pending is None:
                raise MotionFileError(f"{path}, line {line}: '{{' without a joint.")
            stack.append(pending)
            pending = None
            k += 1
        elif key == "}":
            if not stack:
                raise MotionFileError(f"{path}, line {line}: unbalanced '}}'.")
            stack.pop()
            k += 1
        elif key == "OFFSET":
            need(4)
            if not stack:
                raise MotionFileError(f"{path}, line {line}: OFFSET outside a joint.")
            offsets[stack[-1]] = floats(k + 1, 3)
            k += 4
        elif key == "CHANNELS":
            need(2)
            try:
                n = int(tokens[k + 1][0])
            except ValueError:
                raise MotionFileError(f"{path}, line {line}: bad channel count {tokens[k + 1][0]!r}.") from None
            need(2 + n)
            if not stack:
                raise MotionFileError(f"{path}, line {line}: CHANNELS outside a joint.")
            chans = tuple(t.lower() for t, _ in tokens[k + 2 : k + 2 + n])
            bad = [c for c in chans if c not in _CHANNELS]
            if bad:
                raise MotionFileError(f"{path}, line {line}: unknown channels {bad}.")
            channels[stack[-1]] = chans
            k += 2 + n
        elif key == "MOTION":
            break
        else:
            raise MotionFileError(f"{path}, line {line}: unexpected {tok!r} in HIERARCHY.")
    if stack or k >= len(tokens):
        raise MotionFileError(f"{path}: HIERARCHY is not closed or MOTION is missing (truncated file?).")
    if not names:
        raise MotionFileError(f"{path}: no joints in HIERARCHY.")
    skel = BvhSkeleton(names, parents, offsets, channels, is_end)

    # MOTION / Frames: N / Frame Time: dt / values.
    rest = tokens[k + 1 :]
    try:
        assert rest[0][0].lower() == "frames:" and rest[2][0].lower() == "frame" and rest[3][0].lower() == "time:"
        num_frames = int(rest[1][0])
        frame_time = float(rest[4][0])
    except (AssertionError, IndexError, ValueError):
        line = rest[0][1] if rest else tokens[k][1]
        raise MotionFileError(f"{path}, line {line}: expected 'Frames: N' and 'Frame Time: dt' after MOTION.") from None
    if num_frames < 1 or not frame_time > 0:
        raise MotionFileError(f"{path}: Frames must be >= 1 and Frame Time > 0.")
    data = rest[5:]
    C = skel.num_channels
    if len(data) < num_frames * C:
        have = len(data) // C if C else 0
        raise MotionFileError(
            f"{path}: MOTION declares {num_frames} frames of {C} channels but only {have} complete "
            f"frames follow (file truncated after line {data[-1][1] if data else rest[4][1]})."
        )
    try:
        values = np.array([float(t) for t, _ in data[: num_frames * C]], np.float64)
    except ValueError:
        bad = next(i for i, (t, _) in enumerate(data) if not _is_float(t))
        raise MotionFileError(f"{path}, line {data[bad][1]}: non-numeric value {data[bad][0]!r}.") from None
    if not np.isfinite(values).all():
        bad = int(np.flatnonzero(~np.isfinite(values))[0])
        raise MotionFileError(f"{path}, line {data[bad][1]}: NaN or inf value.")
    return skel, values.reshape(num_frames, C), frame_time


def _is_float(t: str) -> bool:
    try:
        float(t)
        return True
    except ValueError:
        return False


def estimate_stature(skel: BvhSkeleton, scale: float = 1.0) -> float:
    """Rest-pose height (top minus bottom joint, End Sites included) x 1.1, in metres.

    The 10% stands for the scalp above the head End Site and the sole below the toes.
    """
    rest = _rest_positions(skel) * scale
    return float(rest[:, 1].max() - rest[:, 1].min()) * 1.1


def _rest_positions(skel: BvhSkeleton) -> np.ndarray:
    rest = np.zeros((len(skel.names), 3))
    for j, p in enumerate(skel.parents):
        if p >= 0:
            rest[j] = rest[p] + skel.offsets[j]
    return rest


def choose_scale(skel: BvhSkeleton) -> float:
    """The candidate unit (UNIT_CANDIDATES) giving a stature closest to 1.7 m (log ratio)."""
    height = estimate_stature(skel, 1.0)
    if not height > 0:
        return 1.0
    return min(UNIT_CANDIDATES.values(), key=lambda s: abs(np.log(height * s / 1.7)))


def skeleton_motion(skel: BvhSkeleton, values: np.ndarray, fps: float, scale: float, name: str = "") -> SkeletonMotion:
    """Forward kinematics of BVH channel `values` (T, C); positions in metres (x `scale`)."""
    T = values.shape[0]
    N = len(skel.names)
    rot = np.zeros((T, N, 3, 3))
    pos = np.zeros((T, N, 3))
    col = 0
    for j, (p, chans) in enumerate(zip(skel.parents, skel.channels)):
        v = values[:, col : col + len(chans)]
        col += len(chans)
        t = np.broadcast_to(skel.offsets[j], (T, 3)).copy()
        for i, c in enumerate(chans):
            if c.endswith("position"):
                t[:, "xyz".index(c[0])] += v[:, i]
        rcols = [i for i, c in enumerate(chans) if c.endswith("rotation")]
        local = (
            host_euler("".join(chans[i][0] for i in rcols).upper(), v[:, rcols], degrees=True)
            if rcols
            else np.broadcast_to(np.eye(3), (T, 3, 3))
        )
        if p < 0:
            rot[:, j] = local
            pos[:, j] = t * scale
        else:
            rot[:, j] = rot[:, p] @ local
            pos[:, j] = pos[:, p] + np.einsum("tab,tb->ta", rot[:, p], t * scale)
    rest = _rest_positions(skel) * scale
    rest -= rest[0]
    tips = np.zeros((N, 3))
    for j in range(N):
        kids = [c for c, p in enumerate(skel.parents) if p == j]
        if len(kids) == 1:
            tips[j] = skel.offsets[kids[0]] * scale
    return SkeletonMotion(
        names=skel.names,
        parents=skel.parents,
        rest_positions=rest,
        tips=tips,
        rotations=rot,
        positions=pos,
        fps=float(fps),
        name=name,
    )


def load_bvh(path, scale: float | str = "auto") -> SkeletonMotion:
    """Read a BVH file and run its forward kinematics.

    Args:
        path: the .bvh file.
        scale: metres per file unit, or "auto" (see the module docstring).
    Returns:
        SkeletonMotion whose joints are the BVH joints and End Sites (``<parent>_end``).
    """
    if isinstance(scale, str) and scale != "auto":
        raise ValueError(f"scale must be a number (metres per unit) or 'auto', got {scale!r}.")
    if not isinstance(scale, str) and not (np.isfinite(scale) and scale > 0):
        raise ValueError(f"scale must be a finite number > 0 (metres per unit), got {scale!r}.")
    skel, values, frame_time = read_bvh(path)
    try:
        scale = choose_scale(skel) if isinstance(scale, str) else scale
        fps = 1.0 / frame_time
        if not np.isfinite(fps):
            raise MotionFileError(f"{path}: Frame Time {frame_time} gives no finite frame rate.")
        if abs(fps - round(fps)) < 0.01:
            fps = float(round(fps))
        return skeleton_motion(skel, values, fps, float(scale), name=str(path))
    except MotionFileError:
        raise
    except (ValueError, KeyError, IndexError, TypeError, ZeroDivisionError, OverflowError, np.linalg.LinAlgError) as e:
        raise MotionFileError(f"{path}: inconsistent content ({type(e).__name__}: {e}).") from e
