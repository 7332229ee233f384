"""IT, SOP and SIP (von Marcard ch. 3): energies at the truth, the prior, and the must-shows.

Short sequences (30-45 frames), the low-resolution default body, float32 like the
methods' default use; weights are arrays, so the ablation runs reuse compiled solves.
"""

from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxmocap import metrics
from jaxmocap.app.scenarios import inertial_setup
from jaxmocap.body import default_body
from jaxmocap.energies import imu as E
from jaxmocap.methods import inertial as I
from jaxmocap.priors import PosePrior, default_pose_prior, joint_limits
from jaxmocap.sensors import IMUErrorModel, ScenarioConfig, make_scenario

# The repository's data sit beside the checkout (../shared), in CI as here.
CMU_JUMP = Path(__file__).resolve().parents[2] / "shared" / "data" / "cmu" / "02_04.amc"


@pytest.fixture(scope="module")
def body():
    return default_body("low")


def _motion():
    # A real jump, never silently a procedural stand-in: the thresholds below were set on it.
    assert CMU_JUMP.is_file(), f"{CMU_JUMP} is missing: these tests need ../shared/data/cmu beside the checkout"
    return CMU_JUMP


def _scenario(body, imu_set, errors, frames):
    cfg = ScenarioConfig(fps=30.0, max_frames=frames, imu_set=imu_set, imu_errors=errors, betas_std=0.0)
    return make_scenario([_motion()], cfg, seed=0, body=body)


@pytest.fixture(scope="module")
def clean13_scenario(body):
    return _scenario(body, "totalcapture13", IMUErrorModel.off(), 30)


@pytest.fixture(scope="module")
def clean13(body, clean13_scenario):
    sc = clean13_scenario
    setup = inertial_setup(sc, 0, body, dtype=jnp.float64)
    return sc.sequence(0), setup


@pytest.fixture(scope="module")
def noisy6(body):
    """The jump seen by 6 IMUs with realistic errors, 48 frames, and its first 45 frames'
    SOP and SIP fits: the must-show, the padded batch and the Jacobian checks share this
    one scenario and these compiled SOP and SIP solves."""
    sc = _scenario(body, "sip6", IMUErrorModel.xsens(), 48)
    setup48 = inertial_setup(sc, 0, body)
    setup45 = eqx_set_frames(setup48, 45)
    sop, _ = I.sparse_orientation_poser(setup45)
    sip = I.sparse_inertial_poser(setup45, init=sop, max_steps=15)
    return sc, setup48, setup45, sop, sip


def _truth_params(seq, setup):
    pose = jnp.asarray(seq["poses"][0], setup.pose0.dtype)
    return {"pose": _exp_all(pose), "trans": jnp.asarray(seq["trans"][0], pose.dtype)}


@eqx.filter_jit
def _residual_at(residual, params, data):
    # One compiled program per residual: run op by op, each was dozens of small ones.
    return residual(params, data)


@jax.jit
def _exp_all(w):
    from jaxmocap.rotation import axis_angle_to_matrix

    return axis_angle_to_matrix(w)


def _lm_step(problem, params, data, lam=0.1):
    """Cost and damped LM step of the engine's linearisation (float64), layout order."""
    from jaxmocap.solve.linearisation import Args

    st = Args(problem, data, None, problem.layout(params)).structure()
    return (st, *_jit_lm_step(problem, params, data, lam))


@eqx.filter_jit
def _jit_lm_step(problem, params, data, lam):
    # One compiled program per problem: run op by op, the linearisation was ~770 small ones.
    from jaxmocap.solve.linearisation import Args
    from jaxmocap.solve.linearisation import linearise
    from jaxmocap.solve.factorise import factor, solve_factored

    args = Args(problem, data, None, problem.layout(params))
    st = args.structure()
    normal, (gF, _, _), cost = linearise(params, args, st, jnp.float64, jnp.float64)
    step = solve_factored(factor(normal, st, lam), gF)[0]
    return cost, st.from_solver_order(gF), st.from_solver_order(step)


