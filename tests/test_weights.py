"""One weights convention and one result protocol across the methods (issue 49): fields
named after the terms they weight, one validation, to_dict / from_dict, `term_weights`
matching each method's `Problem`, VIP's old field name `prior` kept for one release; every
result a `FitResult` (solution, converged, params)."""

import types
import warnings

import jax.numpy as jnp
import numpy as np
import pytest

from jaxmocap.methods import interaction as ic
from jaxmocap.methods import multiview as mv
from jaxmocap.methods import visual_inertial as vip
from jaxmocap.methods.inertial import SIPResult, SIPWeights, inertial_problem
from jaxmocap.methods.weights import FitResult, Weights
from jaxmocap.solve import Solution

CLASSES = [SIPWeights, vip.VIPWeights, mv.MuVSWeights, ic.InterCapWeights]


@pytest.mark.parametrize("cls", CLASSES, ids=lambda c: c.__name__)
def test_every_weight_checked_and_named_in_the_message(cls):
    assert issubclass(cls, Weights)
    for name in cls.weight_names():
        for bad in (-1.0, float("nan"), float("inf")):
            with pytest.raises(ValueError, match=rf"{cls.__name__}\.{name} must be"):
                cls(**{name: bad})
        assert getattr(cls(**{name: 0.0}), name) == 0.0  # 0 switches the term off


def test_constants_are_not_weights():
    assert "sigma" not in mv.MuVSWeights.weight_names() and "steps" not in mv.MuVSWeights.weight_names()
    assert mv.MuVSWeights(temporal_noise=None, reference_focal=None).temporal_noise is None
    assert "body_points" not in ic.InterCapWeights.weight_names()
    assert "accel_delta" not in ic.InterCapWeights().term_weights()


@pytest.mark.parametrize("cls", CLASSES, ids=lambda c: c.__name__)
def test_to_dict_from_dict_round_trip(cls):
    w = cls()
    d = w.to_dict()
    assert cls.from_dict(d) == w
    first = cls.weight_names()[0]
    assert cls.from_dict({first: 0.5}) == w.replace(**{first: 0.5})
    with pytest.raises(ValueError, match=rf"{cls.__name__} has no field 'nonsense'"):
        cls.from_dict({"nonsense": 1.0})


def test_from_dict_takes_json_lists_as_tuples():
    w = mv.MuVSWeights(anneal=(5.0, 1.0), steps=(3, 4, 5))
    assert mv.MuVSWeights.from_dict({"anneal": [5.0, 1.0], "steps": [3, 4, 5]}) == w


def test_sip_term_weights_are_the_problem_s():
    w = SIPWeights(ori=2.0, acc=0.5, anthro=3.0, mahal=0.01, limit=0.2)
    setup = types.SimpleNamespace(bones=(4, 5, 18, 19, 15, 0), fps=60.0)  # what inertial_problem reads
    problem = inertial_problem(setup, w, acceleration=True)
    got = {t.name: float(t.weight) for t in problem.terms}
    want = w.term_weights(6)
    assert set(got) == set(want)
    np.testing.assert_allclose([got[k] for k in want], list(want.values()), rtol=1e-6)


@pytest.mark.parametrize("free_camera", [True, False])
def test_vip_term_weights_are_the_problem_s(free_camera):
    w = vip.VIPWeights(ori=2.0, acc=0.5, img=1e-3, mahal=0.01, limit=0.2, x0=0.3)
    bones = (4, 5, 18, 19, 15, 0)
    problem = vip._vip_problem(bones, 30.0, True, True, free_camera, 100.0)
    want = w.term_weights(len(bones), free_camera=free_camera)
    assert {t.name for t in problem.terms} == set(want)
    weighed = w.weigh(problem, np.float64, num_sensors=len(bones), free_camera=free_camera)
    n = len(bones) + free_camera  # the camera IMU counts as a sensor in eq. 4.20's mean
    assert {t.name: float(t.weight) for t in weighed.terms} == pytest.approx(want)
    assert want["ori"] == pytest.approx(2.0 / n) and want["mahal"] == 0.01


