"""Does Multi-view SMPLify depend on the image resolution when nothing else changes?

    python experiments/muvs_resolution.py                 # -> out/muvs_resolution.json (~6 min on 2 cores)
    python experiments/muvs_resolution.py --out experiments/results

The first 3 clips of `muvs_tables.pick_clips` (CMU subjects 05, 06, 07, one each; MuVS's
weights were chosen on the development subjects 02 and 131, `jaxmocap.motion.splits`)
filmed by the same 4 ring cameras with the same field of view,
at 256 x 192 px and at `--scale` times that, the detector noise scaled alike (muvs_tables'
detector, 3 px at 256 x 192): only the pixel units differ. Joints only (stage 1 with the
annealed prior, then stage 2), the development-tuned weights (`muvs_tables.tuned_weights`;
`MuVSWeights()` until 2026-11-28) with its reference focal length (weights
converted to each recording's pixels) and with `reference_focal=None` (raw pixels).
MPJPE over SMPL's 24 joints in mm, no alignment.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _provenance import subjects_of, write_json  # noqa: E402
from muvs_tables import DETECTOR, SPLIT, build, joints_of, pick_clips, tuned_weights  # noqa: E402

from jaxmocap.body import default_body  # noqa: E402
from jaxmocap.methods import multiview as mv  # noqa: E402
from jaxmocap.motion.splits import Split  # noqa: E402
from jaxmocap.sensors import CameraConfig  # noqa: E402

#: Until 2026-11-28: 02_04, 02_06, 131_01, the subjects MuVS's weights are now chosen on.
SPLIT = Split("muvs_resolution", tuning=SPLIT.tuning, training=SPLIT.training, evaluation=SPLIT.evaluation)


def fit(body, clips, frames: int, scale: int, weights: mv.MuVSWeights) -> dict:
    detector = DETECTOR.__class__(**{**DETECTOR.__dict__, "pixel_noise": DETECTOR.pixel_noise * scale})
    cameras = CameraConfig(num_views=4, width=256 * scale, height=192 * scale)
    data, truth = build(clips, frames, 7, body, cameras, detector, silhouettes=False)
    truth = [joints_of(body, t["poses"], t["betas"][:10], t["trans"]) for t in truth]
    p1, _ = mv.stage_one(data, mv.initialise(data, weights.num_betas), weights, silhouettes=False)
    p2, _ = mv.stage_two(data, p1, weights)
    out = {}
    for name, p in (("stage1", p1), ("stage2", p2)):
        betas = p["betas"] if p["betas"].ndim == 3 else np.repeat(p["betas"][:, None], frames, 1)
        pred = np.stack([joints_of(body, p["pose"][b], betas[b], p["trans"][b]) for b in range(len(clips))])
        out[name] = float(np.linalg.norm(pred - np.stack(truth), axis=-1).mean() * 1000)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--scale", type=int, default=4)
    ap.add_argument("--out", type=Path, default=Path("out"))
    args = ap.parse_args(argv)
    clips = pick_clips(3, args.frames)
    if len(clips) < 3:
        raise SystemExit("fewer than 3 evaluation clips in ../shared/data/cmu_cc (set JAXMOCAP_CMU_CC).")
    body = default_body("low")
    rows = {}
    tuned, tuned_from = tuned_weights()
    for key, scale, w in (("low_resolution", 1, tuned), ("high_resolution", args.scale, tuned),
                          ("high_resolution_raw_pixels", args.scale, tuned.replace(reference_focal=None))):  # fmt: skip
        rows[key] = fit(body, clips, args.frames, scale, w)
        print(f"{key:28s} MPJPE stage 1 {rows[key]['stage1']:.1f}  stage 2 {rows[key]['stage2']:.1f} mm", flush=True)
    result = {"clips": [c.name for c in clips], "frames": args.frames, "scale": args.scale, "image_low": [256, 192],
              "reference_focal": mv.REFERENCE_FOCAL, "weights_tuned": tuned_from, "mpjpe_mm": rows}  # fmt: skip
    write_json(
        args.out / "muvs_resolution.json",
        result,
        split=SPLIT,
        argv=argv,
        data={"clips": result["clips"], "subjects": subjects_of(result["clips"]), "frames": args.frames},
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
