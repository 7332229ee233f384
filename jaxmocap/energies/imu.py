"""The energies of the Sparse Inertial Poser as `jaxmocap.solve.Term`s (von Marcard §3.3).

E_motion = w_ori E_ori + w_acc E_acc + w_anthro E_anthro   (eq. 3.5)

- E_ori = 1/(T N_s) Σ_t Σ_s ‖e_ori‖², e_ori = log(R̃_s^g(x_t) (R_s^g(t))⁻¹)^∨ with the model
  sensor orientation R̃_s^g(x_t) = R_b^g(x_t) R_s^b (eq. 3.6-3.8).
- E_acc = 1/(T N_s) Σ_t Σ_s ‖ã^g(t) - a^g(t)‖², the model vertex acceleration
  ã^g(t) = (p(t-1) - 2 p(t) + p(t+1)) / dt² (eq. 3.10) of the sensor point rigidly
  attached to its bone, p = M_b^g(x) p^b (eq. 3.11), against the measured
  a^g = R_s^g a^s - g^g (eq. 3.9, computed once by `global_acceleration`).
- E_anthro = w_mahal 1/T Σ_t d_mahal(t)² + w_limit 1/T Σ_t ‖e_limit(t)‖² (eq. 3.14-3.16);
  with a `MixturePosePrior`, d_mahal² becomes 2 (E_θ − c_min) of SMPLify's mixture.

Each term is a residual function `fn(params, data)`; the engine squares and sums it, so
the weight of a `Term` is w / N_s for the sensor terms and w_anthro w_mahal, w_anthro w_limit
for the prior terms (the 1/T common to all four terms does not change the minimiser and
is left out: the reported costs are per-sequence sums, not means).

Parameters (the engine's per-frame pytree): "pose" (T, 24, 3) axis-angle, a rotation key
(the term functions see (T, 24, 3, 3) local rotation matrices), and for E_acc also
"trans" (T, 3). Data (one sequence; `InertialData`): measured orientations and
accelerations with NaN for dropped samples (masked out), the calibration (sensor-to-bone
rotations, sensor points in their bone frames, the shaped rest joints) and the prior.

Each residual also supplies its analytic Jacobian (eq. 3.17-3.29) for the solver's
left-multiplicative update R_j ← exp(δ_j^) R_j: a perturbation of joint j rotates every
descendant about joint j by ω = R_parent(j)^g δ_j in the world frame, so

- orientation: ∂e_ori/∂δ_j = J_l⁻¹(e_ori) R_parent(j)^g            (eq. 3.17-3.21)
- sensor point: ∂p/∂δ_j = -[p - J_j]_× R_parent(j)^g, ∂p/∂trans = I   (eq. 3.22-3.26)
- prior: ∂x_j/∂δ_j = J_l⁻¹(x_j) for the joint's own angles            (eq. 3.27-3.29)

with J_l⁻¹ the inverse left Jacobian of SO(3) (`rotation.left_jacobian_inverse`); only
sensor bones' ancestors enter. tests/test_inertial.py checks each against forward-mode
AD. The block-diagonal / block-banded structure of eq. 3.30-3.31 is declared through
`Term.bandwidth` (0 for E_ori, E_anthro; 1 for E_acc) and `Term.reads` (which joints a
term sees), and exploited by the engine's banded solver: joints no sensor hangs on (hands,
feet) are seen by the per-frame prior only and are eliminated frame by frame.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jax import Array

from ..body.kinematics import ancestors, chain_transforms, mat3_apply, mat3_mul
from ..body.model import SMPL_PARENTS
from ..priors.pose_prior import MixturePosePrior, PosePrior
from ..rotation import hat, left_jacobian_inverse, log_small, matrix_to_axis_angle
from ..solve import BlockJacobian, Term, nan_mask
from ..timeseries import second_difference, shift_frames

__all__ = [
    "GRAVITY_REACTION",
    "InertialData",
    "global_acceleration",
    "OrientationResidual",
    "AccelerationResidual",
    "MahalanobisResidual",
    "JointLimitResidual",
    "orientation_term",
    "acceleration_term",
    "mahalanobis_term",
    "joint_limit_term",
]

#: g^g of eq. 3.9 as our accelerometers see it: the reaction to gravity, +9.81 m/s² along
#: the world's up axis y (an accelerometer at rest reads R^T (0, 9.81, 0)).
GRAVITY_REACTION = (0.0, 9.81, 0.0)


class InertialData(eqx.Module):
    """Everything the inertial energies read for one sequence (T frames, S sensors).

    orientation: (T, S, 3, 3) measured R_s^g in the model frame (eq. 3.2 applied); NaN = dropped.
    acceleration: (T, S, 3) measured a^g, world frame, gravity removed (eq. 3.9); NaN = dropped.
    sensor_to_bone: (S, 3, 3) R_s^b (eq. 3.3).
    sensor_point: (S, 3) p^b, the sensor's vertex relative to its bone's joint, bone frame.
    rest_joints: (24, 3) the shaped rest joints J(β) of the body.
    prior: the pose prior (μ, W, limits): a `PosePrior` or a `MixturePosePrior`.
    """

    orientation: Array
    acceleration: Array
    sensor_to_bone: Array
    sensor_point: Array
    rest_joints: Array
    prior: PosePrior | MixturePosePrior

    @property
    def num_frames(self) -> int:
        return self.orientation.shape[-4]

    @property
    def num_sensors(self) -> int:
        return self.orientation.shape[-3]


def global_acceleration(orientation: Array, acceleration: Array) -> Array:
    """a^g = R_s^g a^s - g^g (eq. 3.9): (..., 3, 3), (..., 3) -> (..., 3)."""
    g = jnp.asarray(GRAVITY_REACTION, acceleration.dtype)
    return jnp.einsum("...ab,...b->...a", orientation, acceleration) - g


class OrientationResidual(eqx.Module):
    """e_ori(x_t) = log(R_b^g(x_t) R_s^b (R_s^g(t))⁻¹)^∨ per frame and sensor (eq. 3.7): (T, S, 3)."""

    bones: tuple[int, ...] = eqx.field(static=True)
    parents: tuple[int, ...] = eqx.field(static=True, default=SMPL_PARENTS)

    def _chain_and_residual(self, params, data: InertialData):
        R, _ = chain_transforms(self.parents, params["pose"], data.rest_joints, self.bones)
        R_bone = jnp.stack([R[b] for b in self.bones], 1)
        R_model = mat3_mul(R_bone, data.sensor_to_bone.astype(R_bone.dtype))  # eq. 3.6
        R_meas = data.orientation.astype(R_bone.dtype)
        return R, matrix_to_axis_angle(mat3_mul(R_model, jnp.swapaxes(R_meas, -1, -2)))

    def __call__(self, params, data: InertialData) -> Array:
        return self._chain_and_residual(params, data)[1]

    @property
    def reads(self):
        return (("pose", ancestors(self.parents, self.bones)),)

    def jacobian(self, params, data: InertialData) -> dict[str, Array]:
        """∂e_ori/∂δ_j = J_l⁻¹(e) R_parent(j)^g for j on the sensor's chain: pose (T, 1, S, 3, J, 3)."""
        R, e = self._chain_and_residual(params, data)
        Jl = left_jacobian_inverse(e)  # (T, S, 3, 3)
        blocks = _chain_blocks(self.parents, self.bones, R, lambda s, Rp: mat3_mul(Jl[:, s], Rp))
        return {"pose": blocks[:, None]}


