"""Association precision and recall of VIP (von Marcard §4.3.2, §4.4.4) on crowded synthetic scenes.

    python experiments/vip_association.py --scenes 8 --frames 150     # ~10 min on 2 CPU cores

Scenes (`vip_config(bystanders=3)`: 4 people, a hand-held camera with an IMU,
OpenPose-like COCO-18 detections with misses, left/right swaps and false detections)
from held-out motion: clips of CMU subjects 5, 6, 7 (../shared/data/cmu_cc), none of
which the association weights were trained on (`experiments/train_association.py`:
subjects 2, 131 and the procedural library). Persons 0 and 1 wear IMUs, 2 and 3 are
bystanders. Hypotheses: each wearer's Inertial Tracker (eq. 4.10, the prior built without
the clip's subject, x₀ with 10° (1σ) error per joint), as in VIP's first association.

Splits (`jaxmocap.motion.splits`, recorded under "split"): the test scenes draw their
clips from the evaluated subjects 05, 06, 07 only; development scenes (`--development`,
and the `--dev-seed` summary) from the development subjects 02 and 131 only (their clips
of >= `--frames` frames at 30 fps, ../shared/data/cmu), so no choice is made on an
evaluated subject. Until 2026-11-28 development seed 0 drew from the evaluated subjects'
clips (all 19 clips of test seeds 53, 54 appeared in seeds 0 and 50-52): the penalty
window and cross_tracks were chosen there (issue 52); `development_before_splits` keeps
those numbers, and the choice must be re-made on development scenes.

History: seed 0 developed (it chose the penalty window and checked cross_tracks); the
model was tested on seeds 51 and 52 (`--seed 51,52`, pooled in the headline, each under
`per_seed`), both run after the model was fixed. Seed 51's one failing scene was examined
afterwards (the wearers' Inertial Tracker keypoints, off by x₀'s errors, fitted either
wearer); a fix tried on it, an identity check by fusion cost, failed on seed 52 and was
removed (`tried_identity_check`). Its cause was the chunked binary program: the first
100 frames favoured the wearers exchanged a little (eq. 4.11 31 lower, of −2640), their
2D tracks carried that through the scene, and over all 150 frames the exchange was 532
worse. The wearer exchanges after the chunks (`association.solve_labelling`) mend it
(first round of 51/5: 0 -> 281 right of 297, 0 wrong); first round of development seed 0
unchanged (3114 right, 5 wrong of 3293, scene by scene). Seeds 50-52 no longer test the
method: a test needs fresh seeds. Seed 50, the test before cross_tracks, was examined to
find why a wearer who left the view lost their track, so it no longer tests anything (its
numbers, with the model before, are kept under `earlier_test_seed_50`).

precision: of the assigned detections, the fraction that is that wearer's (identity
labels); recall: of the wearers' detections (every detection the simulator made of them),
the fraction assigned to the right wearer. Thesis (3DPW, real video): 99.3 % / 92.2 %.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import platform
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "experiments"))

from train_association import WEARERS, scene_inputs, scene_vip_data  # noqa: E402

from jaxmocap.body.io import default_body  # noqa: E402
from jaxmocap.methods import association as A  # noqa: E402
from jaxmocap.methods import visual_inertial as vip  # noqa: E402
from jaxmocap.priors.build import evaluation_prior  # noqa: E402
from jaxmocap.motion.corpus import find_cmu_cc_dir, subject_of  # noqa: E402
from jaxmocap.motion.splits import DEVELOPMENT, EVALUATION, LEAVE_SUBJECT_OUT, Split  # noqa: E402

from _provenance import subjects_of, write_json, write_text  # noqa: E402

#: Association weights trained on the development subjects and the procedural library
#: (train_association.py), priors built without the clip's subject; scenes of 05, 06, 07.
SPLIT = Split("vip_association", tuning=DEVELOPMENT, training=LEAVE_SUBJECT_OUT, evaluation=EVALUATION)


def eligible_clips(folder: Path, frames: int, subjects=EVALUATION) -> list[str]:
    """cmu_cc clips (60 fps) of `subjects` long enough for `frames` frames at 30 fps."""
    import csv

    rows = list(csv.DictReader(open(folder / "index.csv")))
    out = []
    for r in rows:
        f = folder / f"{int(r['Subject']):03d}_{int(r['Trial #']):02d}.bvh"
        if f.exists() and int(r["Frames 60fps"]) >= 2 * frames and subject_of(f) in subjects:
            out.append(str(f))
    return sorted(out)


def development_clips(frames: int) -> list[str]:
    """The development subjects' clips (SPLIT.tuning) long enough for `frames` frames at 30 fps."""
    from jaxmocap.motion import load_motion

    out = []
    for c in SPLIT.clips("tuning"):
        m = load_motion(c.path)
        if m.duration * 30.0 + 1 >= frames:
            out.append(str(c.path))
    return sorted(out)


