"""Check the retargeting of an animation rig against CMU's own skeleton (issue 14, item 3).

The clips of `../shared/data/cmu_cc` are CMU motion re-exported on Reallusion's CC rig,
whose bones carry their own frames. This script

1. loads every clip of the folder (rig, rest kind, warnings, local-angle extremes),
2. compares the walks (subjects 5, 6, 7 on the CC rig) with the walks read from CMU's own
   skeleton (02_01, 02_02 ASF/AMC; 131_01 BVH): cadence, stride, speed, and the ranges of
   knee, hip and ankle flexion and of the largest local angles,
3. draws one dance clip on the default body (filmstrip, a mesh frame, a GLB).

    python experiments/retarget_check.py            # -> experiments/results/retarget_check.{json,md}, retarget_dance/

Different subjects walk differently: the comparison says whether the CC walks fall in
the range of CMU's own walks, not that they match a particular one; every sentence of the
.md that compares them is computed from the table beside it (`compare_ranges`).

Split (`jaxmocap.motion.splits`): nothing is tuned or trained; the check reads every
subject (recorded as evaluation of all five, tuning and training none).
"""

from __future__ import annotations

import argparse
import csv
import time
import warnings
from pathlib import Path

import numpy as np

import jaxmocap
from _provenance import record, subjects_of, write_json, write_text
from jaxmocap.body import SMPL_JOINT_NAMES
from jaxmocap.motion import load_motion
from jaxmocap.motion.bvh import load_bvh
from jaxmocap.motion.retarget import detect_rig, rest_kind, smpl_rest, strip_namespace
from jaxmocap.motion.splits import SUBJECTS, Split

SPLIT = Split("retarget_check", tuning=(), training=(), evaluation=SUBJECTS)

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"
N = {n: i for i, n in enumerate(SMPL_JOINT_NAMES)}
FPS = 60.0


def compare_ranges(a: dict | None, b: dict | None) -> str:
    """How the range a = {min, max} of one group of walks lies against b's: "inside",
    "wider" (b inside a), "above", "below" (disjoint), "higher" / "lower" (overlapping,
    shifted), or "n/a"."""
    if a is None or b is None:
        return "n/a"
    if a["min"] >= b["min"] and a["max"] <= b["max"]:
        return "inside"
    if a["min"] <= b["min"] and a["max"] >= b["max"]:
        return "wider"
    if a["min"] > b["max"]:
        return "above"
    if a["max"] < b["min"]:
        return "below"
    return "higher" if a["max"] > b["max"] else "lower"


def residual_sentence(P: dict, rows, own_subjects, cc_subjects) -> str:
    """The comparison of the CC walks with CMU's own, measured: one clause per kind of relation."""
    words = {
        "inside": "fall inside the range of CMU's own walks",
        "wider": "span a wider range than CMU's own walks",
        "above": "lie entirely above CMU's own walks",
        "below": "lie entirely below CMU's own walks",
        "higher": "overlap CMU's own walks but reach higher",
        "lower": "overlap CMU's own walks but reach lower",
    }
    groups: dict = {}
    for label, key, fmt in rows:
        a, b = P["cc_rig"][key], P["cmu_own_skeleton"][key]
        rel = compare_ranges(a, b)
        if rel == "n/a":
            continue
        name = label.split(" (")[0]
        span = lambda s, fmt=fmt: f"{fmt.format(s['min'])}–{fmt.format(s['max'])}"  # noqa: E731
        groups.setdefault(rel, []).append(f"{name} {span(a)} against {span(b)}")
    clauses = [f"{words[rel]} for {'; '.join(items)}" for rel, items in groups.items()]
    return (
        f"The CC walks (subjects {', '.join(cc_subjects)}) against CMU's own skeleton (subjects "
        f"{', '.join(own_subjects)}), min–max over clips: they " + "; they ".join(clauses) + "."
    )


