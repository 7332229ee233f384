"""The `jaxmocap` command line: inspect, convert, export, demo, and its error handling."""

import numpy as np
import pytest
from conftest import assert_picture

from jaxmocap.body import save_body
from jaxmocap.cli import COMMANDS, main
from jaxmocap.body import mannequin_body
from jaxmocap.motion.io import find_cmu_dir

T = 16  # same frame count as test_viz: the jitted posing is compiled once


@pytest.fixture(scope="module")
def body_file(tmp_path_factory):
    return save_body(mannequin_body(detail=0), tmp_path_factory.mktemp("body") / "mannequin.npz")


@pytest.fixture(scope="module")
def amass_file(tmp_path_factory):
    """A small AMASS-style file written with NumPy alone (z up, SMPL 72-column poses)."""
    rng = np.random.default_rng(0)
    poses = rng.normal(scale=0.1, size=(T, 72))
    poses[:, :3] = [np.pi / 2, 0.0, 0.0]  # upright in AMASS's z-up world
    t = np.arange(T) / 30.0
    trans = np.stack([0.0 * t, 1.0 * t, 0.9 + 0.0 * t], 1)  # 1 m/s along AMASS's y
    path = tmp_path_factory.mktemp("amass") / "walk_poses.npz"
    np.savez(
        path, poses=poses, trans=trans, betas=np.zeros(10), gender=np.array("neutral"), mocap_framerate=np.array(30.0)
    )
    return path


def test_commands_registered():
    assert [c.name for c in COMMANDS][:4] == ["inspect", "convert", "export", "demo"]


def test_inspect_motion(amass_file, capsys):
    assert main(["inspect", str(amass_file)]) == 0
    out = capsys.readouterr().out
    assert "frames       16" in out
    assert "fps          30" in out
    assert "duration     0.500 s" in out
    assert "joints       24" in out
    path = float(out.split("root path")[1].split()[0])
    assert path == pytest.approx(0.5, abs=1e-6)  # 15 steps of 1/30 m


@pytest.mark.skipif(
    find_cmu_dir() is None or not (find_cmu_dir().parent / "cmu_cc" / "005_02.bvh").is_file(),
    reason="needs ../shared/data/cmu_cc",
)
def test_inspect_names_the_rig(capsys):
    clip = find_cmu_dir().parent / "cmu_cc" / "005_02.bvh"
    assert main(["inspect", str(clip)]) == 0
    out = capsys.readouterr().out
    assert "frames       562" in out and "fps          60" in out
    assert "rig          Reallusion Character Creator" in out and "22/24 SMPL joints mapped" in out
    assert "rest         motion" in out
    assert main(["inspect", str(clip), "--map", "cc"]) == 0
    capsys.readouterr()
    assert main(["inspect", str(clip), "--map", "mixamo"]) != 0
    assert "names 'Hips', which" in capsys.readouterr().err


def test_inspect_body(body_file, capsys):
    assert main(["inspect", str(body_file)]) == 0
    out = capsys.readouterr().out
    assert "vertices     656" in out and "joints       24" in out and "betas        10" in out


def test_convert(amass_file, body_file, tmp_path, capsys):
    out = tmp_path / "conv" / "half.npz"
    assert main(["convert", str(amass_file), str(out), "--fps", "15", "--body", str(body_file)]) == 0
    assert "8 frames at 15 fps" in capsys.readouterr().out
    with np.load(out) as f:
        assert f["poses"].shape[0] == 8
        assert float(f["mocap_framerate"]) == 15.0
    assert main(["inspect", str(out)]) == 0
    assert "frames       8" in capsys.readouterr().out