def evaluate(s: dict, res: A.Association) -> dict:
    labels = s["labels"]
    who = np.take_along_axis(labels, np.maximum(res.index, 0).T, 1).T  # (P, T)
    got = res.index >= 0
    ok = got & (who == np.asarray(WEARERS)[:, None])
    return {"assigned": int(got.sum()), "right": int(ok.sum()), "wrong": int((got & ~ok).sum()),
            "wearer_detections": int(sum((labels == p).sum() for p in WEARERS)),
            "detections": int((labels != -2).sum()), "false_detections": int((labels == -1).sum()),
            "wrong_to_other_wearer": int((got & ~ok & (who >= 0) & (who < len(WEARERS))).sum()),
            "wrong_to_bystander": int((got & (who >= len(WEARERS))).sum()),
            "wrong_to_false_detection": int((got & (who == -1)).sum()),
            # chunks whose binary program stopped at HiGHS's time limit (a loaded machine)
            "time_limited_chunks": sum("time limit" in str(m).lower() for m in res.status)}  # fmt: skip


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenes", default="8", help="scenes per seed: one number, or one per --seed (comma-separated)")
    p.add_argument("--frames", type=int, default=150)
    p.add_argument("--seed", default="0", help="scene seed, or several comma-separated (pooled in the headline)")
    p.add_argument("--cmu-cc", default=str(find_cmu_cc_dir() or ROOT.parent / "shared" / "data" / "cmu_cc"))
    p.add_argument("--out", default=str(ROOT / "experiments" / "results"))
    p.add_argument("--cache", default=str(ROOT / "out" / "vip_association"))
    p.add_argument(
        "--fusion",
        action="store_true",
        help="run the whole method (association, fusion, association "
        "again: `video_inertial_scene`) and score its final association; a GPU job",
    )
    p.add_argument(
        "--penalty-window",
        type=int,
        default=None,
        help="override the shipped model's penalty_window (frames; results cached apart)",
    )
    p.add_argument(
        "--dev-seed",
        type=int,
        default=None,
        help="also summarise the cached whole-method results of "
        "this development seed, for the models in --dev-models (tags; cached results only)",
    )
    p.add_argument(
        "--dev-models",
        default="",
        help="model tags of the development summary besides the run's own (cached results); see "
        "DEV_MODELS; earlier ones, measured on another machine, are in DEV_RECORDED",
    )
    p.add_argument(
        "--development",
        action="store_true",
        help="development scenes: clips of the development "
        "subjects (02, 131) instead of the evaluated ones (cached apart, tagged 'dev')",
    )
    p.add_argument(
        "--only",
        default="",
        help="comma-separated scene indices: compute and cache only these (e.g. one "
        "process per scene); a run without it then gathers the cached scenes into the tables",
    )
    a = p.parse_args(argv)
    only = {int(i) for i in a.only.split(",") if i.strip()}
    body = default_body("low")
    clips = development_clips(a.frames) if a.development else eligible_clips(Path(a.cmu_cc), a.frames)
    if len(clips) < 4:
        raise SystemExit(f"fewer than 4 {'development' if a.development else 'cmu_cc'} clips of >= {a.frames} frames "
                         "at 30 fps.")  # fmt: skip
    role = "_dev" if a.development else ""
    seeds = [int(x) for x in a.seed.split(",")]
    counts = [int(x) for x in a.scenes.split(",")]
    if len(counts) not in (1, len(seeds)):
        raise SystemExit(f"--scenes gives {len(counts)} counts for {len(seeds)} seeds: give one, or one per seed.")
    counts = counts * len(seeds) if len(counts) == 1 else counts
    model = A.load_model()
    if a.penalty_window is not None:
        model = dataclasses.replace(model, penalty_window=a.penalty_window)
    variant = f"_{model.tag}"
    cache = Path(a.cache)
    cache.mkdir(parents=True, exist_ok=True)
    per_scene, t_start = [], time.time()
    for seed, i, motions in scenes(seeds, counts, clips):
        if only and i not in only:
            continue
        done = cache / f"result{role}_{seed}_{i}_{a.frames}_{'fusion' if a.fusion else 'first'}{variant}.json"
        if done.exists():  # finished scenes of an interrupted run
            per_scene.append({"seed": seed, **json.loads(done.read_text())})
            continue
        f = cache / f"scene{role}_{seed}_{i}_{a.frames}.npz"
        t0 = time.time()
        if f.exists():
            d = np.load(f, allow_pickle=True)
            s = {k: d[k] for k in d.files}
        else:
            priors = [evaluation_prior(motions[k]) for k in WEARERS]
            s = scene_inputs(motions, 3, a.frames, seed + 1000 + i, body, priors=priors)
            np.savez(f.with_suffix(".tmp.npz"), **{k: np.asarray(v) for k, v in s.items()})
            f.with_suffix(".tmp.npz").replace(f)  # atomic: a killed run leaves no half scene
        t1 = time.time()
        res = A.associate(s["joints3d"], s["K"], s["cam_orientation"], s["detections"], model=model)
        t2 = time.time()
        r = evaluate(s, res)
        if a.fusion:  # the method's own association: the second round, from the fused people
            datas, bones = scene_vip_data(motions, 3, a.frames, seed + 1000 + i, body,
                                          priors=[evaluation_prior(motions[k]) for k in WEARERS])  # fmt: skip
            scene = vip.video_inertial_scene(datas, bones, s["detections"], model=model)
            r = {**evaluate(s, scene.associations[-1]), "first_round": r,
                 "seconds_whole_method": {k: round(v, 1) for k, v in scene.seconds.items()}}  # fmt: skip
        r.update({"clips": [Path(str(m)).name for m in s["names"]], "frames": int(len(s["detections"])),
                  "seconds_scene_and_tracker": round(t1 - t0, 1), "seconds_association": round(t2 - t1, 2),
                  "seconds_features": round(res.seconds["features"], 2), "seconds_milp": round(res.seconds["solve"], 2),
                  "precision": r["right"] / max(r["assigned"], 1), "recall": r["right"] / max(r["wearer_detections"], 1)})  # fmt: skip
        print(json.dumps(r), flush=True)
        done.with_suffix(".tmp").write_text(json.dumps(r))
        done.with_suffix(".tmp").replace(done)
        per_scene.append({"seed": seed, **r})
    if only:
        return 0
    tot = {k: sum(s.get(k, 0) for s in per_scene) for k in ("assigned", "right", "wrong", "wearer_detections",
                                                            "detections", "false_detections", "wrong_to_other_wearer",
                                                            "wrong_to_bystander", "wrong_to_false_detection", "frames",
                                                            "time_limited_chunks")}  # fmt: skip
    out = {
        "association": {"precision": tot["right"] / max(tot["assigned"], 1),
                        "recall": tot["right"] / max(tot["wearer_detections"], 1)},
        "thesis_3dpw": {"precision": 0.993, "recall": 0.922},
        "counts": tot,
        "timing": {"association_seconds_total": round(sum(s["seconds_association"] for s in per_scene), 2),
                   "association_seconds_per_100_frames": round(100 * sum(s["seconds_association"] for s in per_scene)
                                                               / max(tot["frames"], 1), 2),
                   "wall_seconds": round(time.time() - t_start, 1),
                   "note": "association = features + HiGHS; the scene simulation and Inertial Tracker are not "
                           "counted (cached scenes take 0 s there). Seconds are those of the process that ran "
                           "each scene (cached results keep theirs; the committed ones: one scene per core of the "
                           "GPU host's CPU, taskset), not of `machine`, where the tables were gathered"},
        "machine": {"platform": platform.platform(), "processor": platform.processor() or platform.machine(),
                    "cpus": __import__("os").cpu_count(), "jax": jax.__version__, "device": str(jax.devices()[0])},
        "per_seed": {str(sd): rates([s for s in per_scene if s["seed"] == sd]) for sd in seeds},
        "config": {"scenes": sum(counts), "scenes_per_seed": counts, "frames": a.frames, "seeds": seeds, "bystanders": 3, "wearers": list(WEARERS),
                   "data": ("../shared/data/cmu (development subjects 02, 131: development scenes)" if a.development
                            else "../shared/data/cmu_cc (CMU subjects 05, 06, 07; held out from training and tuning)"),
                   "development_scenes": a.development,
                   "hypotheses": "Inertial Tracker keypoints, x0 with 10 deg (1 sigma) error per joint",
                   "weights": str(A.WEIGHTS_FILE.relative_to(ROOT)), "window": 30,
                   "penalty_window": model.penalty_window, "model": model.tag, "cross_tracks": model.cross_tracks,
                   "command": "python experiments/vip_association.py " + " ".join(argv if argv is not None else sys.argv[1:])},
        "per_scene": per_scene,
    }  # fmt: skip
    if a.dev_seed is not None:
        out["development"] = development(cache, a, [*filter(None, a.dev_models.split(",")), model.tag])
    out["development_before_splits"] = {"seed": 0, "note": "development seed 0 before 2026-11-28 drew its clips from "
                                        "the evaluated subjects 05, 06, 07: these chose the penalty window",
                                        **{f"model_{w}": dict(zip(("scenes", "precision", "recall", "assigned", "right",
                                                                   "wrong", "wearer_detections"), v))
                                           for w, v in DEV_RECORDED.items()}}  # fmt: skip
    if 50 not in seeds:
        out["earlier_test_seed_50"] = EARLIER_TEST
    if not {51, 52} & set(seeds):
        out["earlier_test_seeds_51_52"] = EARLIER_TEST_51_52
    out["tried_identity_check"] = IDENTITY_CHECK_TRIED
    if a.fusion:
        fr = {k: sum(s["first_round"][k] for s in per_scene) for k in ("assigned", "right", "wearer_detections")}
        out["association_first_round"] = {"precision": fr["right"] / max(fr["assigned"], 1),
                                          "recall": fr["right"] / max(fr["wearer_detections"], 1), **fr}  # fmt: skip
        out["config"]["hypotheses"] = ("the whole method (video_inertial_scene, 2 rounds): scored on its final association, "
                                       "from the fused people and camera; the first round's from Inertial Tracker "
                                       "keypoints, x0 with 10 deg (1 sigma) error per joint")  # fmt: skip
    res_dir = Path(a.out)
    name = "vip_association" + ("_development" if a.development else "")
    # development scenes choose (they evaluate nothing that is published as a test)
    split = Split(name, tuning=DEVELOPMENT, training=DEVELOPMENT, evaluation=()) if a.development else SPLIT
    scene_clips = sorted({c for s in per_scene for c in s["clips"]})
    data = {"clips": scene_clips, "subjects": subjects_of(scene_clips), "seeds": seeds, "scenes_per_seed": counts,
            "frames": a.frames}  # fmt: skip
    res_dir.mkdir(parents=True, exist_ok=True)
    if (res_dir / f"{name}.json").exists():  # experiments/vip_association_unseen.py's blocks
        old = json.loads((res_dir / f"{name}.json").read_text())
        out.update({k: old[k] for k in UNSEEN_BLOCKS if k in old})
    write_json(res_dir / f"{name}.json", out, split=split, data=data, argv=argv)
    write_text(res_dir / f"{name}.md", markdown(out), split=split, data=data, argv=argv)
    print(markdown(out))
    return 0


