"""The anthropometric pose prior of SIP: a Gaussian over joint angles plus joint limits.

Von Marcard §3.3.3: E_anthro = w_mahal (1/T) Σ_t d_mahal(t)² + w_limit (1/T) Σ_t ‖e_limit(t)‖²
(eq. 3.16), with d_mahal(t) = √((x_t - μ)ᵀ Σ⁻¹ (x_t - μ)) (eq. 3.14) and the hinge
e_limit(t) = min(x_t - l_lower, 0) + max(x_t - l_upper, 0) (eq. 3.15).

x_t here is the 69-vector of the 23 non-root joints' axis-angle coordinates (joints 1..23
of SMPL's tree, three per joint, in SMPL's order). The root rotation and the translation
are global quantities no pose distribution can say anything about, so the prior leaves
them out (the thesis's x ∈ R⁷⁵ includes them; with a learnt covariance their rows would
only encode the heading of the training clips).

The shipped prior `pose_prior.npz` is replaceable: any file with `mean` (69,),
`covariance` (69, 69), `lower` (69,) and `upper` (69,) in radians works
(`PosePrior.load(path)`). See README.md in this folder for where the default came from.

`MixturePosePrior` is the richer form of SMPLify (Bogo et al. 2016, eq. 6): K Gaussians
with weights w_k, of which each frame takes its best,

    E_θ(x) = min_k [½ d_k(x)² − log w_k + ½ log det Σ_k] = min_k [½ d_k(x)² + c_k],
    d_k(x)² = (x − μ_k)ᵀ Σ_k⁻¹ (x − μ_k).

It has `PosePrior`'s interface, so the SIP energies (`jaxmocap.energies.imu`) take either.
Its least-squares residual is r(x) = (W_k (x − μ_k), √(2 (c_k − c_min))) for the selected
k = argmin_k [d_k(x)² + 2 (c_k − c_min)], c_min = min_k c_k: ‖r‖² = 2 (E_θ(x) − c_min).
The constant entry keeps the solver's cost exactly the mixture energy (up to the constant
c_min and the factor 2, which makes K = 1 the single Gaussian's d_mahal²): the cost is then
continuous where the choice of k switches, and the LM's cost-decrease test judges the
energy that chose k. (Leaving c_k out of the residual and using it only to pick k would
make the cost jump at every switch.) The entry does not depend on x: its Jacobian row is 0,
and the rows of the rest are the selected component's W_k. The choice of k is piecewise
constant in x; the Jacobian is that of the selected component (the derivative of the
minimum wherever it is attained by one component).
"""

from __future__ import annotations

import errno
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

__all__ = [
    "PosePrior",
    "MixturePosePrior",
    "DEFAULT_PRIOR_PATH",
    "default_pose_prior",
    "load_pose_prior",
    "JOINT_LIMITS_DEG",
    "joint_limits",
]

DEFAULT_PRIOR_PATH = Path(__file__).with_name("pose_prior.npz")

