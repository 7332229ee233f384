"""Property-based tests: the file readers get truncated, mutated and random bytes.

Whatever the bytes, a reader either reads the file or raises its own error naming the file
(MotionFileError / BodyFileError, both ValueErrors) — never another exception, never a hang.
Each seed is a small valid file; hypothesis truncates it, overwrites a few bytes, splices
random bytes in, or replaces it with random bytes. Few examples each (the suite's time
budget); `derandomize` keeps runs reproducible.
"""

from __future__ import annotations

import io
import os
import pickle
import signal
import uuid
from pathlib import Path

import numpy as np
import pytest
from conftest import random_smpl_dict

# hypothesis is a pinned test dependency (pyproject's `test` extra): imported, never skipped.
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from jaxmocap.body.io import BodyFileError, load_body  # noqa: E402
from jaxmocap.motion import MotionFileError  # noqa: E402
from jaxmocap.motion.amass import load_amass  # noqa: E402
from jaxmocap.motion.asf_amc import load_asf_amc  # noqa: E402
from jaxmocap.motion.bvh import load_bvh  # noqa: E402
from jaxmocap.formats.dip import load_dip  # noqa: E402

CMU = Path(__file__).resolve().parents[2] / "shared" / "data" / "cmu"
# JAXMOCAP_FUZZ_EXAMPLES=2000 explores further with fresh random examples (a long run).
_LONG = int(os.environ.get("JAXMOCAP_FUZZ_EXAMPLES", "0"))
FUZZ = settings(
    max_examples=_LONG or 50, deadline=None, derandomize=not _LONG, database=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow, HealthCheck.data_too_large],
)  # fmt: skip


@st.composite
def spoiled(draw, seed: bytes) -> bytes:
    """`seed` truncated, with bytes overwritten, with bytes spliced in, or random bytes."""
    how = draw(st.sampled_from(["truncate", "overwrite", "splice", "random"]))
    if how == "truncate":
        return seed[: draw(st.integers(0, max(len(seed) - 1, 0)))]
    if how == "random":
        return draw(st.binary(max_size=512))
    data = bytearray(seed)
    for _ in range(draw(st.integers(1, 6))):
        at = draw(st.integers(0, len(data)))
        chunk = draw(st.binary(min_size=1, max_size=8))
        data[at : at + (len(chunk) if how == "overwrite" else 0)] = chunk
    return bytes(data)


def _write(folder: Path, suffix: str, data: bytes, stem: str = "") -> Path:
    path = folder / f"{stem or 'fuzz'}_{uuid.uuid4().hex[:8]}{suffix}"
    path.write_bytes(data)
    return path


class _Hang(Exception):
    pass


def _alarm(signum, frame):
    raise _Hang("a reader took more than 20 s on a small file")


def _reads_or_names(path: Path, error: type, read) -> None:
    """`read(path)` succeeds or raises `error` with the file name in the message, in < 20 s."""
    old = signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(20)
    try:
        with np.errstate(all="ignore"):  # overflow in absurd numbers is the data's problem
            read(path)
    except error as e:
        assert path.name in str(e), f"{type(e).__name__} does not name the file: {e}"
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


# --- seeds ------------------------------------------------------------------------------


def _amc_seed(frames: int = 3) -> bytes:
    out = []
    for line in (CMU / "02_01.amc").read_text().splitlines():
        if line.strip().isdigit() and int(line) > frames:
            break
        out.append(line)
    return ("\n".join(out) + "\n").encode()


BVH_SEED = b"""HIERARCHY
ROOT hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT spine
  {
    OFFSET 0 10 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 10 0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.0333333
0 90 0 0 0 0 5 0 0
1 90 0 0 10 0 5 5 0
"""


def _npz_bytes(**arrays) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


AMASS_SEED = _npz_bytes(
    poses=np.zeros((3, 72)), trans=np.zeros((3, 3)), betas=np.zeros(16),
    gender=np.array("female"), mocap_framerate=np.array(60.0),
)  # fmt: skip
SMPL = random_smpl_dict(num_vertices=30, num_betas=4, seed=1)
SMPL_PKL_SEED = pickle.dumps(SMPL, protocol=2)
SMPL_NPZ_SEED = _npz_bytes(**SMPL)
DIP_SEED = pickle.dumps(
    {"imu_ori": np.tile(np.eye(3), (2, 17, 1, 1)), "imu_acc": np.zeros((2, 17, 3)), "gt": np.zeros((2, 72))},
    protocol=2,
)


def test_seeds_are_valid(tmp_path):
    """The unspoiled seeds load, so the properties below test spoiling, not the seeds."""
    load_asf_amc(_write(tmp_path, ".amc", _amc_seed()), asf_path=CMU / "02.asf")
    load_bvh(_write(tmp_path, ".bvh", BVH_SEED))
    load_amass(_write(tmp_path, ".npz", AMASS_SEED))
    load_body(_write(tmp_path, ".pkl", SMPL_PKL_SEED))
    load_body(_write(tmp_path, ".npz", SMPL_NPZ_SEED))
    load_dip(_write(tmp_path, ".pkl", DIP_SEED))