#: Blocks written by experiments/vip_association_unseen.py, kept when this script rewrites the file.
UNSEEN_BLOCKS = (
    "defaults_unseen",
    "defaults_development",
    "defaults_unseen_same_clip",
    "defaults_development_same_clip",
)


def scenes(seeds, counts, clips):
    """(seed, index, 4 clips) of every scene: each seed draws its scenes' clips in order (so a
    seed's first n scenes do not depend on how many follow)."""
    for seed, n in zip(seeds, counts):
        rng = np.random.default_rng(seed)
        for i in range(n):
            yield seed, i, list(rng.choice(clips, 4, replace=False))


def rates(per_scene) -> dict:
    n = {k: sum(s[k] for s in per_scene) for k in ("assigned", "right", "wrong", "wearer_detections", "detections")}
    return {
        "scenes": len(per_scene),
        "precision": n["right"] / max(n["assigned"], 1),
        "recall": n["right"] / max(n["wearer_detections"], 1),
        **n,
    }


# The previous model's test (penalty window 90, no cross_tracks; `--seed 50`, 2026-11-25):
# examined afterwards, so no longer a test.
EARLIER_TEST = {
    "seed": 50,
    "model": "pw90",
    "precision": 0.983,
    "recall": 0.969,
    "wrong": 59,
    "note": "55 of the 59 wrong in one scene: a wearer who left the view was replaced by a bystander "
    "seen beside them before; cross_tracks was built against it",
}