class AccelerationResidual(eqx.Module):
    """e_acc(t) = ã^g(x_{t-1}, x_t, x_{t+1}) - a^g(t) (eq. 3.10-3.12): (T, S, 3), bandwidth 1.

    The sensor point moves rigidly with its bone, p = R_b^g(x) p^b + J_b(x) + trans (eq. 3.11).
    """

    bones: tuple[int, ...] = eqx.field(static=True)
    fps: float = eqx.field(static=True)
    parents: tuple[int, ...] = eqx.field(static=True, default=SMPL_PARENTS)

    def _chain_and_points(self, pose, data: InertialData):
        """Chain rotations and joints, and the sensor points without translation (T, S, 3)."""
        R, J = chain_transforms(self.parents, pose, data.rest_joints, self.bones)
        R_bone = jnp.stack([R[b] for b in self.bones], 1)
        p = mat3_apply(R_bone, data.sensor_point.astype(R_bone.dtype)) + jnp.stack([J[b] for b in self.bones], 1)
        return R, J, p

    def __call__(self, params, data: InertialData) -> Array:
        _, _, p = self._chain_and_points(params["pose"], data)
        if "trans" in params:
            p = p + params["trans"][:, None, :]
        a_model = second_difference(p) * (self.fps**2)
        return a_model - data.acceleration.astype(a_model.dtype)

    @property
    def reads(self):
        return (("pose", ancestors(self.parents, self.bones)), ("trans", None))

    def jacobian(self, params, data: InertialData) -> dict[str, Array]:
        """fps² (1, -2, 1)_d ∂p_{t+d}/∂x_{t+d}: pose (T, 3, S, 3, J, 3), trans (T, 3, S, 3, 3)."""
        pose = params["pose"]
        R, J, p = self._chain_and_points(pose, data)

        def block(s, Rp, j):
            return -mat3_mul(hat(p[:, s] - J[j]), Rp)

        P = _chain_blocks(self.parents, self.bones, R, block, with_joint=True)  # (T, S, 3, J, 3)
        eye = jnp.broadcast_to(jnp.eye(3, dtype=pose.dtype), p.shape + (3,))
        out = {"pose": P}
        if "trans" in params:
            out["trans"] = eye
        # Row t reads frames t-1, t, t+1 with weights fps² (1, -2, 1) (eq. 3.10).
        c = self.fps**2
        return {
            k: jnp.stack([c * shift_frames(v, 1), -2.0 * c * v, c * shift_frames(v, -1)], 1) for k, v in out.items()
        }