@FUZZ
@given(data=spoiled(_amc_seed()))
def test_amc_bytes(tmp_path, data):
    path = _write(tmp_path, ".amc", data)
    _reads_or_names(path, MotionFileError, lambda p: load_asf_amc(p, asf_path=CMU / "02.asf"))


@FUZZ
@given(data=spoiled((CMU / "02.asf").read_bytes() if (CMU / "02.asf").is_file() else b""))
def test_asf_bytes(tmp_path, data):
    amc = tmp_path / "seed.amc"
    if not amc.exists():
        amc.write_bytes(_amc_seed())
    path = _write(tmp_path, ".asf", data)
    _reads_or_names(path, MotionFileError, lambda p: load_asf_amc(amc, asf_path=p))


@FUZZ
@given(data=spoiled(BVH_SEED))
def test_bvh_bytes(tmp_path, data):
    _reads_or_names(_write(tmp_path, ".bvh", data), MotionFileError, load_bvh)


@FUZZ
@given(data=spoiled(AMASS_SEED))
def test_amass_npz_bytes(tmp_path, data):
    _reads_or_names(_write(tmp_path, ".npz", data), MotionFileError, load_amass)


@FUZZ
@given(data=spoiled(SMPL_PKL_SEED))
def test_body_pkl_bytes(tmp_path, data):
    _reads_or_names(_write(tmp_path, ".pkl", data), BodyFileError, load_body)


@FUZZ
@given(data=spoiled(SMPL_NPZ_SEED))
def test_body_npz_bytes(tmp_path, data):
    _reads_or_names(_write(tmp_path, ".npz", data), BodyFileError, load_body)


@FUZZ
@given(data=spoiled(DIP_SEED))
def test_dip_pkl_bytes(tmp_path, data):
    _reads_or_names(_write(tmp_path, ".pkl", data), MotionFileError, load_dip)


# --- multi-view inputs: calibrations and OpenPose JSON ----------------------------------

from jaxmocap.formats import (  # noqa: E402
    CalibratedCamera,
    CalibrationError,
    KeypointFileError,
    load_calibration,
    read_openpose,
    save_calibration,
    write_openpose,
)


def _calibration_seeds() -> dict:
    import tempfile

    cam = CalibratedCamera(
        name="cam01", K=np.array([[800.0, 0, 320], [0, 800, 240], [0, 0, 1]]),
        dist=np.array([0.01, -0.02, 0.0, 0.0, 0.0]), R=np.eye(3), t=np.array([0.0, 0.0, 4.0]),
        width=640, height=480,
    )  # fmt: skip
    seeds = {}
    with tempfile.TemporaryDirectory() as tmp:
        for fmt, name in (("pose2sim", "calib.toml"), ("qualisys", "calib.qca.txt"), ("npz", "calib.npz")):
            save_calibration(Path(tmp) / name, [cam], fmt)
            seeds[fmt] = (name, (Path(tmp) / name).read_bytes())
        save_calibration(Path(tmp) / "easy", [cam], "easymocap")
        seeds["easymocap"] = ("intri.yml", (Path(tmp) / "easy" / "intri.yml").read_bytes())
        seeds["extri"] = (Path(tmp) / "easy" / "extri.yml").read_bytes()
        write_openpose(Path(tmp) / "op", ["cam01"], [np.ones((1, 1, 25, 3))], "body25")
        seeds["openpose"] = next((Path(tmp) / "op" / "cam01").glob("*.json")).read_bytes()
    return seeds


CALIB = _calibration_seeds()


@pytest.mark.parametrize("fmt", ["pose2sim", "qualisys", "easymocap", "npz"])
def test_calibration_bytes(tmp_path, fmt):
    name, seed = CALIB[fmt]

    @FUZZ
    @given(data=spoiled(seed))
    def run(data):
        folder = tmp_path / uuid.uuid4().hex[:8]
        folder.mkdir()
        if fmt == "easymocap":
            (folder / "extri.yml").write_bytes(CALIB["extri"])
        path = folder / name
        path.write_bytes(data)
        _reads_or_names(path, CalibrationError, lambda p: load_calibration(p, format=fmt))

    run()


@FUZZ
@given(data=spoiled(CALIB["openpose"]))
def test_openpose_json_bytes(tmp_path, data):
    root = tmp_path / uuid.uuid4().hex[:8]
    (root / "cam01").mkdir(parents=True)
    path = root / "cam01" / "cam01_000000000000_keypoints.json"
    path.write_bytes(data)
    _reads_or_names(path, KeypointFileError, lambda p: read_openpose(root, "body25"))


# --- the other readers (issue 50, goal 4): EasyMocap extrinsics, 3DPW, jaxmocap's own motion
# and scenario files, pose priors, sweep configs --------------------------------------------

from jaxmocap.app.sweep import SweepConfigError, load_config  # noqa: E402
from jaxmocap.formats.threedpw import load_threedpw  # noqa: E402
from jaxmocap.motion import load_motion  # noqa: E402
from jaxmocap.priors.pose_prior import load_pose_prior  # noqa: E402
from jaxmocap.sensors.scenario import load_scenario  # noqa: E402


