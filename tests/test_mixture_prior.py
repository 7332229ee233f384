"""SMPLify's mixture pose prior: K = 1 is the single Gaussian, the cost is the min over
components, the SIP residual's Jacobian uses the selected component, files round-trip."""

from __future__ import annotations

from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxmocap.energies.imu import MahalanobisResidual
from jaxmocap.motion import Motion
from jaxmocap.motion.amass import save_amass
from jaxmocap.priors import MixturePosePrior, PosePrior, load_pose_prior
from jaxmocap.priors.build import build_prior, fit_prior, held_out_prior, prior_from_fit, save_prior
from jaxmocap.rotation import axis_angle_to_matrix, log_small

K = 3


def _components(seed=0, K=K):
    """K well-separated components with random SPD covariances (radians²) and weights."""
    rng = np.random.default_rng(seed)
    means = rng.normal(scale=0.4, size=(K, 69))
    A = rng.normal(scale=0.06, size=(K, 69, 69))
    covs = A @ np.swapaxes(A, 1, 2) + 0.01 * np.eye(69)
    weights = rng.random(K) + 0.2
    return means, covs, weights / weights.sum()


def _numpy_energy(x, means, covs, weights):
    """E_θ(x) = min_k [½ d_k² − log w_k + ½ log det Σ_k] and its argmin (Bogo et al. 2016)."""
    e = np.stack([0.5 * np.einsum("ti,ij,tj->t", x - m, np.linalg.inv(c), x - m) - np.log(w) + 0.5 * np.linalg.slogdet(c)[1]
                  for m, c, w in zip(means, covs, weights)], -1)  # fmt: skip
    return e.min(-1), e.argmin(-1), e


def _frames_near_each_component(means, T_per=2, seed=1):
    rng = np.random.default_rng(seed)
    return np.concatenate([m + rng.normal(scale=0.05, size=(T_per, 69)) for m in means])


@jax.jit
def _prior_maps(prior, x):
    """What the tests read of a prior at poses x (T, 69), in one compiled program per prior
    kind (op by op, these were a hundred small ones): residual, its Jacobian, the negative
    log-likelihood and the SIP term's cost with the prior's rotations."""
    pose = axis_angle_to_matrix(jnp.concatenate([jnp.zeros((len(x), 1, 3)), x.reshape(len(x), 23, 3)], 1))
    r_sip = MahalanobisResidual()({"pose": pose}, SimpleNamespace(prior=prior))
    return dict(r=prior.mahalanobis_residual(x), J=prior.mahalanobis_jacobian(x), nll=prior.neg_log_likelihood(x),
                sip_cost=jnp.sum(r_sip**2))  # fmt: skip