def test_muvs_term_weights_are_the_stages_terms():
    w = mv.MuVSWeights()
    floor = ((0.0, 1.0, 0.0), 0.0, (0,), (0.0,), 0.1)
    one = mv._stage_one_problem(10.0, 2, 2.0, True, floor=floor)
    two = mv._stage_two_problem(10.0, 2, 2.0, True, 30, 10, 0.05, floor=floor)
    assert {t.name for p in (one, two) for t in p.terms} == set(w.term_weights())
    weighed = w.weigh(one, np.float32, prior_factor=4.0)
    got = {t.name: float(t.weight) for t in weighed.terms}
    assert got["pose_prior"] == 4.0 * w.pose_prior and got["shape"] == 4.0 * w.shape
    assert got["keypoints"] == w.keypoints


def test_intercap_term_weights_are_the_problem_s():
    w = ic.InterCapWeights()
    names = ic._JOINT_TERMS + ("shape",)
    assert {t.name for t in ic._problem(names, w.sigma).terms} == set(w.term_weights())
    weighed = ic._weighted(names, w, np.float64, off=("contact",))
    got = {t.name: float(t.weight) for t in weighed.terms}
    assert got == {**w.term_weights(), "contact": 0.0}


def test_vip_prior_is_mahal_for_one_release():
    with pytest.warns(DeprecationWarning, match=r"VIPWeights.prior is now VIPWeights.mahal"):
        w = vip.VIPWeights(prior=0.0006)
    assert w == vip.VIPWeights(mahal=0.0006)
    with pytest.warns(DeprecationWarning):
        assert w.prior == 0.0006
    with pytest.warns(DeprecationWarning):
        assert w.replace(prior=0.1).mahal == 0.1
    with pytest.warns(DeprecationWarning):
        assert vip.VIPWeights.from_dict({"prior": 0.1}).mahal == 0.1
    with pytest.warns(DeprecationWarning), pytest.raises(ValueError, match="pass 'mahal' only"):
        vip.VIPWeights(prior=0.1, mahal=0.2)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert vip.VIPWeights(mahal=0.1).to_dict()["mahal"] == 0.1  # the new name: no warning
    with pytest.raises(AttributeError, match="no attribute 'nonsense'"):
        w.nonsense  # noqa: B018


def _solution(result, value=None) -> Solution:
    r = jnp.asarray(result)
    return Solution(value or {}, r, jnp.zeros_like(r), jnp.zeros(r.shape), {}, jnp.zeros(r.shape))


def test_every_method_result_is_a_fit_result():
    for cls in (SIPResult, vip.VIPResult, mv.MuVSResult, ic.InterCapResult):
        assert issubclass(cls, FitResult) and isinstance(cls.__dict__.get("params"), property), cls.__name__


def test_one_solve_converges_by_its_result_code():
    poses, trans = jnp.zeros((2, 24, 3)), jnp.ones((2, 3))
    ok = SIPResult(poses, trans, poses, _solution(0))
    assert bool(ok.converged) and ok.solutions == {"fit": ok.solution}
    assert ok.params["pose"] is poses and ok.params["trans"] is trans
    assert not bool(SIPResult(poses, trans, poses, _solution(2)).converged)


def test_staged_results_converge_when_every_stage_did_per_batch_member():
    z = np.zeros(1)
    mk = lambda sols: mv.MuVSResult(z, z, z, {}, {}, solution=sols)  # noqa: E731
    assert bool(mk({"joints_0": _solution(0), "temporal": _solution(0)}).converged)
    assert not bool(mk({"joints_0": _solution(0), "temporal": _solution(1)}).converged)
    batched = mk({"joints_0": _solution([0, 0, 1]), "temporal": _solution([0, 2, 0])})
    np.testing.assert_array_equal(batched.converged, [True, False, False])
    with pytest.raises(ValueError, match="MuVSResult records no solve"):
        mk({}).converged  # noqa: B018
    r = ic.InterCapResult(z, z, z, z, z, z, {}, {"human": _solution(0), "joint": _solution(0)})
    assert bool(r.converged) and set(r.params) == {"pose", "trans", "betas", "object_R", "object_t"}
