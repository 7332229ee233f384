"""Tests for the least-squares engine (jaxmocap.solve): structure, LM, masks, batches.

A three-bone chain with a rigidly attached sensor per bone stands in for the body: it
has the structure of SIP (von Marcard §3.3: per-frame orientation residuals, t-1/t/t+1
acceleration residuals, a prior) at a size that keeps this file fast. Float64 is on
(tests/conftest.py); float32 behaviour is tested explicitly.
"""

import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
import pytest
import scipy.optimize

from jaxmocap.body import forward_kinematics
from jaxmocap.rotation import axis_angle_to_matrix, matrix_to_axis_angle
from jaxmocap.solve import (
    Args,
    Cauchy,
    GemanMcClure,
    Huber,
    Problem,
    Term,
    nan_mask,
    pad_sequences,
    second_difference,
    result_message,
    solve,
    solve_batch,
)
from jaxmocap.solve import frame, linear_solver, sequence, window
from jaxmocap.solve.solver import residuals
from jaxmocap.solve.unknowns import to_manifold

PARENTS = (-1, 0, 1)
REST = jnp.array([[0.0, 0.0, 0.0], [0.0, 0.4, 0.0], [0.3, 0.6, 0.1]])
OFFSETS = jnp.array([[0.05, 0.0, 0.02], [0.0, 0.1, 0.03], [0.02, 0.05, 0.0]])
DT = 1.0 / 30.0


def sensors(x):
    """Sensor orientations (T, 3, 3, 3) and positions (T, 3, 3) of the chain; x on SO(3)."""
    T = x["rot"].shape[0]
    R, p = forward_kinematics(PARENTS, x["rot"], jnp.broadcast_to(REST, (T, 3, 3)))
    return R, p + jnp.einsum("tjab,jb->tja", R, OFFSETS) + x["trans"][:, None]


def e_ori(x, data):  # von Marcard eq. 3.7
    R, _ = sensors(x)
    return matrix_to_axis_angle(R @ jnp.swapaxes(data["R"], -1, -2))


def e_acc(x, data):  # eq. 3.10-3.12
    _, p = sensors(x)
    return second_difference(p) / DT**2 - data["acc"]


def e_prior(x, data):
    return 0.1 * matrix_to_axis_angle(x["rot"]).reshape(x["rot"].shape[0], -1, 1)


def e_smooth2(x, data):  # bandwidth 2: couples t-2 .. t+2 (tests a wider band)
    w = matrix_to_axis_angle(x["rot"])
    pad = jnp.concatenate([w[:2], w, w[-2:]])
    return (pad[:-4] - pad[4:]).reshape(w.shape[0], -1, 3)


CHAIN = Problem(
    [
        Term("ori", e_ori, weight=1.0, mask=lambda d: nan_mask(d["R"], (-2, -1))),
        Term("acc", e_acc, weight=0.05, bandwidth=1, mask=lambda d: nan_mask(d["acc"])),
        # Accelerations leave translation free up to a constant velocity; pin it weakly.
        Term("trans", lambda x, d: (x["trans"] - d["trans"])[..., None], weight=1e-2),
    ],
    rotations=("rot",),
)


def motion(T, seed=0, dtype=jnp.float64):
    """Smooth ground truth, its synthetic measurements and a perturbed start."""
    rng = np.random.default_rng(seed)
    t = np.arange(T)[:, None] * DT
    rot = 0.6 * np.sin(2 * np.pi * rng.uniform(0.3, 1.0, (1, 9)) * t + rng.uniform(0, 6, (1, 9)))
    trans = np.concatenate([np.sin(t), np.cos(2 * t), 0.3 * t], 1)
    truth = {"rot": jnp.asarray(rot.reshape(T, 3, 3), dtype), "trans": jnp.asarray(trans, dtype)}
    R, p = sensors(to_manifold(truth, CHAIN.layout(truth)))
    data = {"R": R, "acc": second_difference(p) / DT**2, "trans": truth["trans"]}
    init = {
        "rot": truth["rot"] + jnp.asarray(rng.normal(scale=0.3, size=(T, 3, 3)), dtype),
        "trans": truth["trans"] + jnp.asarray(rng.normal(scale=0.05, size=(T, 3)), dtype),
    }
    return truth, init, data