# The test of the model before the wearer exchanges (`--seed 51,52`, 2026-11-26): seed 51's
# scene 5 was examined afterwards and the exchanges built against it, so no longer a test.
EARLIER_TEST_51_52 = {"seeds": [51, 52], "model": "pw90_151a14", "scenes": 24, "precision": 0.9563807839669909,
                      "recall": 0.9293999713590148, "assigned": 6786, "right": 6490, "wrong": 296,
                      "per_seed": {"51": {"precision": 0.9136922176711527, "recall": 0.8915215529546103, "wrong": 295},
                                   "52": {"precision": 0.9997030878859857, "recall": 0.9675287356321839, "wrong": 1}},
                      "note": "293 of the 296 wrong in scene 51/5, its wearers exchanged throughout: the first 100-frame "
                              "chunk of the binary program favoured the exchange, which the wearer exchanges after the "
                              "chunks now undo"}  # fmt: skip


# Tried and removed (2026-11-26): after the first fusion, fuse each pair of wearers again with
# their detections exchanged and keep the exchange where the pair's fusion cost falls. It
# mended the exchanged wearers of test scene 51/5 (cost 153.9 -> 62.4; 293 right, 0 wrong) but
# a fusion that fails leaves a right assignment with a high cost: on seed 52 it exchanged two
# right scenes (1165.6 -> 353.3 and 3244.7 -> 1861.3) even when the cost had to fall below 2/3.
IDENTITY_CHECK_TRIED = {
    "rule": "exchange two wearers' detections after the first fusion where the pair's fusion cost falls below "
            "ratio x its cost",
    "dev_seed_0_any_decrease": {"precision": 0.9276, "recall": 0.8916, "note": "a right scene exchanged at a 2.3 % "
                                "decrease (138.9 -> 135.8)"},
    "dev_seed_0_ratio_2_3": {"precision": 0.9981, "recall": 0.9638, "note": "no exchange: the shipped method's numbers"},
    "test_seed_52_ratio_2_3": {"precision": 0.8432, "recall": 0.8034, "assigned": 3316, "right": 2796, "wrong": 520,
                               "note": "two right scenes (first round 100 %) exchanged; without the check 99.97 % / 96.75 %"},
    "seed_51_scene_5_ratio_2_3": {"right": 293, "wrong": 0, "note": "the exchanged scene mended (before: 0 right, 293 wrong)"},
}  # fmt: skip


