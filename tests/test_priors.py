"""Priors from motion files: the corpus split, fit_prior against a NumPy derivation, folds, the CLI."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from jaxmocap.motion import Motion
from jaxmocap.motion.amass import save_amass
from jaxmocap.motion.corpus import Clip, corpus, subject_of, training_clips
from jaxmocap.priors import PosePrior
from jaxmocap.priors.build import FLOOR_DEG, fit_prior, held_out_prior, motion_files


def _clip(path, seed, frames, scale):
    rng = np.random.default_rng(seed)
    poses = np.zeros((frames, 24, 3))
    poses[:, 1:22] = rng.normal(scale=scale, size=(frames, 21, 3))
    save_amass(Motion(poses, np.zeros((frames, 3)), 30.0, name=path.stem), path, layout="smpl")
    return poses[:, 1:].reshape(frames, 69)


@pytest.fixture(scope="module")
def two_subjects(tmp_path_factory):
    """Subject 10 (two clips of 40 and 90 frames) and subject 11 (one of 60)."""
    d = tmp_path_factory.mktemp("motions")
    x = {name: _clip(d / f"{name}.npz", i, n, s) for i, (name, n, s) in
         enumerate((("10_01", 40, 0.2), ("10_02", 90, 0.4), ("11_01", 60, 0.3)))}  # fmt: skip
    return d, x


def test_subject_of_reads_cmu_names():
    assert subject_of("02_01.amc") == "02" and subject_of("/a/005_12.bvh") == "05" and subject_of("131_01.bvh") == "131"
    with pytest.raises(ValueError, match="walk.bvh"):
        subject_of("walk.bvh")


def test_training_clips_drop_the_excluded_subjects(two_subjects):
    d, _ = two_subjects
    clips = corpus([d])
    assert [c.subject for c in clips] == ["10", "10", "11"]
    assert [c.name for c in training_clips(clips, exclude=["10"])] == ["11_01.npz"]
    assert [c.name for c in training_clips(clips, exclude=[11])] == ["10_01.npz", "10_02.npz"]


def test_fit_prior_weighs_each_clip_equally(two_subjects):
    """μ and Σ against a separate derivation: every clip's frames weigh 1/(its length)."""
    d, x = two_subjects
    mean, cov, meta = fit_prior(sorted(d.glob("*.npz")), include_library=False)
    frames = list(x.values())
    mu = np.mean([f.mean(0) for f in frames], axis=0)
    second = np.mean([(f - mu).T @ (f - mu) / len(f) for f in frames], axis=0)
    np.testing.assert_allclose(mean, mu, atol=1e-6)
    np.testing.assert_allclose(cov, second + np.eye(69) * np.radians(FLOOR_DEG) ** 2, atol=1e-6)
    assert [s["frames"] for s in meta["sources"]] == [40, 90, 60]


def test_held_out_prior_never_sees_the_excluded_subject(two_subjects):
    d, x = two_subjects
    import jax.numpy as jnp

    prior = held_out_prior(["10"], clips=corpus([d]), dtype=jnp.float64)
    only_11 = PosePrior.from_moments(*fit_prior([d / "11_01.npz"])[:2], dtype=jnp.float64)
    np.testing.assert_allclose(prior.mean, only_11.mean, atol=1e-12)
    precision = lambda p: np.asarray(p.whitening.T @ p.whitening)  # noqa: E731
    np.testing.assert_allclose(precision(prior), precision(only_11), rtol=1e-9)
    with_10 = held_out_prior(["11"], clips=corpus([d]), dtype=jnp.float64)
    assert not np.allclose(with_10.mean, prior.mean)


def test_prior_build_cli_writes_a_loadable_prior(two_subjects, tmp_path, capsys):
    from jaxmocap.cli import main

    d, _ = two_subjects
    out = tmp_path / "mine.npz"
    assert main(["prior", "build", str(d), "--out", str(out), "--no-library"]) == 0
    assert "3 clips" in capsys.readouterr().out
    prior = PosePrior.load(out)
    mean, _, _ = fit_prior(sorted(d.glob("*.npz")), include_library=False)
    np.testing.assert_allclose(prior.mean, mean, atol=1e-6)
    with np.load(out) as f:
        assert [s["source"] for s in json.loads(str(f["meta"]))["sources"]] == ["10_01.npz", "10_02.npz", "11_01.npz"]


def test_prior_build_names_missing_and_empty_folders(tmp_path):
    with pytest.raises(FileNotFoundError, match="nowhere"):
        motion_files([tmp_path / "nowhere"])
    with pytest.raises(FileNotFoundError, match="holds no motion files"):
        motion_files([tmp_path])
    with pytest.raises(ValueError, match="at least one clip"):
        fit_prior([], include_library=False)
    with pytest.raises(FileNotFoundError, match="does not exist"):
        corpus([tmp_path / "nowhere"])


def test_bundled_prior_lists_every_corpus_clip():
    """The bundled prior's provenance names every clip found (so no clip of the corpus is held out of it)."""
    clips = corpus()
    if not clips:
        pytest.skip("../shared/data/cmu and cmu_cc are not beside the checkout")
    from jaxmocap.priors.pose_prior import DEFAULT_PRIOR_PATH

    with np.load(DEFAULT_PRIOR_PATH) as f:
        sources = {s["source"] for s in json.loads(str(f["meta"]))["sources"]}
    assert {c.name for c in clips} <= sources
    readme = (DEFAULT_PRIOR_PATH.parent / "README.md").read_text()  # its table of training clips is current
    assert all(f" {name.rsplit('.', 1)[0]} " in readme for name in sources)
    assert {c.subject for c in clips} >= {"02", "05", "06", "07"}
    assert all(isinstance(c, Clip) and c.activity != "unknown" for c in clips)


def test_sweep_datasets_take_the_held_out_prior(two_subjects, monkeypatch):
    """A sweep dataset with prior = "held_out" fits each clip with the fold of its subject."""
    from jaxmocap.app import sweep_methods
    from jaxmocap.priors import build

    d, _ = two_subjects
    monkeypatch.setattr(build, "_FOLDS", {})
    monkeypatch.setattr(build, "held_out_prior", lambda exclude, clips=None, dtype=None: held_out_prior(
        exclude, clips=corpus([d]), dtype=dtype))  # fmt: skip
    assert sweep_methods._prior("bundled", "10_01.npz") is None
    fold = sweep_methods._prior("held_out", "10_02.npz")
    np.testing.assert_allclose(fold.mean, held_out_prior(["10"], clips=corpus([d])).mean, atol=1e-6)
    assert sweep_methods._prior("held_out", "10_01.npz") is fold  # one fold per subject and dtype


def test_interleave_spreads_over_subjects():
    from jaxmocap.motion.corpus import interleave

    clips = [Clip(Path(f"{s}_{k:02d}.bvh"), s) for s, n in (("07", 3), ("02", 1), ("05", 2)) for k in range(1, n + 1)]
    assert [c.path.stem for c in interleave(clips, 5)] == ["02_01", "05_01", "07_01", "05_02", "07_02"]
    assert len(interleave(clips, 99)) == len(clips)