def rot_error(a, b):
    Ra, Rb = axis_angle_to_matrix(a), axis_angle_to_matrix(b)
    return float(jnp.max(jnp.linalg.norm(matrix_to_axis_angle(Ra @ jnp.swapaxes(Rb, -1, -2)), axis=-1)))


# --- known minimiser, all backends, manifold parametrisations ------------------------


@pytest.mark.parametrize("method", ["lm", "optx_lm", "optx_gn", "jaxopt"])
def test_known_minimiser_recovered(method):
    truth, init, data = motion(8)
    atol = 1e-7 if method == "jaxopt" else 1e-12  # jaxopt: a bound on ‖Jᵀr‖
    sol = solve(CHAIN, init, data, method=method, max_steps=60, rtol=1e-10, atol=atol)
    assert int(sol.result) == 0, (method, int(sol.result), float(sol.cost))
    assert rot_error(sol.value["rot"], truth["rot"]) < 1e-6
    np.testing.assert_allclose(sol.value["trans"], truth["trans"], atol=1e-6)
    assert float(sol.cost) < 1e-12
    assert set(sol.costs) == {"ori", "acc", "trans"}


def test_manifold_parametrisations_converge_alike():
    """Re-anchored exp(δ^)R updates ("lm", eq. 2.60) and a fixed anchor (optimistix)."""
    truth, init, data = motion(8, seed=3)
    steps = {}
    for method in ("lm", "optx_lm"):
        sol = solve(CHAIN, init, data, method=method, max_steps=60, rtol=1e-10, atol=1e-12)
        assert rot_error(sol.value["rot"], truth["rot"]) < 1e-6
        assert int(sol.result) == 0, (method, int(sol.result))
        steps[method] = int(sol.num_steps)
    # Both stop on their own (optimistix's trust region takes more steps: 41 here).
    assert max(steps.values()) < 60, steps


# --- the structured linear solve ------------------------------------------------------


def _linear_system(T, with_wide_band):
    terms = list(CHAIN.terms) + [Term("prior", e_prior, weight=0.5)]
    if with_wide_band:
        terms.append(Term("smooth2", e_smooth2, weight=0.3, bandwidth=2))
    problem = Problem(terms, rotations=("rot",))
    _, init, data = motion(T, seed=1)
    args = (problem, FrameLayout.of(init), to_manifold(init, ("rot",)), data, None)
    return args, 0.01 * jnp.ones((T, 12)), _bandwidths(problem, False)


def test_structured_step_equals_dense_step():
    """Gauss-Newton and damped (optimistix's own [J; √λ I] operator) steps, 1e-7.

    Bandwidths 0, 1 and 2 together, and T = 9 not a multiple of the super-block size 4.
    """
    from optimistix._solver.levenberg_marquardt import _Damped

    args, y, bw = _linear_system(9, True)

    @jax.jit
    def steps(y):
        r, lin = jax.linearize(lambda d: _residual_fn(d, args), y)
        J = lx.FunctionLinearOperator(lin, jax.eval_shape(lambda: y))
        damped = lx.FunctionLinearOperator(_Damped(J, jnp.asarray(0.3)), jax.eval_shape(lambda: y))
        out = []
        for op, vec in ((J, r), (damped, (r, jnp.zeros_like(y)))):
            for solver in (BandedNormalCholesky(bandwidths=bw), lx.QR()):
                out.append(lx.linear_solve(op, vec, solver, throw=False).value)
        return out

    gn, gn_dense, lm, lm_dense = steps(y)
    for a, b in ((gn, gn_dense), (lm, lm_dense)):
        # 1e-7: the banded substitutions multiply by explicit inverse factors (faster
        # on XLA-CPU than triangular solves in a scan; measured 1.8e-8 here).
        assert float(jnp.max(jnp.abs(a - b))) < 1e-7 * max(float(jnp.max(jnp.abs(b))), 1.0)


