"""VIP association with the library's defaults on unseen clips, 0-3 bystanders (issue 46, goal 5).

    python experiments/vip_association_unseen.py --role development --scenes 4 --grid \
        --weights out/association_weights_dev.json --install     # choose the defaults (from train_association.py)
    python experiments/vip_association_unseen.py --role evaluation --scenes 5  # measure them

(2026-11-28, a loaded 2-core CPU: about 40 s per scene after the first, ~10 min per role
with `--only 0,1` and `--only 2,3` in two processes, then one run without --only to gather.)

Scenes (`vip_config(bystanders=k)`, k = 0, 1, 2, 3): one IMU wearer (person 0, as
`experiments/vip_tables.py` and `jaxmocap vip`) and k bystanders, every person a *different*
clip (`experiments/vip_tables.py` gives `make_scenario` one clip, so its bystanders perform
the wearer's own motion in step, turned and moved aside: see `clone_scenes` in the results).
Clips come from a `Split` (`jaxmocap.motion.splits`): development scenes from subjects 02
and 131 (../shared/data/cmu) choose the settings; evaluation scenes from subjects 05, 06, 07
(../shared/data/cmu_cc), which neither the association model (`train_association.py`) nor the
setting choice saw, measure them. Each wearer's Inertial Tracker uses a prior built without
the wearer's subject (and, on development scenes, without any evaluation subject).

Hypotheses: the first association of `video_inertial_scene` (Inertial Tracker keypoints, x0
with 10 deg (1 sigma) error per joint), scored with identity labels: precision = right /
assigned, recall = right / the wearer's detections. `--fusion` also runs the whole method
(two rounds, `video_inertial_scene` with its defaults) and scores its final association.

Results: a block in experiments/results/vip_association.json ("defaults_unseen" for the
evaluation role, "defaults_development" for the development role); other keys are kept.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "experiments"))

from train_association import noisy_x0, wearer_prior  # noqa: E402

from jaxmocap.app.scenarios import vip_sequence  # noqa: E402
from jaxmocap.body.io import default_body  # noqa: E402
from jaxmocap.methods import association as A  # noqa: E402
from jaxmocap.methods import visual_inertial as vip  # noqa: E402
from jaxmocap.motion.splits import DEVELOPMENT, EVALUATION, Split  # noqa: E402
from jaxmocap.sensors import make_scenario  # noqa: E402
from jaxmocap.sensors.scenario import vip_config  # noqa: E402

SPLIT = Split("vip_association_defaults", tuning=DEVELOPMENT, training=DEVELOPMENT, evaluation=EVALUATION)
BYSTANDERS = (0, 1, 2, 3)


def frames_at_30fps(path) -> int:
    """A clip's length at 30 fps from its header (BVH: Frames, Frame Time) or frame lines (AMC, 120 fps)."""
    text = Path(path).read_text(errors="ignore")
    if str(path).endswith(".bvh"):
        n = int(text.split("Frames:")[1].split()[0])
        dt = float(text.split("Frame Time:")[1].split()[0])
        return int(n * dt * 30)
    return sum(line.strip().isdigit() for line in text.splitlines()) // 4


def scene_list(role: str, per_count: int, seed: int, same_clip: bool = False, frames: int = 90) -> list[dict]:
    """Per bystander count, `per_count` scenes; wearers cycle through the role's clips (shuffled),
    bystanders are other clips of the role (every person a different clip), or with
    `same_clip` the wearer's clip (`make_scenario` given one clip, as experiments/vip_tables.py)."""
    clips = [str(c.path) for c in SPLIT.clips("tuning" if role == "development" else "evaluation")]
    clips = [c for c in clips if frames_at_30fps(c) >= frames]  # one length: one compile of the tracker
    rng = np.random.default_rng(seed)
    order = list(rng.permutation(clips))
    out, n = [], 0
    for k in BYSTANDERS:
        for j in range(per_count):
            wearer = order[n % len(order)]
            n += 1
            others = [c for c in clips if c != wearer]
            by = [str(c) for c in rng.choice(others, k, replace=False)]
            out.append({"bystanders": k, "index": j, "clips": [wearer] if same_clip else [wearer, *by]})
    return out


