"""`load_motion`: one entry point for every motion file; jaxmocap's own `.npz` format.

Dispatch on the suffix:
    .npz  jaxmocap's own file (has the key ``jaxmocap_motion``; y up, (T, 24, 3) poses)
          or else an AMASS file (z up, converted; see `amass`);
    .amc  CMU ASF/AMC, with the skeleton ``<subject>.asf`` next to it (02_01.amc →
          02.asf) or given as ``asf=``; retargeted onto SMPL's tree (see `retarget`);
    .bvh  BVH, retargeted likewise.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .._checks import check_rate
from .sequence import Motion
from .._checks import output_npz
from .skeleton import MotionFileError, check_file, read_npz

__all__ = ["FORMAT_VERSION", "find_cmu_dir", "load_motion", "save_motion"]

FORMAT_VERSION = 1


def save_motion(motion: Motion, path) -> Path:
    """Write `motion` as jaxmocap's own npz (y up, no conversion).

    `path` gets `.npz` appended unless it ends so; an existing folder is refused
    (ValueError): name the file. Returns the path written.
    """
    if not isinstance(motion, Motion):
        raise ValueError(f"save_motion: motion must be a jaxmocap.motion.Motion, got {type(motion).__name__}.")
    path = output_npz(path)
    np.savez(
        path,
        jaxmocap_motion=np.array(FORMAT_VERSION),
        poses=motion.poses,
        trans=motion.trans,
        fps=np.array(motion.fps),
        betas=motion.betas,
        gender=np.array(motion.gender),
        name=np.array(motion.name),
    )
    return path


def _load_own(path: Path, d: dict) -> Motion:
    missing = [k for k in ("poses", "trans", "fps") if k not in d]
    if missing:
        raise MotionFileError(f"{path}: jaxmocap motion file misses key(s) {missing}.")
    try:
        return Motion(
            poses=d["poses"],
            trans=d["trans"],
            fps=float(np.asarray(d["fps"]).reshape(-1)[0]),
            betas=d.get("betas", np.zeros(0)),
            gender=str(d.get("gender", "neutral")),
            name=str(d.get("name", path)),
        )
    except (ValueError, TypeError, IndexError) as e:
        raise MotionFileError(f"{path}: {e}") from e


def load_motion(path, fps: float | None = None, body=None, asf=None, **retarget_options) -> Motion:
    """Load any supported motion file as a y-up `Motion` on SMPL's 24-joint tree.

    Args:
        path: .npz (jaxmocap or AMASS), .amc (CMU ASF/AMC) or .bvh file.
        fps: resample to this rate (slerp); default: the file's rate.
        body: the body used for the AMASS pelvis pivot and as retargeting target
            (default: `jaxmocap.default_body()`).
        asf: the ASF skeleton for an .amc file (default: found next to it).
        **retarget_options: passed to `retarget` (mapping, floor, betas, ...), and
            `scale` to `load_bvh`.
    Raises:
        FileNotFoundError (missing file or skeleton) or MotionFileError (a ValueError:
        unknown suffix, corrupt content), always naming the file.
    """
    path = check_file(path)
    if fps is not None:
        check_rate("fps", fps)  # before the work of reading and retargeting
    suffix = path.suffix.lower()
    if suffix == ".npz":
        from .amass import load_amass

        d = read_npz(path)
        motion = _load_own(path, d) if "jaxmocap_motion" in d else load_amass(path, body=body, _arrays=d)
    elif suffix == ".amc":
        from .asf_amc import load_asf_amc
        from .retarget import retarget

        motion = retarget(load_asf_amc(path, asf_path=asf), body=body, **retarget_options)
    elif suffix == ".bvh":
        from .bvh import load_bvh
        from .retarget import retarget

        scale = retarget_options.pop("scale", "auto")
        motion = retarget(load_bvh(path, scale=scale), body=body, **retarget_options)
    else:
        raise MotionFileError(
            f"Unknown motion file type {path.suffix!r} for {path}; expected .npz (AMASS or "
            "jaxmocap), .amc (with its .asf) or .bvh."
        )
    return motion if fps is None else motion.resample(fps)


def find_cmu_dir() -> Path | None:
    """The CMU clip folder: $JAXMOCAP_CMU, else `shared/data/cmu` beside the repository."""
    return find_data_dir("JAXMOCAP_CMU", "cmu")


def find_data_dir(variable: str, name: str) -> Path | None:
    """$`variable` if set, else `shared/data/<name>` beside or in the repository (None if
    there is none). A $`variable` that names no folder is a ValueError: a typo there
    must not fall back silently to other data (the demo's procedural walk)."""
    env = os.environ.get(variable)
    if env:
        if not Path(env).is_dir():
            raise ValueError(f"${variable}={env!r} is not a folder; point it at the folder holding the clips, "
                             f"or unset it to use shared/data/{name} beside the repository.")  # fmt: skip
        return Path(env)
    repo = Path(__file__).resolve().parents[2]
    for candidate in (repo.parent / "shared" / "data" / name, repo / "shared" / "data" / name):
        if candidate.is_dir():
            return candidate
    return None