def _chain_blocks(parents, bones, R, block, with_joint=False) -> Array:
    """Stack block(s, R_parent(j)^g[, j]) (T, 3, 3) for every sensor s and every joint j
    on its bone's chain (zero elsewhere) into (T, S, 3, J, 3)."""
    some = next(iter(R.values()))
    T, dtype = some.shape[0], some.dtype
    eye = jnp.broadcast_to(jnp.eye(3, dtype=dtype), (T, 3, 3))
    zero = jnp.zeros((T, 3, 3), dtype)
    chains = [set(ancestors(parents, (b,))) for b in bones]
    per_joint = []
    for j in range(len(parents)):
        Rp = eye if parents[j] < 0 else R.get(parents[j])
        per_s = [
            (block(s, Rp, j) if with_joint else block(s, Rp)) if j in chains[s] else zero for s in range(len(bones))
        ]
        per_joint.append(jnp.stack(per_s, 1))  # (T, S, 3, 3)
    return jnp.stack(per_joint, -2)


def _joint_angles(local: Array) -> Array:
    """x_t: the 69 axis-angle coordinates of joints 1..23, (T, 24, 3, 3) -> (T, 69)."""
    return log_small(local[:, 1:]).reshape(local.shape[0], -1)


#: The prior terms read the 23 non-root joints.
_PRIOR_JOINTS = tuple(range(1, 24))
_PRIOR_READS = (("pose", _PRIOR_JOINTS),)