def build_scene(sc: dict, frames: int, seed: int, body, x0_degrees: float = 10.0):
    """(scenario, VIPData of the wearer, bones, labels (T, D), detections (T, D, 18, 3))."""
    k, j = sc["bystanders"], sc["index"]
    for retry in range(5):  # a draw whose IMUs dropped frame 0 (VIP calibrates on it) is drawn again
        scen = make_scenario(sc["clips"], vip_config(bystanders=k, max_frames=frames),
                             seed=seed + 100 * k + j + 10_000 * retry, body=body, num_sequences=1)  # fmt: skip
        seq = scen.sequence(0)
        x0 = noisy_x0(np.random.default_rng([seed, k, j]), seq["poses"][0][0], x0_degrees)
        try:
            data, _, bones = vip_sequence(scen, 0, body, x0=x0, prior=wearer_prior(sc["clips"][0]))
        except ValueError as e:
            if "dropped samples" not in str(e):
                raise
            continue
        return scen, data, bones, seq["det_person"][0], seq["det_keypoints"][0]
    raise RuntimeError(f"scene {k}/{j}: frame 0 dropped in 5 draws")


def counts(index, labels) -> dict:
    """index (T,) the wearer's detection or -1; labels (T, D) identities (-1 false, -2 padding)."""
    T = len(index)
    who = labels[np.arange(T), np.maximum(index, 0)]
    got = index >= 0
    right = got & (who == 0)
    return {"assigned": int(got.sum()), "right": int(right.sum()), "wrong": int((got & ~right).sum()),
            "wearer_detections": int((labels == 0).sum()), "wrong_to_bystander": int((got & (who > 0)).sum()),
            "wrong_to_false_detection": int((got & (who == -1)).sum())}  # fmt: skip


def rates(rows) -> dict:
    n = {k: sum(r[k] for r in rows) for k in ("assigned", "right", "wrong", "wearer_detections")}
    return {"scenes": len(rows), "precision": n["right"] / max(n["assigned"], 1),
            "recall": n["right"] / max(n["wearer_detections"], 1), **n}  # fmt: skip


def inputs(sc, frames, seed, body, cache: Path, x0_degrees: float = 10.0) -> dict:
    """The scene's first-round inputs (IT keypoints, camera, detections, labels), cached."""
    f = cache / f"scene_{sc['bystanders']}_{sc['index']}_{frames}_{seed}.npz"
    names = np.array([Path(c).name for c in sc["clips"]])
    if f.exists():
        d = np.load(f)
        if "names" not in d.files or list(d["names"]) == list(names):  # another --scenes draws other clips
            return {k: d[k] for k in d.files if k != "names"}
    _, data, bones, labels, det = build_scene(sc, frames, seed, body, x0_degrees)
    s = {"joints3d": vip.tracker_hypotheses([data], bones), "K": np.asarray(data.K),
         "cam_orientation": np.asarray(data.cam_orientation), "detections": np.asarray(det), "labels": np.asarray(labels)}  # fmt: skip
    np.savez(f.with_suffix(".tmp.npz"), **s, names=names)
    f.with_suffix(".tmp.npz").replace(f)
    return s


