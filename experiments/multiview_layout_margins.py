"""How far apart BODY_25 and BODY_25B score on detections of either (`jaxmocap.app.layout`).

    python experiments/multiview_layout_margins.py [--out experiments/results/multiview_layout_margins.json]

The default body walks (30 frames) in front of four ring cameras (f = 1000 px, 4.5 m);
its keypoints in each layout are projected and spoiled in two ways: pixel noise with 10 %
of points missed, and "realistic" (5 px noise, 15 % missed, 5 % outliers of 80 px, every
point of one view left/right swapped in 30 % of the frames). Each is scored under both
layouts with 4, 2 and 1 views; the table gives both scores and their ratio (wrong / true).
NumPy only after the body is posed (seconds on a CPU).
"""

from __future__ import annotations

import sys as _sys
from pathlib import Path as _Path

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import _provenance  # noqa: E402,F401  (its commit is taken now, at the start of the run)

import argparse
from pathlib import Path

import numpy as np

from jaxmocap.app.layout import layout_scores
from jaxmocap.body import posed_vertices
from jaxmocap.body.io import default_body
from jaxmocap.geometry.camera import ring_cameras
from jaxmocap.geometry.keypoints import KEYPOINT_FORMATS, keypoint_regressor, regress_keypoints
from jaxmocap.motion.library import walk


def _swap(names):
    return np.array([names.index(n.replace("left", "T").replace("right", "left").replace("T", "right")) for n in names])


def main(out: Path) -> dict:
    body = default_body("low")
    T = 30
    verts, joints = (np.asarray(a, np.float64) for a in posed_vertices(body, walk(T, fps=30.0, body=body)))
    R, t = ring_cameras(4, 4.5, 1.6, [0.0, 0.9, 0.2], start_angle=0.4)
    K = np.array([[1000.0, 0.0, 640.0], [0.0, 1000.0, 360.0], [0.0, 0.0, 1.0]])
    P = np.stack([K @ np.concatenate([R[v], t[v][:, None]], 1) for v in range(4)])
    rng = np.random.default_rng(0)
    rows = []
    for true in ("body25", "body25b"):
        other = "body25b" if true == "body25" else "body25"
        X = regress_keypoints(keypoint_regressor(body, true), verts, joints)
        x = np.einsum("vab,tkb->vtka", P[:, :, :3], X) + P[:, None, None, :, 3]
        clean = x[..., :2] / x[..., 2:]
        for case, noise in (("noise 0 px", 0.0), ("noise 3 px", 3.0), ("noise 10 px", 10.0), ("realistic", 5.0)):
            uv = clean + rng.normal(scale=noise, size=clean.shape)
            missed = 0.15 if case == "realistic" else 0.1
            conf = np.where(rng.random(uv.shape[:-1]) < missed, 0.0, 0.8)[..., None]
            subject = np.concatenate([uv, conf], -1)
            if case == "realistic":
                swapped = rng.random(T) < 0.3
                subject[1, swapped] = subject[1, swapped][:, _swap(KEYPOINT_FORMATS[true])]
                outlier = rng.random(subject.shape[:-1]) < 0.05
                subject[..., :2][outlier] += rng.normal(scale=80.0, size=(int(outlier.sum()), 2))
            for views in (4, 2, 1):
                s = layout_scores(subject[:views], P[:views], body, [true, other])
                rows.append({"true": true, "case": case, "views": views, "score_true": s[true],
                             "score_other": s[other], "ratio": s[other] / s[true]})  # fmt: skip
                print(
                    f"{true:8s} {case:12s} {views} views: true {s[true]:.3f}, other {s[other]:.3f} "
                    f"(x{s[other] / s[true]:.1f})"
                )
    result = {"description": __doc__.split("\n\n")[2].strip(), "rows": rows,
              "min_ratio": min(r["ratio"] for r in rows)}  # fmt: skip
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from _provenance import write_json

    from jaxmocap.motion.splits import Split

    # The procedural walk belongs to no CMU subject: nothing is tuned, trained or evaluated on one.
    write_json(
        out,
        result,
        split=Split("multiview_layout_margins", tuning=(), training=(), evaluation=()),
        data={"motions": ["jaxmocap.motion.library.walk"], "subjects": []},
    )
    return result


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("experiments/results/multiview_layout_margins.json"))
    main(parser.parse_args().out)
