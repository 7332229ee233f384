"""Model files: SMPL pkl (with chumpy objects, without chumpy), npz, SMPL-H/X reduction, errors."""

import pickle
import sys
import types

import jax
import numpy as np
import pytest
import scipy.sparse

import jaxmocap
from jaxmocap import BodyFileError, load_body, save_body
from conftest import random_smpl_dict
from smpl_numpy import smpl_forward_numpy

forward_jit = jax.jit(jaxmocap.forward)


def _write_chumpy_pickle(d: dict, path):
    """Pickle like SMPL's release: chumpy arrays and a scipy.sparse regressor."""
    chumpy = types.ModuleType("chumpy")
    ch = types.ModuleType("chumpy.ch")

    class Ch:
        def __init__(self, x):
            self.x = x

        def __getstate__(self):
            return {"x": self.x, "_dirty_vars": set()}

    Ch.__module__, Ch.__qualname__ = "chumpy.ch", "Ch"
    ch.Ch = Ch
    chumpy.ch = ch
    sys.modules.update({"chumpy": chumpy, "chumpy.ch": ch})
    try:
        out = dict(d)
        for k in ("v_template", "shapedirs", "posedirs", "weights"):
            out[k] = Ch(d[k])
        out["J_regressor"] = scipy.sparse.csc_matrix(d["J_regressor"])
        out["bs_style"] = "lbs"
        with open(path, "wb") as f:
            pickle.dump(out, f, protocol=2)
    finally:
        del sys.modules["chumpy"], sys.modules["chumpy.ch"]


def test_smpl_pickle_with_chumpy_objects(tmp_path, smpl_dict):
    path = tmp_path / "basicModel_f_lbs_10_207_0_v1.0.0.pkl"
    _write_chumpy_pickle(smpl_dict, path)
    assert "chumpy" not in sys.modules
    body = load_body(path, dtype=np.float64)
    assert body.gender == "female" and body.kind == "smpl"
    pose = np.random.default_rng(0).normal(scale=0.5, size=(24, 3))
    betas = np.linspace(-1, 1, 10)
    ref, _, _ = smpl_forward_numpy(smpl_dict, pose, betas, np.zeros(3))
    np.testing.assert_allclose(forward_jit(body, pose, betas).vertices, ref, atol=1e-6)


def test_npz_round_trip(tmp_path, random_body):
    path = save_body(random_body, tmp_path / "model.npz")
    again = load_body(path, dtype=np.float64)
    for a, b in zip(jax.tree_util.tree_leaves(random_body), jax.tree_util.tree_leaves(again)):
        np.testing.assert_array_equal(a, b)
    assert again.faces.tolist() == random_body.faces.tolist()
    assert load_body(path, num_betas=4).num_betas == 4


def _family_dict(num_joints: int) -> dict:
    """A random SMPL-H (52) or SMPL-X (55) style model, in their published joint order."""
    d = random_smpl_dict(num_vertices=150, num_betas=12, seed=num_joints)
    rng = np.random.default_rng(num_joints)
    body_parents = list(d["kintree_table"][0][:22].astype(np.int64))
    body_parents[0] = -1
    parents = body_parents + ([12, 15, 15] if num_joints == 55 else [])
    for wrist in (20, 21):  # 5 fingers x 3 segments per hand
        for _ in range(5):
            parents += [wrist, len(parents), len(parents) + 1]
    assert len(parents) == num_joints
    V = len(d["v_template"])
    w = rng.random((V, num_joints)) ** 4
    w /= w.sum(1, keepdims=True)
    reg = rng.random((num_joints, V)) * (rng.random((num_joints, V)) < 0.1) + 1e-4
    reg /= reg.sum(1, keepdims=True)
    kintree = np.stack([np.array(parents), np.arange(num_joints)])
    kintree[0, 0] = 4294967295
    return dict(
        d,
        weights=w,
        J_regressor=reg,
        kintree_table=kintree,
        posedirs=rng.normal(scale=0.02, size=(V, 3, 9 * (num_joints - 1))),
    )


@pytest.mark.parametrize("num_joints,kind", [(52, "smplh"), (55, "smplx")])
def test_smplh_smplx_reduction_is_exact_with_resting_hands(tmp_path, num_joints, kind):
    d = _family_dict(num_joints)
    path = tmp_path / f"{kind}_male.npz"
    np.savez(path, **d)
    body = load_body(path, dtype=np.float64)
    assert body.kind == kind and body.num_joints == 24 and body.gender == "male"
    pose = np.random.default_rng(1).normal(scale=0.4, size=(24, 3))
    full_pose = np.zeros((num_joints, 3))
    full_pose[:22] = pose[:22]
    pose[22:] = 0.0  # hands at rest in both models
    ref_v, ref_j, _ = smpl_forward_numpy(d, full_pose, np.ones(12) * 0.3, np.zeros(3))
    out = forward_jit(body, pose, np.ones(12) * 0.3)
    np.testing.assert_allclose(out.vertices, ref_v, atol=1e-6)
    np.testing.assert_allclose(out.joints[:22], ref_j[:22], atol=1e-6)
    base = (22, 37) if num_joints == 52 else (25, 40)
    np.testing.assert_allclose(out.joints[22:], ref_j[list(base)], atol=1e-6)


def test_directory_and_gender(tmp_path, smpl_dict):
    for g in ("MALE", "FEMALE", "NEUTRAL"):
        np.savez(tmp_path / f"SMPL_{g}.npz", **smpl_dict)
    assert load_body(tmp_path, gender="male").gender == "male"
    assert load_body(tmp_path, gender="female").gender == "female"
    with pytest.raises(ValueError, match="gender must be"):
        load_body(tmp_path, gender="other")


def test_bad_files_name_the_file_and_problem(tmp_path, smpl_dict):
    with pytest.raises(BodyFileError, match="no such file"):
        load_body(tmp_path / "missing.pkl")
    bad = tmp_path / "model.obj"
    bad.write_text("v 0 0 0")
    with pytest.raises(BodyFileError, match=r"model\.obj.*unknown model file type"):
        load_body(bad)
    corrupt = tmp_path / "corrupt.pkl"
    corrupt.write_bytes(b"\x80\x02not a pickle at all")
    with pytest.raises(BodyFileError, match=r"corrupt\.pkl.*cannot read"):
        load_body(corrupt)
    truncated = tmp_path / "truncated.npz"
    np.savez(truncated, **smpl_dict)
    truncated.write_bytes(truncated.read_bytes()[:500])
    with pytest.raises(BodyFileError, match="truncated.npz"):
        load_body(truncated)
    partial = tmp_path / "partial.npz"
    np.savez(partial, v_template=smpl_dict["v_template"])
    with pytest.raises(BodyFileError, match=r"missing \['f'"):
        load_body(partial)
    mano = dict(smpl_dict, weights=np.ones((120, 16)) / 16)
    np.savez(tmp_path / "mano.npz", **mano)
    with pytest.raises(BodyFileError, match="16 joints is not supported"):
        load_body(tmp_path / "mano.npz")
    (tmp_path / "empty").mkdir()
    with pytest.raises(BodyFileError, match="no neutral model"):
        load_body(tmp_path / "empty")
