"""`jaxmocap vip demo` and `jaxmocap vip fit` (app.vip): the files they write and the numbers in them.

A real VIP fit of even a tiny scene takes minutes on a 2-core CPU (compiling the tracker
and the batched fusion), so, as in test_interaction_cli, `fit_inputs` is swapped for the
truth: simulation or the 3DPW reader, the scoring, the pictures, the GLB, the report and
the CLI's wiring all run for real, and a perfect fit has known numbers (zero VIP error,
every detection of a wearer assigned to them, headings equal to the simulated offsets).
"""

import json
from types import SimpleNamespace

import matplotlib.image
import numpy as np
import pytest
import trimesh

from jaxmocap.app import vip as app
from jaxmocap.cli import main
from jaxmocap.methods.association import Association
from jaxmocap.methods.visual_inertial import VIPScene
from jaxmocap.motion.io import load_motion
from jaxmocap.rotation import matrix_to_axis_angle
from threedpw_file import threedpw_dict, write_threedpw


def _truth_fit(inputs, max_steps=30, rounds=2, log=print):
    """A `VIPScene` of the truth: true poses and camera, headings undoing the offsets, the
    IT start 3° off on every joint, detections assigned by the identity labels."""
    people = []
    for k, truth in enumerate(inputs.truths):
        Rcw = np.swapaxes(truth["cam_R"], -1, -2)
        camera = np.concatenate(
            [np.asarray(matrix_to_axis_angle(Rcw)), -np.einsum("tab,tb->ta", Rcw, truth["cam_t"])], -1
        )
        heading = np.zeros(len(inputs.bones)) if inputs.imu_heading is None else -inputs.imu_heading[k]
        people.append(SimpleNamespace(poses=truth["poses"], trans=truth["trans"], camera=camera, heading=heading,
                                      x0=truth["poses"][0], init=truth["poses"] + np.radians(3.0),
                                      solution=SimpleNamespace(cost=0.0)))  # fmt: skip
    mine = np.stack([inputs.labels == p for p in inputs.people])  # (P, T, D)
    index = np.where(mine.any(-1), mine.argmax(-1), -1)
    log(f"round 1: {int((index >= 0).sum())} detections assigned")
    assoc = Association(index, None, 0.0, (), {})
    return VIPScene(tuple(people), (assoc,) * rounds, {"tracker": 0.0, "association": 0.0, "fusion": 0.0})


@pytest.fixture
def truth_fit(monkeypatch):
    monkeypatch.setattr(app, "fit_inputs", _truth_fit)


def _check_outputs(out, report, T, P):
    assert report["frames"] == T and len(report["people"]) == P
    for name in report["outputs"]:
        assert (out / name).stat().st_size > 0, name
    overlays = sorted(out.glob("overlay_*.png"))
    assert [p.name for p in overlays] == [f"overlay_{t:04d}.png" for t in (0, T // 2, T - 1)]
    assert matplotlib.image.imread(overlays[0]).ndim == 3
    nodes = trimesh.load(out / "scene.glb").graph.nodes_geometry
    assert {f"person{p}_frame0000" for p in range(P)} | {"camera_0000", "camera_path"} <= set(nodes)
    for k in range(P):
        motion = load_motion(out / f"wearer{k}.npz")
        assert motion.poses.shape == (T, 24, 3)
        with np.load(out / f"wearer{k}.npz") as f:
            assert f["camera"].shape == (T, 6) and f["x0"].shape == (24, 3) and f["tracker_poses"].shape == (T, 24, 3)
        e = report["people"][k]
        assert e["vip_mpjpe_mm"] < 0.1 < 1.0 < e["it_mpjpe_mm"], e
        assert len(e["heading_deg"]) == 13
    for a in report["association"]:
        assert a["assigned"] == a["right"] == a["wearer_frames_detected"], a
    assert {"inputs", "tracker", "association", "fusion", "files", "overlays", "errors", "scene", "total"} <= set(
        report["seconds"]
    )
    assert json.loads((out / "report.json").read_text()) == report


def test_demo_writes_every_file(tmp_path, capsys, truth_fit):
    out = tmp_path / "vip"
    assert main(["vip", "demo", "--out", str(out), "--frames", "24", "--wearers", "2", "--bystanders", "1",
                 "--steps", "2"]) == 0  # fmt: skip
    printed = capsys.readouterr().out
    for word in ("inputs   simulated scene: walk (IMUs), slow_walk (IMUs), arm_raises (bystander)", "vip      round 1",
                 "overlays", "errors", "wearer 1 (person 1)", "wrote", "done in"):  # fmt: skip
        assert word in printed, (word, printed)
    report = json.loads((out / "report.json").read_text())
    _check_outputs(out, report, 24, 2)
    assert report["settings"]["max_steps"] == 2 and report["settings"]["bystanders"] == 1
    assert all(e["heading_error_deg"] < 1e-9 for e in report["people"])


def test_fit_reads_a_threedpw_file(tmp_path, capsys, truth_fit):
    from jaxmocap.body.io import default_body

    # 27 frames: the fits below are 24 frames long, the length of the demo's and of test_vip's
    # scene, so that the programs compiled for one (kinematics, IMU simulation, errors) serve all.
    path = write_threedpw(tmp_path / "courtyard.pkl", threedpw_dict(default_body("low"), 27)[0])
    out = tmp_path / "fit"
    assert main(["vip", "fit", str(path), "--out", str(out), "--steps", "2"]) == 0
    report = json.loads((out / "report.json").read_text())
    _check_outputs(out, report, 24, 2)  # person 0's camera pose is valid on frames 0..23
    assert report["settings"]["frames"] == [0, 24] and [e["person"] for e in report["people"]] == [0, 1]
    assert "3DPW courtyard_synthetic_00" in capsys.readouterr().out
    assert main(["vip", "fit", str(path), "--out", str(out), "--people", "1", "--frames", "2:26"]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["frames"] == 24 and [e["person"] for e in report["people"]] == [1]


@pytest.mark.parametrize("argv, message", [
    (["fit", "absent.pkl"], "absent.pkl"),
    (["fit", "SEQ", "--people", "0,5"], "indices must be distinct and in 0 .. 1"),
    (["fit", "SEQ", "--people", ","], "no wearers"),
    (["fit", "SEQ", "--frames", "5:5"], "select 0 of the 27 frames"),
    (["fit", "JUNK"], "not a 3DPW sequence pickle"),
    (["demo", "--wearers", "3", "--bystanders", "2"], "at most 4 people"),
])  # fmt: skip
def test_bad_input_is_one_line(tmp_path, capsys, monkeypatch, argv, message):
    from jaxmocap.body.io import default_body

    def refuse(*a, **k):
        raise AssertionError("the fit must not start")

    monkeypatch.setattr(app, "fit_inputs", refuse)
    seq = write_threedpw(tmp_path / "seq.pkl", threedpw_dict(default_body("low"), 27)[0])  # as the fit's file
    (tmp_path / "junk.pkl").write_bytes(b"not a pickle")
    files = {"SEQ": str(seq), "JUNK": str(tmp_path / "junk.pkl"), "absent.pkl": str(tmp_path / "absent.pkl")}
    argv = ["vip", *[files.get(a, a) for a in argv], "--out", str(tmp_path / "out")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("jaxmocap vip: error:") and message in err and err.count("\n") == 1, err