#: Joint limits on the axis-angle components (x, y, z) of each non-root joint, degrees,
#: in SMPL's joint frames (y up, the body facing +z, its left side +x; at the rest pose
#: every joint frame is the world frame). For a rotation about one axis the component is
#: the angle itself; for combined rotations the components are the exponential
#: coordinates, so the box is an approximation of the anatomical range, kept generous
#: (a limit that cuts into real motion would bias every fit). Anatomical sources: the
#: usual clinical ranges of motion (AAOS), widened by about 15°. Sign conventions:
#: knee flexion is +x (shank swings back), hip flexion is -x (thigh swings forward),
#: left elbow flexion is -y and right elbow flexion +y (forearm swings forward).
JOINT_LIMITS_DEG: dict[str, tuple[tuple[float, float], tuple[float, float], tuple[float, float]]] = {
    "left_hip": ((-150, 50), (-70, 70), (-60, 90)),
    "right_hip": ((-150, 50), (-70, 70), (-90, 60)),
    "spine1": ((-60, 90), (-60, 60), (-50, 50)),
    "left_knee": ((-15, 165), (-40, 40), (-30, 30)),
    "right_knee": ((-15, 165), (-40, 40), (-30, 30)),
    "spine2": ((-40, 60), (-45, 45), (-40, 40)),
    "left_ankle": ((-60, 75), (-50, 50), (-50, 50)),
    "right_ankle": ((-60, 75), (-50, 50), (-50, 50)),
    "spine3": ((-40, 60), (-45, 45), (-40, 40)),
    "left_foot": ((-60, 60), (-30, 30), (-30, 30)),
    "right_foot": ((-60, 60), (-30, 30), (-30, 30)),
    "neck": ((-70, 80), (-90, 90), (-60, 60)),
    "left_collar": ((-40, 40), (-50, 50), (-40, 50)),
    "right_collar": ((-40, 40), (-50, 50), (-50, 40)),
    "head": ((-60, 60), (-80, 80), (-50, 50)),
    "left_shoulder": ((-120, 120), (-150, 120), (-120, 120)),
    "right_shoulder": ((-120, 120), (-120, 150), (-120, 120)),
    "left_elbow": ((-60, 60), (-165, 20), (-60, 60)),
    "right_elbow": ((-60, 60), (-20, 165), (-60, 60)),
    "left_wrist": ((-100, 100), (-60, 60), (-100, 100)),
    "right_wrist": ((-100, 100), (-60, 60), (-100, 100)),
    "left_hand": ((-60, 60), (-40, 40), (-60, 60)),
    "right_hand": ((-60, 60), (-40, 40), (-60, 60)),
}  # fmt: skip


def joint_limits() -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper), each (69,) radians, from `JOINT_LIMITS_DEG` in SMPL's joint order."""
    from ..body.model import SMPL_JOINT_NAMES

    rows = np.array([JOINT_LIMITS_DEG[n] for n in SMPL_JOINT_NAMES[1:]], np.float64)  # (23, 3, 2)
    return np.radians(rows[..., 0]).reshape(-1), np.radians(rows[..., 1]).reshape(-1)


class PosePrior(eqx.Module):
    """Gaussian pose prior N(μ, Σ) and joint-limit box over the 69 non-root joint angles.

    Attributes (all (69,) or (69, 69), radians):
        mean: μ.
        whitening: W with Wᵀ W = Σ⁻¹, so that d_mahal = ‖W (x - μ)‖ (eq. 3.14).
        lower, upper: l_lower, l_upper of eq. 3.15.
    """

    mean: Array
    whitening: Array
    lower: Array
    upper: Array

    @classmethod
    def from_moments(cls, mean, covariance, lower=None, upper=None, dtype=jnp.float32) -> PosePrior:
        """The prior from μ (69,) and Σ (69, 69); limits default to `joint_limits()`."""
        mean = np.asarray(mean, np.float64)
        cov = np.asarray(covariance, np.float64)
        if mean.shape != (69,) or cov.shape != (69, 69):
            raise ValueError(f"mean must be (69,) and covariance (69, 69); got {mean.shape}, {cov.shape}.")
        whitening, _ = _whitening(cov)
        lower, upper = _limits(lower, upper)
        as_leaf = lambda x: jnp.asarray(np.asarray(x, np.float64), dtype)  # noqa: E731
        return cls(as_leaf(mean), as_leaf(whitening), as_leaf(lower), as_leaf(upper))

    @classmethod
    def load(cls, path=DEFAULT_PRIOR_PATH, dtype=jnp.float32) -> PosePrior | MixturePosePrior:
        """Read a prior file (keys mean, covariance, optional lower/upper; see README.md).

        A file of a mixture with K > 1 components (key `weights`) gives a `MixturePosePrior`,
        which the SIP energies take alike; one with K = 1 gives this single Gaussian.
        """
        return load_pose_prior(path, dtype)

    @property
    def num_components(self) -> int:
        return 1

    def mahalanobis_residual(self, x: Array) -> Array:
        """W (x - μ) for x (..., 69): its squared norm is d_mahal² (eq. 3.14)."""
        return jnp.einsum("ij,...j->...i", self.whitening.astype(x.dtype), x - self.mean.astype(x.dtype))

    def mahalanobis_jacobian(self, x: Array) -> Array:
        """∂r/∂x of `mahalanobis_residual`: W (69, 69), the same for every frame."""
        return self.whitening.astype(x.dtype)

    def limit_residual(self, x: Array) -> Array:
        """e_limit = min(x - l_lower, 0) + max(x - l_upper, 0) (eq. 3.15), (..., 69)."""
        return _limit_residual(self, x)

    def neg_log_likelihood(self, x: Array) -> Array:
        """−log N(x; μ, Σ) (..., ) in nats: ½ d² + ½ log det Σ + (69/2) log 2π."""
        r = self.mahalanobis_residual(x)
        half_logdet = -jnp.linalg.slogdet(self.whitening.astype(x.dtype))[1]
        return 0.5 * jnp.sum(r**2, -1) + half_logdet + 0.5 * x.shape[-1] * jnp.log(2 * jnp.pi).astype(x.dtype)


