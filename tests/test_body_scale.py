"""Body scale from the accelerations (`inertial.estimate_body_scale`) and `scaled_body`.

One short synthetic walk (45 frames, 30 fps, low-resolution default body, float64) whose
subject is 1.1 × the model, noise-free sensors: one batched SIP solve over four candidates
and one bisection round of two more. The input checks run before any solve.
"""

import jax.numpy as jnp
import numpy as np
import pytest

from jaxmocap.app.scenarios import inertial_setup
from jaxmocap.body import default_body, scaled_body, shaped_joints
from jaxmocap.methods import inertial as I
from jaxmocap.sensors import IMUErrorModel, ScenarioConfig, make_scenario

TRUE_SCALE = 1.1
CANDIDATES = (0.95, 1.05, 1.15, 1.25)  # the truth between two candidates: the parabola must find it


@pytest.fixture(scope="module")
def body():
    return default_body("low")


@pytest.fixture(scope="module")
def make_setup(body):
    cfg = ScenarioConfig(fps=30.0, max_frames=45, imu_set="sip6", imu_errors=IMUErrorModel.off(), betas_std=0.0)
    sc = make_scenario(["walk"], cfg, seed=0, body=scaled_body(body, TRUE_SCALE))
    return lambda s: inertial_setup(sc, 0, scaled_body(body, s), dtype=jnp.float64)


def test_scaled_body_scales_the_joints_and_keeps_the_dtype(body):
    big = scaled_body(body, np.float64(1.2))  # a NumPy float64 must not promote a float32 body
    assert big.dtype == body.dtype
    zero = np.zeros(body.num_betas, np.float32)
    np.testing.assert_allclose(
        shaped_joints(big, zero), 1.2 * np.asarray(shaped_joints(body, zero)), rtol=1e-5, atol=1e-6
    )
    for bad in (0.0, -1.1, np.nan, np.inf, [1.0, 1.1]):
        with pytest.raises(ValueError, match="finite number > 0"):
            scaled_body(body, bad)


@pytest.fixture(scope="module")
def start(make_setup):
    return I.sparse_orientation_poser(make_setup(1.0), I.SIPWeights(mahal=0.0))[0]  # SOP: size-free


@pytest.fixture(scope="module")
def estimate(make_setup, start):
    return I.estimate_body_scale(make_setup, start, scales=CANDIDATES, weights=I.SIPWeights(mahal=0.0), max_steps=25)


def test_estimate_recovers_a_subject_ten_percent_larger(estimate):
    """Without the Mahalanobis prior nothing but the readings picks the size. Noise-free,
    the true poses explain the accelerations on the body of exactly 1.1 (only the rigid
    sensor point against the skinned vertex differs), so there the fit need not bend away
    from the orientations (E_ori, the default criterion, is least); what is left is the
    fitted poses' error and the parabola. The bisection round adds 1.0, 1.1 or 1.1, 1.2
    around the best candidate; 0.0125, an eighth of the grid's spacing, is within the
    refined points' half spacing of the truth."""
    est = estimate
    assert abs(est.scale - TRUE_SCALE) < 0.0125, (est.scale, est.scales, est.profile)
    assert est.criterion == "ori" and not est.at_edge
    assert len(est.scales) == 6 and np.any(np.isclose(est.scales, 1.1)), est.scales  # one bisection round
    assert np.all(np.diff(est.scales) > 0)
    np.testing.assert_allclose(est.profile, est.costs["ori"])
    assert abs(est.scale_by("acc") - TRUE_SCALE) < 0.025
    assert est.solution.value["pose"].shape == (6, 45, 24, 3)


def test_a_given_size_is_plain_sip(make_setup, start, estimate):
    """When the size is known nothing is estimated: SIP on that body is what the estimate's
    own fit of that candidate is, poses and costs (the refined candidates come in order)."""
    k = int(np.flatnonzero(np.isclose(estimate.scales, 1.1))[0])
    sol = I.sparse_inertial_poser(
        make_setup(1.1), I.SIPWeights(mahal=0.0), init=start, max_steps=25, rtol=1e-4, atol=1e-4
    ).solution
    np.testing.assert_allclose(sol.value["pose"], estimate.solution.value["pose"][k], atol=1e-6)
    np.testing.assert_allclose(float(sol.costs["acc"]), estimate.costs["acc"][k], rtol=1e-6)


def test_the_truth_beyond_the_candidates_is_flagged(make_setup, start):
    """A bound that wins is reported (at_edge) and not refined: the true scale may lie beyond it."""
    # Four candidates, as CANDIDATES: the batched solve compiled for `estimate`.
    est = I.estimate_body_scale(
        make_setup, start, scales=(0.75, 0.8, 0.85, 0.9), weights=I.SIPWeights(mahal=0.0), max_steps=25
    )
    assert est.at_edge and est.scales[est.best] == 0.9 and len(est.scales) == 4


def test_bad_input_is_refused_before_solving(make_setup):
    with pytest.raises(ValueError, match="finite and > 0"):
        I.estimate_body_scale(make_setup, scales=(0.9, 0.0, 1.1))
    with pytest.raises(ValueError, match="finite and > 0"):
        I.estimate_body_scale(make_setup, scales=(-1.0, 1.0, 1.1))
    with pytest.raises(ValueError, match="at least 3"):
        I.estimate_body_scale(make_setup, scales=(1.0, 1.1))
    with pytest.raises(ValueError, match="at least 3"):
        I.estimate_body_scale(make_setup, scales=1.1)
    with pytest.raises(ValueError, match="distinct"):
        I.estimate_body_scale(make_setup, scales=(1.0, 1.1, 1.1))
    with pytest.raises(ValueError, match="criterion"):
        I.estimate_body_scale(make_setup, criterion="prior")
    with pytest.raises(ValueError, match="refine"):
        I.estimate_body_scale(make_setup, refine=-1)
    with pytest.raises(ValueError, match="callable"):
        I.estimate_body_scale(make_setup(1.0))
    with pytest.raises(ValueError, match="InertialSetup"):
        I.estimate_body_scale(lambda s: None)
    with pytest.raises(ValueError, match=r"init has shape \(44, 24, 3\)"):
        I.estimate_body_scale(make_setup, init=np.zeros((44, 24, 3)))
    with pytest.raises(ValueError, match=r"init_trans has shape"):
        I.estimate_body_scale(make_setup, init=np.zeros((45, 24, 3)), init_trans=np.zeros((45, 2)))
    short = lambda s: make_setup(s) if s < 1.0 else make_setup(s).subset(range(5))  # noqa: E731
    with pytest.raises(ValueError, match="equal sensor bones"):
        I.estimate_body_scale(short, scales=(0.9, 1.0, 1.1))