def test_banded_solver_rejects_misuse():
    y = jnp.zeros((4, 2))
    J = lx.FunctionLinearOperator(lambda v: {"a": v, "b": 2 * v}, jax.eval_shape(lambda: y))
    with pytest.raises(ValueError, match="bandwidths"):
        lx.linear_solve(J, {"a": y, "b": y}, BandedNormalCholesky(bandwidths=(0,)), throw=False)
    flat = lx.FunctionLinearOperator(lambda v: v.reshape(-1), jax.eval_shape(lambda: y))
    with pytest.raises(ValueError, match="frame axis"):
        lx.linear_solve(flat, jnp.zeros(8), BandedNormalCholesky(bandwidths=0), throw=False)


# --- LM acceptance --------------------------------------------------------------------


def test_optx_lm_never_accepts_a_cost_increase():
    truth, init, data = motion(6, seed=2)
    init = {"rot": init["rot"] * 4.0, "trans": init["trans"]}  # far start: rejections happen
    losses = []

    def record(**kw):
        jax.debug.callback(lambda v: losses.append(float(v)), kw["loss_last_accepted_step"][1])

    args = (CHAIN, FrameLayout.of(init), to_manifold(init, ("rot",)), data, None)
    solver = optx.LevenbergMarquardt(
        rtol=1e-10, atol=1e-12, verbose=record, linear_solver=BandedNormalCholesky(bandwidths=_bandwidths(CHAIN, False))
    )
    optx.least_squares(_residual_fn, solver, jnp.zeros((6, 12)), args, max_steps=40, throw=False)
    losses = losses[1:]  # the first entry is optimistix's placeholder before any evaluation
    assert len(losses) > 5 and losses[-1] < 1e-2 * losses[0]
    assert all(b <= a for a, b in zip(losses, losses[1:])), losses


def test_lm_never_accepts_a_cost_increase():
    truth, init, data = motion(6, seed=2)
    init = {"rot": init["rot"] * 4.0, "trans": init["trans"]}
    costs = [float(CHAIN.cost(init, data))]
    for steps in range(1, 9):  # max_steps is a traced loop bound for "lm": one compilation
        sol = solve(CHAIN, init, data, method="lm", max_steps=steps, rtol=0.0, atol=0.0)
        costs.append(float(sol.cost))
    # A rejected step leaves the cost unchanged, but costs[0] comes from `Problem.cost`
    # and the rest from the solver's own evaluation: allow their last-bit difference.
    assert all(b <= a * (1 + 1e-12) for a, b in zip(costs, costs[1:])), costs
    assert costs[-1] < 1e-2 * costs[0]


# --- padding, batches, dtypes ---------------------------------------------------------


@pytest.mark.parametrize("method", ["lm", "optx_lm"])
def test_padded_frames_do_not_change_the_result(method):
    truth, init, data = motion(6)
    ref = solve(CHAIN, init, data, method=method, max_steps=50, rtol=1e-10, atol=1e-12)
    rng = np.random.default_rng(5)
    junk = lambda x: jnp.concatenate([x, jnp.asarray(rng.normal(size=(3,) + x.shape[1:]))])  # noqa: E731
    init_p = jax.tree_util.tree_map(junk, init)
    data_p = jax.tree_util.tree_map(junk, data)
    mask = jnp.arange(9) < 6
    sol = solve(CHAIN, init_p, data_p, frame_mask=mask, method=method, max_steps=50, rtol=1e-10, atol=1e-12)
    for k in ref.value:
        np.testing.assert_allclose(sol.value[k][:6], ref.value[k], atol=1e-8)
        np.testing.assert_allclose(sol.value[k][6:], init_p[k][6:], atol=1e-12)  # padded: untouched
    assert abs(float(sol.cost) - float(ref.cost)) < 1e-10


# r_t = exp(x_t) - target_t: a minimiser iff target > 0; for target < 0 the infimum is at
# x → -∞ (no minimiser); a NaN target without a mask poisons the cost.
EXP = Problem([Term("exp", lambda p, d: (jnp.exp(p["x"]) - d["target"])[..., None])])


def _exp_problem():
    return EXP


