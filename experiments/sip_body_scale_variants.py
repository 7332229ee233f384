"""Body scale under sensor placement error (issue 46 goal 4): variants of the estimate, development subjects only.

    python experiments/sip_body_scale_variants.py                     # every variant, cached per case
    python experiments/sip_body_scale_variants.py --variants ori,drop-root --seeds 0
    python experiments/sip_body_scale_variants.py --table-only        # the table from what is cached

**Question.** `inertial.estimate_body_scale` (final E_ori over candidate scales) errs by 5.8 %
on the evaluation subjects, one factor per clip that the simulated sensors' 2 cm placement
offset along the limb makes (experiments/results/sip_body_scale.md). Does an estimator that
models or avoids the offset do better? Every choice here is made on the development subjects
(02, 131; `sip_body_scale.SPLIT.tuning`) only; nothing here reads an evaluation subject.

**Cases.** Every tuning clip of `sip_body_scale` (90-frame windows, sip6 IMUs with
`IMUErrorModel.xsens()`, held-out prior and w_mahal, SOP start; its `run_clip` protocol) with
the subject at the model's size (true scale 1.0: the error is one factor per clip, the same for
every true scale), for sensor-error seeds `--seeds` (seed + a checksum of the clip's name, as
there): seed 0 draws the errors `sip_body_scale --role tuning` used, seed 1 a second draw of
placement offsets, biases, ... on the same motion.

**Variants** (each a profile over the candidates 0.75 .. 1.35 in 0.05 steps, one batched SIP
solve, estimate = parabola vertex of the final E_ori, as `estimate_body_scale` with a 0.05 grid):

- `ori`: today's estimator (≤ 60 LM steps, as `sip_body_scale`); `ori-200`: ≤ 200 steps.
- `drop-root`: the root (pelvis) sensor's accelerations left out of E_acc: the free translation
  absorbs all of its acceleration but its short lever arm, which 2 cm moves by ~20 %.
- `offsets`, `offsets-w30`, `offsets-w100`: one placement offset per sensor along its limb
  (the sensor's bone towards its child, `sensors.errors`' convention) fitted as a sequence-wide
  unknown with the poses (E_acc sees the sensor at p^b + δ_s u_s), without a prior on δ or
  with w Σ_s δ_s² added to the cost.

**Fixed-pose least squares** (no solve): with the poses fixed, the modelled accelerations are
linear in the scale s (the chain's joints and the sensor points scale with it) and in the
translation's acceleration (eliminated per frame by centring over the sensors), so s has a
closed form. Rows: the true poses (what the placement error alone does to a lever-arm fit),
SOP's (orientation-only, noisy second differences) and SIP's on the model body.

Writes `sip_body_scale_variants.json` / `.md` to `--out` (default experiments/results).
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import sys
import time
import zlib
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import equinox as eqx  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import sip_body_scale as SB  # noqa: E402  (sip_tables sets jax_enable_x64)
from sip_tables import TOL, Fold, item, with_starts  # noqa: E402

from _provenance import write_json, write_text  # noqa: E402

from jaxmocap.app.sweep_methods import InertialItem, InertialMethod  # noqa: E402
from jaxmocap.body import default_body, scaled_body  # noqa: E402
from jaxmocap.body.kinematics import ancestors, chain_transforms  # noqa: E402
from jaxmocap.body.model import SMPL_PARENTS  # noqa: E402
from jaxmocap.energies import imu as E  # noqa: E402
from jaxmocap.methods import inertial as I  # noqa: E402
from jaxmocap.motion.corpus import corpus  # noqa: E402
from jaxmocap.rotation import host_exp  # noqa: E402
from jaxmocap.sensors import IMUErrorModel, ScenarioConfig, make_scenario  # noqa: E402
from jaxmocap.solve import Problem, Term, frame, sequence, solve_batch  # noqa: E402
from jaxmocap.timeseries import second_difference  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SCALES = tuple(float(x) for x in np.round(np.arange(0.75, 1.351, 0.05), 3))
#: name -> (mode, offset prior weight, LM step limit)
VARIANTS = {
    "ori": ("base", 0.0, 60),
    "ori-200": ("base", 0.0, 200),
    "drop-root": ("drop-root", 0.0, 60),
    "offsets": ("offsets", 0.0, 60),
    "offsets-w30": ("offsets", 30.0, 60),
    "offsets-w100": ("offsets", 100.0, 60),
}
ROOT_JOINT = 0


class OffsetAcceleration(eqx.Module):
    """E_acc (eq. 3.10-3.12) with each sensor at p^b_s + δ_s u_s: δ (S,) a sequence-wide unknown."""

    bones: tuple[int, ...] = eqx.field(static=True)
    fps: float = eqx.field(static=True)
    axes: tuple[tuple[float, float, float], ...] = eqx.field(static=True)  # u_s in the bone frame

    def _moved(self, params, data):
        off = params["offset"][:, None] * jnp.asarray(self.axes, params["offset"].dtype)
        return eqx.tree_at(lambda d: d.sensor_point, data, data.sensor_point + off)

    def __call__(self, params, data):
        return E.AccelerationResidual(self.bones, self.fps)(params, self._moved(params, data))

    def jacobian(self, params, data):
        # The pose and translation blocks are E_acc's at the moved points; the engine takes
        # the sequence-wide offset's columns by forward-mode AD.
        return E.AccelerationResidual(self.bones, self.fps).jacobian(params, self._moved(params, data))


class OffsetPrior(eqx.Module):
    """Σ_s δ_s², spread over the frames (a per-frame term's rows: each frame carries 1/T of it)."""

    num_frames: int = eqx.field(static=True)

    def __call__(self, params, data):
        o = params["offset"] / np.sqrt(self.num_frames)
        return jnp.broadcast_to(o, (data.orientation.shape[0],) + o.shape)[..., None]


def limb_axes(setup: I.InertialSetup) -> tuple:
    """Unit direction from each sensor's joint to its child in the rest pose (up for leaves),
    the axis along which `IMUErrorModel.placement_offset` moves a sensor."""
    rest = np.asarray(setup.data.rest_joints)
    out = []
    for b in setup.bones:
        kids = sorted((j for j, p in enumerate(SMPL_PARENTS) if p == b), key=lambda j: abs(rest[j, 0] - rest[b, 0]))
        d = rest[kids[0]] - rest[b] if kids else np.array([0.0, 1.0, 0.0])
        out.append(tuple(float(x) for x in d / np.linalg.norm(d)))
    return tuple(out)


def scaled(setup: I.InertialSetup, s: float) -> I.InertialSetup:
    """The setup calibrated on the body scaled by s: the sensor points and rest joints scale,
    the readings, calibration rotations and prior do not (exactly `make_setup(s)`)."""
    d = setup.data
    return eqx.tree_at(
        lambda x: (x.data.sensor_point, x.data.rest_joints), setup, (d.sensor_point * s, d.rest_joints * s)
    )


def profile(case: dict, variant: str) -> dict:
    """One batched SIP solve over SCALES; the final per-term costs and fitted offsets."""
    mode, prior_w, steps = VARIANTS[variant]
    setup, init, w = case["setup"], jnp.asarray(case["sop"]), I.SIPWeights(mahal=case["w_mahal"])
    if mode == "drop-root":
        acc = np.array(setup.data.acceleration)
        acc[:, [i for i, b in enumerate(setup.bones) if b == ROOT_JOINT]] = np.nan  # dropped: E_acc masks it
        setup = eqx.tree_at(lambda x: x.data.acceleration, setup, jnp.asarray(acc))
    st = I.stack_setups([scaled(setup, s) for s in SCALES])
    K, T, S = len(SCALES), setup.num_frames, len(setup.bones)
    prob = I.inertial_problem(setup, w)
    params = {"pose": jnp.broadcast_to(init, (K, T, 24, 3)), "trans": jnp.broadcast_to(st.trans0[:, None], (K, T, 3))}
    if mode == "offsets":
        fn = OffsetAcceleration(setup.bones, setup.fps, limb_axes(setup))
        reads = (("pose", ancestors(SMPL_PARENTS, setup.bones)), ("trans", None), ("offset", None))
        acc = Term("acc", fn, jnp.asarray(w.acc / S, jnp.float32), 1, None, E._ACC_MASK, reads, fn.jacobian)
        terms = [t for t in prob.terms if t.name != "acc"] + [acc]
        if prior_w > 0:
            terms.append(Term("offset_prior", OffsetPrior(T), jnp.asarray(prior_w, jnp.float32), 0, None, None, (("offset", None),)))  # fmt: skip
        prob = Problem(terms, unknowns={"pose": frame("so3"), "offset": sequence("vector")})
        params["offset"] = jnp.zeros((K, S))
    sol = solve_batch(prob, params, st.data, None, **I._limits(I.preset(w), steps, TOL, TOL))
    costs = {k: np.asarray(v, float).tolist() for k, v in sol.costs.items()}
    c = np.asarray(costs["ori"])
    return {"scales": list(SCALES), "costs": costs, "estimate": I._parabola_vertex(np.asarray(SCALES), c, int(np.argmin(c))),
            "at_edge": int(np.argmin(c)) in (0, K - 1), "steps": np.asarray(sol.num_steps).tolist(),
            "offset_cm": None if mode != "offsets" else (100 * np.asarray(sol.value["offset"])).tolist()}  # fmt: skip


def lever_arm_least_squares(case: dict, poses) -> float:
    """The closed-form scale at fixed poses: a_s(t) = ẗ(t) + s · d²/dt²(J_b + R_b p^b) (eq. 3.10-3.11)."""
    d = case["setup"].data
    bones = case["setup"].bones
    R, J = chain_transforms(SMPL_PARENTS, host_exp(np.array(poses, float)), np.asarray(d.rest_joints), bones)
    Rb = np.stack([np.asarray(R[b]) for b in bones], 1)
    p = np.stack([np.asarray(J[b]) for b in bones], 1) + np.einsum("tsij,sj->tsi", Rb, np.asarray(d.sensor_point))
    A = np.asarray(second_difference(p))[1:-1] * case["setup"].fps ** 2
    a = np.asarray(d.acceleration)[1:-1]
    ok = np.isfinite(a).all((1, 2))  # frames with a dropped sample are left out
    centre = lambda x: (x - x.mean(1, keepdims=True)).reshape(-1)  # noqa: E731  (the free ẗ(t))
    X, y = centre(A[ok]), centre(a[ok])
    return float(X @ y / (X @ X))


def make_case(clip, seed: int, body, folds, cache: Path) -> dict:
    """`sip_body_scale.run_clip`'s calibrated window at true scale 1.0, its SOP start, and SIP
    on the model body and on a body 10 % larger (cached per clip and seed)."""
    path = cache / f"variants_case_{clip.path.stem}_s{seed}.pkl"
    case = pickle.loads(path.read_bytes()) if path.is_file() else None
    T = 90
    prior = SB.held_out_prior(folds, clip.subject)
    w = I.SIPWeights(mahal=SB.chosen_w_mahal(clip.subject))
    if case is None:
        cfg = ScenarioConfig(fps=SB.FPS, max_frames=T + SB.MARGIN, imu_set="sip6", imu_errors=IMUErrorModel.xsens(), betas_std=0.0)  # fmt: skip
        sc = make_scenario(
            [str(clip.path)], cfg, seed=seed + zlib.crc32(clip.name.encode()), body=scaled_body(body, 1.0)
        )
        k = I.first_complete_frame(sc.sequence(0)["imu_ori"][0])
        it = item(sc, 0, k, body, prior, clip.name)
        it = InertialItem(SB.window(it.setup, T), it.truth[:T], it.betas, None, it.name)
        with_starts([it], InertialMethod("sop"))
        case = {"clip": clip.name, "subject": clip.subject, "seed": seed, "setup": jax.device_get(it.setup),
                "w_mahal": w.mahal, "truth": np.asarray(it.truth), "sop": np.asarray(it.init)}  # fmt: skip
    missing = [(key, s) for key, s in (("sip", 1.0), ("sip_110", 1.1)) if key not in case]
    if missing:
        setups = I.stack_setups([scaled(case["setup"], s) for _, s in missing])
        init = np.broadcast_to(case["sop"], (len(missing),) + case["sop"].shape)
        sol = I.sparse_inertial_poser_batch(setups, init, weights=w, max_steps=60, rtol=TOL, atol=TOL)
        for j, (key, _) in enumerate(missing):
            case[key] = np.asarray(sol.value["pose"][j])
        tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")  # parallel processes: write, then rename
        tmp.write_bytes(pickle.dumps(case))
        tmp.replace(path)
    return case


def stats(errors: list[float]) -> dict:
    e = np.asarray(errors)
    return {"mean_abs_error_percent": float(np.abs(e).mean()), "bias_percent": float(e.mean()),
            "max_abs_error_percent": float(np.abs(e).max()), "cases": len(e)}  # fmt: skip


def table(cases: dict, results: dict, least_squares: dict) -> dict:
    rows = {}
    for v, per in results.items():
        keys = [k for k in cases if k in per]
        if keys:
            rows[v] = {**stats([100 * (per[k]["estimate"] - 1) for k in keys]), "at_edge": sum(per[k]["at_edge"] for k in keys),
                       "per_case_percent": {k: 100 * (per[k]["estimate"] - 1) for k in keys}}  # fmt: skip
    # Paired with today's estimator on the same cases (variants may cover fewer of them).
    for r in rows.values():
        same = list(r["per_case_percent"])
        if "ori" in rows and all(k in rows["ori"]["per_case_percent"] for k in same):
            r["ori_on_the_same_cases"] = stats([rows["ori"]["per_case_percent"][k] for k in same])
    ls = {src: stats([100 * (x - 1) for x in per.values()]) | {"per_case_percent": {k: 100 * (x - 1) for k, x in per.items()}}
          for src, per in least_squares.items()}  # fmt: skip
    return {"variants": rows, "fixed_pose_least_squares": ls}


def markdown(res: dict) -> str:
    L = ["# Body scale under placement error: variants on the development subjects (issue 46)", "",
         "Generated by `experiments/sip_body_scale_variants.py` (its docstring: protocol). Cases: "
         f"{res['protocol']['cases']} (tuning clips of subjects {', '.join(res['protocol']['subjects'])} × sensor-error "
         f"seeds {res['protocol']['seeds']}, subject at the model's size). Error = estimate / true scale − 1.", "",
         "| variant | cases | mean abs error | bias | max abs error | at a bound | `ori` on the same cases (mean abs) |",
         "| --- | --- | --- | --- | --- | --- | --- |"]  # fmt: skip
    for v, r in res["variants"].items():
        same = r.get("ori_on_the_same_cases")
        paired = "" if same is None else f"{same['mean_abs_error_percent']:.2f} %"
        L.append(f"| {v} | {r['cases']} | {r['mean_abs_error_percent']:.2f} % | {r['bias_percent']:+.2f} % | "
                 f"{r['max_abs_error_percent']:.1f} % | {r['at_edge']} | {paired} |")  # fmt: skip
    L += ["", "## Fixed-pose least squares (closed-form scale at the given poses)", "",
          "| poses | cases | mean abs error | bias | max abs error |", "| --- | --- | --- | --- | --- |"]  # fmt: skip
    for src, r in res["fixed_pose_least_squares"].items():
        L.append(f"| {src} | {r['cases']} | {r['mean_abs_error_percent']:.2f} % | {r['bias_percent']:+.2f} % | {r['max_abs_error_percent']:.1f} % |")  # fmt: skip
    names = sorted({k for r in res["variants"].values() for k in r["per_case_percent"]})
    L += ["", "## Per case (error %)", "", "| case | " + " | ".join(res["variants"]) + " |",
          "| --- |" + " --- |" * len(res["variants"])]  # fmt: skip
    for k in names:
        L.append(f"| {k} | " + " | ".join(f"{r['per_case_percent'][k]:+.1f}" if k in r["per_case_percent"] else "" for r in res["variants"].values()) + " |")  # fmt: skip
    L.append("")
    return "\n".join(L)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--variants", default=",".join(VARIANTS), help=f"comma-separated, of {list(VARIANTS)}")
    p.add_argument("--seeds", default="0,1", help="sensor-error seeds (default 0,1)")
    p.add_argument("--clips", help="comma-separated indices of the tuning clips (sip_body_scale --role tuning --list)")
    p.add_argument("--table-only", action="store_true", help="no solves: the table from the cached results")
    p.add_argument("--out", default=str(ROOT / "experiments" / "results"))
    p.add_argument("--cache", default=str(ROOT / "out" / "sip_body_scale" / "cache"))
    args = p.parse_args(argv)
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    variants = args.variants.split(",")
    bad = [v for v in variants if v not in VARIANTS]
    if bad:
        raise SystemExit(f"--variants {bad}: pick from {list(VARIANTS)}.")
    clips = [c for c in SB.eligible_clips(90, cache) if c.subject in SB.SPLIT.tuning]
    if args.clips:
        clips = [clips[int(i)] for i in args.clips.split(",")]
    seeds = [int(s) for s in args.seeds.split(",")]
    body, folds = default_body("low"), Fold(corpus(), cache)
    store = lambda v: cache / f"variants_{v}.json"  # noqa: E731
    results = {v: json.loads(store(v).read_text()) if store(v).is_file() else {} for v in VARIANTS}
    cases, least_squares = (
        {},
        {"true poses": {}, "SOP poses": {}, "SIP on the model body": {}, "SIP on a body 10 % larger": {}},
    )
    for seed in seeds:
        for c in clips:
            key = f"{c.name} s{seed}"
            if args.table_only and not (cache / f"variants_case_{c.path.stem}_s{seed}.pkl").is_file():
                continue
            case = cases[key] = make_case(c, seed, body, folds, cache)
            for src, poses in (("true poses", "truth"), ("SOP poses", "sop"), ("SIP on the model body", "sip"),
                               ("SIP on a body 10 % larger", "sip_110")):  # fmt: skip
                least_squares[src][key] = lever_arm_least_squares(case, case[poses])
            for v in [] if args.table_only else variants:
                if key not in results[v]:
                    t0 = time.perf_counter()
                    results[v][key] = profile(case, v)
                    SB.atomic_write(store(v), json.dumps(results[v]))
                    print(f"{key:16s} {v:13s} {100 * (results[v][key]['estimate'] - 1):+6.1f} %  ({time.perf_counter() - t0:.0f} s)", flush=True)  # fmt: skip
    res = table(cases, {v: results[v] for v in VARIANTS if results[v]}, least_squares)
    res["protocol"] = {"cases": len(cases), "subjects": sorted({c["subject"] for c in cases.values()}), "seeds": seeds,
                       "candidates": list(SCALES), "true_scale": 1.0, "imu": "sip6, IMUErrorModel.xsens(), 30 fps, 90 frames",
                       "prior": "held_out_prior(exclude=[subject]) with sip_tables' chosen w_mahal",
                       "solves": f"float64, rtol = atol = {TOL}, SOP start", "variants": {v: list(VARIANTS[v]) for v in VARIANTS}}  # fmt: skip
    out = Path(args.out)
    data = {"clips": sorted({c["clip"] for c in cases.values()}), "role": "tuning"}
    write_json(out / "sip_body_scale_variants.json", res, split=SB.SPLIT, data=data, argv=argv)
    write_text(out / "sip_body_scale_variants.md", markdown(res), split=SB.SPLIT, data=data, argv=argv)
    print(markdown(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