# What the development tags are (AssociationModel.tag).
DEV_MODELS = {
    "pw30": "the thesis's 30-frame window, no cross_tracks",
    "pw90": "penalties up to 90 frames apart, no cross_tracks",
    "pw90_d8990f": "90 frames and cross_tracks as -1e4 pair penalties within them (before the frame cliques)",
    "pw90_151a14": "90 frames, cross_tracks as frame cliques",
    "pw90_fa2ab0": "90 frames, cross_tracks as frame cliques, wearer exchanges after the chunks",
}

# Development results of earlier models, measured 2026-11-24/26 on the device (their caches
# are not kept): scenes, precision, recall, assigned, right, wrong, wearer_detections.
DEV_SCENES = 12  # development seed 0's scenes

DEV_RECORDED = {
    "pw30": (12, 0.9843269821757836, 0.9726692985119951, 3254, 3203, 51, 3293),
    "pw90": (12, 0.9962674961119751, 0.9726692985119951, 3215, 3203, 12, 3293),
    "pw90_d8990f": (12, 0.9981132075471698, 0.9638627391436381, 3180, 3174, 6, 3293),
    "pw90_151a14": (12, 0.9981132075471698, 0.9638627391436381, 3180, 3174, 6, 3293),
}


def development(cache: Path, a, tags) -> dict:
    """Precision and recall of the cached whole-method results of seed `a.dev_seed`, per model tag."""
    out = {
        "seed": a.dev_seed,
        "note": "development scenes: they chose the shipped penalty_window "
        "(experiments/train_association.py, PENALTY_WINDOW) and checked cross_tracks; the headline numbers are "
        "the test seed's",
    }
    for w in tags:  # development scenes (--development): clips of the development subjects
        rs = [
            json.loads(f.read_text())
            for i in range(DEV_SCENES)
            if (f := cache / f"result_dev_{a.dev_seed}_{i}_{a.frames}_fusion_{w}.json").exists()
        ]
        if rs:  # the shipped model's development scenes are run with --seed 0 --fusion
            out[f"model_{w}"] = {"model": DEV_MODELS.get(w, "shipped" if w == tags[-1] else w), **rates(rs)}
    return out