def _threedpw_seed(T: int = 3) -> bytes:
    """One person, T frames, 3DPW's keys and shapes (values need not be a real recording)."""
    cam = np.tile(np.eye(4), (T, 1, 1))
    cam[:, 2, 3] = 4.0
    data = {
        "sequence": "fuzz_00", "genders": [b"m"], "betas": [np.zeros(10)], "poses": [np.zeros((T, 72))],
        "trans": [np.zeros((T, 3))], "poses2d": [np.ones((T, 3, 18))], "jointPositions": [np.zeros((T, 72))],
        "cam_poses": cam, "cam_intrinsics": np.array([[1000.0, 0, 540], [0, 1000, 960], [0, 0, 1]]),
        "campose_valid": [np.ones(T, bool)], "img_frame_ids": np.arange(T),
    }  # fmt: skip
    # As 3DPW's files are: protocol 2, NumPy 1's reconstructor path (tests/threedpw_file.py).
    return pickle.dumps(data, protocol=2).replace(b"numpy._core.", b"numpy.core.")


THREEDPW_SEED = _threedpw_seed()
OWN_MOTION_SEED = _npz_bytes(jaxmocap_motion=np.array(1), poses=np.zeros((3, 24, 3)), trans=np.zeros((3, 3)),
                             fps=np.array(30.0), betas=np.zeros(0), gender=np.array("neutral"), name=np.array("m"))  # fmt: skip
PRIOR_SEED = _npz_bytes(mean=np.zeros(69), covariance=np.eye(69), lower=np.full(69, -3.0), upper=np.full(69, 3.0))
SWEEP_SEED = b"""[sweep]
name = "fuzz"
methods = ["sweep_toy:ToyMethod"]
datasets = ["tracks"]
sensor_errors = ["low"]
metric = "rmse"
max_steps = 5

[grid.weights]
smooth = [0.1, 1.0]

[grid.terms]
smooth = [true, false]

[datasets.tracks]
motions = ["walk"]
sequences = 2
frames = 8
fps = 30.0

[sensor_errors.low]
acc_noise = 0.05
"""


def _scenario_seed() -> bytes:
    import json

    meta = {"format": "jaxmocap_scenario", "version": 1, "seed": 0, "config": {}, "names": ["a"]}
    return _npz_bytes(meta_json=np.array(json.dumps(meta)), mask=np.ones((1, 3), bool), length=np.array([3]),
                      poses=np.zeros((1, 1, 3, 24, 3)))  # fmt: skip


SCENARIO_SEED = _scenario_seed()


def test_more_seeds_are_valid(tmp_path):
    load_threedpw(_write(tmp_path, ".pkl", THREEDPW_SEED))
    load_motion(_write(tmp_path, ".npz", OWN_MOTION_SEED))
    load_pose_prior(_write(tmp_path, ".npz", PRIOR_SEED))
    load_config(_write(tmp_path, ".toml", SWEEP_SEED))
    load_scenario(_write(tmp_path, ".npz", SCENARIO_SEED))
    folder = tmp_path / "easy"
    folder.mkdir()
    (folder / "intri.yml").write_bytes(CALIB["easymocap"][1])
    (folder / "extri.yml").write_bytes(CALIB["extri"])
    load_calibration(folder / "intri.yml", format="easymocap")


@FUZZ
@given(data=spoiled(CALIB["extri"]))
def test_easymocap_extri_bytes(tmp_path, data):
    folder = tmp_path / uuid.uuid4().hex[:8]
    folder.mkdir()
    (folder / "intri.yml").write_bytes(CALIB["easymocap"][1])
    (folder / "extri.yml").write_bytes(data)
    # The error names the file at fault, extri.yml, though intri.yml was the one named.
    _reads_or_names(
        folder / "extri.yml", CalibrationError, lambda p: load_calibration(p.parent / "intri.yml", format="easymocap")
    )


@FUZZ
@given(data=spoiled(THREEDPW_SEED))
def test_threedpw_pkl_bytes(tmp_path, data):
    _reads_or_names(_write(tmp_path, ".pkl", data), MotionFileError, load_threedpw)


@FUZZ
@given(data=spoiled(OWN_MOTION_SEED))
def test_own_motion_npz_bytes(tmp_path, data):
    _reads_or_names(_write(tmp_path, ".npz", data), MotionFileError, load_motion)


@FUZZ
@given(data=spoiled(SCENARIO_SEED))
def test_scenario_npz_bytes(tmp_path, data):
    _reads_or_names(_write(tmp_path, ".npz", data), MotionFileError, load_scenario)


@FUZZ
@given(data=spoiled(PRIOR_SEED))
def test_pose_prior_npz_bytes(tmp_path, data):
    _reads_or_names(_write(tmp_path, ".npz", data), ValueError, load_pose_prior)


@FUZZ
@given(data=spoiled(SWEEP_SEED))
def test_sweep_toml_bytes(tmp_path, data):
    _reads_or_names(_write(tmp_path, ".toml", data), SweepConfigError, load_config)