@pytest.mark.parametrize("method", ["lm", "optx_lm"])
def test_batch_reports_converging_and_diverging_problems(method):
    problem = _exp_problem()
    seqs = [{"x": jnp.zeros((4, 1))}, {"x": jnp.zeros((3, 1))}, {"x": jnp.zeros((4, 1))}]
    datas = [{"target": jnp.full((T, 1), v)} for T, v in ((4, 2.0), (3, -1.0), (4, np.nan))]
    params, mask = pad_sequences(seqs)
    data, _ = pad_sequences(datas)
    sol = solve_batch(problem, params, data, mask, method=method, max_steps=15, rtol=1e-8, atol=1e-10)
    assert sol.result.shape == (3,) and sol.num_steps.shape == (3,) and sol.cost.shape == (3,)
    ok, no_minimum, nan = (int(r) for r in sol.result)
    R = optx.RESULTS
    assert ok == R.successful._value
    assert no_minimum == R.nonlinear_max_steps_reached._value
    assert nan == R.nonlinear_divergence._value  # non-finite cost
    assert result_message(no_minimum).startswith("The maximum number of steps")
    np.testing.assert_allclose(sol.value["x"][0], np.log(2.0), atol=1e-6)
    assert int(sol.num_steps[0]) < int(sol.num_steps[1]) == 15
    assert np.isfinite(np.asarray(sol.value["x"][:2])).all()


def test_batch_of_one_equals_unbatched():
    truth, init, data = motion(6)
    one = solve(CHAIN, init, data, method="lm", max_steps=40)
    init1, data1 = jax.tree_util.tree_map(lambda x: x[None], (init, data))
    batch = solve_batch(CHAIN, init1, data1, method="lm", max_steps=40)
    for k in one.value:
        np.testing.assert_allclose(batch.value[k][0], one.value[k], rtol=1e-12, atol=1e-12)
    assert int(batch.num_steps[0]) == int(one.num_steps) and int(batch.result[0]) == int(one.result)


def test_per_sequence_tolerances():
    params = {"x": jnp.zeros((2, 3, 1))}
    data = {"target": jnp.full((2, 3, 1), 2.0)}
    sol = solve_batch(_exp_problem(), params, data, method="lm", max_steps=40,
                      rtol=jnp.array([1e-1, 1e-12]), atol=jnp.array([1e-1, 1e-14]))  # fmt: skip
    assert int(sol.num_steps[0]) < int(sol.num_steps[1])
    assert (np.asarray(sol.result) == 0).all()


def test_float32_default_and_float64_on_request():
    truth, init, data = motion(6, dtype=jnp.float32)
    data32 = jax.tree_util.tree_map(lambda x: x.astype(jnp.float32), data)
    sol = solve(CHAIN, init, data32, method="lm", max_steps=40)
    assert sol.value["rot"].dtype == jnp.float32 and bool(jnp.isfinite(sol.cost))
    assert rot_error(sol.value["rot"], truth["rot"]) < 1e-3
    x32 = {"x": jnp.zeros((3, 1), jnp.float32)}
    sol64 = solve(_exp_problem(), x32, {"target": jnp.full((3, 1), 2.0)}, method="lm", dtype=jnp.float64)
    assert sol64.value["x"].dtype == jnp.float64 and sol64.cost.dtype == jnp.float64


# --- robust losses and masks ----------------------------------------------------------


@pytest.mark.parametrize("loss", [GemanMcClure(0.5), Huber(0.3), Cauchy(0.4)])
def test_robust_minimiser_matches_robust_cost(loss):
    rng = np.random.default_rng(0)
    points = np.concatenate([rng.normal(scale=0.1, size=(20, 2)), rng.normal(loc=3.0, size=(5, 2))])
    problem = Problem([Term("fit", lambda p, d: p["x"][:, None, :] - d["pts"], loss=loss)])
    data = {"pts": jnp.asarray(points)[None]}
    x0 = {"x": jnp.asarray([[0.3, -0.2]])}
    sol = solve(problem, x0, data, method="lm", max_steps=100, rtol=1e-12, atol=1e-14)

    def robust_cost(x):
        return 0.5 * np.sum(np.asarray(loss.rho(jnp.asarray(np.sum((x - points) ** 2, 1)))))

    ref = scipy.optimize.minimize(robust_cost, np.array([0.3, -0.2]), method="Nelder-Mead",
                                  options={"xatol": 1e-10, "fatol": 1e-14, "maxiter": 4000})  # fmt: skip
    np.testing.assert_allclose(np.asarray(sol.value["x"][0]), ref.x, atol=1e-6)
    np.testing.assert_allclose(float(sol.cost), robust_cost(ref.x), rtol=1e-8)
    # Robust: far from the least-squares mean, which the outliers drag towards (3, 3).
    assert np.linalg.norm(np.asarray(sol.value["x"][0])) < 0.1 < np.linalg.norm(points.mean(0))


