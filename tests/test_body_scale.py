"""Body scale from the accelerations (`inertial.estimate_body_scale`) and `scaled_body`.

One short synthetic walk (45 frames, 30 fps, low-resolution default body, float64) whose
subject is 1.1 × the model, noise-free sensors: one batched SIP solve over four candidates.
The input checks run before any solve.
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
    np.testing.assert_allclose(shaped_joints(big, zero), 1.2 * np.asarray(shaped_joints(body, zero)), rtol=1e-5, atol=1e-6)
    for bad in (0.0, -1.1, np.nan, np.inf, [1.0, 1.1]):
        with pytest.raises(ValueError, match="finite number > 0"):
            scaled_body(body, bad)


def test_estimate_recovers_a_subject_ten_percent_larger(make_setup):
    """Without the Mahalanobis prior nothing but the readings picks the size. Noise-free,
    the acceleration residual at the true poses is minimal at exactly 1.1 (only the rigid
    sensor point against the skinned vertex differs); what is left is the fitted poses'
    error and the parabola through candidates 0.1 apart. 0.025, a quarter of that spacing,
    separates the truth from both neighbouring candidates (measured: 1.095)."""
    est = I.estimate_body_scale(make_setup, scales=CANDIDATES, weights=I.SIPWeights(mahal=0.0), max_steps=25)
    assert abs(est.scale - TRUE_SCALE) < 0.025, (est.scale, est.profile)
    assert est.criterion == "data" and not est.at_edge and est.scales[est.best] in (1.05, 1.15)
    np.testing.assert_allclose(est.profile, est.costs["ori"] + est.costs["acc"])
    assert abs(est.scale_by("acc") - TRUE_SCALE) < 0.025
    assert est.solution.value["pose"].shape == (4, 45, 24, 3)


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
