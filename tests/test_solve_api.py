"""`jaxmocap.solve`'s public surface: solver objects, the one-release aliases of the old
loose keywords and names, and `solve_batch` taking what `solve` takes."""

import importlib
import warnings

import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest

import jaxmocap.solve as S
from jaxmocap.solve import Problem, Term, VonMarcardLM, solve, solve_batch
from jaxmocap.solve.options import DEPRECATED_KEYWORDS, SOLVERS, OptxGaussNewton, resolve

# r_t = exp(x_t) - target_t (minimiser log target): tiny, non-linear, per frame.
EXP = Problem([Term("exp", lambda p, d: (jnp.exp(p["x"]) - d["target"])[..., None])])
X0 = {"x": jnp.zeros((3, 1))}
DATA = {"target": jnp.full((3, 1), 2.0)}


def _same(a, b):
    for k in a.value:
        np.testing.assert_array_equal(np.asarray(a.value[k]), np.asarray(b.value[k]))
    assert int(a.num_steps) == int(b.num_steps) and int(a.result) == int(b.result)
    np.testing.assert_array_equal(np.asarray(a.cost), np.asarray(b.cost))


@pytest.mark.parametrize(
    "old, new",
    [
        (dict(rtol=1e-9, atol=1e-11), VonMarcardLM(rtol=1e-9, atol=1e-11)),
        (
            dict(method="lm", damping="marquardt", tridiagonal="scan"),
            VonMarcardLM(damping="marquardt", tridiagonal="scan"),
        ),
        (dict(factor_dtype=jnp.float32), VonMarcardLM(factor_dtype=jnp.float32)),
        (dict(method="optx_gn", rtol=1e-9, atol=1e-11), OptxGaussNewton(rtol=1e-9, atol=1e-11)),
    ],
    ids=["tolerances", "damping-band", "factor-dtype", "optx-gn"],
)
def test_old_keywords_warn_and_give_the_same_solve(old, new):
    with pytest.warns(DeprecationWarning, match=f"pass solver={type(new).__name__}\\(") as record:
        before = solve(EXP, X0, DATA, max_steps=20, **old)
    assert record[0].filename == __file__  # the warning points at the caller's line
    _same(before, solve(EXP, X0, DATA, max_steps=20, solver=new))


def test_old_keywords_in_solve_batch_per_sequence_tolerances():
    params, data = {"x": jnp.zeros((2, 3, 1))}, {"target": jnp.full((2, 3, 1), 2.0)}
    rtol, atol = jnp.array([1e-1, 1e-12]), jnp.array([1e-1, 1e-14])
    with pytest.warns(DeprecationWarning, match=r"solve_batch\(rtol=, atol=\) is deprecated"):
        before = solve_batch(EXP, params, data, max_steps=40, rtol=rtol, atol=atol)
    after = solve_batch(EXP, params, data, max_steps=40, solver=VonMarcardLM(rtol=rtol, atol=atol))
    np.testing.assert_array_equal(np.asarray(before.value["x"]), np.asarray(after.value["x"]))
    np.testing.assert_array_equal(np.asarray(before.num_steps), np.asarray(after.num_steps))
    assert int(after.num_steps[0]) < int(after.num_steps[1])  # the tolerances are per sequence


@pytest.mark.parametrize("keyword", DEPRECATED_KEYWORDS)
def test_a_solver_and_a_loose_option_conflict(keyword):
    value = {"method": "lm", "damping": "levenberg", "factor_dtype": jnp.float32, "tridiagonal": "scan"}.get(
        keyword, 1e-3
    )
    for solver in (VonMarcardLM(), optx.LevenbergMarquardt(rtol=1e-6, atol=1e-8)):
        with pytest.raises(ValueError, match=f"got solver= and also {keyword}=.*set them on it instead"):
            solve(EXP, X0, DATA, solver=solver, **{keyword: value})


def test_damping_belongs_to_the_lm():
    with pytest.raises(ValueError, match="damping is an option of method 'lm'"):
        solve(EXP, X0, DATA, method="optx_lm", damping="marquardt")


def test_equal_solver_objects_share_one_program():
    # What the jitted solve sees as static: equal for new tolerances (they travel as
    # traced arrays) and for spelling out a default; the damping picks another program.
    def static(solver):
        return resolve(solver, {}, jnp.float32, 20, "solve").solver

    base = static(VonMarcardLM(rtol=1e-5, atol=1e-7))
    assert base == static(VonMarcardLM(rtol=1e-9, atol=1e-11)) == static(VonMarcardLM(factor_dtype=None))
    assert hash(base) == hash(static(VonMarcardLM(rtol=jnp.asarray(1e-3))))
    assert base != static(VonMarcardLM(damping="marquardt"))
    how = resolve(VonMarcardLM(rtol=1e-9), {}, jnp.float32, 20, "solve")
    assert how.rtol.dtype == jnp.float32 and float(how.rtol) == np.float32(1e-9)
    assert isinstance(how.max_steps, jnp.ndarray)  # a traced loop bound: no program per cap


def test_solve_batch_takes_solver_and_adjoint():
    params, data = {"x": jnp.zeros((2, 3, 1))}, {"target": jnp.stack([jnp.full((3, 1), 2.0), jnp.full((3, 1), 3.0)])}
    lm = VonMarcardLM(rtol=1e-9, atol=1e-11, damping="marquardt")
    batch = solve_batch(EXP, params, data, max_steps=30, solver=lm)
    for b in range(2):
        one = solve(EXP, {"x": params["x"][b]}, {"target": data["target"][b]}, max_steps=30, solver=lm)
        np.testing.assert_allclose(batch.value["x"][b], one.value["x"], rtol=1e-12, atol=1e-12)
        assert int(batch.num_steps[b]) == int(one.num_steps)
    np.testing.assert_allclose(batch.value["x"][:, :, 0], np.log([[2.0] * 3, [3.0] * 3]), rtol=1e-6)

    used = []

    class Recording(optx.ImplicitAdjoint):
        def apply(self, primal_fn, rewrite_fn, inputs, tags):
            used.append(type(self).__name__)
            return super().apply(primal_fn, rewrite_fn, inputs, tags)

    solve_batch(EXP, params, data, max_steps=30, solver=lm, adjoint=Recording())
    assert used == ["Recording"]
    # check_bandwidth: tests/test_bad_inputs.py ('batch-check-bandwidth').


def test_solvers_by_old_name():
    assert tuple(SOLVERS) == S.solver.METHODS == ("lm", "optx_lm", "optx_gn", "jaxopt")
    assert SOLVERS["lm"] is VonMarcardLM


def test_the_public_api_is_small_and_imports():
    assert len(S.__all__) <= 20 and len(set(S.__all__)) == len(S.__all__)
    for name in S.__all__:
        assert getattr(S, name) is not None, name
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        exec(f"from jaxmocap.solve import {', '.join(S.__all__)}", {})


@pytest.mark.parametrize("name", sorted(S._MOVED))
def test_old_names_resolve_for_one_release(name):
    where = importlib.import_module(f"jaxmocap.solve.{S._MOVED[name]}")
    with pytest.warns(DeprecationWarning, match=f"import it from jaxmocap.solve.{S._MOVED[name]}"):
        old = getattr(S, name)
    assert old is getattr(where, name)
    assert name not in S.__all__


def test_unknown_names_and_submodules():
    with pytest.raises(AttributeError, match="no attribute 'nonsense'"):
        S.nonsense  # noqa: B018
    from jaxmocap.solve import options, solver  # submodules still import as modules

    assert options.VonMarcardLM is solver.VonMarcardLM is VonMarcardLM