def gait(motion, body) -> dict:
    """Cadence, stride, speed and sagittal joint ranges of a walk."""
    joints = np.asarray(jaxmocap.forward(body, motion.poses, None, motion.trans).joints)
    root = joints[:, 0, [0, 2]]
    travel = root[-1] - root[0]
    direction = travel / max(np.linalg.norm(travel), 1e-9)
    # Steps: sign changes of the left-minus-right ankle distance along the walking direction.
    ahead = (joints[:, N["left_ankle"], [0, 2]] - joints[:, N["right_ankle"], [0, 2]]) @ direction
    crossings = np.flatnonzero(np.diff(np.sign(ahead)) != 0)
    steps = len(crossings)
    duration = motion.num_frames / motion.fps
    step_time = np.diff(crossings).mean() / motion.fps if steps >= 2 else np.nan
    speed = np.linalg.norm(travel) / duration
    deg = np.degrees(motion.poses)
    ranges = {
        f"{j}_flexion_range_deg": float(np.ptp(deg[:, N[f"left_{j}"], 0]) / 2 + np.ptp(deg[:, N[f"right_{j}"], 0]) / 2)
        for j in ("knee", "hip", "ankle")
    }
    angle = np.degrees(np.linalg.norm(motion.poses, axis=-1))
    return {
        "frames": motion.num_frames,
        "cadence_steps_per_min": 60.0 / step_time if np.isfinite(step_time) else None,
        "stride_m": 2 * step_time * speed if np.isfinite(step_time) else None,
        "speed_m_per_s": float(speed),
        **ranges,
        "max_local_angle_deg": {n: float(angle[:, N[n]].max()) for n in ("left_hip", "left_knee", "spine1", "spine3", "neck", "left_shoulder")},
    }  # fmt: skip


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cc", type=Path, default=SHARED / "cmu_cc")
    ap.add_argument("--cmu", type=Path, default=SHARED / "cmu")
    ap.add_argument("--dance", default="005_02.bvh", help="the clip to draw")
    ap.add_argument("--out", type=Path, default=ROOT / "experiments" / "results")
    args = ap.parse_args(argv)
    body = jaxmocap.default_body()
    rest_joints = smpl_rest(body)[0]
    index = {
        f"{int(r['Subject']):03d}_{int(r['Trial #']):02d}": r["Motion Description"]
        for r in csv.DictReader(open(args.cc / "index.csv"))
    }

    # 1. Every clip of the folder.
    clips, motions = {}, {}
    for path in sorted(args.cc.glob("*.bvh")):
        t0 = time.perf_counter()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            src = strip_namespace(load_bvh(path))
            rig, table = detect_rig(src)
            motion = load_motion(path, fps=FPS, body=body)
        angle = np.degrees(np.linalg.norm(motion.poses[:, 1:22], axis=-1))
        clips[path.stem] = {
            "description": index.get(path.stem, ""), "rig": rig, "rest": rest_kind(src, rest_joints, table),
            "frames": motion.num_frames, "seconds_to_load": time.perf_counter() - t0,
            "warnings": sorted({str(w.message) for w in caught}),
            "max_local_angle_deg": float(angle.max()), "median_local_angle_deg": float(np.median(angle)),
            "frames_over_150_deg": float((angle > 150).any(axis=1).mean()),
            "joint_of_max": SMPL_JOINT_NAMES[1 + int(np.argmax(angle.max(axis=0)))],
            "finite": bool(np.isfinite(motion.poses).all() and np.isfinite(motion.trans).all()),
        }  # fmt: skip
        motions[path.stem] = motion
        print(f"{path.stem}: {rig}/{clips[path.stem]['rest']}, {motion.num_frames} frames, "
              f"max local angle {angle.max():.0f}°, {len(caught)} warnings", flush=True)  # fmt: skip

    # 2. Walks on the CC rig against walks read from CMU's own skeleton.
    cc_walks = {k: gait(m, body) for k, m in motions.items() if "walk" in clips[k]["description"]}
    own = {}
    for name in ("02_01.amc", "02_02.amc", "131_01.bvh"):
        if (args.cmu / name).is_file():
            own[name] = gait(load_motion(args.cmu / name, fps=FPS, body=body), body)

    def pooled(group: dict) -> dict:
        keys = ["cadence_steps_per_min", "stride_m", "speed_m_per_s", "knee_flexion_range_deg", "hip_flexion_range_deg", "ankle_flexion_range_deg"]  # fmt: skip
        out = {}
        for k in keys:
            v = np.array([g[k] for g in group.values() if g[k] is not None], float)
            out[k] = {"mean": float(v.mean()), "min": float(v.min()), "max": float(v.max())} if v.size else None
        return out

    result = {
        "clips": clips,
        "all_clips_load": all(c["finite"] for c in clips.values()),
        "clips_with_warnings": [k for k, c in clips.items() if c["warnings"]],
        "walks": {"cc_rig": cc_walks, "cmu_own_skeleton": own},
        "walks_pooled": {"cc_rig": pooled(cc_walks), "cmu_own_skeleton": pooled(own)},
    }
    result["walks_compared"] = {k: compare_ranges(result["walks_pooled"]["cc_rig"][k], result["walks_pooled"]["cmu_own_skeleton"][k])
                                for k in result["walks_pooled"]["cc_rig"]}  # fmt: skip
    data = {"clips": sorted(clips) + sorted(own), "subjects": subjects_of([*[f"{k}.bvh" for k in clips], *own]),
            "walks_cc": sorted(cc_walks), "walks_own": sorted(own)}  # fmt: skip
    write_json(args.out / "retarget_check.json", result, split=SPLIT, data=data)

    # 3. One dance clip on the default body.
    from jaxmocap.app.demo import export_motion

    dance = load_motion(args.cc / args.dance, fps=30.0, body=body)
    exported = export_motion(dance, body, args.out / "retarget_dance", fmt="glb", every=3)
    pictures = exported.pictures
    for written in [*exported.meshes, *pictures]:  # committed results too: each needs its provenance entry
        record(written, split=SPLIT, data={"clips": [args.dance], "subjects": subjects_of([args.dance])})

    P = result["walks_pooled"]
    rows = [
        ("cadence (steps/min)", "cadence_steps_per_min", "{:.0f}"), ("stride (m)", "stride_m", "{:.2f}"),
        ("speed (m/s)", "speed_m_per_s", "{:.2f}"), ("knee flexion range (°)", "knee_flexion_range_deg", "{:.0f}"),
        ("hip flexion range (°)", "hip_flexion_range_deg", "{:.0f}"), ("ankle flexion range (°)", "ankle_flexion_range_deg", "{:.0f}"),
    ]  # fmt: skip

    def cell(group, key, fmt):
        s = P[group][key]
        return "n/a" if s is None else f"{fmt.format(s['mean'])} ({fmt.format(s['min'])}–{fmt.format(s['max'])})"

    wide = sorted(k for k, c in clips.items() if c["frames_over_150_deg"] > 0)
    md = [
        "# Retargeting check: the CC rig against CMU's own skeleton",
        "",
        f"`python experiments/retarget_check.py`. {len(clips)} clips of `../shared/data/cmu_cc` loaded "
        f"({'all finite' if result['all_clips_load'] else 'NOT all finite'}; clips with warnings: "
        f"{result['clips_with_warnings'] or 'none'}), rig detected as "
        f"{sorted({c['rig'] for c in clips.values()})}, rest {sorted({c['rest'] for c in clips.values()})}; "
        f"largest local joint angle over all clips {max(c['max_local_angle_deg'] for c in clips.values()):.0f}° "
        f"(median of the clips' medians {np.median([c['median_local_angle_deg'] for c in clips.values()]):.0f}°).",
        "",
        f"Walks: {len(cc_walks)} on the CC rig (subjects {', '.join(subjects_of(f'{k}.bvh' for k in cc_walks))}: "
        f"{', '.join(cc_walks)}) against "
        f"{len(own)} read from CMU's own skeleton ({', '.join(own)}); mean (min–max) over clips, "
        "flexion ranges averaged over left and right (x rotation of the SMPL local pose).",
        "",
        "| | CC rig | CMU's own skeleton |",
        "| --- | --- | --- |",
        *[f"| {label} | {cell('cc_rig', k, f)} | {cell('cmu_own_skeleton', k, f)} |" for label, k, f in rows],
        "",
        "Residual differences. "
        + residual_sentence(P, rows, subjects_of(own), subjects_of(f"{k}.bvh" for k in cc_walks))
        + " (131_01 includes a start and a stop.) "
        f"{len(wide)} clips ({', '.join(sorted({clips[k]['description'].split(' - ')[0].strip().lower() for k in wide}))}) have "
        "frames with a local angle over 150°, "
        f"{100 * np.mean([c['frames_over_150_deg'] for c in clips.values()]):.1f} % of all clip frames on average, "
        f"at {sorted({c['joint_of_max'] for c in clips.values() if c['frames_over_150_deg'] > 0})}: "
        "raised arms and pointed feet whose twist about the bone the rig carries (positions are "
        "exact, the twist is the source's); "
        + (
            f"walks among them: {', '.join(k for k in wide if k in cc_walks)}."
            if any(k in cc_walks for k in wide)
            else "no walk has any."
        ),
        "",
        f"Pictures: {', '.join(str(p.relative_to(args.out)) for p in pictures)} and "
        "`retarget_dance/meshes/sequence.glb` (every third frame at 30 fps).",
        "",
    ]
    write_text(args.out / "retarget_check.md", "\n".join(md), split=SPLIT, data=data)
    print("\n".join(md))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
