"""The inertial posers' presets: the validated default, the thesis's values kept exact.

The "validated" preset must be what `experiments/defaults.py` chose on the development
subjects (defaults.json records the choice); the "thesis" preset must reproduce the
committed thesis-weight check numbers; a fit that meets its tolerance says success.
"""

import json
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

from jaxmocap import metrics
from jaxmocap.app.scenarios import inertial_setup
from jaxmocap.body import default_body
from jaxmocap.methods import inertial as I
from jaxmocap.sensors import IMUErrorModel, ScenarioConfig, make_scenario

ROOT = Path(__file__).resolve().parents[1]
DEFAULTS = ROOT / "experiments" / "results" / "defaults.json"
CMU = ROOT.parent / "shared" / "data" / "cmu"


@pytest.fixture(scope="module")
def recorded():
    assert DEFAULTS.is_file(), "experiments/results/defaults.json is missing: run python experiments/defaults.py"
    return json.loads(DEFAULTS.read_text())


def test_presets_exist_and_differ():
    thesis, validated = I.PRESETS["thesis"], I.PRESETS["validated"]
    assert thesis.weights == I.SIPWeights()  # the seeds' values, exact (§3.4.1)
    assert (thesis.max_steps, thesis.rtol, thesis.atol) == (20, 1e-6, 1e-10)
    assert validated.weights != thesis.weights and validated.rtol > thesis.rtol
    assert I.preset() is validated and I.preset("thesis") is thesis
    mine = I.preset(I.SIPWeights(acc=0.1))
    assert mine.weights.acc == 0.1 and mine.max_steps == validated.max_steps
    with pytest.raises(ValueError, match="preset name"):
        I.preset("validate")


def test_validated_preset_is_what_the_development_subjects_chose(recorded):
    from jaxmocap.motion.splits import check_record

    check_record(recorded["split"])
    chosen = recorded["tuning"]["chosen"]
    v = I.PRESETS["validated"]
    assert (v.weights.mahal, v.max_steps, v.rtol, v.atol) == (
        chosen["mahal"],
        chosen["max_steps"],
        chosen["rtol"],
        chosen["atol"],
    )
    assert recorded["preset_matches_tuning"]
    assert set(recorded["tuning"]["clips"]).isdisjoint(recorded["evaluation"]["clips"])


@pytest.fixture(scope="module")
def jump(recorded):
    check = recorded["check"]
    assert (CMU / check["clip"]).is_file(), (
        f"{CMU / check['clip']} is missing: these tests need ../shared beside the checkout"
    )
    body = default_body("low")
    cfg = ScenarioConfig(fps=30.0, max_frames=check["frames"], imu_set=check["imu_set"],
                         imu_errors=IMUErrorModel.xsens(), betas_std=0.0)  # fmt: skip
    sc = make_scenario([CMU / check["clip"]], cfg, seed=check["seed"], body=body)
    return body, inertial_setup(sc, 0, body), sc.sequence(0)["poses"][0], check


@pytest.mark.parametrize("name", ["thesis", "validated"])
def test_presets_reproduce_the_committed_check(jump, name):
    body, setup, truth, check = jump
    r = I.sparse_inertial_poser(setup, name)
    e = metrics.pose_errors(body, np.asarray(r.poses, np.float64), truth)
    np.testing.assert_allclose(e["mpjpe"].mean(), check[name]["mpjpe_mm"], atol=0.05)
    np.testing.assert_allclose(e["mpjae"].mean(), check[name]["mpjae_deg"], atol=0.01)
    assert int(r.solution.result) == check[name]["result"]
    assert int(r.solution.num_steps) == check[name]["steps"]
    if int(r.solution.result) != 0:
        # Stopped by the cap: it says so, and how fast the cost was still falling.
        assert f"step cap ({check[name]['steps']} steps)" in r.solution.status()
        assert 0 < float(r.solution.decrease) < 1


def test_a_fit_that_meets_its_tolerance_reports_success(jump):
    _, setup, _, _ = jump
    r = I.sparse_inertial_poser(setup, "validated", max_steps=200)
    assert int(r.solution.result) == 0 and bool(r.solution.converged) and bool(r.converged)
    assert r.solution.status() == f"converged in {int(r.solution.num_steps)} steps"
    assert int(r.solution.num_steps) < 200


