"""Gradients through a solve (the implicit adjoint of jaxmocap.solve) against finite
differences: term weights, observations, per-sequence constants, a gauge freedom, padded
batches. A file of its own, so that its compilations run beside tests/test_solve.py's."""

import functools

import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap.solve import Problem, Term, VonMarcardLM, solve, solve_batch
from jaxmocap.timeseries import second_difference
from solve_chain import _variants

# --- gradients through a solve ---------------------------------------------------------------


def _grad_problem():
    problems, data = _variants(6, seed=5)
    problem, params = problems["border"]
    small = [t for t in problem.terms if t.name not in ("smooth2", "prior")]  # keep compilation short
    # Noisy accelerations: the terms disagree at the optimum, so every weight matters.
    noise = np.random.default_rng(6).normal(0, 2.0, data["acc"].shape)
    return Problem(small, dict(problem.unknowns)), params, dict(data, acc=data["acc"] + noise)


def _scalar(v, frames=6):
    """A scalar of the solution that depends on every kind of unknown (frames: unpadded)."""
    return (jnp.sum(jnp.sin(v["rot"][..., :frames, :, :])) + jnp.sum(v["trans"][..., :frames, :] * jnp.arange(3.0))
            + jnp.sum(v["heading"]) + 3 * jnp.sum(v["offset"][..., 0]))  # fmt: skip


_KW = dict(max_steps=100, solver=VonMarcardLM(rtol=1e-13, atol=1e-15))


def _solution_scalar(problem, params, data, w_acc, obs, const):
    from jaxmocap.solve.batch import with_weights

    data = dict(data, trans=data["trans"].at[2, 1].set(obs) + const * jnp.asarray([1.0, 0.5, 2.0]))
    return _scalar(solve(with_weights(problem, {"acc": w_acc}), params, data, **_KW).value)


@functools.lru_cache(maxsize=None)
def _grad_fixture():
    """The problem, its parameters θ = (w_acc, one observation, a per-sequence constant), the
    jitted scalar and its jitted value and gradient: compiled once for the tests below."""
    problem, params, data = _grad_problem()
    # strongly typed float64, as the finite differences and the vmapped weights pass them: one compile each
    theta = (jnp.asarray(0.05, jnp.float64), data["trans"][2, 1], jnp.asarray(0.01, jnp.float64))
    f = jax.jit(lambda w, o, c: _solution_scalar(problem, params, data, w, o, c))
    return problem, params, data, theta, f, jax.jit(jax.value_and_grad(f, argnums=(0, 1, 2)))


def _five_point(f, theta, i, eps=1e-3):
    """Five-point central difference of f along θ_i. The solves end within ~2e-10 of the
    scalar's exact value (where the LM stops varies with θ), which this rule multiplies by
    ~1.5/eps: at eps = 1e-4 that is up to 2.5e-4 of d/dw_acc (0.0108) and fails; at 1e-3,
    3e-6 to 2e-5 of it with either factorisation of the band, truncation included. (The
    two-point rule at 1e-4 kept a 4e-4 truncation error.)"""

    def shifted(h):
        t = [np.asarray(v, np.float64).copy() for v in theta]
        t[i] = t[i] + h
        return float(f(*t))

    return (8 * (shifted(eps) - shifted(-eps)) - (shifted(2 * eps) - shifted(-2 * eps))) / (12 * eps)


def test_gradients_through_solve_match_finite_differences():
    """d(solution scalar) / d(term weight, observation, per-sequence constant) by implicit
    differentiation equals central differences, float64. (Under vmap: the padded batch
    test below.)"""
    _, _, _, theta, f, value_and_grad = _grad_fixture()
    _, grads = value_and_grad(*theta)
    assert abs(float(grads[0])) > 1e-3
    for i, g in enumerate(grads):
        fd = _five_point(f, theta, i)
        assert abs(float(g) - fd) <= 1e-4 * abs(fd) + 1e-6, (i, float(g), fd)


def test_gradient_through_solve_with_a_gauge_freedom():
    """A cost blind to a constant + linear drift (SIP's translation, seen through second
    differences only) has a singular Hessian; a gauge-invariant output still gets its
    gradient (the adjoint's relative ridge), equal to central differences."""
    T = 12
    data = {
        "acc": jnp.sin(jnp.arange(T, dtype=jnp.float64))[:, None],
        "obs": jnp.cos(jnp.arange(T, dtype=jnp.float64))[:, None],
    }

    def f(log_w):
        problem = Problem([
            Term("acc", lambda p, d: second_difference(p["x"]) - d["acc"], jnp.exp(log_w), 1),
            Term("obs", lambda p, d: second_difference(p["x"]) - d["obs"], 1.0, 1),
        ])  # fmt: skip
        x = solve(
            problem, {"x": jnp.zeros((T, 1))}, data, max_steps=100, solver=VonMarcardLM(rtol=1e-12, atol=1e-14)
        ).value["x"]
        return jnp.sum(second_difference(x)[1:-1] ** 2)

    g = float(jax.grad(f)(0.0))
    # The solves stop on the cost (rtol 1e-12), which pins this output to ~1e-9 only: a
    # step of 1e-4 left differences at that level (1 % off under another LLVM -O level).
    fd = float((f(1e-3) - f(-1e-3)) / 2e-3)
    assert np.isfinite(g) and abs(g - fd) <= 1e-4 * abs(fd), (g, fd)


def test_gradient_through_a_padded_batch():
    """Padded frames change neither the solution nor its gradient w.r.t. per-member weights,
    and a batch of two weights gives each member its own solve's gradient (vmap)."""
    problem, params, data, theta, _, value_and_grad = _grad_fixture()
    rng = np.random.default_rng(8)

    def pad(x):  # two junk frames on every per-frame leaf
        return jnp.concatenate([x, jnp.asarray(rng.normal(size=(2,) + x.shape[1:]))]) if x.shape[:1] == (6,) else x

    # the unpadded member: the observation and constant of θ applied as `_solution_scalar` does
    data = dict(data, trans=data["trans"].at[2, 1].set(theta[1]) + theta[2] * jnp.asarray([1.0, 0.5, 2.0]))
    pparams, pdata = {k: pad(v) for k, v in params.items()}, {k: pad(v) for k, v in data.items()}
    mask = jnp.arange(8) < 6

    def batched(w):  # w (2,): one weight per member; the members' scalars sum
        b = jax.tree_util.tree_map(lambda x: jnp.stack([x, x]), (pparams, pdata))
        sol = solve_batch(problem, *b, jnp.stack([mask, mask]), weights={"acc": w}, **_KW)
        values = jax.vmap(_scalar)(sol.value)
        return jnp.sum(values), values

    (_, vb), gb = jax.value_and_grad(batched, has_aux=True)(jnp.stack([theta[0], 0.2]))
    for b, w in enumerate((theta[0], jnp.asarray(0.2, jnp.float64))):
        vs, gs = value_and_grad(w, *theta[1:])  # the single solve, compiled once for both tests
        np.testing.assert_allclose(vb[b], vs, rtol=1e-9)
        np.testing.assert_allclose(gb[b], gs[0], rtol=1e-6)
    assert abs(float(gb[0] - gb[1])) > 1e-3 * abs(float(gb[0]))  # the weights matter