class MixturePosePrior(eqx.Module):
    """SMPLify's mixture-of-Gaussians pose prior (best component per frame) and the joint-limit box.

    The residual and its Jacobian are those of the module docstring: r(x) (..., 70), the
    whitened offset from the selected component and √(2 (c_k − c_min)).

    Attributes (radians):
        weights: w_k (K,), summing to 1.
        means: μ_k (K, 69).
        whitenings: W_k (K, 69, 69) with W_kᵀ W_k = Σ_k⁻¹.
        constants: c_k = −log w_k + ½ log det Σ_k (K,).
        lower, upper: l_lower, l_upper of eq. 3.15 (69,).
    """

    weights: Array
    means: Array
    whitenings: Array
    constants: Array
    lower: Array
    upper: Array

    @classmethod
    def from_moments(
        cls, means, covariances, weights=None, lower=None, upper=None, dtype=jnp.float32
    ) -> MixturePosePrior:
        """The mixture from μ_k (K, 69), Σ_k (K, 69, 69) and w_k (K,) (default 1/K each).

        A single μ (69,), Σ (69, 69) is the K = 1 mixture. Limits default to `joint_limits()`.
        """
        means = np.asarray(means, np.float64)
        covs = np.asarray(covariances, np.float64)
        if means.shape == (69,) and covs.shape == (69, 69):
            means, covs = means[None], covs[None]
        if means.ndim != 2 or means.shape[1:] != (69,) or covs.shape != (len(means), 69, 69) or not len(means):
            raise ValueError(f"means must be (K, 69) and covariances (K, 69, 69) with K >= 1; "
                             f"got {means.shape}, {covs.shape}.")  # fmt: skip
        K = len(means)
        weights = np.full(K, 1.0 / K) if weights is None else np.asarray(weights, np.float64)
        if weights.shape != (K,):
            raise ValueError(f"weights must be ({K},), one per component; got {weights.shape}.")
        if not np.all(np.isfinite(weights)) or weights.min() <= 0 or abs(weights.sum() - 1.0) > 1e-5:
            raise ValueError(
                f"weights must be positive and sum to 1; got {weights.tolist()} (sum {weights.sum():.6g})."
            )
        weights = weights / weights.sum()
        if not (np.all(np.isfinite(means)) and np.all(np.isfinite(covs))):
            raise ValueError("means and covariances must be finite (found NaN or inf).")
        whitenings, half_logdets = [], []
        for k in range(K):
            try:
                W, half_logdet = _whitening(covs[k])
            except ValueError as e:
                raise ValueError(f"component {k}: {e}") from None
            whitenings.append(W)
            half_logdets.append(half_logdet)
        constants = -np.log(weights) + np.asarray(half_logdets)
        lower, upper = _limits(lower, upper)
        as_leaf = lambda x: jnp.asarray(np.asarray(x, np.float64), dtype)  # noqa: E731
        return cls(as_leaf(weights), as_leaf(means), as_leaf(np.stack(whitenings)), as_leaf(constants),
                   as_leaf(lower), as_leaf(upper))  # fmt: skip

    @classmethod
    def load(cls, path=DEFAULT_PRIOR_PATH, dtype=jnp.float32) -> MixturePosePrior:
        """Read a prior file as a mixture: a single-Gaussian file is the K = 1 mixture."""
        d = _read_prior_file(path)
        try:
            return cls.from_moments(d["mean"], d["covariance"], d.get("weights"), d.get("lower"), d.get("upper"), dtype)
        except ValueError as e:
            raise ValueError(f"{path}: {e}") from None

    @property
    def num_components(self) -> int:
        return int(self.weights.shape[-1])

    @property
    def mean(self) -> Array:
        """The mixture's mean Σ_k w_k μ_k (69,) (e.g. a neutral start pose)."""
        return jnp.einsum("k,ki->i", self.weights, self.means)

    def _whitened(self, x: Array) -> Array:
        """W_k (x − μ_k) for every component: (..., K, 69)."""
        W, mu = self.whitenings.astype(x.dtype), self.means.astype(x.dtype)
        return jnp.einsum("kij,...kj->...ki", W, x[..., None, :] - mu)

    def _offsets(self, dtype) -> Array:
        """√(2 (c_k − c_min)) (K,)."""
        c = self.constants.astype(dtype)
        return jnp.sqrt(2.0 * (c - jnp.min(c)))

    def _select(self, x: Array):
        r = self._whitened(x)
        off = self._offsets(x.dtype)
        k = jnp.argmin(jnp.sum(r**2, -1) + off**2, axis=-1)
        return k, r, off

    def component(self, x: Array) -> Array:
        """The selected k = argmin_k [d_k(x)² + 2 c_k] per frame, (...,) int: piecewise constant in x."""
        return self._select(x)[0]

    def mahalanobis_residual(self, x: Array) -> Array:
        """(W_k (x − μ_k), √(2 (c_k − c_min))) of the selected k, (..., 70): ‖r‖² = 2 (E_θ(x) − c_min)."""
        k, r, off = self._select(x)
        sel = jnp.take_along_axis(r, k[..., None, None], axis=-2)[..., 0, :]
        return jnp.concatenate([sel, off[k][..., None]], -1)

    def mahalanobis_jacobian(self, x: Array) -> Array:
        """∂r/∂x with k held at its selection: (W_k; 0) per frame, (..., 70, 69)."""
        k = jax.lax.stop_gradient(self.component(x))
        W = self.whitenings.astype(x.dtype)[k]
        return jnp.concatenate([W, jnp.zeros_like(W[..., :1, :])], -2)

    def energy(self, x: Array) -> Array:
        """SMPLify's E_θ(x) = min_k [½ d_k(x)² + c_k] (...,) (= ½ ‖r‖² + c_min)."""
        r = self._whitened(x)
        return jnp.min(0.5 * jnp.sum(r**2, -1) + self.constants.astype(x.dtype), axis=-1)

    def limit_residual(self, x: Array) -> Array:
        """e_limit = min(x - l_lower, 0) + max(x - l_upper, 0) (eq. 3.15), (..., 69)."""
        return _limit_residual(self, x)

    def neg_log_likelihood(self, x: Array) -> Array:
        """The exact mixture's −log Σ_k w_k N(x; μ_k, Σ_k) (...,) in nats (not the min approximation)."""
        r = self._whitened(x)
        log_terms = -0.5 * jnp.sum(r**2, -1) - self.constants.astype(x.dtype)
        return -jax.scipy.special.logsumexp(log_terms, axis=-1) + 0.5 * x.shape[-1] * jnp.log(2 * jnp.pi).astype(
            x.dtype
        )