def test_export(amass_file, body_file, tmp_path, capsys):
    outdir = tmp_path / "export"
    args = ["export", str(amass_file), str(outdir), "--body", str(body_file), "--every", "4", "--png"]
    assert main(args) == 0
    out = capsys.readouterr().out
    plys = sorted((outdir / "meshes").glob("*.ply"))
    assert [p.name for p in plys] == ["frame_0000.ply", "frame_0004.ply", "frame_0008.ply", "frame_0012.ply"]
    assert_picture(outdir / "filmstrip.png", min_bytes=30_000, min_colour_fraction=0.005)  # limbs, path
    assert_picture(outdir / "body.png", min_drawn_fraction=0.05)  # the shaded body
    assert "wrote 4 PLY" in out
    assert main(["export", str(amass_file), str(outdir / "g"), "--body", str(body_file), "--format", "glb"]) == 0
    assert (outdir / "g" / "meshes" / "sequence.glb").is_file()


def test_missing_file_is_one_line_exit_2(tmp_path, capsys):
    missing = tmp_path / "nope.npz"
    assert main(["inspect", str(missing)]) == 2
    err = capsys.readouterr().err
    assert str(missing) in err and err.startswith("jaxmocap inspect: error:")
    assert "Traceback" not in err and err.count("\n") == 1
    assert main(["export", str(missing), str(tmp_path / "o"), "--body", str(tmp_path / "no_body.npz")]) == 2
    assert "no_body.npz" in capsys.readouterr().err


def test_bad_formats_exit_2(amass_file, tmp_path, capsys):
    assert main(["convert", str(amass_file), str(tmp_path / "out.txt")]) == 2
    assert ".npz" in capsys.readouterr().err
    text = tmp_path / "notes.txt"
    text.write_text("hello")
    assert main(["inspect", str(text)]) == 2
    assert "notes.txt" in capsys.readouterr().err
    broken = tmp_path / "broken.npz"
    broken.write_bytes(b"not a zip")
    assert main(["inspect", str(broken)]) == 2
    assert "broken.npz" in capsys.readouterr().err


def test_bad_arguments_exit_2(amass_file, tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        main(["export", str(amass_file), str(tmp_path), "--every", "0"])
    assert e.value.code == 2
    assert "must be positive" in capsys.readouterr().err


@pytest.mark.skipif(find_cmu_dir() is None, reason="CMU clips not present")
def test_demo(tmp_path, capsys):
    assert (
        main(["demo", "--out", str(tmp_path), "--seconds", "0.5", "--every", "4", "--body", "default-low", "--no-fit"])
        == 0
    )
    out = capsys.readouterr().out
    assert "CMU walk" in out and "16 frames" in out
    assert len(list((tmp_path / "meshes").glob("*.ply"))) == 4
    assert (tmp_path / "meshes" / "sequence.glb").is_file()
    assert (tmp_path / "filmstrip.png").is_file() and (tmp_path / "body.png").is_file()


def test_demo_without_cmu_uses_procedural_walk(tmp_path, monkeypatch, capsys):
    empty = tmp_path / "no_cmu"
    empty.mkdir()
    monkeypatch.setenv("JAXMOCAP_CMU", str(empty))
    assert (
        main(
            [
                "demo",
                "--out",
                str(tmp_path / "demo"),
                "--seconds",
                "0.5",
                "--every",
                "8",
                "--body",
                "default-low",
                "--no-fit",
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert "procedural walk" in out and "16 frames" in out
    assert len(list((tmp_path / "demo" / "meshes").glob("*.ply"))) == 2


def test_demo_counts_meshes_per_folder(tmp_path):
    """meshes/, meshes_sop/ and meshes_sip/ of 18 PLY each: three lines of 18, not one of 54."""
    from jaxmocap.cli import _mesh_lines

    paths = [
        tmp_path / d / f"frame_{i:04d}.ply" for d in ("meshes", "meshes_sop", "meshes_sip") for i in range(0, 90, 5)
    ]
    lines = _mesh_lines(paths + [tmp_path / "meshes" / "sequence.glb"])
    assert lines == [f"meshes   18 PLY in {tmp_path / d} (frame_0000.ply .. frame_0085.ply)"
                     for d in ("meshes", "meshes_sop", "meshes_sip")]  # fmt: skip