class MahalanobisResidual(eqx.Module):
    """W (x_t - μ) with Wᵀ W = Σ⁻¹, so ‖·‖² = d_mahal(t)² (eq. 3.14): (T, 69).

    With a `MixturePosePrior` (SMPLify's mixture, best component per frame) the residual
    is (W_k (x_t − μ_k), √(2 (c_k − c_min))) of the frame's selected component k, (T, 70),
    so ‖·‖² = 2 (E_θ(x_t) − c_min) (see `jaxmocap.priors.pose_prior`).
    """

    reads = _PRIOR_READS

    def __call__(self, params, data: InertialData) -> Array:
        return data.prior.mahalanobis_residual(_joint_angles(params["pose"]))

    def jacobian(self, params, data: InertialData) -> dict[str, BlockJacobian]:
        """∂r/∂δ_j = W_[:, j] J_l⁻¹(x_j) for joints 1..23: W · blockdiag(J_l⁻¹(x_j)).

        W is the prior's ∂r/∂x: one (69, 69) matrix for the single Gaussian, the selected
        component's (W_k; 0) per frame for a mixture, (T, 70, 69) (its constant entry has
        a zero row).
        """
        x = _joint_angles(params["pose"])
        Jl = left_jacobian_inverse(x.reshape(x.shape[0], 23, 3))
        return {"pose": BlockJacobian(Jl, data.prior.mahalanobis_jacobian(x).astype(x.dtype), _PRIOR_JOINTS)}


class JointLimitResidual(eqx.Module):
    """e_limit(t) = min(x_t - l_lower, 0) + max(x_t - l_upper, 0) (eq. 3.15): (T, 23, 3)."""

    reads = _PRIOR_READS

    def __call__(self, params, data: InertialData) -> Array:
        x = _joint_angles(params["pose"])
        return data.prior.limit_residual(x).reshape(x.shape[0], 23, 3)

    def jacobian(self, params, data: InertialData) -> dict[str, BlockJacobian]:
        """∂e_j/∂δ_j = diag(1[x_j outside the box]) J_l⁻¹(x_j) for joints 1..23 (W = I)."""
        x = _joint_angles(params["pose"])
        T = x.shape[0]
        # e_limit is elementwise in x: its derivative is the JVP with a unit tangent.
        _, slope = jax.jvp(data.prior.limit_residual, (x,), (jnp.ones_like(x),))
        Jl = left_jacobian_inverse(x.reshape(T, 23, 3)) * slope.reshape(T, 23, 3, 1)
        return {"pose": BlockJacobian(Jl, None, _PRIOR_JOINTS)}


def _sensor_mask(key: str):
    def mask(data: InertialData) -> Array:
        value = getattr(data, key)
        return nan_mask(value, axis=(-2, -1) if key == "orientation" else -1)

    mask.__name__ = f"{key}_mask"
    mask.__qualname__ = f"_sensor_mask.{key}"
    return mask


_ORI_MASK = _sensor_mask("orientation")
_ACC_MASK = _sensor_mask("acceleration")


def orientation_term(bones, num_sensors: int | None = None, w_ori=1.0, loss=None) -> Term:
    """w_ori E_ori (eq. 3.8) as a `Term`: weight w_ori / N_s, per frame, NaN-masked."""
    n = len(bones) if num_sensors is None else num_sensors
    fn = OrientationResidual(tuple(int(b) for b in bones))
    return Term("ori", fn, w_ori / n, 0, loss, _ORI_MASK, fn.reads, fn.jacobian)


def acceleration_term(bones, fps: float, num_sensors: int | None = None, w_acc=0.05, loss=None) -> Term:
    """w_acc E_acc (eq. 3.13) as a `Term`: weight w_acc / N_s, frames t-1..t+1, NaN-masked."""
    n = len(bones) if num_sensors is None else num_sensors
    fn = AccelerationResidual(tuple(int(b) for b in bones), float(fps))
    return Term("acc", fn, w_acc / n, 1, loss, _ACC_MASK, fn.reads, fn.jacobian)


def mahalanobis_term(w_anthro=1.0, w_mahal=0.003) -> Term:
    """w_anthro w_mahal Σ_t d_mahal(t)² (eq. 3.14, 3.16) as a `Term`."""
    fn = MahalanobisResidual()
    return Term("mahal", fn, w_anthro * w_mahal, 0, None, None, fn.reads, fn.jacobian)


def joint_limit_term(w_anthro=1.0, w_limit=0.1) -> Term:
    """w_anthro w_limit Σ_t ‖e_limit(t)‖² (eq. 3.15, 3.16) as a `Term`."""
    fn = JointLimitResidual()
    return Term("limit", fn, w_anthro * w_limit, 0, None, None, fn.reads, fn.jacobian)
