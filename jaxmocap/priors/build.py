"""Build pose priors from motion files: the bundled one, a user's own, and held-out folds.

    jaxmocap prior build DIR [DIR ...] [--out prior.npz] [--no-library]
    python -m jaxmocap.priors.build            # rebuild the bundled pose_prior.npz

A prior is μ, Σ of the 69 non-root joint angles (von Marcard eq. 3.14) over every frame
of the given clips (AMASS .npz, ASF/AMC, BVH, read by `jaxmocap.motion.load_motion`),
resampled to 30 fps and retargeted to the default body, plus the procedural motions of
`jaxmocap.motion.library` unless `include_library=False`. Frames are pooled with equal
weight per clip (clips subsampled to at most 600 frames) so no long clip dominates. Σ gets
an isotropic floor of (5°)²: directions the clips never move (retargeted knees do not
twist) would otherwise get a near-infinite precision and lock the fit.

`held_out_prior(exclude=...)` is the prior of an evaluation fold: built from every clip of
`jaxmocap.motion.corpus()` except the excluded subjects' (clips are read once per process).

`components=K > 1` fits SMPLify's mixture of K full-covariance Gaussians instead
(`MixturePosePrior`) with scikit-learn's `GaussianMixture` (EM, k-means start, fixed seed).
It takes no frame weights, so equal weight per clip is had by resampling every clip to
`MIXTURE_FRAMES_PER_CLIP` frames (evenly spaced indices: short clips repeat frames, long
ones are thinned; at 30 fps neighbouring frames are nearly equal). Each Σ_k gets the same
(5°)² floor as the single Gaussian (`reg_covar`): a component sees only the frames near its
mean, a fraction of the clips, and in 69 dimensions many of its directions (knee twist,
the retargeted hands, whatever its few clips hold still) would get a near-infinite
precision; the floor bounds both that precision and ½ log det Σ_k, which enters the
choice of component. With the same floor, K = 1 is the single Gaussian again and forms
differ only by K. `components=1` (default) is the moment fit above, unchanged.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from .pose_prior import DEFAULT_PRIOR_PATH, MixturePosePrior, PosePrior, joint_limits

__all__ = [
    "FLOOR_DEG",
    "MAX_FRAMES_PER_CLIP",
    "MIXTURE_FRAMES_PER_CLIP",
    "clip_poses",
    "fit_prior",
    "prior_from_fit",
    "save_prior",
    "build_prior",
    "held_out_prior",
    "evaluation_prior",
    "motion_files",
]

FLOOR_DEG = 5.0
MAX_FRAMES_PER_CLIP = 600
MIXTURE_FRAMES_PER_CLIP = 300
_FPS = 30.0
_POSES: dict[str, np.ndarray] = {}  # source -> (N, 69): clips are read once per process


def motion_files(paths: Iterable) -> list[Path]:
    """Motion files from files and folders (searched recursively for .npz, .amc, .bvh)."""
    from ..motion.corpus import MOTION_SUFFIXES

    out = []
    for p in map(Path, paths):
        if p.is_dir():
            found = sorted(f for f in p.rglob("*") if f.suffix.lower() in MOTION_SUFFIXES)
            if not found:
                raise FileNotFoundError(f"{p} holds no motion files ({', '.join(MOTION_SUFFIXES)}).")
            out += found
        elif p.is_file():
            out.append(p)
        else:
            raise FileNotFoundError(f"motion file or folder {p} does not exist.")
    return out


def _subsample(x: np.ndarray) -> np.ndarray:
    if len(x) > MAX_FRAMES_PER_CLIP:
        x = x[np.linspace(0, len(x) - 1, MAX_FRAMES_PER_CLIP).astype(int)]
    return x


def clip_poses(source) -> np.ndarray:
    """(N, 69) non-root joint angles of one clip (a path, or a `motion.library` name), cached."""
    key = str(source)
    if key not in _POSES:
        from ..body.io import default_body
        from ..motion import library
        from ..motion.io import load_motion

        body = default_body("low")
        if key in library.MOTIONS:
            poses = library.MOTIONS[key](num_frames=int(8 * _FPS), fps=_FPS, body=body).poses
        else:
            poses = load_motion(key, fps=_FPS, body=body).poses
        x = np.asarray(poses, np.float64)[:, 1:, :].reshape(len(poses), -1)
        _POSES[key] = _subsample(x)
    return _POSES[key]


def fit_prior(sources: Sequence, include_library: bool = True, components: int = 1,
              seed: int = 0) -> tuple[np.ndarray, np.ndarray, dict]:  # fmt: skip
    """μ (69,), Σ (69, 69) and provenance of the clips `sources` (paths or library names).

    With `components=K > 1`: the mixture's μ_k (K, 69), Σ_k (K, 69, 69) and the provenance,
    whose "weights" are the K mixing weights w_k (see the module docstring; `seed` seeds
    the k-means start). `prior_from_fit` and `save_prior` take the result either way.
    """
    from ..motion import library

    components = _check_components(components)
    sources = [str(s) for s in sources] + (sorted(library.MOTIONS) if include_library else [])
    if not sources:
        raise ValueError("fit_prior needs at least one clip (or include_library=True).")
    chunks = [clip_poses(s) for s in sources]
    x = np.concatenate(chunks)
    lower, upper = joint_limits()
    meta = {
        "built": datetime.date.today().isoformat(),
        "sources": [
            {"source": s if s in library.MOTIONS else Path(s).name, "frames": int(len(c))}
            for s, c in zip(sources, chunks)
        ],
        "floor_deg": FLOOR_DEG,
        "fps": _FPS,
        "fraction_of_training_values_outside_limits": float(np.mean((x < lower) | (x > upper))),
    }
    if components > 1:
        means, covs, weights, info = _fit_mixture(chunks, components, seed)
        meta.update(components=components, weights=weights.tolist(), mixture=info)
        return means, covs, meta
    # Equal weight per clip: each frame weighs 1 / (its clip's frame count).
    w = np.concatenate([np.full(len(c), 1.0 / len(c)) for c in chunks])
    w /= w.sum()
    mean = w @ x
    centred = x - mean
    cov = (centred * w[:, None]).T @ centred + np.eye(69) * np.radians(FLOOR_DEG) ** 2
    return mean, cov, meta


def _check_components(components) -> int:
    if isinstance(components, bool) or not isinstance(components, (int, np.integer)) or components < 1:
        raise ValueError(f"components must be a positive integer (1: one Gaussian), got {components!r}.")
    return int(components)


def _fit_mixture(chunks, components: int, seed: int):
    """SMPLify's mixture by scikit-learn's EM on the clips, each resampled to equal frame counts."""
    from sklearn.mixture import GaussianMixture

    idx = lambda n: np.round(np.linspace(0, n - 1, MIXTURE_FRAMES_PER_CLIP)).astype(int)  # noqa: E731
    x = np.concatenate([c[idx(len(c))] for c in chunks])
    if len(x) < 2 * components:
        raise ValueError(f"{components} components need more frames than {len(x)}.")
    gm = GaussianMixture(components, covariance_type="full", reg_covar=np.radians(FLOOR_DEG) ** 2, max_iter=500,
                         n_init=1, init_params="kmeans", random_state=seed)  # fmt: skip
    gm.fit(x)
    order = np.argsort(-gm.weights_, kind="stable")  # heaviest component first
    info = {"method": "sklearn.mixture.GaussianMixture (full covariances, k-means start)", "seed": int(seed),
            "reg_covar_deg": FLOOR_DEG, "frames_per_clip": MIXTURE_FRAMES_PER_CLIP, "em_steps": int(gm.n_iter_),
            "converged": bool(gm.converged_),
            "mean_log_likelihood_per_frame": float(gm.score(x))}  # fmt: skip
    return gm.means_[order], gm.covariances_[order], gm.weights_[order], info


def prior_from_fit(mean, cov, meta=None, dtype=None) -> PosePrior | MixturePosePrior:
    """The prior of a `fit_prior` result: a `PosePrior`, or a `MixturePosePrior` if it holds K > 1 components."""
    import jax.numpy as jnp

    dtype = jnp.float32 if dtype is None else dtype
    if np.ndim(mean) == 2:
        return MixturePosePrior.from_moments(mean, cov, (meta or {}).get("weights"), dtype=dtype)
    return PosePrior.from_moments(mean, cov, dtype=dtype)


def save_prior(out, mean, cov, meta: dict | None = None) -> Path:
    """Write a `fit_prior` result as a `PosePrior.load`-able .npz (atomic: temp file, then rename).

    A mixture (mean (K, 69)) also gets `weights` (K,) from meta["weights"].
    """
    lower, upper = joint_limits()
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    arrays = dict(mean=mean, covariance=cov, lower=lower, upper=upper)
    if np.ndim(mean) == 2:
        if not meta or "weights" not in meta:
            raise ValueError("a mixture (mean (K, 69)) needs meta['weights'], the K mixing weights.")
        arrays["weights"] = np.asarray(meta["weights"], np.float64)
    if meta is not None:
        arrays["meta"] = json.dumps(meta)
    tmp = out.with_name(f"{out.name}.{os.getpid()}.tmp.npz")  # one per process: concurrent writers never share it
    np.savez(tmp, **arrays)
    tmp.replace(out)  # atomic: a reader never sees half a file
    return out


def build_prior(sources: Sequence, out=DEFAULT_PRIOR_PATH, include_library: bool = True, components: int = 1) -> Path:
    """Fit a prior to `sources` (motion files) and write it as a `PosePrior.load`-able .npz."""
    mean, cov, meta = fit_prior(sources, include_library, components)
    return save_prior(out, mean, cov, meta)


def held_out_prior(exclude: Iterable[str], clips=None, dtype=None, components: int = 1) -> PosePrior | MixturePosePrior:
    """The prior of every clip of `clips` (default `corpus()`) but the `exclude` subjects'.

    components: 1 (default) the single Gaussian `PosePrior`; K > 1 a `MixturePosePrior`.
    """
    from ..motion.corpus import corpus, training_clips

    clips = corpus() if clips is None else clips
    return prior_from_fit(*fit_prior([c.path for c in training_clips(clips, exclude)], components=components),
                          dtype=dtype)  # fmt: skip


_FOLDS: dict = {}


def evaluation_prior(clip, dtype=None, components: int = 1) -> PosePrior | MixturePosePrior:
    """The prior to evaluate on `clip` (a path or a CMU name like '005_02.bvh'): built without its subject.

    Folds are built once per process. Use it wherever a number is measured on a corpus clip:
    the bundled prior has seen every clip of the corpus.
    """
    from ..motion.corpus import subject_of

    import jax.numpy as jnp

    dtype = jnp.float32 if dtype is None else dtype
    key = (subject_of(clip), jnp.dtype(dtype).name) + ((components,) if components != 1 else ())
    if key not in _FOLDS:
        extra = {"components": components} if components != 1 else {}  # K = 1: the call of old
        _FOLDS[key] = held_out_prior([key[0]], dtype=dtype, **extra)
    return _FOLDS[key]


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "paths",
        nargs="*",
        metavar="DIR",
        help="motion files or folders (AMASS .npz, ASF/AMC, BVH); default: every CMU clip found",
    )
    p.add_argument("--out", default=None, help="output .npz (default: out/pose_prior.npz, or the bundled prior "
                   "with --bundled)")  # fmt: skip
    p.add_argument("--bundled", action="store_true", help="rebuild the bundled jaxmocap/priors/pose_prior.npz")
    p.add_argument("--no-library", action="store_true", help="leave out the procedural motions")
    p.add_argument("--components", type=int, default=1, help="Gaussians of the prior: 1 (default) one Gaussian, "
                   "K > 1 SMPLify's mixture (fitted by scikit-learn's GaussianMixture)")  # fmt: skip


def run(args) -> int:
    from ..motion.corpus import corpus

    files = motion_files(args.paths) if args.paths else [c.path for c in corpus()]
    if not files:
        raise SystemExit("no motion clips found: pass folders of AMASS .npz, ASF/AMC or BVH files.")
    out = Path(args.out) if args.out else DEFAULT_PRIOR_PATH if args.bundled else Path("out/pose_prior.npz")
    print(f"reading {len(files)} clips ...", flush=True)
    path = build_prior(files, out, include_library=not args.no_library, components=args.components)
    with np.load(path) as f:
        meta = json.loads(str(f["meta"]))
    form = f"a mixture of {args.components} Gaussians, " if args.components > 1 else ""
    print(f"wrote {path}: {form}{sum(r['frames'] for r in meta['sources'])} frames from {len(meta['sources'])} clips; "
          f"{100 * meta['fraction_of_training_values_outside_limits']:.2f} % of training values outside the joint "
          f"limits. Use it with PosePrior.load({str(path)!r}).")  # fmt: skip
    return 0


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description="Rebuild the bundled pose prior from every CMU clip found.")
    configure(p)
    args = p.parse_args(argv)
    if args.out is None and not args.paths:
        args.bundled = True
    return run(args)


if __name__ == "__main__":
    raise SystemExit(main())