#: Why experiments/vip_tables.py reports 93.9 % (issue 46), measured 2026-11-28 with
#: out-of-tree checks: its scenes give `make_scenario` one clip, so every bystander performs the
#: wearer's motion; clips shorter than its 300 frames start at frame 0 for everyone, so the
#: bystanders are exact copies of the wearer, turned (random yaw) and moved aside, which the
#: wearer's IMUs cannot tell apart. All 123 of its wrong assignments are in two such scenes:
#: clip 2 (005_03, 2 bystanders, 32 wrong) and clip 7 (005_08, 3 bystanders, 91 wrong, the
#: wearer visible in 84 of 181 frames). Scene 7 again, first round, the shipped model: 90 of
#: 159 assigned detections went to bystander 2 (the copy); the same wearer, seed and x0 with
#: three other clips as bystanders: 70 right, 1 wrong (a false detection) of 71.
TABLES_CAUSE = {
    "vip_tables": {"precision": 0.939, "recall": 0.960, "assigned": 2030, "right": 1907, "wrong": 123,
                   "model": "pw90_151a14", "wearers": 1, "frames": 300,
                   "wrong_by_scene": {"02 005_03 (2 bystanders)": 32, "07 005_08 (3 bystanders)": 91}},
    "cause": "experiments/vip_tables.py gives make_scenario one clip, so its bystanders perform the wearer's own "
             "motion (from frame 0 when the clip is shorter than 300 frames at 30 fps: exact copies, turned and moved "
             "aside); the wearer's IMUs cannot tell a copy from the wearer",
    "check_scene_7_first_round": {
        "bystanders_copy_the_wearer": {"assigned": 159, "right": 69, "wrong": 90, "wrong_to_bystander": 90},
        "bystanders_other_clips": {"assigned": 71, "right": 70, "wrong": 1, "wrong_to_bystander": 0}},
    "not_the_cause": "threshold and rounds are the same (model defaults, 2 rounds); the model tags differ only by "
                     "the wearer exchanges, which need two wearers (vip_tables has one)",
}  # fmt: skip


#: What limits the evaluation (examined after it, so nothing was chosen from it): scene 2/3
#: (wearer 006_07, bystanders 005_16, 005_12), first round, the shipped model. The unary
#: evidence favours the wearer (the wearer's detection has the best unary in 82 of 90 frames;
#: eq. 4.11's unary sum over the wearer's 86 detections -155.9, over bystander 2's 89: +64.0),
#: but the inter-frame pair rewards, which score a track's consistency and not whose it is
#: (train_association.py's labels), favour the longer, steadier bystander track (-1039.7 against
#: -852.0 at pair_scale 0.1). The program's optimum (HiGHS: optimal) takes 87 of bystander 2's
#: detections at -1010.6; all of the wearer's give -1007.9. One wearer and nobody else to take
#: the bystander's track: nothing but the unary margin opposes the switch.
WORST_SCENE = {
    "scene": "bystanders 2, index 3: 006_07.bvh (wearer), 005_16.bvh, 005_12.bvh; model pw30_c4ed28, before the identity check",
    "wearer_best_unary_frames": 82, "frames": 90,
    "objective_terms": {"wearer_all": {"detections": 86, "unary": -155.9, "pairs": -852.0, "total": -1007.9},
                        "bystander_2_all": {"detections": 89, "unary": 64.0, "pairs": -1039.7, "total": -975.7},
                        "solver": {"detections": 87, "person": "bystander 2", "total": -1010.6, "status": "optimal"}},
    "cause": "identity-blind inter-frame pair rewards (track consistency) outweigh the unary identity evidence "
             "when one wearer has no rival for a bystander's steadier track; reported, not tuned on",
}  # fmt: skip


#: The development grid: (name, changes to the model). Chosen by the most recall at a
#: development precision >= 99.5 % (ties: the more precise), as train_association.py.
#: The first grid (2026-11-28: pw30, pw90, pw90 without cross_tracks, pw90 with assignment cost
#: 1; 16 scenes, seed 0) chose penalty_window 30 (provenance in association_weights.json); this
#: one, on the same model, the identity check's margin (`association.solve_labelling`), None: off.
GRID = {
    "identity_off": {"identity_margin": None},
    "identity_0.5": {"identity_margin": 0.5},
    "identity_1": {"identity_margin": 1.0},
    "identity_2": {"identity_margin": 2.0},
}