def _whitening(cov: np.ndarray) -> tuple[np.ndarray, float]:
    """W = Λ^(-1/2) Vᵀ (Wᵀ W = Σ⁻¹) and ½ log det Σ of a symmetric positive definite Σ."""
    cov = 0.5 * (cov + cov.T)
    evals, evecs = np.linalg.eigh(cov)
    if evals.min() <= 0:
        raise ValueError(f"covariance must be positive definite (smallest eigenvalue {evals.min():.3g}).")
    return evecs.T / np.sqrt(evals)[:, None], 0.5 * float(np.sum(np.log(evals)))


def _limits(lower, upper) -> tuple[np.ndarray, np.ndarray]:
    lo, up = joint_limits() if lower is None or upper is None else (None, None)
    lower = lo if lower is None else np.asarray(lower, np.float64)
    upper = up if upper is None else np.asarray(upper, np.float64)
    if np.shape(lower) != (69,) or np.shape(upper) != (69,):
        raise ValueError(f"lower and upper must be (69,); got {np.shape(lower)}, {np.shape(upper)}.")
    return lower, upper


def _limit_residual(prior, x: Array) -> Array:
    lo, up = prior.lower.astype(x.dtype), prior.upper.astype(x.dtype)
    return jnp.minimum(x - lo, 0.0) + jnp.maximum(x - up, 0.0)


