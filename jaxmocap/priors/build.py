"""Rebuild `pose_prior.npz`: learn μ, Σ of the 69 non-root joint angles from motion data.

    python -m jaxmocap.priors.build [--cmu DIR] [--out PATH]

Sources: every motion of `jaxmocap.motion.library` (procedural, 8 s each at 30 fps) and
every CMU clip found in the CMU folder (`find_cmu_dir()`), resampled to 30 fps and
retargeted to the default body. Frames are pooled with equal weight per clip (clips are
subsampled to at most 600 frames) so that no long clip dominates. The covariance gets an
isotropic floor of (5°)² added: directions the training clips never move (retargeted
CMU knees have no twist) would otherwise get a near-infinite precision and lock the fit.
"""

from __future__ import annotations

import argparse
import datetime
import json
from pathlib import Path

import numpy as np

from .pose_prior import DEFAULT_PRIOR_PATH, joint_limits

FLOOR_DEG = 5.0
MAX_FRAMES_PER_CLIP = 600


def collect_poses(cmu_dir=None, fps: float = 30.0) -> tuple[np.ndarray, list[dict]]:
    """(N, 69) joint angles and a list of {source, frames} records."""
    from ..body.io import default_body
    from ..motion import library
    from ..motion.io import load_motion
    from ..motion.io import find_cmu_dir

    body = default_body("low")
    chunks, records = [], []

    def add(poses, source):
        x = np.asarray(poses, np.float64)[:, 1:, :].reshape(len(poses), -1)
        if len(x) > MAX_FRAMES_PER_CLIP:
            x = x[np.linspace(0, len(x) - 1, MAX_FRAMES_PER_CLIP).astype(int)]
        chunks.append(x)
        records.append({"source": source, "frames": int(len(x))})

    for name, make in sorted(library.MOTIONS.items()):
        add(make(num_frames=int(8 * fps), fps=fps, body=body).poses, f"jaxmocap.motion.library.{name}")
    cmu_dir = find_cmu_dir() if cmu_dir is None else Path(cmu_dir)
    if cmu_dir is not None:
        for path in sorted(cmu_dir.glob("*.amc")) + sorted(cmu_dir.glob("*.bvh")):
            add(load_motion(path, fps=fps, body=body).poses, f"CMU {path.name}")
    return np.concatenate(chunks), records


def build(out=DEFAULT_PRIOR_PATH, cmu_dir=None) -> Path:
    x, records = collect_poses(cmu_dir)
    # Pool clips with equal weight: weight each frame by 1 / (its clip's frame count).
    w = np.concatenate([np.full(r["frames"], 1.0 / r["frames"]) for r in records])
    w /= w.sum()
    mean = w @ x
    centred = x - mean
    cov = (centred * w[:, None]).T @ centred + np.eye(69) * np.radians(FLOOR_DEG) ** 2
    lower, upper = joint_limits()
    outside = float(np.mean((x < lower) | (x > upper)))
    meta = {
        "built": datetime.date.today().isoformat(),
        "sources": records,
        "floor_deg": FLOOR_DEG,
        "fraction_of_training_values_outside_limits": outside,
    }
    out = Path(out)
    np.savez(out, mean=mean, covariance=cov, lower=lower, upper=upper, meta=json.dumps(meta))
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cmu", help="CMU clip folder (default: find_cmu_dir())")
    p.add_argument("--out", default=str(DEFAULT_PRIOR_PATH))
    args = p.parse_args(argv)
    path = build(args.out, args.cmu)
    with np.load(path) as f:
        meta = json.loads(str(f["meta"]))
    print(f"wrote {path}: {sum(r['frames'] for r in meta['sources'])} frames from {len(meta['sources'])} clips; "
          f"{100 * meta['fraction_of_training_values_outside_limits']:.2f} % of training values outside the limits")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
