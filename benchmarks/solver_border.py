"""Time per LM step, peak memory and step accuracy with sequence-wide and per-window unknowns.

Two problems extend solver_scaling.py's SIP-shaped energy (von Marcard §3.3: the default
body `default_body("low")`, 24 joints, 75 unknowns per frame (24 rotations on SO(3) +
root translation), 6 sensors on pelvis, head, lower arms and lower legs, E_ori (eq.
3.7, w = 1), E_acc (eq. 3.10-3.12, t-1/t/t+1, w = 0.05), a Gaussian pose prior with a
weak translation prior (eq. 3.14, w = 0.003)):

- "border": 20 sequence-wide unknowns, the border of the banded-plus-border normal
  equations. `heading` (6,) `sequence("angle")`: each sensor's reference frame differs
  from the world by a rotation Ry(γ_s) about the vertical y axis (SIP's heading
  offset), so its measured orientation and acceleration enter E_ori and E_acc rotated
  by Ry(γ_s). `calib` (14,) `sequence()`: a constant horizontal (x, z) accelerometer
  bias per sensor (12, m/s², world frame) and two body-proportion scales (bone offsets
  of the legs and of the upper body × (1 + s)), which move the sensor positions in
  E_acc. A calibration prior (γ ~ N(0, 0.35²) rad, bias ~ N(0, 0.5²) m/s², s ~ N(0,
  0.05²)) fixes the global-yaw gauge (rotating body, translation, headings and
  biases together leaves E_ori and E_acc unchanged).
- "window": 30-frame non-overlapping windows (`window(30, 30)`) of 10 DCT-II
  coefficients of the root translation, `dct` (W, 10, 3), and a bandwidth-0 term
  pulling the translation of every frame towards the DCT reconstruction of its window
  (Huang eq. 4.7-4.8: a trajectory as low-frequency DCT coefficients per window), w =
  10 (m); a weak ridge prior on the coefficients (0.01 (k+1) c_k) keeps a clipped last
  window of only a few frames well-posed.

Only the joints on the chains to the sensors (16 of 24) are declared read by E_ori and
E_acc, so the other 8 (hands, feet, ...) are eliminated frame by frame (their fill
lands in the windows and the border); 51 unknowns per frame stay in the band.

For each T (default 100, 300, 1000, 3000, 10000) and problem it times `solve` (von
Marcard's LM, float32 parameters and data, normal equations formed and factorised in
float64 under x64) for `--steps` LM steps with rtol = atol = 0 after a warm-up call that
compiles and runs the same steps, and records peak memory (GPU: the device allocator's
peak_bytes_in_use; CPU: the process's peak resident set, ru_maxrss). It fits the log-log
slope of time per step against T. At T <= 300 (`--dense-T`) it compares one damped LM
step of the engine (`linearise`, `factor`, `solve_factored`, float64) with a dense
float64 solve of the same normal equations: J of δ ↦ r(x ⊕ δ) by forward-mode AD
(chunks of unit tangents, kept sparse on the host), JᵀJ + λI and Jᵀr in SciPy/NumPy
float64, dense Cholesky.

Usage:
    python benchmarks/solver_border.py --T 100 300 --dense-T 100          # this CPU (solver_border.json)
    python benchmarks/solver_border.py --suffix gpu --process problem --parallel   # a GPU host
    python benchmarks/solver_border.py --T --dense-T 300 --lams 10 1 --suffix part  # dense check only
    python benchmarks/solver_border.py --merge a.json b.json --suffix gpu  # combine runs made in pieces
Each (problem, T) runs in a child process (`--process problem`: one per problem, T ascending);
`--parallel` starts them all at once so that their compiles overlap while a file lock
serialises their device work (on the H200 a compile takes 25-40 s, a step at T = 10000
under 1 s). Writes benchmarks/results/solver_border[_<suffix>].json atomically after every
row and prints a table.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from _common import machine, peak_memory_bytes, write_json  # noqa: E402

import jaxmocap  # noqa: E402
from jaxmocap.body import forward_kinematics, shaped_joints  # noqa: E402
from jaxmocap.rotation import axis_angle_to_matrix, matrix_to_axis_angle  # noqa: E402
from jaxmocap.solve import Problem, Term, VonMarcardLM, Windows, frame, sequence, solve, window  # noqa: E402
from jaxmocap.timeseries import second_difference  # noqa: E402

SENSOR_JOINTS = (0, 15, 18, 19, 4, 5)  # pelvis, head, left/right elbow (lower arm), knees (lower leg)
DT = 1.0 / 60.0
WIN = Windows(30, 30)
NUM_DCT = 10
PROBLEMS = ("border", "window")
ALL_T = (100, 300, 1000, 3000, 10000)


def _prior_cov(rng):
    A = rng.normal(size=(72, 72)) * 0.05
    return A @ A.T + np.eye(72) * 0.1


def ry(angle):
    """Rotation about the vertical y axis, (...) -> (..., 3, 3)."""
    c, s = jnp.cos(angle), jnp.sin(angle)
    o, z = jnp.ones_like(c), jnp.zeros_like(c)
    return jnp.stack([jnp.stack([c, z, s], -1), jnp.stack([z, o, z], -1), jnp.stack([-s, z, c], -1)], -2)


def dct_basis(length=WIN.length, k=NUM_DCT):
    """Orthonormal DCT-II basis, (length, k): column j = cos(π (l + ½) j / length)."""
    l = np.arange(length)[:, None] + 0.5
    B = np.sqrt(2.0 / length) * np.cos(np.pi * l * np.arange(k)[None, :] / length)
    B[:, 0] /= np.sqrt(2.0)
    return B


def build(body, kind: str, dtype=jnp.float32):
    """(problem, make_data) for problem `kind` ("border" or "window"); see the module docstring."""
    if kind not in PROBLEMS:
        raise ValueError(f"problem must be one of {PROBLEMS}, got {kind!r}")
    rest_np = np.asarray(shaped_joints(body, jnp.zeros((1,), body.dtype)), np.float64)
    rest = jnp.asarray(rest_np, dtype)
    parents = tuple(int(p) for p in body.parents)
    J = len(parents)
    rng = np.random.default_rng(1)  # the constants of solver_scaling.py
    offsets = jnp.asarray(rng.normal(scale=0.05, size=(6, 3)), dtype)  # sensor in bone frame
    sensor_to_bone = axis_angle_to_matrix(jnp.asarray(rng.normal(scale=0.3, size=(6, 3)), dtype))
    prior_L = jnp.asarray(np.linalg.cholesky(np.linalg.inv(_prior_cov(rng))).T, dtype)  # Σ⁻¹ = LᵀL

    # Chains: ancestors-or-self, the joints the sensors depend on, body regions for the scales.
    chain = np.zeros((J, J))
    for j in range(J):
        k = j
        while k >= 0:
            chain[j, k] = 1.0
            k = parents[k]
    read_joints = tuple(int(k) for k in np.nonzero(chain[list(SENSOR_JOINTS)].any(0))[0])
    legs = chain[:, 1] + chain[:, 2] > 0  # descendants of the hips (SMPL joints 1, 2)
    region = np.where(np.arange(J) == 0, 0, np.where(legs, 1, 2))  # 0 root, 1 legs, 2 upper body
    bones = np.concatenate([rest_np[:1], rest_np[1:] - rest_np[np.asarray(parents[1:])]], 0)
    chain_j, bones_j = jnp.asarray(chain, dtype), jnp.asarray(bones, dtype)
    idx = np.asarray(SENSOR_JOINTS)

    def joints_of(calib):
        """Rest joints with leg / upper-body bone offsets scaled by 1 + calib[12:14]."""
        if calib is None:
            return rest
        scale = jnp.concatenate([jnp.ones((1,), calib.dtype), 1.0 + calib[12:14]])[region]
        return chain_j @ (bones_j * scale[:, None])

    def sensors(x, calib=None):
        """Sensor orientations (T, 6, 3, 3) and positions (T, 6, 3); pose as matrices."""
        T = x["pose"].shape[0]
        R, p = forward_kinematics(parents, x["pose"], jnp.broadcast_to(joints_of(calib), (T, J, 3)))
        R_b, p_b = R[:, idx], p[:, idx]
        pos = p_b + jnp.einsum("tsab,sb->tsa", R_b, offsets) + x["trans"][:, None]
        return R_b @ sensor_to_bone, pos

    def bias(calib):  # (6, 3) horizontal accelerometer biases
        b = calib[:12].reshape(6, 2)
        return jnp.stack([b[:, 0], jnp.zeros_like(b[:, 0]), b[:, 1]], -1)

    def e_prior(x, data):  # eq. 3.14, 3.28-3.29 with a weak translation prior
        pose = matrix_to_axis_angle(x["pose"]).reshape(-1, 72)
        return jnp.concatenate([pose @ prior_L.T, 0.1 * x["trans"]], axis=1)[..., None]

    pose_reads = ("pose", read_joints)
    prior = Term("prior", e_prior, weight=0.003)
    basis = jnp.asarray(dct_basis(), dtype)
    ridge = jnp.asarray(0.01 * (1.0 + np.arange(NUM_DCT)), dtype)
    sigma = jnp.asarray([0.35] * 6 + [0.5] * 12 + [0.05] * 2, dtype)

    if kind == "border":

        def e_ori(x, data):  # eq. 3.7, measurement in the sensor's reference frame
            R, _ = sensors(x)
            R_world = ry(x["heading"])[None] @ data["R_meas"]
            return matrix_to_axis_angle(R @ jnp.swapaxes(R_world, -1, -2))

        def e_acc(x, data):  # eq. 3.10-3.12 with heading and bias
            _, p = sensors(x, x["calib"])
            a_world = jnp.einsum("sab,tsb->tsa", ry(x["heading"]), data["acc"]) + bias(x["calib"])
            return second_difference(p) / DT**2 - a_world

        def e_calib(x, data):  # the calibration prior, in the rows of frame 0
            T = x["pose"].shape[0]
            v = jnp.concatenate([x["heading"], x["calib"]]) / sigma
            return jnp.zeros((T, 20), v.dtype).at[0].set(v)[..., None]

        terms = [
            Term("ori", e_ori, weight=1.0, reads=(pose_reads, ("heading", None))),
            Term("acc", e_acc, weight=0.05, bandwidth=1,
                 reads=(pose_reads, ("trans", None), ("heading", None), ("calib", None))),
            prior,
            Term("calib_prior", e_calib, weight=1.0, reads=(("heading", None), ("calib", None))),
        ]  # fmt: skip
        unknowns = {"pose": frame("so3"), "trans": frame(), "heading": sequence("angle"), "calib": sequence()}
    else:

        def e_ori(x, data):  # eq. 3.7
            R, _ = sensors(x)
            return matrix_to_axis_angle(R @ jnp.swapaxes(data["R_meas"], -1, -2))

        def e_acc(x, data):  # eq. 3.10-3.12
            _, p = sensors(x)
            return second_difference(p) / DT**2 - data["acc"]

        def e_dct(x, data):  # Huang eq. 4.7-4.8: trans_t ≈ Σ_k B[t - w·30, k] c_w,k
            T = x["trans"].shape[0]
            framed, _ = WIN.frames(x["trans"])  # (W, 30, 3)
            return WIN.rows(framed - jnp.einsum("lk,wkd->wld", basis, x["dct"]), T)  # (T, 1, 3)

        def e_dct_ridge(x, data):  # a weak ridge on the coefficients, in the rows of each window's first frame
            T = x["trans"].shape[0]
            c = (x["dct"] * ridge[:, None]).reshape(x["dct"].shape[0], 1, -1)  # (W, 1, 30)
            per_window = jnp.concatenate([c, jnp.zeros((c.shape[0], WIN.length - 1, c.shape[2]), c.dtype)], 1)
            return WIN.rows(per_window, T)[..., None]  # (T, 1, 30, 1)

        terms = [
            Term("ori", e_ori, weight=1.0, reads=(pose_reads,)),
            Term("acc", e_acc, weight=0.05, bandwidth=1, reads=(pose_reads, ("trans", None))),
            prior,
            Term("dct", e_dct, weight=10.0, reads=(("trans", None), ("dct", None))),
            Term("dct_ridge", e_dct_ridge, weight=1.0, reads=(("dct", None),)),
        ]
        unknowns = {"pose": frame("so3"), "trans": frame(), "dct": window(WIN.length, WIN.stride)}
    problem = Problem(terms, unknowns)

    def make_data(T: int, seed: int = 0):
        """(truth, init, data) in `dtype`: smooth random motion, exact measurements, noisy start."""
        r = np.random.default_rng(seed)
        t = np.arange(T)[:, None] * DT
        freq, phase = r.uniform(0.3, 1.5, (1, 72)), r.uniform(0, 2 * np.pi, (1, 72))
        amp = r.uniform(0.05, 0.4, (1, 72))
        pose = amp * np.sin(2 * np.pi * freq * t + phase)
        trans = np.concatenate([0.3 * np.sin(t), 0.9 + 0.02 * np.sin(3 * t), 0.2 * t], 1)
        truth = {"pose": jnp.asarray(pose.reshape(T, 24, 3), dtype), "trans": jnp.asarray(trans, dtype)}
        x = {"pose": axis_angle_to_matrix(truth["pose"]), "trans": truth["trans"]}
        init = {
            "pose": truth["pose"] + jnp.asarray(r.normal(scale=0.1, size=(T, 24, 3)), dtype),
            "trans": truth["trans"] + jnp.asarray(r.normal(scale=0.02, size=(T, 3)), dtype),
        }
        if kind == "border":
            truth["heading"] = jnp.asarray(r.uniform(-0.25, 0.25, 6), dtype)
            truth["calib"] = jnp.asarray(np.concatenate([r.normal(scale=0.2, size=12), [0.04, -0.03]]), dtype)
            R, p = sensors(x, truth["calib"])
            Ry_inv = jnp.swapaxes(ry(truth["heading"]), -1, -2)
            data = {
                "R_meas": Ry_inv[None] @ R,
                "acc": jnp.einsum("sab,tsb->tsa", Ry_inv, second_difference(p) / DT**2 - bias(truth["calib"])),
            }
            init["heading"] = jnp.zeros((6,), dtype)
            init["calib"] = jnp.zeros((14,), dtype)
        else:
            R, p = sensors(x)
            data = {"R_meas": R, "acc": second_difference(p) / DT**2}
            framed, valid = WIN.frames(init["trans"])  # least-squares DCT of the noisy start
            framed = framed * valid[..., None]
            init["dct"] = jnp.linalg.solve(
                jnp.einsum("wl,lk,lj->wkj", valid.astype(dtype), basis, basis) + 1e-6 * jnp.eye(NUM_DCT, dtype=dtype),
                jnp.einsum("lk,wld->wkd", basis, framed),
            )
            f2, _ = WIN.frames(truth["trans"])
            truth["dct"] = jnp.einsum("lk,wld->wkd", basis, f2)
        return truth, init, data

    return problem, make_data


def unknown_counts(params: dict, problem: Problem) -> dict:
    layout = problem.layout(params)
    return {
        "per_frame": layout.size("frame"),
        "windows": layout.num_windows,
        "per_window": layout.size("window"),
        "sequence": layout.size("sequence"),
        "total": layout.T * layout.size("frame") + layout.num_windows * layout.size("window") + layout.size("sequence"),
    }


# --- timing -----------------------------------------------------------------------------------


class _Lock:
    """An exclusive file lock around device work, so that children running in parallel
    compile concurrently but never execute concurrently (none without a path)."""

    def __init__(self, path):
        self.path = path

    def __enter__(self):
        if self.path:
            import fcntl

            self.f = open(self.path, "a")
            fcntl.flock(self.f, fcntl.LOCK_EX)
        return self

    def __exit__(self, *exc):
        if self.path:
            import fcntl

            fcntl.flock(self.f, fcntl.LOCK_UN)
            self.f.close()


def time_rows(kind: str, Ts, steps: int, repeats: int, lock: str | None = None):
    """Time `steps` LM steps at each T (ascending), one ROW line per T.

    The solve is compiled ahead of time (outside the lock), then run once (warm-up) and
    `repeats` times (timed) inside the lock."""
    body = jaxmocap.default_body("low")
    problem, make_data = build(body, kind, jnp.float32)
    for T in sorted(Ts):
        _, init, data = make_data(T)
        fn = jax.jit(
            lambda init, data: solve(problem, init, data, solver=VonMarcardLM(rtol=0.0, atol=0.0), max_steps=steps)
        )
        t0 = time.perf_counter()
        compiled = fn.lower(init, data).compile()
        compile_s = time.perf_counter() - t0
        cost0 = float(jax.jit(problem.cost)(init, data))
        with _Lock(lock):
            t0 = time.perf_counter()
            sol = jax.block_until_ready(compiled(init, data))
            first = time.perf_counter() - t0
            times = []
            for _ in range(max(1, repeats)):
                t0 = time.perf_counter()
                sol = jax.block_until_ready(compiled(init, data))
                times.append(time.perf_counter() - t0)
                if times[-1] > 20.0:
                    break
            peak = peak_memory_bytes()
        n = int(sol.num_steps)
        row = {
            "problem": kind,
            "T": T,
            "unknowns": unknown_counts(init, problem),
            "dtype": "float32",
            "factor_dtype": "float64",
            "steps": n,
            "s_per_step": min(times) / max(n, 1),
            "s_per_step_all_repeats": [x / max(n, 1) for x in times],
            "compile_s": compile_s,
            "first_run_s": first,
            "cost_start": cost0,
            "cost_after_steps": float(sol.cost),
            "result": int(sol.result),
            "peak_memory_bytes": peak,
        }
        print("ROW " + json.dumps(row), flush=True)


# --- dense check ----------------------------------------------------------------------------


def _dense_cholesky(A: np.ndarray, backend: str):
    """(solve, matvec) of a dense SPD float64 matrix, through its Cholesky factor L (A = L Lᵀ):
    SciPy on the host (A is overwritten) or JAX on the default device."""
    if backend == "jax":
        L = jnp.linalg.cholesky(jnp.asarray(A))
        sol = jax.jit(lambda b: jax.scipy.linalg.cho_solve((L, True), b))
        mv = jax.jit(lambda v: L @ (L.T @ v))
        return (lambda b: np.asarray(sol(jnp.asarray(b)))), (lambda v: np.asarray(mv(jnp.asarray(v))))
    import scipy.linalg
    from scipy.linalg.blas import dtrmv

    c = scipy.linalg.cho_factor(A, lower=True, overwrite_a=True, check_finite=False)
    return (
        lambda b: scipy.linalg.cho_solve(c, b, check_finite=False),
        lambda v: dtrmv(c[0], dtrmv(c[0], v, lower=1, trans=1), lower=1),
    )


def _condition_estimate(solve_dense, matvec, N: int, iters: int = 40) -> float:
    """2-norm condition number of an SPD matrix by power and inverse iteration (a lower bound)."""
    rng = np.random.default_rng(0)
    v = rng.normal(size=N)
    w = rng.normal(size=N)
    hi = lo = 1.0
    for _ in range(iters):
        v = matvec(v / np.linalg.norm(v))
        hi = np.linalg.norm(v)
        w = solve_dense(w / np.linalg.norm(w))
        lo = np.linalg.norm(w)
    return float(hi * lo)


def dense_check(
    kind: str, T: int, lams, chunk: int, max_n: int, backend: str = "scipy", lock: str | None = None
) -> dict:
    """One damped step, structured vs a dense float64 solve of the same normal equations."""
    import scipy.sparse as sp

    from jaxmocap.solve.linearisation import Args
    from jaxmocap.solve.linearisation import linearise
    from jaxmocap.solve.factorise import factor, solve_factored
    from jaxmocap.solve.unknowns import retract, to_manifold

    f64 = jnp.float64
    body = jaxmocap.default_body("low")
    problem, make_data = build(body, kind, f64)
    _, params, data = make_data(T)
    layout = problem.layout(params)
    st = Args(problem, data, None, layout).structure()
    N = unknown_counts(params, problem)["total"]
    out = {"problem": kind, "T": T, "unknowns": N, "coupled_per_frame": st.nc, "lambdas": list(lams)}
    if N > max_n:
        gb = N * N * 8 / 2**30
        out["skipped"] = f"dense JtJ would be {N}^2 float64 = {gb:.1f} GiB (> --dense-max-n {max_n})"
        return out

    # The engine's linearisation and damped step (compiled here, run under the lock).
    t0 = time.perf_counter()
    lin = jax.jit(lambda p, d: linearise(p, Args(problem, d, None, layout), st, f64, f64))
    lin_c = lin.lower(params, data).compile()
    normal_s, grads_s, _ = jax.eval_shape(lin, params, data)
    step = jax.jit(lambda nrm, g, lam: solve_factored(factor(nrm, st, lam), *g))
    step_c = step.lower(normal_s, grads_s, jax.ShapeDtypeStruct((), f64)).compile()

    # Dense: J of δ ↦ r(x ⊕ δ) in the layout's flat tangent order (F, W, G).
    x = to_manifold(params, layout)
    zF, zW, zG = layout.ravel(layout.zeros(f64))
    shapes = [None if z is None else z.shape for z in (zF, zW, zG)]
    assert sum(int(np.prod(sh)) for sh in shapes if sh is not None) == N

    def r_of(d):
        parts, start = [], 0
        for shape in shapes:
            if shape is None:
                parts.append(None)
                continue
            size = int(np.prod(shape))
            parts.append(d[start : start + size].reshape(shape))
            start += size
        moved = retract(x, layout.unravel(*parts), layout)
        res = problem.residuals_on_manifold(moved, data, None, T)
        return jnp.concatenate([res[k].reshape(-1) for k in sorted(res)])

    z = jnp.zeros((N,), f64)

    def columns(ix):
        E = jax.nn.one_hot(ix, N, dtype=f64)
        return jax.vmap(lambda e: jax.jvp(r_of, (z,), (e,))[1])(E)  # (c, M)

    r_c = jax.jit(r_of).lower(z).compile()
    columns_c = jax.jit(columns).lower(jax.ShapeDtypeStruct((chunk,), jnp.int32)).compile()
    out["compile_s"] = time.perf_counter() - t0

    def flat(F, W, G):
        parts = [st.from_solver_order(F).reshape(-1)]
        parts += [p.reshape(-1) for p in (W, G) if p is not None]
        return np.asarray(jnp.concatenate(parts), np.float64)

    t0 = time.perf_counter()
    with _Lock(lock):
        normal, grads, cost = lin_c(params, data)
        g_struct = flat(*grads)
        x_struct = {lam: flat(*step_c(normal, grads, jnp.asarray(lam, f64))) for lam in lams}
        del normal
        r0 = np.asarray(r_c(z), np.float64)
        JT = []
        for start in range(0, N, chunk):
            ix = np.minimum(np.arange(start, start + chunk), N - 1).astype(np.int32)
            block = np.asarray(columns_c(jnp.asarray(ix)), np.float64)[: min(chunk, N - start)]
            JT.append(sp.csr_matrix(block))
    JT = sp.vstack(JT).tocsr()  # Jᵀ, (N, M)
    out["jacobian_rows"] = int(JT.shape[1])
    out["jacobian_nnz"] = int(JT.nnz)
    H_sparse = (JT @ JT.T).tocsr()
    g_dense = JT @ r0
    del JT
    out["jacobian_s"] = time.perf_counter() - t0
    out["cost_rel_err"] = abs(float(cost) - 0.5 * float(r0 @ r0)) / (0.5 * float(r0 @ r0))
    out["grad_max_rel_err"] = float(np.max(np.abs(g_struct - g_dense)) / np.max(np.abs(g_dense)))
    t0 = time.perf_counter()
    errs, backward, cond = {}, {}, {}
    for lam in lams:
        # Jacobi-scaled dense Cholesky of the same equations, D (JtJ + lam I) D y = D Jt r, x = D y,
        # D = diag^-1/2 (the engine scales the same way).
        A = H_sparse.toarray()
        A[np.diag_indices(N)] += lam
        d = 1.0 / np.sqrt(np.diag(A).copy())
        A *= d[:, None]
        A *= d[None, :]
        with _Lock(lock if backend == "jax" else None):
            solve_dense, matvec = _dense_cholesky(A, backend)
            del A
            x_dense = d * solve_dense(d * g_dense)
            cond[str(lam)] = _condition_estimate(solve_dense, matvec, N)
            del solve_dense, matvec
        xs = x_struct[lam]
        errs[str(lam)] = float(np.max(np.abs(xs - x_dense)) / np.max(np.abs(x_dense)))
        res = H_sparse @ xs + lam * xs - g_dense  # the structured step's backward error
        backward[str(lam)] = float(np.linalg.norm(res) / np.linalg.norm(g_dense))
    eps = float(np.finfo(np.float64).eps)
    out["dense_backend"] = backend
    out["dense_solve_s"] = time.perf_counter() - t0
    out["step_max_rel_err"] = errs
    out["scaled_condition_number_estimate"] = cond
    out["cond_times_eps"] = {k: v * eps for k, v in cond.items()}
    out["err_over_cond_eps"] = {k: errs[k] / (cond[k] * eps) for k in errs}
    out["structured_step_rel_residual"] = backward
    primary = [errs[str(lam)] for lam in lams if lam >= 1.0]
    out["max_rel_err_vs_dense"] = max(primary) if primary else max(errs.values())
    out["max_rel_err_vs_dense_all_lambdas"] = max(errs.values())
    out["peak_memory_bytes"] = peak_memory_bytes()
    return out


# --- driver ------------------------------------------------------------------------------------


def _slope(rows):
    pts = sorted((r["T"], r["s_per_step"]) for r in rows if "s_per_step" in r)
    if len(pts) < 2:
        return None
    return float(np.polyfit(np.log([p[0] for p in pts]), np.log([p[1] for p in pts]), 1)[0])


def _run_jobs(jobs, parallel: bool, on_row, env=None):
    """Run child commands (sequentially or all at once), streaming their ROW lines to
    `on_row(job, row)`; returns {job index: stderr tail} for children that failed."""
    import tempfile
    import threading

    failures = {}

    def run(i, cmd):
        with tempfile.TemporaryFile("w+") as err:
            proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=err, text=True, env=env)
            for line in proc.stdout:
                if line.startswith("ROW "):
                    on_row(i, json.loads(line[4:]))
            if proc.wait():
                err.seek(0)
                failures[i] = err.read()[-3000:] or f"exit code {proc.returncode}"

    if not parallel:
        for i, (cmd, _) in enumerate(jobs):
            run(i, cmd)
        return failures
    threads = [threading.Thread(target=run, args=(i, cmd)) for i, (cmd, _) in enumerate(jobs)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return failures


def main():
    import os
    import tempfile
    import threading

    p = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    p.add_argument(
        "--T", type=int, nargs="*", default=list(ALL_T), help="sequence lengths to time (default: all; none: no timing)"
    )
    p.add_argument("--problems", nargs="+", default=list(PROBLEMS), choices=PROBLEMS)
    p.add_argument("--steps", type=int, default=3, help="LM steps per timed solve (rtol = atol = 0)")
    p.add_argument("--repeats", type=int, default=2, help="timed solves after the warm-up (best taken)")
    p.add_argument("--dense-T", type=int, nargs="*", default=[100, 300], help="T for the dense check (none: skip)")
    p.add_argument(
        "--lams",
        type=float,
        nargs="+",
        default=[10.0, 1.0, 1e-2],
        help="LM damping for the dense check (max_rel_err_vs_dense: lambda >= 1)",
    )
    p.add_argument("--dense-chunk", type=int, help="Jacobian columns per forward-mode batch (256 CPU, 1024 GPU)")
    p.add_argument(
        "--dense-backend",
        choices=("scipy", "jax"),
        help="dense Cholesky: SciPy on the host (CPU default) or JAX on the device (GPU default)",
    )
    p.add_argument("--dense-max-n", type=int, default=30000, help="largest unknown count solved densely")
    p.add_argument(
        "--process",
        choices=("T", "problem"),
        default="T",
        help="one child process per (problem, T) (per-T peak memory) or per problem (T ascending)",
    )
    p.add_argument(
        "--parallel",
        action="store_true",
        help="run the children at once: compiles overlap, device work is serialised by a file lock "
        "(for a GPU host with many cores; device memory is then not preallocated)",
    )
    p.add_argument("--suffix", default="", help="results file suffix, e.g. gpu")
    p.add_argument("--child", help=argparse.SUPPRESS)
    p.add_argument("--dense-child", help=argparse.SUPPRESS)
    p.add_argument("--lock", help=argparse.SUPPRESS)
    p.add_argument(
        "--merge",
        nargs="+",
        metavar="JSON",
        help="combine earlier results files (rows and dense checks; later files win per (problem, T)) "
        "into results/solver_border[_<suffix>].json and recompute the summaries; runs nothing",
    )
    p.add_argument("--note", help="a note stored in the results file")
    args = p.parse_args()

    if args.child:
        time_rows(args.child, args.T, args.steps, args.repeats, args.lock)
        return
    if args.dense_child:
        for T in args.T:
            row = dense_check(
                args.dense_child, T, args.lams, args.dense_chunk, args.dense_max_n, args.dense_backend, args.lock
            )
            print("ROW " + json.dumps(row), flush=True)
        return

    name = "solver_border" + (f"_{args.suffix}" if args.suffix else "") + ".json"
    Ts = sorted(set(args.T))
    dense_T = sorted(set(args.dense_T or []))
    on_gpu = jax.devices()[0].platform != "cpu"
    args.dense_chunk = args.dense_chunk or (1024 if on_gpu else 256)
    args.dense_backend = args.dense_backend or ("jax" if on_gpu else "scipy")

    payload = {
        "description": __doc__.strip().splitlines()[0],
        "problems": {
            "border": "SIP-shaped (solver_scaling.py) + heading (6,) sequence('angle') rotating each sensor's "
            "measured orientation and acceleration about y + calib (14,) sequence(): horizontal accelerometer "
            "bias per sensor (12) and leg / upper-body bone scales (2); calibration prior. 20 border unknowns.",
            "window": "SIP-shaped (solver_scaling.py) + dct (W, 10, 3) window(30, 30): 10 DCT-II coefficients "
            "of the root translation per 30-frame window, bandwidth-0 term trans_t ~ DCT reconstruction "
            "(Huang eq. 4.7-4.8, w = 10) + weak ridge on the coefficients.",
        },
        "common": "default_body('low') forward kinematics, 6 sensors, E_ori (w=1) + E_acc (w=0.05, dt=1/60) + "
        "Gaussian pose prior (w=0.003); 75 unknowns per frame of which 51 coupled (E_ori/E_acc read the 16 "
        "joints on the sensor chains; the other 8 are eliminated per frame); float32 parameters and data, "
        "normal equations formed and factorised in float64 (x64 on)",
        "timing": f"{args.steps} LM steps (jax.jit of solve(..., solver=VonMarcardLM(rtol=0, atol=0), max_steps={args.steps}), von "
        "Marcard LM), compiled ahead of time ('compile_s'), run once ('first_run_s'), then best of up to "
        f"{args.repeats} timed runs divided by the steps taken; an accepted step relinearises, a rejected one "
        "only refactorises",
        "process": (
            "one child process per (problem, T)"
            if args.process == "T"
            else "one child process per problem, T ascending (peak memory is the process peak so far, "
            "dominated by the largest T)"
        )
        + (
            "; children in parallel, device work serialised by a file lock (compiles overlap), "
            "XLA_PYTHON_CLIENT_PREALLOCATE=false"
            if args.parallel
            else ""
        ),
        "peak_memory": "GPU: jax device memory_stats()['peak_bytes_in_use']"
        if on_gpu
        else "CPU: peak resident set of the child process (resource.getrusage ru_maxrss), not device memory",
        "dense_check": "one damped LM step (JtJ + lam I) x = Jt r at the noisy start, engine (linearise -> factor "
        "-> solve_factored, float64 problem data) vs J of delta -> r(x (+) delta) by jax.jvp on unit tangents "
        "(float64), JtJ and Jt r in SciPy sparse float64 on the host, dense Jacobi-scaled Cholesky in float64 "
        f"({args.dense_backend}); error = max|x_struct - x_dense| / max|x_dense|; max_rel_err_vs_dense takes "
        "lambda >= 1 (10 = the LM's first damping); at lambda = 0.01 the scaled system is far worse conditioned "
        "(scaled_condition_number_estimate, a power-iteration lower bound; the translation is pinned only by "
        "0.003 x 0.1 priors against 1/dt^2 accelerations), so two backward-stable float64 solves may differ by "
        "up to about cond * eps (cond_times_eps); structured_step_rel_residual = "
        "||(JtJ + lam I) x_struct - Jt r|| / ||Jt r|| is the engine's backward error",
        "machine": machine(),
        "rows": [],
        "dense": [],
    }
    if not on_gpu:
        payload["note"] = "shared 2-core CPU, other jobs running: absolute times are noisy"
    if args.note:
        payload["note"] = args.note
    lock = threading.Lock()

    def finish():
        per = {}
        for kind in [k for k in PROBLEMS if any(r.get("problem") == k for r in payload["rows"])]:
            rows = sorted((r for r in payload["rows"] if r.get("problem") == kind and "s_per_step" in r),
                          key=lambda r: r["T"])  # fmt: skip
            per[kind] = {"loglog_slope": _slope(rows), "Ts": [r["T"] for r in rows],
                         "loglog_slope_T_ge_1000": _slope([r for r in rows if r["T"] >= 1000])}  # fmt: skip
        payload["per_problem"] = per
        slopes = [v["loglog_slope"] for v in per.values() if v["loglog_slope"] is not None]
        payload["loglog_slope"] = max(slopes) if slopes else None
        ok = [d for d in payload["dense"] if "max_rel_err_vs_dense" in d]
        payload["max_rel_err_vs_dense"] = max((d["max_rel_err_vs_dense"] for d in ok), default=None)
        payload["max_rel_err_vs_dense_all_lambdas"] = max(
            (d["max_rel_err_vs_dense_all_lambdas"] for d in ok), default=None
        )
        payload["dense_T"] = sorted({d["T"] for d in ok})
        payload["rows"].sort(key=lambda r: (r["problem"], r["T"]))
        payload["dense"].sort(key=lambda r: (r["problem"], r["T"]))
        write_json(name, payload)

    def fmt(d):
        return "{" + ", ".join(f"{k}: {v:.1e}" for k, v in d.items()) + "}"

    def show(r):
        if "error" in r:
            print(f"{r['problem']:>8} {r['T']:6d} failed: {r['error'][-600:]}", flush=True)
        elif "s_per_step" in r:
            print(f"{r['problem']:>8} {r['T']:6d} {r['unknowns']['total']:8d} {r['s_per_step']:9.4f} "
                  f"{r['compile_s']:9.1f} {r['steps']:5d} {r['cost_start']:10.3g} "
                  f"{r['cost_after_steps']:10.3g} {(r['peak_memory_bytes'] or 0) / 2**20:9.0f}", flush=True)  # fmt: skip
        elif "max_rel_err_vs_dense" in r:
            print(f"dense check {r['problem']:>7} T={r['T']:4d} N={r['unknowns']}: step max rel err by lambda "
                  f"{fmt(r['step_max_rel_err'])}, cond {fmt(r['scaled_condition_number_estimate'])}, "
                  f"backward err {fmt(r['structured_step_rel_residual'])}, grad {r['grad_max_rel_err']:.1e}; "
                  f"J {r['jacobian_s']:.0f} s, dense {r['dense_solve_s']:.0f} s", flush=True)  # fmt: skip
        else:
            print(f"dense check {r['problem']:>7} T={r['T']:4d}: {r.get('skipped')}", flush=True)

    if args.merge:
        from pathlib import Path

        loaded = [json.loads(Path(f).read_text()) for f in args.merge]
        payload = dict(loaded[0], merged_from=[
            {"file": Path(f).name, "machine": d.get("machine"), "process": d.get("process"), "timing": d.get("timing"),
             "rows": [[r["problem"], r["T"]] for r in d.get("rows", [])],
             "dense": [[r["problem"], r["T"]] for r in d.get("dense", [])]} for f, d in zip(args.merge, loaded)])  # fmt: skip
        if args.note:
            payload["note"] = args.note
        for what in ("rows", "dense"):
            merged = {}
            for d in loaded:
                for r in d.get(what, []):
                    if "error" not in r or (r["problem"], r["T"]) not in merged:
                        merged[(r["problem"], r["T"])] = r
            payload[what] = list(merged.values())
        finish()
        print(f"merged {len(args.merge)} files into {name}: rows {sorted((r['problem'], r['T']) for r in payload['rows'])}, "
              f"dense {sorted((r['problem'], r['T']) for r in payload['dense'])}; loglog_slope {payload['per_problem']}, "
              f"max_rel_err_vs_dense {payload['max_rel_err_vs_dense']}")  # fmt: skip
        return

    me = [sys.executable, os.path.abspath(__file__)]
    jobs = []  # (command, (list name, problem, Ts))
    for kind in args.problems:
        for group in [[T] for T in Ts] if args.process == "T" else [Ts] if Ts else []:
            cmd = me + [
                "--steps",
                str(args.steps),
                "--repeats",
                str(args.repeats),
                "--child",
                kind,
                "--T",
                *map(str, group),
            ]
            jobs.append((cmd, ("rows", kind, group)))
    for kind in args.problems if dense_T else []:
        cmd = me + ["--dense-child", kind, "--T", *map(str, dense_T), "--lams", *map(str, args.lams),
                    "--dense-chunk", str(args.dense_chunk), "--dense-max-n", str(args.dense_max_n),
                    "--dense-backend", args.dense_backend]  # fmt: skip
        jobs.append((cmd, ("dense", kind, dense_T)))
    env = None
    if args.parallel:
        lock_path = os.path.join(tempfile.gettempdir(), f"solver_border_{os.getpid()}.lock")
        jobs = [(cmd + ["--lock", lock_path], meta) for cmd, meta in jobs]
        env = dict(os.environ, XLA_PYTHON_CLIENT_PREALLOCATE="false")

    print(f"{'problem':>8} {'T':>6} {'unknowns':>8} {'s/step':>9} {'compile s':>9} {'steps':>5} "
          f"{'cost0':>10} {'cost':>10} {'peak MiB':>9}", flush=True)  # fmt: skip

    def on_row(i, row):
        with lock:
            payload[jobs[i][1][0]].append(row)
            show(row)
            finish()

    failures = _run_jobs(jobs, args.parallel, on_row, env)
    for i, err in failures.items():
        what, kind, group = jobs[i][1]
        done = {r["T"] for r in payload[what] if r["problem"] == kind}
        for T in group:
            if T not in done:
                on_row(i, {"problem": kind, "T": T, "error": err})
    finish()
    print(
        "log-log slope of time per step against T:",
        {k: v["loglog_slope"] for k, v in payload["per_problem"].items()},
        "max",
        payload["loglog_slope"],
    )
    print(
        "max relative error of the structured step vs dense float64 (lambda >= 1):",
        payload["max_rel_err_vs_dense"],
        "at T",
        payload["dense_T"],
        "; all lambdas:",
        payload["max_rel_err_vs_dense_all_lambdas"],
    )
    print("wrote", name)


if __name__ == "__main__":
    main()