@pytest.mark.parametrize("robust", [False, True])
def test_analytic_jacobians_and_local_elimination_match_autodiff(body, noisy6, robust):
    """Eq. 3.17-3.29 against forward-mode AD: the LM step with analytic blocks, the
    declared `reads` and the hands/feet eliminated per frame equals the step with
    AD blocks over all 75 unknowns (no elimination), also with robust losses and a
    dropped sample."""
    from jaxmocap.solve import Cauchy, Huber, Problem, Term

    sc = noisy6[0]
    setup = eqx_set_frames(inertial_setup(sc, 0, body, dtype=jnp.float64), 10)
    data = eqx_set(setup.data, setup.data.acceleration.at[4, 2].set(jnp.nan))
    terms = [
        E.orientation_term(setup.bones, 6, 1.0, loss=Huber(0.05) if robust else None),
        E.acceleration_term(setup.bones, setup.fps, 6, 0.05, loss=Cauchy(2.0) if robust else None),
        E.mahalanobis_term(),
        E.joint_limit_term(),
    ]
    analytic = Problem(terms, rotations=("pose",))
    plain = Problem([Term(t.name, t.fn, t.weight, t.bandwidth, t.loss, t.mask) for t in terms], rotations=("pose",))
    # AD blocks over the declared columns only, with the elimination.
    ad_reads = Problem(
        [Term(t.name, t.fn, t.weight, t.bandwidth, t.loss, t.mask, t.reads) for t in terms], rotations=("pose",)
    )
    rng = np.random.default_rng(3)
    params = {
        "pose": jnp.asarray(sc.sequence(0)["poses"][0][:10]) + jnp.asarray(rng.normal(0, 0.3, (10, 24, 3))),
        "trans": jnp.asarray(rng.normal(0, 0.05, (10, 3))),
    }
    st, cost, g, step = _lm_step(analytic, params, data)
    st_ad, cost_ad, g_ad, step_ad = _lm_step(plain, params, data)
    assert st.nc == 51 and st.perm is not None  # 16 joints on sensor chains + translation
    assert st_ad.perm is None and st_ad.nc == 75
    assert abs(float(cost - cost_ad)) <= 1e-12 * float(cost_ad)
    assert float(jnp.max(jnp.abs(g - g_ad))) <= 1e-8 * float(jnp.max(jnp.abs(g_ad)))
    # The steps agree to the conditioning of JᵀJ + λI (fps² of E_acc squares into it).
    assert float(jnp.max(jnp.abs(step - step_ad))) <= 1e-6 * float(jnp.max(jnp.abs(step_ad)))
    if not robust:
        _, _, g_r, step_r = _lm_step(ad_reads, params, data)
        assert float(jnp.max(jnp.abs(g_r - g_ad))) <= 1e-8 * float(jnp.max(jnp.abs(g_ad)))
        assert float(jnp.max(jnp.abs(step_r - step_ad))) <= 1e-6 * float(jnp.max(jnp.abs(step_ad)))


def eqx_set(data, acceleration):
    import equinox as eqx

    return eqx.tree_at(lambda d: d.acceleration, data, acceleration)


def test_orientation_residual_vanishes_at_truth(clean13):
    seq, setup = clean13
    e = _residual_at(E.OrientationResidual(setup.bones), _truth_params(seq, setup), setup.data)
    assert e.shape == (30, 13, 3)
    assert float(jnp.abs(e).max()) < 1e-5


def test_acceleration_residual_small_at_truth(clean13):
    """The rigid sensor point (eq. 3.11) against skinned-vertex data: only the skinning
    and blend-shape motion of the vertex relative to its bone remains."""
    seq, setup = clean13
    e = _residual_at(E.AccelerationResidual(setup.bones, setup.fps), _truth_params(seq, setup), setup.data)
    inner = np.linalg.norm(np.asarray(e[1:-1]), axis=-1)
    scale = np.linalg.norm(np.asarray(setup.data.acceleration[1:-1]), axis=-1)
    assert np.median(inner) < 0.1 * np.median(scale) + 0.05


def test_global_acceleration_removes_gravity():
    R = jnp.eye(3)[None]
    a_s = jnp.array([[0.0, 9.81, 0.0]])
    np.testing.assert_allclose(E.global_acceleration(R, a_s), 0.0, atol=1e-6)


def test_prior_file_and_residuals():
    prior = default_pose_prior(jnp.float64)
    x = jnp.asarray(np.random.default_rng(0).normal(scale=0.3, size=(5, 69)))
    with np.load(__import__("jaxmocap.priors", fromlist=["x"]).DEFAULT_PRIOR_PATH) as f:
        mean, cov = f["mean"], f["covariance"]
    d2 = np.einsum("ti,ij,tj->t", x - mean, np.linalg.inv(cov), x - mean)  # eq. 3.14
    r = prior.mahalanobis_residual(x)
    np.testing.assert_allclose(np.sum(np.asarray(r) ** 2, -1), d2, rtol=1e-8)
    lo, up = joint_limits()
    assert np.all(lo < up)
    e = prior.limit_residual(jnp.asarray(np.stack([lo - 0.1, up + 0.2, 0.5 * (lo + up)])))
    np.testing.assert_allclose(e[0], -0.1, atol=1e-12)
    np.testing.assert_allclose(e[1], 0.2, atol=1e-12)
    np.testing.assert_allclose(e[2], 0.0)
    with pytest.raises(ValueError, match="69"):
        PosePrior.from_moments(np.zeros(3), np.eye(3))