def choose(grid: dict) -> str:
    """The rule's pick; on a tie the trained model as it is ("defaults": nothing changes without evidence)."""
    grid = {"defaults": grid["defaults"]} | grid  # max() keeps the first of equals
    ok = [k for k, r in grid.items() if r["precision"] >= 0.995]
    rank = lambda k: (grid[k]["recall"], grid[k]["precision"])  # noqa: E731
    return max(ok, key=rank) if ok else max(grid, key=lambda k: (grid[k]["precision"], grid[k]["recall"]))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--role", choices=("development", "evaluation"), default="evaluation")
    p.add_argument("--scenes", type=int, default=5, help="scenes per bystander count")
    p.add_argument("--frames", type=int, default=90, help="frames per scene; clips shorter are left out")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--grid", action="store_true", help="score every GRID setting (development role)")
    p.add_argument("--weights", default=None, help="association weights file (default: the shipped ones)")
    p.add_argument("--fusion", action="store_true", help="also the whole method's final association")
    p.add_argument("--only", default="", help="bystander counts to run (comma-separated); results cached")
    p.add_argument(
        "--same-clip",
        action="store_true",
        help="bystanders perform the wearer's clip (vip_tables' scenes); written as defaults_unseen_same_clip",
    )
    p.add_argument(
        "--inputs-only",
        action="store_true",
        help="only simulate and cache the scenes' Inertial Tracker hypotheses (no association, no result)",
    )
    p.add_argument(
        "--install",
        action="store_true",
        help="with --grid: write the chosen setting of --weights "
        "to jaxmocap/methods/association_weights.json (the library's default)",
    )
    p.add_argument(
        "--x0-noise",
        type=float,
        default=10.0,
        help="x0's error per joint, degrees (1 sigma; 10 as vip_tables): more makes harder development scenes",
    )
    p.add_argument("--cache", default=str(ROOT / "out" / "vip_association_unseen"))
    p.add_argument("--out", default=str(ROOT / "experiments" / "results" / "vip_association.json"))
    a = p.parse_args(argv)
    if a.grid and a.role != "development":
        raise SystemExit("--grid chooses settings: development scenes only (the evaluation subjects choose nothing).")
    body = default_body("low")
    cache = Path(a.cache) / (
        a.role + ("_same_clip" if a.same_clip else "") + (f"_x0_{a.x0_noise:g}" if a.x0_noise != 10.0 else "")
    )
    cache.mkdir(parents=True, exist_ok=True)
    base = A.load_model(a.weights)
    models = {"defaults": base}
    if a.grid:
        models.update({k: dataclasses.replace(base, **v) for k, v in GRID.items()})
    only = {int(x) for x in a.only.split(",") if x.strip()}
    rows = {k: [] for k in models}
    per_scene = []
    for sc in scene_list(a.role, a.scenes, a.seed, a.same_clip, a.frames):
        if only and sc["bystanders"] not in only:
            continue
        t0 = time.time()
        s = inputs(sc, a.frames, a.seed, body, cache, a.x0_noise)
        t1 = time.time()
        if a.inputs_only:
            print(f"scene {sc['bystanders']}/{sc['index']}: {len(s['detections'])} frames, {t1 - t0:.0f} s", flush=True)
            continue
        rec = {"bystanders": sc["bystanders"], "clips": [Path(c).name for c in sc["clips"]],
               "frames": int(len(s["detections"])), "seconds_scene": round(t1 - t0, 1)}  # fmt: skip
        graphs = {}
        for name, m in models.items():
            done = cache / f"result_{sc['bystanders']}_{sc['index']}_{a.frames}_{a.seed}_{a.scenes}_{m.tag}.json"
            if done.exists():
                r = json.loads(done.read_text())
            else:
                gkey = (m.penalty_window, m.cross_tracks, m.unary, m.inter, m.intra, m.min_probability)
                if gkey not in graphs:
                    graphs[gkey] = A.association_graph(s["joints3d"], s["K"], s["cam_orientation"], s["detections"], m)
                res = A.solve_graph(graphs[gkey], s["detections"], m)
                r = counts(res.index[0], s["labels"])
                done.write_text(json.dumps(r))
            rows[name].append({**r, "bystanders": sc["bystanders"]})
            rec[name] = r
        if a.fusion:
            done = cache / f"fusion_{sc['bystanders']}_{sc['index']}_{a.frames}_{a.seed}_{a.scenes}_{base.tag}.json"
            if done.exists():
                r = json.loads(done.read_text())
            else:
                _, data, bones, labels, det = build_scene(sc, a.frames, a.seed, body, a.x0_noise)
                scene = vip.video_inertial_scene([data], bones, det, model=base)
                r = {**counts(scene.associations[-1].index[0], labels),
                     "seconds": {k: round(v, 1) for k, v in scene.seconds.items()}}  # fmt: skip
                done.write_text(json.dumps(r))
            rec["final_round"] = r
        rec["seconds_association"] = round(time.time() - t1, 1)
        print(json.dumps(rec), flush=True)
        per_scene.append(rec)

    if a.inputs_only:
        return 0

    def block(name):
        rs = rows[name]
        return {**rates(rs), "per_bystanders": {str(k): rates([r for r in rs if r["bystanders"] == k])
                                                for k in BYSTANDERS if any(r["bystanders"] == k for r in rs)}}  # fmt: skip

    out = {**block("defaults"), "model": base.tag, "weights": a.weights or str(A.WEIGHTS_FILE.relative_to(ROOT)),
           "round": "first (Inertial Tracker hypotheses)", "frames": a.frames, "seed": a.seed, "x0_noise_deg": a.x0_noise,
           "scenes_per_bystander_count": a.scenes, "wearers": 1, "split": SPLIT.record(), "vip_tables_93_9": TABLES_CAUSE,
           **({"worst_scene": WORST_SCENE} if a.role == "evaluation" and not a.same_clip else {}),
           "clips": sorted({c for r in per_scene for c in r["clips"]}),
           "command": "python experiments/vip_association_unseen.py " + " ".join(argv if argv is not None else sys.argv[1:]),
           "per_scene": per_scene}  # fmt: skip
    if a.fusion:
        fr = [{**r["final_round"], "bystanders": r["bystanders"]} for r in per_scene]
        rows["final"] = fr
        out["final_round"] = block("final")
    if a.grid:
        out["grid"] = {k: block(k) for k in GRID} | {"defaults": block("defaults")}
        out["chosen"] = choose(out["grid"])
        out["rule"] = (
            "the most recall at a development precision >= 99.5 % (ties: the more precise, then the "
            "trained model unchanged)"
        )
        if a.install:
            m = models[out["chosen"]]
            values = {
                k: getattr(m, k)
                for k in ("penalty_window", "cross_tracks", "pair_scale", "assignment_cost", "identity_margin")
            }
            prov = {**m.provenance, "split": m.provenance.get("split", SPLIT.record()),
                    "settings": {"chosen": out["chosen"], "values": values, "grid": {k: GRID.get(k, {}) for k in out["grid"]},
                                 "rule": out["rule"], "split": SPLIT.record(), "command": out["command"],
                                 "scores": {k: {x: v[x] for x in ("precision", "recall", "assigned", "wrong")}
                                            for k, v in out["grid"].items()}}}  # fmt: skip
            m = dataclasses.replace(m, provenance=prov)
            A.WEIGHTS_FILE.write_text(json.dumps(m.to_dict(), indent=1) + "\n")
            out["installed"] = {"file": str(A.WEIGHTS_FILE.relative_to(ROOT)), "model": m.tag, **values}
    path = Path(a.out)
    res = json.loads(path.read_text()) if path.exists() else {}
    key = "defaults_unseen" if a.role == "evaluation" else "defaults_development"
    # Another seed is another set of scenes: a fresh evaluation beside the first, not over it.
    res[key + ("_same_clip" if a.same_clip else "") + (f"_seed{a.seed}" if a.seed else "")] = out
    path.write_text(json.dumps(res, indent=1) + "\n")
    if "association" in res:  # the whole vip_association.md, this block included
        from vip_association import markdown as association_markdown

        path.with_suffix(".md").write_text(association_markdown(res))
    print(json.dumps({k: v for k, v in out.items() if k not in ("per_scene", "clips")}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())


def _pct(x) -> str:
    return f"{100 * x:.1f} %"


def _table(u: dict) -> list[str]:
    """Precision and recall of one evaluation block per bystander count (and the final round's)."""
    fin = "final_round" in u
    L = ["| bystanders | scenes | wearer detections | assigned | wrong | precision | recall |"
         + (" final round precision | final round recall |" if fin else ""),
         "| --- | --- | --- | --- | --- | --- | --- |" + (" --- | --- |" if fin else "")]  # fmt: skip
    for k, v in [*u["per_bystanders"].items(), ("all", u)]:
        f = (u["final_round"] if k == "all" else u["final_round"]["per_bystanders"].get(k)) if fin else None
        L.append(f"| {k} | {v['scenes']} | {v['wearer_detections']} | {v['assigned']} | {v['wrong']} "
                 f"| {_pct(v['precision'])} | {_pct(v['recall'])} |"
                 + (f" {_pct(f['precision'])} | {_pct(f['recall'])} |" if f else (" | |" if fin else "")))  # fmt: skip
    return L


def markdown(r: dict) -> str:
    """The sections of vip_association.md that this script's blocks give ("" without them)."""
    L = []
    u = r.get("defaults_unseen")
    if u:
        goal = lambda b: "meets" if b else "misses"  # noqa: E731
        L += ["", "## The defaults on unseen clips, 0-3 bystanders (issue 46, goal 5)", "",
              f"`{u['command']}`: {u['scenes']} scenes ({u['scenes_per_bystander_count']} per bystander count), "
              f"≤ {u['frames']} frames, one IMU wearer among k bystanders, every person a different clip of the "
              f"evaluation subjects {', '.join(u['split']['evaluation'])} ({len(u['clips'])} clips); association "
              f"model {u['model']} ({u['weights']}), whose training and setting choice used subjects "
              f"{', '.join(u['split']['tuning'])} only. Scored: the {u['round']} association"
              + (" and the whole method's final one (`video_inertial_scene`, its defaults)." if "final_round" in u
                 else "."), "",
              *_table(u)]  # fmt: skip
        if r.get("config", {}).get("model") and r["config"]["model"] != u["model"]:
            L += ["", f"The headline above is of association model {r['config']['model']} (two wearers, "
                  f"{r['config']['bystanders']} bystanders, seeds {r['config']['seeds']}); the library's default is now "
                  f"{u['model']}, measured in this section only."]  # fmt: skip
        t = u.get("vip_tables_93_9")
        if t:
            L += ["", f"experiments/vip_tables.py's {_pct(t['vip_tables']['precision'])} / "
                  f"{_pct(t['vip_tables']['recall'])}: {t['cause']}. Its {t['vip_tables']['wrong']} wrong assignments "
                  f"by scene: {t['vip_tables']['wrong_by_scene']}; scene 7's first round with copies as bystanders: "
                  f"{t['check_scene_7_first_round']['bystanders_copy_the_wearer']}, with other clips: "
                  f"{t['check_scene_7_first_round']['bystanders_other_clips']}."]  # fmt: skip
        bad = sorted((s for s in u["per_scene"] if s["defaults"]["wrong"]), key=lambda s: -s["defaults"]["wrong"])
        if bad:
            w = bad[0]["defaults"]
            rest = {k: u[k] - w[k] for k in ("assigned", "right", "wearer_detections")}
            L += ["", "Wrong assignments by scene (bystanders: clips, wearer first): " + "; ".join(
                f"{s['bystanders']}: {', '.join(s['clips'])}: {s['defaults']['wrong']} wrong of "
                f"{s['defaults']['assigned']} ({s['defaults']['wrong_to_bystander']} to a bystander)" for s in bad)
                  + f". Without the worst scene: precision {_pct(rest['right'] / max(rest['assigned'], 1))}, "
                  f"recall {_pct(rest['right'] / max(rest['wearer_detections'], 1))} (reported, not chosen on)."]  # fmt: skip
        ws = u.get("worst_scene")
        if ws:
            o = ws["objective_terms"]
            L += ["", f"The worst scene ({ws['scene']}), examined after the evaluation: the wearer's detection has "
                  f"the best unary in {ws['wearer_best_unary_frames']} of {ws['frames']} frames; eq. 4.11 over all the "
                  f"wearer's detections: unary {o['wearer_all']['unary']}, pairs {o['wearer_all']['pairs']}, total "
                  f"{o['wearer_all']['total']}; over bystander 2's: unary {o['bystander_2_all']['unary']}, pairs "
                  f"{o['bystander_2_all']['pairs']}; the solver's labelling ({o['solver']['detections']} of "
                  f"{o['solver']['person']}'s, {o['solver']['status']}): {o['solver']['total']}. Cause: {ws['cause']}."]  # fmt: skip
        best = u.get("final_round", u)
        L += ["", f"Goal (precision ≥ 99 %, recall ≥ 95 %): precision {_pct(best['precision'])} "
              f"({goal(best['precision'] >= 0.99)} it), recall {_pct(best['recall'])} ({goal(best['recall'] >= 0.95)} it)"
              f", {'final' if 'final_round' in u else 'first'} round."]  # fmt: skip
        for key in sorted(k for k in r if k.startswith("defaults_unseen_seed")):
            v = r[key]
            fv = v.get("final_round", v)
            L += ["", f"### A fresh evaluation set: seed {v['seed']}", "",
                  f"`{v['command']}`: {v['scenes']} other scenes of the same subjects, run once after the identity "
                  "check and its margin were fixed. The seed-0 set above is not held out for that check: its worst "
                  "scene's diagnosis (examined after its test) led to the check and bounds its margin from above "
                  "(`identity_check` in association_weights.json); this set was never examined before.", "",
                  *_table(v), "",
                  f"Goal: precision {_pct(fv['precision'])} ({goal(fv['precision'] >= 0.99)} it), recall "
                  f"{_pct(fv['recall'])} ({goal(fv['recall'] >= 0.95)} it)."]  # fmt: skip
    d = r.get("defaults_development")
    if d and "grid" in d:
        L += ["", "### Settings chosen on development scenes", "",
              f"`{d['command']}`: {d['scenes']} scenes of subjects {', '.join(d['split']['tuning'])}, first round; "
              f"rule: {d['rule']}. Chosen: **{d['chosen']}**.", "",
              "| setting | precision | recall | assigned | wrong |", "| --- | --- | --- | --- | --- |"]  # fmt: skip
        for k, v in d["grid"].items():
            L.append(f"| {k} | {_pct(v['precision'])} | {_pct(v['recall'])} | {v['assigned']} | {v['wrong']} |")
    c = r.get("defaults_unseen_same_clip")
    if c:
        L += ["", "### Bystanders performing the wearer's own clip (experiments/vip_tables.py's scenes)", "",
              f"`{c['command']}`: as above, but every bystander performs the wearer's clip (`make_scenario` given one "
              f"clip, as vip_tables), turned and moved aside, each from its own random start frame: the clips here "
              f"are longer than the {c['frames']} frames, so the copies are out of step (vip_tables' 300-frame scenes "
              f"start every copy at frame 0 where the clip is shorter than 300 frames): precision "
              f"{_pct(c['precision'])}, recall {_pct(c['recall'])}, {c['wrong']} wrong of {c['assigned']} assigned "
              f"({sum(s['defaults']['wrong_to_bystander'] for s in c['per_scene'])} to a bystander).", ""]  # fmt: skip
    return "\n".join(L) + ("\n" if L else "")