def markdown(r: dict) -> str:
    c, n, t = r["config"], r["counts"], r["timing"]
    a = r["association"]
    held = "development" if c.get("development_scenes") else "held-out"
    subjects = ", ".join(subjects_of(cl for s in r["per_scene"] for cl in s["clips"]))
    L = ["# VIP association on crowded synthetic scenes (von Marcard §4.3.2)", "",
         f"`{c['command']}`: {c['scenes']} scenes × ≤ {c['frames']} frames ({n['frames']} frames), {1 + c['bystanders']} people each "
         f"(persons {', '.join(map(str, c['wearers']))} wear IMUs; {1 + c['bystanders'] - len(c['wearers'])} bystanders), {held} CMU subjects {subjects}; {n['detections']} detections "
         f"({n['false_detections']} false), {n['wearer_detections']} of them the wearers'. Hypotheses: "
         f"{c['hypotheses']}; weights trained on CMU subjects 2, 131 and the procedural library.", "",
         "| | precision | recall |", "| --- | --- | --- |",
         f"| ours (synthetic{', final round' if 'association_first_round' in r else ''}, seeds "
         f"{', '.join(map(str, c['seeds']))}) | {100 * a['precision']:.1f} % | {100 * a['recall']:.1f} % |",
         *[f"| ours, seed {sd} ({v['scenes']} scenes, {v['detections']} detections) | {100 * v['precision']:.2f} % "
           f"| {100 * v['recall']:.2f} % |" for sd, v in r["per_seed"].items() if len(r["per_seed"]) > 1],
         *([f"| ours (synthetic, first round) | {100 * r['association_first_round']['precision']:.1f} % | "
            f"{100 * r['association_first_round']['recall']:.1f} % |"] if "association_first_round" in r else []),
         "| thesis (3DPW, real) | 99.3 % | 92.2 % |",
         *([f"| earlier test (seeds 51, 52), model before the wearer exchanges, examined since | "
            f"{100 * r['earlier_test_seeds_51_52']['precision']:.1f} % | "
            f"{100 * r['earlier_test_seeds_51_52']['recall']:.1f} % |"] if "earlier_test_seeds_51_52" in r else []),
         *([f"| earlier test (seed 50), model before cross_tracks, examined since | "
            f"{100 * r['earlier_test_seed_50']['precision']:.1f} % | {100 * r['earlier_test_seed_50']['recall']:.1f} % |"]
           if "earlier_test_seed_50" in r else []),
         *[f"| development scenes (seed {r['development']['seed']}), {v['model']} "
           f"| {100 * v['precision']:.1f} % | {100 * v['recall']:.1f} % |"
           for k, v in r.get("development", {}).items() if k.startswith("model_") and v["scenes"]],
         *[f"| development seed 0 before the splits (clips of the evaluated subjects), {DEV_MODELS[k[6:]]} "
           f"| {100 * v['precision']:.1f} % | {100 * v['recall']:.1f} % |"
           for k, v in r.get("development_before_splits", {}).items() if k.startswith("model_")], "",
         f"Assigned {n['assigned']}: {n['right']} right, {n['wrong']} wrong ({n['wrong_to_other_wearer']} to the other "
         f"wearer, {n['wrong_to_bystander']} to a bystander, {n['wrong_to_false_detection']} to a false detection). "
         f"Association time {t['association_seconds_total']} s in all ({t['association_seconds_per_100_frames']} s "
         f"per 100 frames: features + HiGHS, one CPU core per scene).", "",
         "| seed | scene clips | frames | precision | recall | wrong | s |",
         "| --- | --- | --- | --- | --- | --- | --- |"]  # fmt: skip
    for s in r["per_scene"]:
        L.append(f"| {s['seed']} | {', '.join(s['clips'])} | {s['frames']} | {100 * s['precision']:.1f} % "
                 f"| {100 * s['recall']:.1f} % | {s['wrong']} | {s['seconds_association']} |")  # fmt: skip
    from vip_association_unseen import markdown as unseen_markdown

    return "\n".join(L) + "\n" + unseen_markdown(r)


if __name__ == "__main__":
    sys.exit(main())
