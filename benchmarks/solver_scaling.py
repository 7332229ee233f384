"""Time per LM iteration and peak memory against sequence length on a SIP-shaped problem.

The problem has the shape of the Sparse Inertial Poser (von Marcard §3.3): the default
body (`default_body("low")`, 24 joints), 75 unknowns per frame (24 axis-angle rotations
updated on SO(3) + root translation), 6 sensors rigidly attached to the pelvis, head,
lower arms and lower legs (§3.2.2), and three terms with the thesis weights (§3.4.1):

- E_ori, eq. 3.7: log(R̃ R_measᵀ)^∨ per sensor (per frame, w = 1),
- E_acc, eq. 3.10-3.12: (p_{t-1} - 2 p_t + p_{t+1}) / dt² - a_meas (couples t-1, t, t+1,
  w = 0.05),
- E_anthro, eq. 3.14: a Gaussian pose prior L(x - μ) (w = 0.003) plus a weak prior on
  the root translation, which orientations and accelerations leave free up to a
  constant velocity.

Sensor positions come from forward kinematics of the bones (eq. 3.11: a point rigidly
attached to a bone), not from skinning, as in the thesis. Measurements are synthesised
from a smooth random motion; the solve starts from a noisy copy of the truth.

For each T in 20, 100, 300, 1000, 3000, 10000 it times `solve(solver=VonMarcardLM())` (von Marcard's LM
on the structured Cholesky) and `solve(solver=OptxLevenbergMarquardt())` (optx.LevenbergMarquardt
with `StructuredCholesky`), each for a fixed number of iterations (tolerances 0), and, at
T = 20 only, optimistix's dense default (QR of the stacked [J; √λ I]: O(T³) flops and
O(T²) memory, already minutes per step at T = 100 on this CPU). It also records iterations to convergence, the largest step disagreement
between the banded and the dense solver, and the float32 step error.

Usage: python benchmarks/solver_scaling.py [--quick] [--max-T 10000]
Writes benchmarks/results/solver_scaling.json and prints a table.
"""

from __future__ import annotations

import argparse
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import optimistix as optx  # noqa: E402

from _common import machine, peak_memory_bytes, write_json  # noqa: E402

import jaxmocap  # noqa: E402
from jaxmocap.body import forward_kinematics, shaped_joints  # noqa: E402
from jaxmocap.rotation import axis_angle_to_matrix, matrix_to_axis_angle  # noqa: E402
from jaxmocap.solve import Problem, Term, solve  # noqa: E402
from jaxmocap.solve.options import SOLVERS  # noqa: E402
from jaxmocap.timeseries import second_difference  # noqa: E402

SENSOR_JOINTS = (0, 15, 18, 19, 4, 5)  # pelvis, head, left/right elbow (lower arm), knees (lower leg)
DT = 1.0 / 60.0


def sip_problem(body, dtype=jnp.float32):
    """(problem, make_data) for a SIP-shaped energy on `body` (see module docstring)."""
    rest = shaped_joints(body, jnp.zeros((1,), body.dtype)).astype(dtype)
    parents = body.parents
    rng = np.random.default_rng(1)
    offsets = jnp.asarray(rng.normal(scale=0.05, size=(6, 3)), dtype)  # sensor in bone frame
    sensor_to_bone = axis_angle_to_matrix(jnp.asarray(rng.normal(scale=0.3, size=(6, 3)), dtype))
    prior_L = jnp.asarray(np.linalg.cholesky(np.linalg.inv(_prior_cov(rng))).T, dtype)  # Σ⁻¹ = LᵀL

    def sensors(params):
        """Sensor orientations (T, 6, 3, 3) and positions (T, 6, 3); pose as matrices."""
        T = params["pose"].shape[0]
        R, p = forward_kinematics(parents, params["pose"], jnp.broadcast_to(rest, (T, 24, 3)))
        idx = jnp.asarray(SENSOR_JOINTS)
        R_b, p_b = R[:, idx], p[:, idx]
        pos = p_b + jnp.einsum("tsab,sb->tsa", R_b, offsets) + params["trans"][:, None]
        return R_b @ sensor_to_bone, pos

    def e_ori(params, data):  # eq. 3.7
        R, _ = sensors(params)
        return matrix_to_axis_angle(R @ jnp.swapaxes(data["R_meas"], -1, -2))

    def e_acc(params, data):  # eq. 3.10-3.12
        _, p = sensors(params)
        return second_difference(p) / DT**2 - data["acc"]

    def e_prior(params, data):  # eq. 3.14, 3.28-3.29 with a weak translation prior
        pose = matrix_to_axis_angle(params["pose"]).reshape(-1, 72)
        return jnp.concatenate([pose @ prior_L.T, 0.1 * params["trans"]], axis=1)[..., None]

    problem = Problem(
        [
            Term("ori", e_ori, weight=1.0),
            Term("acc", e_acc, weight=0.05, bandwidth=1),
            Term("prior", e_prior, weight=0.003),
        ],
        rotations=("pose",),
    )

    def make_data(T, seed=0):
        r = np.random.default_rng(seed)
        t = np.arange(T)[:, None] * DT
        freq, phase = r.uniform(0.3, 1.5, (1, 72)), r.uniform(0, 2 * np.pi, (1, 72))
        amp = r.uniform(0.05, 0.4, (1, 72))
        pose = amp * np.sin(2 * np.pi * freq * t + phase)
        trans = np.concatenate([0.3 * np.sin(t), 0.9 + 0.02 * np.sin(3 * t), 0.2 * t], 1)
        truth = {"pose": jnp.asarray(pose.reshape(T, 24, 3), dtype), "trans": jnp.asarray(trans, dtype)}
        R, p = sensors({"pose": axis_angle_to_matrix(truth["pose"]), "trans": truth["trans"]})
        data = {"R_meas": R, "acc": second_difference(p) / DT**2}
        init = {
            "pose": truth["pose"] + jnp.asarray(r.normal(scale=0.1, size=(T, 24, 3)), dtype),
            "trans": truth["trans"] + jnp.asarray(r.normal(scale=0.02, size=(T, 3)), dtype),
        }
        return truth, init, data

    return problem, make_data


