"""Rotations on SO(3): axis-angle, matrices, quaternions and the 6D representation.

Every map is written for a single rotation with arbitrary leading batch axes, and is
jit-, vmap- and grad-safe in float32 and float64. Small-angle branches use Taylor
series behind a double `where`, so values *and gradients* stay finite at the identity
(von Marcard §2.1.2, eq. 2.10-2.16: exp and log of so(3)).

Conventions: quaternions are (w, x, y, z) with w >= 0 after `quaternion_from_matrix`;
axis-angle vectors are ω = θ·axis with θ in [0, π]; matrices act on column vectors.

Host twins (NumPy in, NumPy out, float64, through SciPy) sit at the end for code that runs
once per sequence outside JAX (sensor error models, file readers, resampling): `host_exp`,
`host_log`, `host_compose`, `host_rotate`, `host_euler`, `host_slerp`. They are the package's
one door to SciPy's `Rotation`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

__all__ = [
    "hat",
    "vee",
    "axis_angle_to_matrix",
    "matrix_to_axis_angle",
    "quaternion_to_matrix",
    "matrix_to_quaternion",
    "axis_angle_to_quaternion",
    "quaternion_to_axis_angle",
    "quaternion_multiply",
    "matrix_to_6d",
    "sixd_to_matrix",
    "geodesic_angle",
    "nearest_rotation",
    "rotation_about_axis",
    "rotation_y",
    "left_jacobian",
    "left_jacobian_inverse",
    "log_small",
    "host_exp",
    "host_log",
    "host_compose",
    "host_rotate",
    "host_euler",
    "host_slerp",
]

# Below this θ² the Taylor branch is used; its truncation error (θ⁶ terms) is far below
# float64 epsilon there, and the exact branch is accurate above it.
_SMALL_THETA2 = 1e-6


def hat(omega: Array) -> Array:
    """Skew-symmetric matrix ω^ with ω^ v = ω × v.  (..., 3) -> (..., 3, 3)."""
    x, y, z = omega[..., 0], omega[..., 1], omega[..., 2]
    zero = jnp.zeros_like(x)
    return jnp.stack(
        [
            jnp.stack([zero, -z, y], -1),
            jnp.stack([z, zero, -x], -1),
            jnp.stack([-y, x, zero], -1),
        ],
        -2,
    )


def vee(matrix: Array) -> Array:
    """Inverse of `hat` for the skew part of a matrix.  (..., 3, 3) -> (..., 3)."""
    return 0.5 * jnp.stack(
        [
            matrix[..., 2, 1] - matrix[..., 1, 2],
            matrix[..., 0, 2] - matrix[..., 2, 0],
            matrix[..., 1, 0] - matrix[..., 0, 1],
        ],
        -1,
    )


def _safe_theta2(theta2: Array) -> tuple[Array, Array]:
    """(small-angle mask, θ² with the small entries replaced by 1) for NaN-free grads."""
    small = theta2 < _SMALL_THETA2
    return small, jnp.where(small, jnp.ones_like(theta2), theta2)


@jax.jit
def axis_angle_to_matrix(omega: Array) -> Array:
    """Rodrigues' formula R = I + a ω^ + b ω^², a = sin θ/θ, b = (1 - cos θ)/θ².

    Von Marcard eq. 2.14. (..., 3) -> (..., 3, 3).
    """
    if jnp.shape(omega)[-1:] != (3,):  # a shape check: free at trace time
        raise ValueError(f"omega has shape {jnp.shape(omega)}; expected (..., 3) axis-angle vectors.")
    theta2 = jnp.sum(omega * omega, axis=-1)
    small, safe2 = _safe_theta2(theta2)
    theta = jnp.sqrt(safe2)
    a = jnp.where(small, 1.0 - theta2 / 6.0 + theta2**2 / 120.0, jnp.sin(theta) / theta)
    # 1 - cos θ = 2 sin²(θ/2) avoids the cancellation that ruins float32 at small θ.
    half_sin = jnp.sin(0.5 * theta)
    b = jnp.where(small, 0.5 - theta2 / 24.0 + theta2**2 / 720.0, 2.0 * half_sin * half_sin / safe2)
    K = hat(omega)
    eye = jnp.eye(3, dtype=omega.dtype)
    return eye + a[..., None, None] * K + b[..., None, None] * (K @ K)


def left_jacobian_inverse(omega: Array) -> Array:
    """J_l⁻¹(ω) = I - ½ ω^ + c(θ) ω^², c = (1 - (θ/2) cot(θ/2)) / θ²  (..., 3) -> (..., 3, 3).

    The derivative of the logarithm under a left perturbation: log(exp(δ^) exp(ω^))^∨ =
    ω + J_l⁻¹(ω) δ + O(δ²) (von Marcard §2.1.2, used for the analytic Jacobians of
    eq. 3.17-3.29). Finite for θ < 2π (c(π) = 1/π²); Taylor series below θ² = 10⁻²,
    where float32 would lose c to cancellation.
    """
    theta2 = jnp.sum(omega * omega, axis=-1)
    small = theta2 < 1e-2
    safe2 = jnp.where(small, jnp.ones_like(theta2), theta2)
    half = 0.5 * jnp.sqrt(safe2)
    exact = (1.0 - half * jnp.cos(half) / jnp.sin(half)) / safe2
    c = jnp.where(small, 1.0 / 12.0 + theta2 / 720.0 + theta2**2 / 30240.0, exact)
    K = hat(omega)
    eye = jnp.eye(3, dtype=omega.dtype)
    return eye - 0.5 * K + c[..., None, None] * (K @ K)


def left_jacobian(omega: Array) -> Array:
    """J_l(ω) = I + a(θ) ω^ + b(θ) ω^², a = (1 - cos θ)/θ², b = (θ - sin θ)/θ³  (..., 3) -> (..., 3, 3).

    exp((ω + δ)^) ≈ exp((J_l(ω) δ)^) exp(ω^); also the V matrix of SE(3)'s exponential,
    t = J_l(φ) ρ. Taylor series below θ² = 10⁻² (finite values and gradients at 0).
    """
    theta2 = jnp.sum(omega * omega, axis=-1)
    small = theta2 < 1e-2
    safe2 = jnp.where(small, jnp.ones_like(theta2), theta2)
    theta = jnp.sqrt(safe2)
    a = jnp.where(small, 0.5 - theta2 / 24.0 + theta2**2 / 720.0, (1.0 - jnp.cos(theta)) / safe2)
    b = jnp.where(small, 1.0 / 6.0 - theta2 / 120.0 + theta2**2 / 5040.0, (theta - jnp.sin(theta)) / (safe2 * theta))
    K = hat(omega)
    eye = jnp.eye(3, dtype=omega.dtype)
    return eye + a[..., None, None] * K + b[..., None, None] * (K @ K)


def rotation_about_axis(axis: Array, angle: Array) -> Array:
    """Rotation by `angle` (...,) about a unit `axis` (..., 3)."""
    return axis_angle_to_matrix(axis * jnp.asarray(angle)[..., None])


def rotation_y(angle: Array) -> Array:
    """R_y(γ): rotation by γ (...,) about the world vertical (+y). -> (..., 3, 3)."""
    angle = jnp.asarray(angle)
    return axis_angle_to_matrix(jnp.stack([jnp.zeros_like(angle), angle, jnp.zeros_like(angle)], -1))


@jax.jit
def matrix_to_quaternion(matrix: Array) -> Array:
    """Rotation matrix to unit quaternion (w, x, y, z) with w >= 0.  (..., 3, 3) -> (..., 4).

    Shepperd's method: of the four algebraically equal formulas, use the one whose
    square root has the largest argument, which keeps it well conditioned near θ = π.
    """
    m = matrix
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    trace = m00 + m11 + m22
    # 4 q_k² for k = w, x, y, z.
    four_sq = jnp.stack([1.0 + trace, 1.0 + m00 - m11 - m22, 1.0 - m00 + m11 - m22, 1.0 - m00 - m11 + m22], -1)
    best = jnp.argmax(four_sq, axis=-1)
    # Clamp so the branches not taken have finite gradients too.
    r = jnp.sqrt(jnp.maximum(four_sq, 1e-12))  # 2|q_k|
    d21, d02, d10 = m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]
    s21, s02, s10 = m[..., 2, 1] + m[..., 1, 2], m[..., 0, 2] + m[..., 2, 0], m[..., 1, 0] + m[..., 0, 1]
    candidates = [
        jnp.stack([r[..., 0], d21 / r[..., 0], d02 / r[..., 0], d10 / r[..., 0]], -1),
        jnp.stack([d21 / r[..., 1], r[..., 1], s10 / r[..., 1], s02 / r[..., 1]], -1),
        jnp.stack([d02 / r[..., 2], s10 / r[..., 2], r[..., 2], s21 / r[..., 2]], -1),
        jnp.stack([d10 / r[..., 3], s02 / r[..., 3], s21 / r[..., 3], r[..., 3]], -1),
    ]
    # Elementwise selects rather than a gather: they fuse, where XLA-CPU runs gathers
    # element by element (this map sits inside every E_ori Jacobian).
    q = candidates[3]
    for k in (2, 1, 0):
        q = jnp.where((best == k)[..., None], candidates[k], q)
    q = 0.5 * q
    q = q / jnp.linalg.norm(q, axis=-1, keepdims=True)
    return jnp.where(q[..., :1] < 0, -q, q)


def quaternion_to_matrix(quaternion: Array) -> Array:
    """Unit quaternion (w, x, y, z) to rotation matrix.  (..., 4) -> (..., 3, 3)."""
    q = quaternion / jnp.linalg.norm(quaternion, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return jnp.stack(
        [
            jnp.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            jnp.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            jnp.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def axis_angle_to_quaternion(omega: Array) -> Array:
    """(..., 3) -> (..., 4): q = (cos θ/2, sin(θ/2)/θ · ω)."""
    theta2 = jnp.sum(omega * omega, axis=-1)
    small, safe2 = _safe_theta2(theta2)
    theta = jnp.sqrt(safe2)
    # sin(θ/2)/θ and cos(θ/2) with their Taylor series at 0.
    s = jnp.where(small, 0.5 - theta2 / 48.0 + theta2**2 / 3840.0, jnp.sin(0.5 * theta) / theta)
    c = jnp.where(small, 1.0 - theta2 / 8.0 + theta2**2 / 384.0, jnp.cos(0.5 * theta))
    return jnp.concatenate([c[..., None], s[..., None] * omega], -1)


@jax.jit
def quaternion_to_axis_angle(quaternion: Array) -> Array:
    """(..., 4) -> (..., 3), θ in [0, π]: ω = 2 atan2(|v|, w) / |v| · v with w >= 0."""
    q = quaternion / jnp.linalg.norm(quaternion, axis=-1, keepdims=True)
    q = jnp.where(q[..., :1] < 0, -q, q)
    w, v = q[..., 0], q[..., 1:]
    n2 = jnp.sum(v * v, axis=-1)
    small, safe2 = _safe_theta2(n2)
    n = jnp.sqrt(safe2)
    # Near the identity w ≈ 1 and 2 atan2(n, w)/n = (2/w)(1 - n²/(3w²) + n⁴/(5w⁴)).
    w_safe = jnp.where(small, w, jnp.ones_like(w))
    ratio = n2 / (w_safe * w_safe)
    factor = jnp.where(
        small,
        2.0 / w_safe * (1.0 - ratio / 3.0 + ratio * ratio / 5.0),
        2.0 * jnp.arctan2(n, w) / n,
    )
    return factor[..., None] * v


def matrix_to_axis_angle(matrix: Array) -> Array:
    """Logarithm map log(R)^∨ (von Marcard eq. 2.15-2.16).  (..., 3, 3) -> (..., 3).

    Goes through the quaternion so that it stays accurate (and differentiable)
    near θ = π, where the textbook formula θ/(2 sin θ)(R - Rᵀ)^∨ loses all precision.
    """
    return quaternion_to_axis_angle(matrix_to_quaternion(matrix))


def quaternion_multiply(p: Array, q: Array) -> Array:
    """Hamilton product p ⊗ q, so that R(p ⊗ q) = R(p) R(q).  (..., 4) x (..., 4)."""
    pw, px, py, pz = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
    qw, qx, qy, qz = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return jnp.stack(
        [
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ],
        -1,
    )


def matrix_to_6d(matrix: Array) -> Array:
    """The continuous 6D representation (Zhou et al. 2019): the first two columns."""
    return jnp.concatenate([matrix[..., :, 0], matrix[..., :, 1]], -1)


def sixd_to_matrix(sixd: Array) -> Array:
    """Gram-Schmidt of the two 3-vectors in (..., 6) to a rotation matrix."""
    a1, a2 = sixd[..., :3], sixd[..., 3:]
    b1 = a1 / jnp.linalg.norm(a1, axis=-1, keepdims=True)
    a2 = a2 - jnp.sum(b1 * a2, -1, keepdims=True) * b1
    b2 = a2 / jnp.linalg.norm(a2, axis=-1, keepdims=True)
    b3 = jnp.cross(b1, b2)
    return jnp.stack([b1, b2, b3], -1)


def nearest_rotation(matrix: Array) -> Array:
    """The rotation closest to a 3x3 matrix in the Frobenius norm (SVD, det fixed to +1):
    how a regressed rotation matrix (DIP's outputs) becomes a rotation.  (..., 3, 3)."""
    u, _, vt = jnp.linalg.svd(matrix)
    d = jnp.sign(jnp.linalg.det(u @ vt))
    u = u.at[..., :, 2].multiply(jnp.where(d == 0, 1.0, d)[..., None])
    return u @ vt


def geodesic_angle(r1: Array, r2: Array) -> Array:
    """Angle ‖log(R₁ R₂ᵀ)‖ in radians (MPJAE, von Marcard eq. 2.74).  -> (...,)."""
    return jnp.linalg.norm(matrix_to_axis_angle(r1 @ jnp.swapaxes(r2, -1, -2)), axis=-1)


def log_small(R: Array) -> Array:
    """log(R)^∨ for rotations with angle θ < π - 0.05, cheap and AD-safe: (..., 3, 3) -> (..., 3).

    θ = atan2(sin θ, cos θ), ω = θ / (2 sin θ) (R - Rᵀ)^∨ (von Marcard eq. 2.15-2.16), with
    its Taylor series near θ = 0. For joint angles (limited to < 170°) and small residual
    rotations, where it is several times cheaper than `matrix_to_axis_angle` (the general one).
    """
    v = jnp.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    c = jnp.clip(0.5 * (R[..., 0, 0] + R[..., 1, 1] + R[..., 2, 2] - 1.0), -1.0 + 1e-6, 1.0)
    s2 = 0.25 * jnp.sum(v * v, -1)  # sin² θ
    small = s2 < 1e-6
    s = jnp.sqrt(jnp.where(small, 1.0, s2))
    theta = jnp.arctan2(s, c)
    factor = jnp.where(small, 0.5 + s2 / 12.0, theta / (2.0 * s))
    return factor[..., None] * v


# --- host twins ---------------------------------------------------------------------------


def host_exp(omega) -> np.ndarray:
    """exp(ω^) on the host: (..., 3) -> (..., 3, 3), float64 (SciPy)."""
    from scipy.spatial.transform import Rotation

    v = np.asarray(omega, np.float64)
    return Rotation.from_rotvec(v.reshape(-1, 3)).as_matrix().reshape(*v.shape, 3)


def host_log(matrix) -> np.ndarray:
    """log(R)^∨ on the host: (..., 3, 3) -> (..., 3), float64 (SciPy)."""
    from scipy.spatial.transform import Rotation

    R = np.asarray(matrix, np.float64)
    return Rotation.from_matrix(R.reshape(-1, 3, 3)).as_rotvec().reshape(*R.shape[:-1])


def host_compose(*omegas) -> np.ndarray:
    """Rotation vectors of the product exp(ω₁^) exp(ω₂^) ⋯ on the host: each (..., 3),
    broadcast against each other -> (..., 3), float64 (SciPy's quaternion product)."""
    from scipy.spatial.transform import Rotation

    if not omegas:
        raise ValueError("host_compose needs at least one rotation vector.")
    # Copies: SciPy asks for writable buffers, which broadcast views are not.
    vs = [np.array(v) for v in np.broadcast_arrays(*(np.asarray(w, np.float64) for w in omegas))]
    shape = vs[0].shape
    product = Rotation.from_rotvec(vs[0].reshape(-1, 3))
    for v in vs[1:]:
        product = product * Rotation.from_rotvec(v.reshape(-1, 3))
    return product.as_rotvec().reshape(shape)


def host_rotate(matrix, omega) -> np.ndarray:
    """Rotation vectors of R exp(ω^) on the host, for one R (3, 3) and ω (..., 3) -> (..., 3),
    float64 (e.g. a root orientation in a rotated world)."""
    from scipy.spatial.transform import Rotation

    R, v = np.asarray(matrix, np.float64), np.asarray(omega, np.float64)
    if R.shape != (3, 3):
        raise ValueError(f"matrix has shape {R.shape}; expected one (3, 3) rotation.")
    return (Rotation.from_matrix(R) * Rotation.from_rotvec(v.reshape(-1, 3))).as_rotvec().reshape(v.shape)


def host_euler(axes: str, angles, degrees: bool = False) -> np.ndarray:
    """Euler-angle rotations on the host: (..., len(axes)) -> (..., 3, 3), float64.

    `axes` as SciPy's `from_euler`: lower case ("zyx") for fixed axes, the first applied
    first; upper case ("ZYX") for intrinsic axes, as a BVH file lists its channels.
    """
    from scipy.spatial.transform import Rotation

    a = np.asarray(angles, np.float64)
    flat = a.reshape(-1, len(axes))
    return Rotation.from_euler(axes, flat, degrees=degrees).as_matrix().reshape(*a.shape[:-1], 3, 3)


def host_slerp(times, omega, new_times) -> np.ndarray:
    """Rotations ω (T, 3) at increasing `times` (T,), spherically interpolated at `new_times`
    (N,) within [times[0], times[-1]] -> (N, 3) rotation vectors, float64 (SciPy's Slerp)."""
    from scipy.spatial.transform import Rotation, Slerp

    return Slerp(times, Rotation.from_rotvec(np.asarray(omega, np.float64)))(new_times).as_rotvec()