def _read_prior_file(path) -> dict[str, np.ndarray]:
    """The arrays of a prior .npz, with a ValueError naming the file if it is not one."""
    from ..motion.skeleton import read_npz

    if not Path(path).is_file():
        raise FileNotFoundError(errno.ENOENT, "no such pose prior file", str(path))
    try:
        # read_npz closes its file when a damaged zip makes numpy raise (np.load leaks it).
        d = read_npz(Path(path))
    except ValueError as e:
        raise ValueError(f"{path}: not a readable .npz pose prior file ({e}).") from None
    missing = {"mean", "covariance"} - set(d)
    if missing:
        raise ValueError(f"{path}: a pose prior file needs {sorted(missing)}; it has {sorted(d)}.")
    mean = d["mean"]
    if "weights" not in d and mean.ndim != 1:
        raise ValueError(f"{path}: mean has shape {mean.shape} but there is no `weights`: a single Gaussian "
                         "has mean (69,), a mixture weights (K,), mean (K, 69) and covariance (K, 69, 69).")  # fmt: skip
    if "weights" in d and (d["weights"].ndim != 1 or mean.ndim != 2):
        raise ValueError(f"{path}: a mixture file needs weights (K,), mean (K, 69), covariance (K, 69, 69); "
                         f"got {d['weights'].shape}, {mean.shape}, {d['covariance'].shape}.")  # fmt: skip
    return d


def load_pose_prior(path=DEFAULT_PRIOR_PATH, dtype=jnp.float32) -> PosePrior | MixturePosePrior:
    """A prior file as `PosePrior` (one Gaussian, or K = 1) or `MixturePosePrior` (K > 1)."""
    d = _read_prior_file(path)
    try:
        if "weights" in d and len(d["weights"]) > 1:
            return MixturePosePrior.from_moments(d["mean"], d["covariance"], d["weights"], d.get("lower"),
                                                 d.get("upper"), dtype)  # fmt: skip
        mean, cov = (d["mean"][0], d["covariance"][0]) if "weights" in d else (d["mean"], d["covariance"])
        if "weights" in d and not np.isclose(float(d["weights"][0]), 1.0):
            raise ValueError(f"the weight of a single component must be 1; got {float(d['weights'][0])}.")
        return PosePrior.from_moments(mean, cov, d.get("lower"), d.get("upper"), dtype)
    except (ValueError, IndexError) as e:
        raise ValueError(f"{path}: {e}") from None


def default_pose_prior(dtype=jnp.float32) -> PosePrior:
    """The shipped prior (`pose_prior.npz`, see README.md)."""
    if not DEFAULT_PRIOR_PATH.is_file():
        raise FileNotFoundError(f"{DEFAULT_PRIOR_PATH} is missing; rebuild it with `python -m jaxmocap.priors.build`.")
    return PosePrior.load(DEFAULT_PRIOR_PATH, dtype)