def _prior_cov(rng):
    A = rng.normal(size=(72, 72)) * 0.05
    return A @ A.T + np.eye(72) * 0.1


def _timed_solve(problem, init, data, method, steps, solver=None):
    """Compile + first call, then the best of up to two timed calls: (s per iteration, first, sol).
    `method` names the solver (`SOLVERS`, no tolerances: `steps` steps), unless `solver` is given."""
    solver = SOLVERS[method](rtol=0.0, atol=0.0) if solver is None else solver
    run = lambda: solve(problem, init, data, solver=solver, max_steps=steps)  # noqa: E731
    t0 = time.perf_counter()
    sol = jax.block_until_ready(run())
    first = time.perf_counter() - t0
    best = np.inf
    for _ in range(2 if first < 30 else 1):
        t0 = time.perf_counter()
        sol = jax.block_until_ready(run())
        best = min(best, time.perf_counter() - t0)
    return best / int(sol.num_steps), first, sol


def one_row(T: int, steps: int, converge_max_T: int) -> dict:
    """All measurements at one T (run in a fresh process so peak RSS is per T)."""
    body = jaxmocap.default_body("low")
    problem, make_data = sip_problem(body, jnp.float32)
    truth, init, data = make_data(T)
    row = {"T": T, "dtype": "float32", "factor_dtype": "float64", "unknowns": 75 * T}
    for method in ("lm", "optx_lm"):
        per_step, first, sol = _timed_solve(problem, init, data, method, steps)
        row[f"{method}_s_per_iter"] = per_step
        row[f"{method}_compile_and_first_s"] = first
    if T <= converge_max_T:
        t0 = time.perf_counter()
        conv = jax.block_until_ready(solve(problem, init, data, max_steps=100))
        row["lm_converge_wall_s"] = time.perf_counter() - t0
        row["lm_iterations"] = int(conv.num_steps)
        row["lm_result"] = int(conv.result)
        row["lm_cost_start"] = float(problem.cost(init, data))
        row["lm_cost_final"] = float(conv.cost)
        row["lm_costs_final"] = {k: float(v) for k, v in conv.costs.items()}
        Rs, Rt = axis_angle_to_matrix(conv.value["pose"]), axis_angle_to_matrix(truth["pose"])
        err = jnp.linalg.norm(matrix_to_axis_angle(Rs @ jnp.swapaxes(Rt, -1, -2)), axis=-1)
        row["lm_mean_joint_angle_error_deg"] = float(jnp.degrees(jnp.mean(err)))
    if T <= 20:  # QR of the stacked [J; √λ I] is O(T³) flops and O(T²) memory
        dense = optx.LevenbergMarquardt(rtol=0.0, atol=0.0)  # optimistix's own dense linear solver
        per_step, first, _ = _timed_solve(problem, init, data, "optx_lm", 3, solver=dense)
        row["optx_lm_dense_s_per_iter"] = per_step
        row["optx_lm_dense_compile_and_first_s"] = first
    row["peak_rss_bytes"] = peak_memory_bytes()
    return row


