"""Physics clean-up of a noisy motion: ground support + foot-contact terms.

A CMU walk of the locked subject (`--clip`, default 007_01 of ../shared/data/cmu_cc, 30 fps,
3 s; `jaxmocap.motion.splits`: the weights below were set on the development walk 02_01,
the clip this script used until 2026-11-28) is the truth. Noise pushes it into the floor and makes
the feet slide: joint angles + N(0, 0.02 rad), root height - 3 cm, and a horizontal
random walk of the root (σ 4 mm per frame). We then minimise
    E = w_d ‖θ - θ_noisy‖² + w_t ‖t - t_noisy‖²              (stay close to the data)
      + w_g Σ_v max(0, -(n·v - h))²                          (ground support)
      + w_c Σ_t Σ_f c_tf ‖p_f(t+1) - p_f(t)‖²                (foot-contact stationarity)
with L-BFGS (SciPy, JAX gradients), contact weights c detected from the noisy motion
itself (low and slow heels/toes). Reported: penetration, skating, MPJPE before/after.

    python experiments/physics_cleanup.py [--frames 90]
"""

from __future__ import annotations

import sys as _sys
from pathlib import Path as _Path

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import _provenance  # noqa: E402,F401  (its commit is taken now, at the start of the run)

import argparse
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from scipy.optimize import minimize

jax.config.update("jax_enable_x64", True)

from jaxmocap.body import default_body, forward  # noqa: E402
from jaxmocap.motion import load_motion  # noqa: E402
from jaxmocap.motion.corpus import corpus  # noqa: E402
from jaxmocap.motion.splits import Split  # noqa: E402
from jaxmocap.physics import Ground, detect_foot_contact, ground_support, make_scene  # noqa: E402
from jaxmocap.body.model import SMPL_FEET  # noqa: E402
from jaxmocap.physics.energies import foot_stationarity  # noqa: E402
from jaxmocap.physics.report import estimate_ground_height, plausibility_report  # noqa: E402


def split_for(clip) -> Split:
    """The weights were set on 02_01 (development); the clip is evaluated."""
    return Split("physics_cleanup", tuning=("02",), training=(), evaluation=(clip.subject,))


def stats(name, body, motion, truth_joints, ground, scene):
    rep = plausibility_report(body, motion, ground=ground, scene=scene)
    joints = np.asarray(forward(body, motion.poses, None, motion.trans).joints)
    s = rep.summary["mesh"]
    return {
        "motion": name,
        "penetration_mean_mm": s["penetration_mean_mm"],
        "penetration_max_mm": s["penetration_max_mm"],
        "frac_contact_frames_above_5mm": s["frac_above_5mm"],
        "skating_mean_mm_s": 1e3 * rep.feet["skating_mean_m_s"],
        "sliding_fraction": rep.feet["sliding_fraction"],
        "mpjpe_mm": 1e3 * float(np.linalg.norm(joints - truth_joints, axis=-1).mean()),
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=90)
    p.add_argument("--iterations", type=int, default=300)
    p.add_argument("--out", default="experiments/results/physics_cleanup.json")
    p.add_argument("--clip", default="007_01.bvh", help="a walk of an evaluated subject (corpus name)")
    args = p.parse_args(argv)
    clip = next((c for c in corpus() if c.name == args.clip), None)
    if clip is None:
        raise SystemExit(f"{args.clip} is not in the corpus (../shared/data/cmu, cmu_cc).")
    split = split_for(clip)

    body = default_body("low").astype(jnp.float64)
    truth = load_motion(clip.path, fps=30.0, body=body)[: args.frames]
    v_true = np.asarray(forward(body, truth.poses, None, truth.trans).vertices)
    ground = Ground(estimate_ground_height(v_true[..., 1].min(-1)))
    truth_joints = np.asarray(forward(body, truth.poses, None, truth.trans).joints)

    rng = np.random.default_rng(0)
    T = truth.num_frames
    poses = truth.poses + rng.normal(scale=0.02, size=truth.poses.shape)
    trans = truth.trans.copy()
    trans[:, 1] -= 0.03
    drift = np.cumsum(rng.normal(scale=0.004, size=(T, 3)), 0)
    drift[:, 1] = 0.0
    trans += drift
    noisy = truth.replace(poses=poses, trans=trans, name="noisy")

    foot_ids = np.asarray([body.joint_index(n) for n in SMPL_FEET])
    j_noisy = np.asarray(forward(body, poses, None, trans).joints)[:, foot_ids]
    # Heights relative to the noisy motion's own floor (it sits 3 cm low): detect from the data.
    own_floor = Ground(float(np.percentile(j_noisy[..., 1].min(-1), 5)))
    contact = detect_foot_contact(j_noisy, own_floor, truth.fps, height=0.06, speed=0.5)

    w_d, w_t, w_g, w_c = 1.0, 10.0, 1e3, 1e4
    p0, t0 = jnp.asarray(poses), jnp.asarray(trans)

    def energy(x):
        pose = x[: T * 72].reshape(T, 24, 3)
        tr = x[T * 72 :].reshape(T, 3)
        out = forward(body, pose, None, tr)
        e = w_d * jnp.sum((pose - p0) ** 2) + w_t * jnp.sum((tr - t0) ** 2)
        e += w_g * jnp.sum(ground_support(out.vertices, ground) ** 2)
        e += w_c * jnp.sum(foot_stationarity(out.joints[:, foot_ids], contact) ** 2)
        return e

    vg = jax.jit(jax.value_and_grad(energy))
    fun = lambda x: tuple(np.asarray(a, np.float64) for a in vg(jnp.asarray(x)))  # noqa: E731
    x0 = np.concatenate([poses.ravel(), trans.ravel()])
    sol = minimize(fun, x0, jac=True, method="L-BFGS-B", options={"maxiter": args.iterations})
    cleaned = truth.replace(
        poses=sol.x[: T * 72].reshape(T, 24, 3), trans=sol.x[T * 72 :].reshape(T, 3), name="cleaned"
    )

    scene = make_scene(body, ground=ground)
    rows = [
        stats(m.name or "truth", body, m, truth_joints, ground, scene)
        for m in (truth.replace(name="truth"), noisy, cleaned)
    ]
    print(f"{'':10s}" + "".join(f"{k:>32s}" for k in rows[0] if k != "motion"))
    for r in rows:
        print(f"{r['motion']:10s}" + "".join(f"{v:>32.3f}" for k, v in r.items() if k != "motion"))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    payload = {
        "setup": {
            "clip": clip.name,
            "frames": T,
            "fps": truth.fps,
            "ground_height": float(ground.height),
            "noise": "pose N(0, 0.02 rad), root y -3 cm, horizontal root random walk 4 mm/frame",
            "weights": {"data_pose": w_d, "data_trans": w_t, "ground": w_g, "contact": w_c},
            "optimizer": f"L-BFGS-B {sol.nit} iterations, {sol.message}",
        },
        "rows": rows,
    }
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from _provenance import write_json

    write_json(
        out,
        payload,
        split=split,
        argv=argv,
        indent=2,
        data={"clips": [clip.name], "subjects": [clip.subject], "frames": T},
    )
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
