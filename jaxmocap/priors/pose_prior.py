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
"""

from __future__ import annotations

from pathlib import Path

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jax import Array

__all__ = ["PosePrior", "DEFAULT_PRIOR_PATH", "default_pose_prior", "JOINT_LIMITS_DEG", "joint_limits"]

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
        cov = 0.5 * (cov + cov.T)
        evals, evecs = np.linalg.eigh(cov)
        if evals.min() <= 0:
            raise ValueError(f"covariance must be positive definite (smallest eigenvalue {evals.min():.3g}).")
        # W = Λ^(-1/2) Vᵀ: Wᵀ W = V Λ⁻¹ Vᵀ = Σ⁻¹.
        whitening = evecs.T / np.sqrt(evals)[:, None]
        if lower is None or upper is None:
            lo, up = joint_limits()
            lower = lo if lower is None else lower
            upper = up if upper is None else upper
        as_leaf = lambda x: jnp.asarray(np.asarray(x, np.float64), dtype)  # noqa: E731
        return cls(as_leaf(mean), as_leaf(whitening), as_leaf(lower), as_leaf(upper))

    @classmethod
    def load(cls, path=DEFAULT_PRIOR_PATH, dtype=jnp.float32) -> PosePrior:
        """Read a prior file (keys mean, covariance, optional lower/upper)."""
        with np.load(path, allow_pickle=False) as f:
            d = {k: f[k] for k in f.files}
        missing = {"mean", "covariance"} - set(d)
        if missing:
            raise ValueError(f"{path}: a pose prior file needs {sorted(missing)}; it has {sorted(d)}.")
        return cls.from_moments(d["mean"], d["covariance"], d.get("lower"), d.get("upper"), dtype)

    def mahalanobis_residual(self, x: Array) -> Array:
        """W (x - μ) for x (..., 69): its squared norm is d_mahal² (eq. 3.14)."""
        return jnp.einsum("ij,...j->...i", self.whitening.astype(x.dtype), x - self.mean.astype(x.dtype))

    def limit_residual(self, x: Array) -> Array:
        """e_limit = min(x - l_lower, 0) + max(x - l_upper, 0) (eq. 3.15), (..., 69)."""
        lo, up = self.lower.astype(x.dtype), self.upper.astype(x.dtype)
        return jnp.minimum(x - lo, 0.0) + jnp.maximum(x - up, 0.0)


def default_pose_prior(dtype=jnp.float32) -> PosePrior:
    """The shipped prior (`pose_prior.npz`, see README.md)."""
    if not DEFAULT_PRIOR_PATH.is_file():
        raise FileNotFoundError(
            f"{DEFAULT_PRIOR_PATH} is missing; rebuild it with `python -m jaxmocap.priors.build`."
        )
    return PosePrior.load(DEFAULT_PRIOR_PATH, dtype)
