"""Train the Deep Inertial Poser (Huang ch. 6) on synthetic IMUs of every CMU clip, per held-apart subject.

    python experiments/train_dip.py --out out/dip                  # 5 folds + 'all' (GPU: minutes)
    python experiments/train_dip.py --clips 6 --steps 50 --hidden 16   # smoke run on a CPU

**Data** (§6.2.2-6.2.3): every clip of `jaxmocap.motion.corpus()` (CMU subjects 02, 05,
06, 07, 131) and every procedural motion of `jaxmocap.motion.library` (8 s each), at
`--fps`, each also mirrored and at 0.8x and 1.25x speed; windows of `--window` frames every
`--stride`; body shapes β ~ N(0, 1); two sensor-error presets (none, `IMUErrorModel.xsens()`).

**Split** (subject-disjoint): one network per CMU subject s, trained without any clip of s
(fold "without_s"), and one on everything (fold "all": the shipped model, never to be
evaluated on these clips). Early stopping reads a validation set of whole clips (every
clip whose name hashes to 0 mod 10, with all its augmented windows) of the training
subjects only, never of the locked subject 07 (`jaxmocap.motion.splits.fold_tuning`; its
validation-hashed clips train instead; before 2026-11-28 they validated): the held-apart
subject shapes nothing, and 07 chooses nothing.

Writes to `--out`: `dip_<fold>.npz` (weights with provenance), `curves.json`,
`training_curves.png`; the synthesised windows are cached in `--out/cache/`.
"""

from __future__ import annotations

import sys as _sys
from pathlib import Path as _Path

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import _provenance  # noqa: E402,F401  (its commit is taken now, at the start of the run)

import argparse
import hashlib
import json
import subprocess
import sys
import time
import zlib
from pathlib import Path

import jax
import numpy as np

from jaxmocap import default_body
from jaxmocap.learned.dip import DIPConfig, save_dip_model
from jaxmocap.learned.dip_training import DIPDataset, TrainConfig, augmented, synthesize, train_dip
from jaxmocap.motion import library
from jaxmocap.motion.corpus import corpus
from jaxmocap.motion.splits import LEAVE_SUBJECT_OUT, LOCKED, Split
from jaxmocap.motion.io import load_motion
from jaxmocap.sensors import IMUErrorModel

SPEEDS = (0.8, 1.0, 1.25)


def clip_name(source: str) -> str:
    """The clip a window came from, without the augmentation suffixes."""
    return source.split(" (")[0]


#: One network per held-apart subject; early stopping inside the fold, never on 07.
SPLIT = Split("train_dip", tuning=LEAVE_SUBJECT_OUT, training=LEAVE_SUBJECT_OUT)


def is_validation(source: str) -> bool:
    return zlib.crc32(clip_name(source).encode()) % 10 == 0


def dataset(args, body, cache: Path) -> DIPDataset:
    clips = corpus()
    if args.clips:
        clips = [clips[i] for i in np.linspace(0, len(clips) - 1, args.clips).astype(int)]
    key = hashlib.sha1(json.dumps([[c.name for c in clips], args.fps, args.window, args.stride, args.seed,
                                   SPEEDS]).encode()).hexdigest()[:12]  # fmt: skip
    path = cache / f"dip_windows_{key}.npz"
    if path.is_file():
        return DIPDataset.load(path)
    t0 = time.perf_counter()
    items = []
    for c in clips:
        m = load_motion(c.path, fps=args.fps).replace(name=c.path.stem)
        items += [(v, c.subject) for v in augmented(m, speeds=SPEEDS)]
    for name, make in library.MOTIONS.items():
        m = make(num_frames=int(8 * args.fps), fps=args.fps, body=body).replace(name=f"procedural {name}")
        items += [(v, "procedural") for v in augmented(m, speeds=SPEEDS)]
    print(f"{len(items)} motions ({len(clips)} clips + procedural, augmented), synthesising ...", flush=True)
    data = synthesize(items, body, [IMUErrorModel.off(), IMUErrorModel.xsens()], args.window, args.stride,
                      seed=args.seed, progress=sys.stderr.isatty())  # fmt: skip
    data.save(path)
    print(f"{len(data)} windows, {int(data.mask.sum())} frames ({time.perf_counter() - t0:.0f} s)", flush=True)
    return data


def commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def plot(curves: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    for fold, c in curves.items():
        (line,) = ax[0].plot(c["step"], c["train_loss"], label=fold)
        ax[1].plot(c["step"], c["val_loss"], color=line.get_color(), label=fold)
        ax[1].axvline(c["best_step"], color=line.get_color(), lw=0.5, ls=":")
    ax[0].set_title("training loss (eq. 6.2 + 6.3, NLL)")
    ax[1].set_title("validation loss (dotted: kept step)")
    for a in ax:
        a.set_xlabel("step")
        a.grid(alpha=0.3)
    ax[1].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--out", default=str(Path(__file__).resolve().parents[1] / "out" / "dip"))
    p.add_argument("--hidden", type=int, default=DIPConfig().hidden, help="LSTM units (thesis: 512)")
    p.add_argument("--steps", type=int, default=TrainConfig().steps)
    p.add_argument("--batch", type=int, default=TrainConfig().batch)
    p.add_argument("--fps", type=float, default=30.0)
    p.add_argument("--window", type=int, default=240)
    p.add_argument("--stride", type=int, default=120)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--clips", type=int, help="use N clips spread over the subjects (smoke runs)")
    p.add_argument("--folds", nargs="*", help="subjects to hold apart (default: every subject) and/or 'all'")
    p.add_argument("--commit", default=None, help="the commit to record (default: git rev-parse HEAD)")
    args = p.parse_args(argv)
    out = Path(args.out)
    (out / "cache").mkdir(parents=True, exist_ok=True)
    body = default_body("low")
    t0 = time.perf_counter()
    data = dataset(args, body, out / "cache")
    subjects = sorted(set(data.group) - {"procedural"})
    folds = args.folds or [*subjects, "all"]
    # Early stopping is a choice: never on the locked subject (its clips all train).
    val = np.asarray([is_validation(s) and g not in LOCKED for s, g in zip(data.source, data.group)])
    train_sets, val_sets = [], []
    for fold in folds:
        if fold != "all" and fold not in subjects:
            raise SystemExit(f"--folds: {fold!r} is not a subject of the data ({subjects}) nor 'all'.")
        keep = data.group != fold
        train_sets.append(data.take(keep & ~val))
        val_sets.append(data.take(keep & val))
        print(
            f"fold {fold}: {len(train_sets[-1])} training windows, {len(val_sets[-1])} validation windows", flush=True
        )
    config, train = DIPConfig(hidden=args.hidden), TrainConfig(steps=args.steps, batch=args.batch, seed=args.seed)
    t1 = time.perf_counter()
    networks, curves = train_dip(train_sets, val_sets, config, train)
    seconds = time.perf_counter() - t1
    info = {
        "commit": args.commit or commit(),
        "device": str(jax.devices()[0]),
        "jax": jax.__version__,
        "training_seconds_all_folds": round(seconds, 1),
        "config": {
            "hidden": args.hidden,
            "input_keep": config.input_keep,
            **train.__dict__,
            "fps": args.fps,
            "window": args.window,
            "stride": args.stride,
            "speeds": SPEEDS,
            "error_presets": ["off", "xsens"],
            "betas_std": 1.0,
        },  # fmt: skip
    }
    for fold, net, curve, tr in zip(folds, networks, curves, train_sets):
        seen = sorted(set(tr.group))
        meta = {**info, "fold": fold, "held_apart_subject": None if fold == "all" else fold,
                "trained_on_groups": seen, "training_clips": sorted({clip_name(s) for s in tr.source}),
                "training_windows": len(tr), "training_frames": int(tr.mask.sum()),
                "best_step": curve["best_step"], "best_val_loss": min(curve["val_loss"])}  # fmt: skip
        save_dip_model(out / f"dip_{fold}.npz", net, meta)
    named = dict(zip(folds, curves))
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from _provenance import write_json

    write_json(
        out / "curves.json",
        {"curves": named, **info},
        split=SPLIT,
        argv=argv,
        data={"subjects": subjects, "folds": folds, "windows": int(len(data))},
    )
    plot(named, out / "training_curves.png")
    print(
        f"done: {len(folds)} networks in {seconds:.0f} s of training ({time.perf_counter() - t0:.0f} s in all) -> {out}"
    )


if __name__ == "__main__":
    sys.exit(main())