def test_one_component_is_the_single_gaussian():
    means, covs, _ = _components()
    x = jnp.asarray(np.random.default_rng(2).normal(scale=0.3, size=(4, 69)))
    single = PosePrior.from_moments(means[0], covs[0], dtype=jnp.float64)
    mix = MixturePosePrior.from_moments(means[0], covs[0], dtype=jnp.float64)
    assert mix.num_components == 1 and single.num_components == 1
    m, s = _prior_maps(mix, x), _prior_maps(single, x)
    r = m["r"]
    np.testing.assert_allclose(r[:, :69], s["r"], rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(r[:, 69], 0.0)  # no component constant to pay
    np.testing.assert_allclose(m["J"][:, :69], jnp.broadcast_to(single.whitening, (4, 69, 69)))
    np.testing.assert_allclose(m["nll"], s["nll"], rtol=1e-12)
    np.testing.assert_allclose(mix.mean, single.mean)
    # The SIP term's cost with either form is d_mahal².
    assert abs(float(m["sip_cost"]) - float(s["sip_cost"])) <= 1e-10 * float(s["sip_cost"])


def test_mixture_cost_is_the_min_over_components():
    """½ ‖r‖² + c_min = min_k [½ d_k² − log w_k + ½ log det Σ_k], from a separate NumPy computation."""
    means, covs, weights = _components()
    prior = MixturePosePrior.from_moments(means, covs, weights, dtype=jnp.float64)
    rng = np.random.default_rng(3)
    x = np.concatenate([_frames_near_each_component(means), rng.normal(scale=0.5, size=(6, 69))])
    E, k, e = _numpy_energy(x, means, covs, weights)
    assert len(set(k.tolist())) == K  # every component is chosen somewhere
    c = -np.log(weights) + 0.5 * np.linalg.slogdet(covs)[1]
    r = np.asarray(prior.mahalanobis_residual(jnp.asarray(x)))
    assert r.shape == (len(x), 70)
    np.testing.assert_allclose(0.5 * np.sum(r**2, -1) + c.min(), E, rtol=1e-10)
    np.testing.assert_allclose(prior.energy(jnp.asarray(x)), E, rtol=1e-10)
    np.testing.assert_array_equal(prior.component(jnp.asarray(x)), k)
    nll = -np.log(np.sum(np.exp(-e), -1)) + 0.5 * 69 * np.log(2 * np.pi)  # e_k = −log(w_k N_k) − (69/2) log 2π
    np.testing.assert_allclose(prior.neg_log_likelihood(jnp.asarray(x)), nll, rtol=1e-10)


def test_sip_residual_jacobian_uses_the_selected_component():
    """`MahalanobisResidual.jacobian` under R_j ← exp(δ_j^) R_j against jax.jacfwd and central differences."""
    means, covs, weights = _components()
    prior = MixturePosePrior.from_moments(means, covs, weights, dtype=jnp.float64)
    x = _frames_near_each_component(0.5 * means, T_per=1)  # small angles, one frame per component
    T = len(x)
    pose = np.concatenate([np.zeros((T, 1, 3)), x.reshape(T, 23, 3)], 1)
    R0 = jax.jit(axis_angle_to_matrix)(jnp.asarray(pose))
    data = SimpleNamespace(prior=prior)
    fn = MahalanobisResidual()
    selected = jax.jit(lambda R: prior.component(log_small(R[:, 1:]).reshape(T, 69)))(R0)
    assert len(set(np.asarray(selected).tolist())) == K

    def residual(delta):  # delta (T, 24, 3) -> (T, 70)
        return fn({"pose": jax.vmap(jax.vmap(axis_angle_to_matrix))(delta) @ R0}, data)

    # Jitted, as the solver runs it (op by op, these Jacobians were ~200 small programs).
    J = np.asarray(
        jax.jit(lambda R: fn.jacobian({"pose": R}, data)["pose"].dense((70,), (24, 3)))(R0)
    )  # (T, 1, 70, 24, 3)
    assert J.shape == (T, 1, 70, 24, 3)
    full = np.asarray(jax.jit(jax.jacfwd(residual))(jnp.zeros((T, 24, 3))))  # (T, 70, T, 24, 3)
    for t in range(T):
        np.testing.assert_allclose(J[t, 0], full[t, :, t], atol=1e-10)
        assert np.abs(np.delete(full[t], t, axis=1)).max() == 0  # per frame: bandwidth 0
    np.testing.assert_array_equal(J[:, 0, 69], 0.0)  # the component constant has no slope
    eps, basis = 1e-6, jnp.eye(T * 72).reshape(T * 72, T, 24, 3)
    plus, minus = jax.jit(jax.vmap(residual))(jnp.concatenate([eps * basis, -eps * basis])).reshape(2, T * 72, T, 70)
    fd = np.moveaxis(np.asarray((plus - minus) / (2 * eps)), 0, -1).reshape(T, 70, T, 24, 3)  # central differences
    for t in range(T):
        np.testing.assert_allclose(J[t, 0], fd[t, :, t], atol=1e-6)
    # Another component's whitening would not do: the selected one is used.
    k = np.asarray(prior.component(jnp.asarray(x)))
    W = np.asarray(prior.mahalanobis_jacobian(jnp.asarray(x)))
    np.testing.assert_allclose(W[:, :69], np.asarray(prior.whitenings)[k])


def _clip(path, seed, frames, scale, offset):
    rng = np.random.default_rng(seed)
    poses = np.zeros((frames, 24, 3))
    poses[:, 1:22] = offset + rng.normal(scale=scale, size=(frames, 21, 3))
    save_amass(Motion(poses, np.zeros((frames, 3)), 30.0, name=path.stem), path, layout="smpl")


def test_mixture_file_round_trip(tmp_path):
    """fit → .npz → load gives the same prior; PosePrior.load hands back the mixture; held_out_prior alike."""
    from jaxmocap.motion.corpus import corpus

    clips = tmp_path / "clips"
    clips.mkdir()
    for i, (name, n, s, o) in enumerate((("10_01", 40, 0.1, -0.3), ("10_02", 60, 0.1, 0.3), ("11_01", 50, 0.1, 0.0))):
        _clip(clips / f"{name}.npz", i, n, s, o)
    files = sorted(clips.glob("*.npz"))
    means, covs, meta = fit_prior(files, include_library=False, components=2)
    assert means.shape == (2, 69) and covs.shape == (2, 69, 69) and meta["components"] == 2
    assert abs(sum(meta["weights"]) - 1) < 1e-9 and meta["weights"][0] >= meta["weights"][1]
    out = build_prior(files, tmp_path / "mix.npz", include_library=False, components=2)
    loaded = PosePrior.load(out, jnp.float64)
    assert isinstance(loaded, MixturePosePrior) and loaded.num_components == 2
    direct = prior_from_fit(means, covs, meta, jnp.float64)
    for a, b in zip(jax.tree_util.tree_leaves(loaded), jax.tree_util.tree_leaves(direct)):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)
    with np.load(out) as f:
        assert set(f.files) == {"mean", "covariance", "weights", "lower", "upper", "meta"}
    assert isinstance(held_out_prior(["11"], clips=corpus([clips])), PosePrior)  # components=1: today's prior
    folds = held_out_prior(["11"], clips=corpus([clips]), dtype=jnp.float64, components=2)
    only_10 = prior_from_fit(*fit_prior(files[:2], components=2), dtype=jnp.float64)
    np.testing.assert_allclose(folds.means, only_10.means, atol=1e-12)
    # A single Gaussian: the layout of today's files, and a one-component file, load as PosePrior.
    mean, cov, meta1 = fit_prior(files, include_library=False)
    single = save_prior(tmp_path / "one.npz", mean, cov, meta1)
    with np.load(single) as f:
        assert "weights" not in f.files
    as_mix = MixturePosePrior.load(single, jnp.float64)
    assert as_mix.num_components == 1
    np.testing.assert_allclose(as_mix.means[0], load_pose_prior(single, jnp.float64).mean)
    np.savez(tmp_path / "k1.npz", mean=mean[None], covariance=cov[None], weights=np.ones(1))
    assert isinstance(PosePrior.load(tmp_path / "k1.npz"), PosePrior)