@pytest.mark.parametrize("loss", [GemanMcClure(0.5), Huber(0.3), Cauchy(0.4)])
def test_robust_residual_gradients_finite_at_zero(loss):
    e = jnp.zeros(3)
    assert np.isfinite(np.asarray(jax.jacfwd(loss)(e))).all()
    np.testing.assert_allclose(jax.jacfwd(loss)(e + 0.2), jax.jacrev(loss)(e + 0.2), atol=1e-12)
    np.testing.assert_allclose(jax.jacfwd(loss)(e), np.eye(3), atol=1e-12)


def test_masks_drop_nan_observations():
    truth, init, data = motion(8)
    holey = dict(data)
    holey["R"] = data["R"].at[2, 1].set(jnp.nan).at[5].set(jnp.nan)
    holey["acc"] = data["acc"].at[3, 0].set(jnp.nan)
    costs = jax.jit(CHAIN.costs)(init, holey)
    assert all(np.isfinite(float(c)) for c in costs.values())
    grads = jax.jit(jax.grad(lambda p: CHAIN.cost(p, holey)))(init)
    assert all(np.isfinite(np.asarray(g)).all() for g in grads.values())
    # Dropping = excluding exactly those rows: same costs as explicit boolean masks.
    explicit = Problem(
        [
            Term("ori", e_ori, mask=lambda d: jnp.ones((8, 3), bool).at[2, 1].set(False).at[5].set(False)),
            Term("acc", e_acc, weight=0.05, bandwidth=1, mask=lambda d: jnp.ones((8, 3), bool).at[3, 0].set(False)),
            CHAIN.terms[2],
        ],
        rotations=("rot",),
    )
    for k, c in jax.jit(explicit.costs)(init, data).items():
        np.testing.assert_allclose(float(costs[k]), float(c), rtol=1e-12)
    sol = solve(CHAIN, init, holey, method="lm", max_steps=60, rtol=1e-10, atol=1e-12)
    assert int(sol.result) == 0 and float(sol.cost) < 1e-12
    assert np.isfinite(np.asarray(sol.value["rot"])).all()
    # Frame 5 lost all orientations (only accelerations and the chain see it); the others
    # are recovered exactly.
    keep = np.arange(8) != 5
    assert rot_error(sol.value["rot"][keep], truth["rot"][keep]) < 1e-6


# --- errors ---------------------------------------------------------------------------


def test_clear_errors():
    truth, init, data = motion(5)
    with pytest.raises(ValueError, match="leading frame axis"):
        solve(CHAIN, {"rot": init["rot"], "trans": init["trans"][:4]}, data)
    with pytest.raises(ValueError, match="method"):
        solve(CHAIN, init, data, method="bfgs")
    with pytest.raises(ValueError, match="unique"):
        Problem([Term("a", e_ori), Term("a", e_acc)])
    bad = Problem([Term("flat", lambda p, d: jnp.zeros((3,)))])
    with pytest.raises(ValueError, match="one row per frame"):
        bad.cost({"x": jnp.zeros((4, 1))}, None)


def test_reads_name_columns_and_are_validated():
    layout = Problem([Term("a", e_ori)]).layout({"pose": jnp.zeros((2, 24, 3)), "trans": jnp.zeros((2, 3))})
    assert layout.columns((("pose", (0, 2)), ("trans", None))) == (0, 1, 2, 6, 7, 8, 72, 73, 74)
    assert layout.columns(None) == tuple(range(75))
    assert layout.columns((("missing", None),)) == ()
    with pytest.raises(ValueError, match="out of range"):
        layout.columns((("pose", (24,)),))
    with pytest.raises(ValueError, match="pairs"):
        Term("a", e_ori, reads=("pose",))