def test_problem_composition_and_ablation(clean13):
    """Which terms exist is structure; weights (0 included) are data of one structure."""
    _, setup = clean13
    names = lambda w, acc=True: [t.name for t in I.inertial_problem(setup, w, acc).terms]  # noqa: E731
    assert names(I.SIPWeights()) == ["ori", "mahal", "limit", "acc"]
    assert names(I.SIPWeights(), acc=False) == ["ori", "mahal", "limit"]
    full, ablated = I.inertial_problem(setup), I.inertial_problem(setup, I.SIPWeights(acc=0.0, limit=0.0))
    same = jax.tree_util.tree_structure(full) == jax.tree_util.tree_structure(ablated)
    assert same  # an ablation reuses the compiled solve
    assert {t.name: float(t.weight) for t in ablated.terms}["acc"] == 0.0


def test_calibration_absorbs_mounting_rotation(body, clean13):
    """Eq. 3.3: a constant sensor-to-bone rotation is recovered from frame 0 and x₀."""
    seq, setup = clean13
    rng = np.random.default_rng(1)
    from jaxmocap.rotation import axis_angle_to_matrix

    mis = np.asarray(axis_angle_to_matrix(jnp.asarray(rng.normal(scale=0.3, size=(13, 3)))))
    ori = np.asarray(setup.data.orientation) @ mis
    acc_s = np.einsum("tsba,tsb->tsa", ori, np.asarray(setup.data.acceleration) + np.array([0, 9.81, 0]))
    s2 = I.calibrate(body, setup.bones, seq["imu_vertices"], ori, acc_s, seq["poses"][0][0], 30.0,
                     trans0=seq["trans"][0][0])  # fmt: skip
    np.testing.assert_allclose(s2.data.sensor_to_bone, mis, atol=1e-5)
    np.testing.assert_allclose(s2.data.acceleration, setup.data.acceleration, atol=1e-4)


def test_it_recovers_noise_free_poses(body, clean13_scenario):
    """Must-show: noise-free IMU-13, IT recovers the true poses (MPJAE < 1°).

    13 orientations leave two splits unobserved: spine1/2/3 between the pelvis and sternum
    sensors, and neck/head between the sternum and head sensors. The prior alone chooses
    them, so the neck's global rotation (TotalCapture's MPJAE set) is the prior's guess,
    not a measurement (15-25° off on this jump with the prior of every CMU clip). The head's
    global rotation, which the head sensor measures, stands in for it. The prior's weight is
    small (w_mahal = 1e-5): with the thesis's 0.003 and our learnt covariance it biases every
    sensed bone by ~3° (reported in experiments/).
    """
    sc = clean13_scenario
    setup = inertial_setup(sc, 0, body)
    poses, results = I.inertial_tracker(setup, I.SIPWeights(mahal=1e-5), sequential=False)
    assert poses.shape == (30, 24, 3)
    observed = tuple("head" if n == "neck" else n for n in metrics.JOINT_SETS["totalcapture_mpjae"])
    err = metrics.pose_errors(body, poses, sc.sequence(0)["poses"][0], angle_joints=observed)
    assert err["mpjae"].mean() < 1.0, err["mpjae"].mean(0)
    sensed = [i for i, n in enumerate(observed) if n != "head"]
    assert err["mpjae"][:, sensed].mean() < 0.2


def test_sip_beats_sop_on_noisy_dynamic_imu6(body, noisy6, capfd):
    """Must-show: dynamic motion, 6 IMUs with realistic errors: SIP < SOP on MPJPE and MPJAE.
    SOP's progress report (on by default from 2000 frames) leaves its poses unchanged."""
    sc, _, setup, sop, sip = noisy6
    capfd.readouterr()
    quiet, _ = I.sparse_orientation_poser(setup)
    assert capfd.readouterr().err == ""
    np.testing.assert_array_equal(np.asarray(quiet), np.asarray(sop))
    loud, _ = I.sparse_orientation_poser(setup, progress=True)
    err = capfd.readouterr().err
    assert "SOP frame 45/45" in err and "ETA" in err and err.endswith("\n")
    np.testing.assert_array_equal(np.asarray(loud), np.asarray(sop))
    assert np.isfinite(float(sip.solution.cost))
    truth = sc.sequence(0)["poses"][0][:45]
    e_sop = metrics.pose_errors(body, sop, truth)
    e_sip = metrics.pose_errors(body, sip.poses, truth)
    assert e_sip["mpjpe"].mean() < e_sop["mpjpe"].mean()
    assert e_sip["mpjae"].mean() < e_sop["mpjae"].mean()
    assert set(sip.solution.costs) == {"ori", "acc", "mahal", "limit"}