@pytest.mark.parametrize("name, arrays, match", [
    ("not_npz", None, "not a readable .npz"),
    ("no_cov", dict(mean=np.zeros(69)), r"needs \['covariance'\]"),
    ("no_weights", dict(mean=np.zeros((2, 69)), covariance=np.stack([np.eye(69)] * 2)), "no `weights`"),
    ("flat_mean", dict(mean=np.zeros(69), covariance=np.eye(69), weights=np.ones(1)), "mixture file needs"),
    ("bad_weights", dict(mean=np.zeros((2, 69)), covariance=np.stack([np.eye(69)] * 2), weights=[1.5, -0.5]), "positive"),
    ("wrong_k", dict(mean=np.zeros((2, 69)), covariance=np.stack([np.eye(69)] * 3), weights=[0.5, 0.5]), r"\(K, 69, 69\)"),
    ("not_spd", dict(mean=np.zeros((2, 69)), covariance=np.stack([np.eye(69), -np.eye(69)]), weights=[0.5, 0.5]),
     "component 1: covariance must be positive definite"),
    ("nan", dict(mean=np.full((2, 69), np.nan), covariance=np.stack([np.eye(69)] * 2), weights=[0.5, 0.5]), "finite"),
])  # fmt: skip
def test_bad_prior_files_raise_clear_errors(tmp_path, name, arrays, match):
    path = tmp_path / f"{name}.npz"
    if arrays is None:
        path.write_bytes(b"this is no zip archive")
    else:
        np.savez(path, **arrays)
    with pytest.raises(ValueError, match=match) as e:
        PosePrior.load(path)
    assert str(path) in str(e.value)
    with pytest.raises(ValueError, match=match):
        MixturePosePrior.load(path)


def test_components_argument_is_checked():
    with pytest.raises(ValueError, match="positive integer"):
        fit_prior(["walk"], components=0)