def test_explicit_limits_override_the_preset(jump):
    _, setup, _, _ = jump
    sop, _ = I.sparse_orientation_poser(setup, "thesis")
    r = I.sparse_inertial_poser(setup, "validated", init=sop, max_steps=3)
    assert int(r.solution.num_steps) == 3 and int(r.solution.result) != 0 and not bool(r.converged)
    with pytest.raises(ValueError, match="max_steps"):
        I.sparse_inertial_poser(setup, init=sop, max_steps=0)
    with pytest.raises(ValueError, match="preset name"):
        I.sparse_inertial_poser(setup, "Thesis", init=sop)
    assert jnp.isfinite(r.solution.decrease)


# --- MuVS (methods.multiview): the same mechanism --------------------------------------

MUVS_TUNING = ROOT / "experiments" / "results" / "muvs_tuning.json"


def test_muvs_presets_the_default_is_validated_and_thesis_keeps_the_seed():
    import inspect

    from jaxmocap.app.multiview import fit_recording
    from jaxmocap.cli import build_parser
    from jaxmocap.methods import multiview as mv

    validated, thesis = mv.PRESETS["validated"], mv.PRESETS["thesis"]
    assert validated == mv.MuVSWeights() and mv.preset() is validated and mv.preset("thesis") is thesis
    assert (thesis.pose_prior, thesis.shape) == (20.0, 50.0)  # the seed's λ_θ, λ_β, exact
    assert thesis.replace(pose_prior=validated.pose_prior, shape=validated.shape) == validated
    for fn in (mv.multiview_smplify, mv.stage_one, mv.stage_two):
        assert inspect.signature(fn).parameters["weights"].default == "validated", fn.__name__
    assert inspect.signature(fit_recording).parameters["weights"].default is None  # None: "validated"
    mine = mv.MuVSWeights(sigma=5.0)
    assert mv.preset(mine) is mine
    with pytest.raises(ValueError, match="preset name"):
        mv.preset("validate")
    with pytest.raises(ValueError, match="preset name"):
        mv.preset({"pose_prior": 1.0})
    # the CLI offers the presets, the validated one by default
    parser = build_parser()
    assert parser.parse_args(["multiview", "demo"]).weights == "validated"
    for name in mv.PRESETS:
        assert parser.parse_args(["multiview", "demo", "--weights", name]).weights == name
    with pytest.raises(SystemExit):
        parser.parse_args(["multiview", "demo", "--weights", "tuned"])


def test_muvs_validated_preset_is_what_the_development_subjects_chose():
    from jaxmocap.methods import multiview as mv
    from jaxmocap.motion.splits import check_record

    assert MUVS_TUNING.is_file(), (
        f"{MUVS_TUNING} is missing: run python experiments/muvs_tuning.py --out experiments/results"
    )
    recorded = json.loads(MUVS_TUNING.read_text())
    check_record(recorded["split"])
    assert recorded["split"]["tuning"] == ["02", "131"] and not recorded["split"]["evaluation"]
    v, thesis = mv.PRESETS["validated"], mv.PRESETS["thesis"]
    assert (v.pose_prior, v.shape) == (recorded["best_pose_prior"], recorded["best_shape"])
    # the silhouette variant chosen: its settings in the preset, the others' at the seed's values
    chosen = recorded["silhouettes"][recorded["best_silhouettes"]]
    fields = {k for row in recorded["silhouettes"].values() for k in row if k in mv.MuVSWeights.__dataclass_fields__}
    assert fields, "muvs_tuning.json records no silhouette setting"
    for k in fields:
        assert getattr(v, k) == chosen.get(k, getattr(thesis, k)), k
    assert all(v for k, v in recorded["defaults_agree"].items() if k != "note"), recorded["defaults_agree"]
    best = recorded["grid"][f"{recorded['best_pose_prior']}/{recorded['best_shape']}"]["mpjpe_mm"]
    assert best == min(row["mpjpe_mm"] for row in recorded["grid"].values())