def test_dropped_samples_are_masked(body, clean13):
    seq, setup = clean13
    ori = np.array(setup.data.orientation)
    ori[5:8, 2] = np.nan
    data = setup.data
    import equinox as eqx

    data = eqx.tree_at(lambda d: d.orientation, data, jnp.asarray(ori))
    term = E.orientation_term(setup.bones)
    m = np.asarray(term.mask(data))
    assert m.shape == (30, 13) and not m[5:8, 2].any() and m.sum() == 30 * 13 - 3


def test_kinematics_and_log_match_the_references():
    """FK of only the sensed bones, and the energies' cheap log map, against the references."""
    from jaxmocap.body import SMPL_PARENTS, forward_kinematics
    from jaxmocap.body.kinematics import chain_transforms
    from jaxmocap.rotation import axis_angle_to_matrix, log_small, matrix_to_axis_angle

    bones = (18, 19, 4, 5, 15, 0)

    @jax.jit  # one program: op by op these maps were over a hundred small ones
    def maps(w, rest):
        local = axis_angle_to_matrix(w)
        R, p = chain_transforms(SMPL_PARENTS, local, rest, needed=bones)
        R_ref, p_ref = forward_kinematics(SMPL_PARENTS, local, jnp.broadcast_to(rest, (4, 24, 3)))
        # Derivative at the identity is finite and equals the identity map (d log = dω there).
        J = jax.jacfwd(lambda v: log_small(axis_angle_to_matrix(v)))(jnp.zeros(3))
        return R, p, R_ref, p_ref, log_small(local), matrix_to_axis_angle(local), J

    rng = np.random.default_rng(5)
    w = np.asarray(rng.normal(scale=0.8, size=(4, 24, 3)))
    w[0, 3], w[1, 4] = 0.0, [1e-5, 0.0, 0.0]  # identity and tiny angles
    rest = jnp.asarray(rng.normal(size=(24, 3)))
    R, p, R_ref, p_ref, log_cheap, log_ref, J = maps(jnp.asarray(w), rest)
    assert 23 not in R  # joints no sensor depends on are not computed
    for j in bones:
        np.testing.assert_allclose(R[j], R_ref[:, j], atol=1e-12)
        np.testing.assert_allclose(p[j], p_ref[:, j], atol=1e-12)
    np.testing.assert_allclose(log_cheap, log_ref, atol=1e-9)
    np.testing.assert_allclose(J, np.eye(3), atol=1e-9)


def test_dip_pickle_input(body, tmp_path):
    """DIP-IMU layout (virtual bone orientations, global accelerations): 17 → 6 sensors."""
    from jaxmocap.sensors import imu_placement, save_dip

    sc = _scenario(body, "xsens17", IMUErrorModel.off(), 12)
    (path,) = save_dip(sc, tmp_path)
    place = imu_placement(body, "xsens17")
    six = [7, 8, 11, 12, 0, 2]
    setup = I.from_dip(path, body, [place.bones[i] for i in six], [place.vertices[i] for i in six],
                       fps=30.0, sensors=six, dtype=jnp.float64)  # fmt: skip
    assert setup.bones == (18, 19, 4, 5, 15, 0)
    seq = sc.sequence(0)
    e = _residual_at(E.OrientationResidual(setup.bones), _truth_params(seq, setup), setup.data)
    assert float(jnp.abs(e).max()) < 1e-4


def test_padded_batch_equals_separate_fits(noisy6):
    """SIP on a padded batch (45 and 48 frames, analytic Jacobians, per-frame elimination,
    masks) gives the padded sequence its separate fit on its real frames."""
    _, long, short, sop, alone = noisy6
    stacked, mask = I.pad_setups([short, long])
    assert stacked.num_frames == 48 and mask.sum(1).tolist() == [45, 48]
    # Any start serves the longer member: only the padded one is compared.
    padded_sop = jnp.concatenate([sop, jnp.repeat(sop[-1:], 3, 0)])
    init = jnp.stack([padded_sop, padded_sop])
    batch = I.sparse_inertial_poser_batch(stacked, init, frame_mask=mask, max_steps=15)
    # The padded member against its own fit (an unpadded member equals its fit by
    # test_solve.py's batch-of-one test; the must-show's SIP fit is that fit here).
    np.testing.assert_allclose(batch.value["pose"][0, :45], alone.poses, atol=2e-3)
    assert abs(float(batch.cost[0]) - float(alone.solution.cost)) <= 1e-3 * float(alone.solution.cost)
    # Padded frames keep their start (up to the exp/log round trip of re-anchoring).
    np.testing.assert_allclose(batch.value["pose"][0, 45:], init[0, 45:], atol=1e-5)


def eqx_set_frames(setup, T):
    import equinox as eqx

    d = setup.data
    return eqx.tree_at(
        lambda s: (s.data.orientation, s.data.acceleration), setup, (d.orientation[:T], d.acceleration[:T])
    )