def step_agreement(T: int = 40) -> dict:
    """Structured vs dense (QR) damped step on the SIP problem: float64, and float32 inputs
    with the factor in float32 or float64, against the float64 dense step."""
    import lineax as lx

    from jaxmocap._compat import damped_operator
    from jaxmocap.solve.linearisation import Args
    from jaxmocap.solve.solver import linear_solver
    from jaxmocap.solve.linearisation import residuals

    body = jaxmocap.default_body("low")
    out = {"T": T, "lambda": 1.0}
    steps = {}
    for dtype, factor in ((jnp.float64, jnp.float64), (jnp.float32, jnp.float64), (jnp.float32, jnp.float32)):
        problem, make_data = sip_problem(body, dtype)
        _, init, data = make_data(T)
        args = Args(problem, data, None, problem.layout(init))

        @jax.jit
        def solve_both(y, args=args, factor=factor, dtype=dtype):
            r, lin = jax.linearize(lambda p: residuals(p, args), y)
            struct = jax.eval_shape(lambda: y)
            op = lx.FunctionLinearOperator(
                damped_operator(lx.FunctionLinearOperator(lin, struct), jnp.asarray(1.0, dtype)), struct
            )
            vec = (r, jax.tree_util.tree_map(jnp.zeros_like, y))
            a = lx.linear_solve(op, vec, linear_solver(args, factor), throw=False)
            b = lx.linear_solve(op, vec, lx.QR(), throw=False)
            flat = lambda v: jnp.concatenate([v["pose"].reshape(T, -1), v["trans"]], 1)  # noqa: E731
            return flat(a.value), flat(b.value)

        steps[(jnp.dtype(dtype).name, jnp.dtype(factor).name)] = solve_both(init)
    ref = np.asarray(steps[("float64", "float64")][1])
    scale = np.max(np.abs(ref))
    for (d, f), (banded, dense) in steps.items():
        out[f"banded_{d}_factor_{f}_max_rel_err"] = float(np.max(np.abs(np.asarray(banded) - ref)) / scale)
        if f == d:
            out[f"dense_qr_{d}_max_rel_err"] = float(np.max(np.abs(np.asarray(dense) - ref)) / scale)
    return out


def main():
    import json
    import subprocess
    import sys

    parser = argparse.ArgumentParser()
    parser.add_argument("--quick", action="store_true", help="T = 100, 300 only")
    parser.add_argument("--max-T", type=int, default=10000)
    parser.add_argument("--steps", type=int, default=5, help="LM iterations per timed solve")
    parser.add_argument("--converge-max-T", type=int, default=1000, help="largest T solved to convergence")
    parser.add_argument("--one", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--skip-agreement", action="store_true")
    parser.add_argument("--agreement", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        print("ROW " + json.dumps(one_row(args.one, args.steps, args.converge_max_T)), flush=True)
        return
    if args.agreement:
        print("ROW " + json.dumps(step_agreement()), flush=True)
        return
    Ts = [T for T in (20, 100, 300, 1000, 3000, 10000) if T <= args.max_T]
    if args.quick:
        Ts = Ts[:3]

    def child(*extra):
        cmd = [
            sys.executable,
            __file__,
            "--steps",
            str(args.steps),
            "--converge-max-T",
            str(args.converge_max_T),
            *extra,
        ]
        out = subprocess.run(cmd, capture_output=True, text=True)
        rows = [json.loads(line[4:]) for line in out.stdout.splitlines() if line.startswith("ROW ")]
        if out.returncode or not rows:
            return {"error": (out.stderr or out.stdout)[-2000:], "returncode": out.returncode}
        return rows[0]

    agreement = child("--agreement") if not args.skip_agreement else {"skipped": True}
    print("step agreement (relative to the float64 dense QR step):", agreement, flush=True)
    rows = []
    print(f"{'T':>6} {'lm s/it':>9} {'optx s/it':>9} {'dense s/it':>10} {'iters':>5} {'err deg':>7} {'peak GiB':>8}")
    for T in Ts:
        row = child("--one", str(T))
        row.setdefault("T", T)
        rows.append(row)
        if "error" in row:
            print(f"{T:6d} failed: {row['error'][-300:]}", flush=True)
            continue
        print(
            f"{T:6d} {row['lm_s_per_iter']:9.3f} {row['optx_lm_s_per_iter']:9.3f} "
            f"{row.get('optx_lm_dense_s_per_iter', float('nan')):10.3f} {row.get('lm_iterations', -1):5d} "
            f"{row.get('lm_mean_joint_angle_error_deg', float('nan')):7.2f} {row['peak_rss_bytes'] / 2**30:8.2f}",
            flush=True,
        )
    slopes = {}
    for key in ("lm_s_per_iter", "optx_lm_s_per_iter"):
        pts = [(r["T"], r[key]) for r in rows if key in r and r["T"] >= 300]
        if len(pts) >= 2:
            slopes[key] = float(np.polyfit(np.log([p[0] for p in pts]), np.log([p[1] for p in pts]), 1)[0])
    print("log-log slope of time per iteration against T (T >= 300):", slopes)
    write_json(
        "solver_scaling.json",
        {
            "description": __doc__.strip().splitlines()[0],
            "problem": (
                "SIP-shaped: default_body('low') forward kinematics (no skinning), 6 sensors, "
                "E_ori + E_acc (central differences, 1/dt^2, dt = 1/60) + Gaussian pose prior; "
                "75 unknowns per frame; float32 residuals, JtJ formed and factorised in float64"
            ),
            "timing": f"{args.steps} LM iterations with tolerances 0, best of up to 2 runs after compilation; "
            "one fresh process per T (peak_rss_bytes is that process's peak resident set)",
            "note": "shared 2-core CPU: other jobs ran concurrently, absolute times are noisy",
            "machine": machine(),
            "step_agreement": agreement,
            "rows": rows,
            "loglog_slope_T_ge_300": slopes,
        },
    )


if __name__ == "__main__":
    main()
