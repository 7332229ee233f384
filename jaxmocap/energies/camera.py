"""Camera energies of Multi-view SMPLify (Huang §4.3): keypoints, silhouettes, DCT prior.

Every term reads the posed body (`PosedInViews`, computed once per evaluation) and the `CameraData` of
calibrated, static views; all are per frame (bandwidth 0), so a sequence is solved as
one batch of independent frames (stage 1) or tied only through per-window DCT
coefficients (stage 2). Each residual is an equinox module whose configuration (σ,
stride, slack) is static (`KeypointResidual(sigma)`, ...) and each mask a module-level
function; the `*_term` constructors wrap them in `Term`s. Problems built twice with the
same settings are therefore equal and share one compiled solve.

- E_J (eq. 4.3-4.4): Σ_views Σ_i w_i c_i ρ_σ(Π_K(J_i) - Ĵ_i), Geman-McClure ρ on the 2-D
  residual's norm, c_i the detector's confidence, w_i a per-keypoint weight. Choice: ρ is
  applied to the 2-D vector (not per coordinate) and scaled as in `solve.GemanMcClure`
  (ρ(s) = σ²s/(σ²+s), i.e. Huang's ρ times σ², so weights keep their meaning near 0).
- E_S (eq. 4.5): Σ_{x∈Ŝ} l(x, U)² + Σ_{x∈U} l(x, Ŝ).
  First sum: the model's projected vertices stand for the points of Ŝ; l(x, U) is read
  from the Euclidean distance transform of the observed mask (0 inside U), bilinearly
  interpolated so it is differentiable in x. Second sum: M points sampled from the mask;
  l(x, Ŝ) is the distance to the nearest projected model vertex (the argmin is taken
  without gradient: the derivative of a minimum is that of its minimiser almost
  everywhere), with a Huber loss of δ = 1 px giving the L1 tails of eq. 4.5 and a
  smooth core. Both sums are over pixels in eq. 4.5; here each sampled point stands for
  area/count pixels (area = the mask's pixel count, which the model's silhouette matches at
  the solution), so the two sums keep the balance of eq. 4.5. Without that weighting the
  ~600 model points per view outweighed the 256 mask points and E_S shrank the body
  (measured on held-out clips: shape error 41.8 -> 73.5 mm).
- E_T (eq. 4.7-4.8): every 3-D joint coordinate trajectory of a window against its
  reconstruction B c from the first `num_dct` DCT-II basis vectors, ρ_σ2 per coordinate;
  plus a linear trend, a shorter last window a basis of its own length (`DCTBasis`, ours).
- E_β: ‖β‖² (shape coefficients are unit-variance PCA coordinates); E_θ: the Gaussian
  pose prior of `priors` (a single Gaussian where SMPLify used a mixture).
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from scipy.ndimage import distance_transform_edt

from ..body.kinematics import forward_rotations, forward_rotations_unchecked
from ..body.model import Body
from ..geometry.camera import project
from ..geometry.keypoints import regress_keypoints
from ..priors.pose_prior import PosePrior
from ..solve import GemanMcClure, Huber, Term, window
from ..solve.basis import WindowBasis, basis_term
from .imu import mahalanobis_term

__all__ = [
    "CameraData",
    "Silhouettes",
    "silhouette_data",
    "dct_basis",
    "DCTBasis",
    "PosedInViews",
    "KeypointResidual",
    "ModelToMask",
    "MaskToModel",
    "Betas",
    "PosedJoints",
    "detected",
    "has_mask",
    "mask_point_valid",
    "keypoint_term",
    "silhouette_terms",
    "mask_to_model",
    "shape_term",
    "pose_prior_term",
    "dct_window",
    "temporal_term",
    "dct_coefficients",
]


class Silhouettes(eqx.Module):
    """Observed masks of every frame and view, prepared for E_S (`silhouette_data`).

    distance: (T, V, H, W) distance in px from each pixel to the mask (0 inside).
    points: (T, V, M, 2) pixel centres sampled from the mask; valid: (T, V, M).
    area: (T, V) the mask's pixel count (what the sampled points stand for).
    """

    distance: Array
    points: Array
    valid: Array
    area: Array


def silhouette_data(masks: np.ndarray, num_points: int = 256, seed: int = 0) -> Silhouettes:
    """`Silhouettes` from boolean masks (T, V, H, W); an empty mask contributes nothing."""
    masks = np.asarray(masks, bool)
    if masks.ndim != 4:
        raise ValueError(f"masks must be (T, V, H, W) booleans, got shape {masks.shape}.")
    T, V, H, W = masks.shape
    rng = np.random.default_rng(seed)
    distance = np.zeros(masks.shape, np.float32)
    points = np.zeros((T, V, num_points, 2), np.float32)
    valid = np.zeros((T, V, num_points), bool)
    area = masks.sum((2, 3)).astype(np.float32)
    for t in range(T):
        for v in range(V):
            m = masks[t, v]
            ys, xs = np.nonzero(m)
            if len(xs) == 0:
                continue  # no observation: distance 0 everywhere and no points
            distance[t, v] = distance_transform_edt(~m)
            pick = rng.choice(len(xs), min(num_points, len(xs)), replace=False)
            points[t, v, : len(pick)] = np.stack([xs[pick] + 0.5, ys[pick] + 0.5], -1)
            valid[t, v, : len(pick)] = True
    return Silhouettes(jnp.asarray(distance), jnp.asarray(points), jnp.asarray(valid), jnp.asarray(area))


class CameraData(eqx.Module):
    """Observations of calibrated static views and what the camera terms need.

    body: the body model; prior: the pose prior; regressor: (K, N + J) keypoint regressor
    (`geometry.keypoint_regressor`) mapping posed vertices and joints to the detector's keypoints.
    K, R, t: (V, 3, 3), (V, 3, 3), (V, 3) intrinsics and world-to-camera extrinsics
    (undistorted pixels: apply `undistort_pixels` to detections first).
    keypoints: (T, V, K, 2) pixels; confidence: (T, V, K), 0 = missing (NaN keypoints
    are masked as well). joint_weights: (K,) w_i. betas: (B,) fixed shape (stage 2) or
    None (shape is an unknown). silhouettes: `Silhouettes` or None. layout: the name of
    the keypoint layout (`geometry.keypoints.KEYPOINT_FORMATS`).
    model_points: (N,) int indices of the body's vertices that stand for the model
    silhouette in E_S, or None (every `stride`-th vertex, `silhouette_terms`).
    pose_blend: False when the body's pose blend shapes are all zero (checked by whoever
    sets it): the forward pass then skips B_p, the same function at a third of the cost.
    """

    body: Body
    prior: PosePrior
    regressor: Array
    K: Array
    R: Array
    t: Array
    keypoints: Array
    confidence: Array
    joint_weights: Array
    betas: Array | None = None
    silhouettes: Silhouettes | None = None
    layout: str = eqx.field(static=True, default="body25")
    model_points: Array | None = None
    pose_blend: bool = eqx.field(static=True, default=True)

    @property
    def num_frames(self) -> int:
        return self.keypoints.shape[0]


class PosedInViews(eqx.Module):
    """`Problem.posed` of the camera terms: the body posed by params["pose"], params["trans"]
    and the shape params["betas"] when it is an unknown, else data.betas; without the pose
    blend shapes when `data.pose_blend` is False."""

    def __call__(self, params, data: CameraData):
        betas = params["betas"] if "betas" in params else data.betas
        if getattr(data, "pose_blend", True):
            return forward_rotations(data.body, params["pose"], betas, params.get("trans"))
        return forward_rotations_unchecked(data.body, params["pose"], betas, params.get("trans"), pose_blend=False)


def posed_in_views(params, data: CameraData, posed=None):
    """The posed body a camera term reads: `posed` as the problem passes it, or (a term
    called on its own) its own pass, `PosedInViews()(params, data)`."""
    return PosedInViews()(params, data) if posed is None else posed


def _model_points(vertices: Array, data: CameraData, stride: int) -> Array:
    """The vertices (T, N, 3) that stand for the model silhouette (`CameraData.model_points`)."""
    points = getattr(data, "model_points", None)
    return vertices[:, ::stride] if points is None else jnp.take(vertices, points, axis=1)


def project_to_views(data: CameraData, points: Array) -> tuple[Array, Array]:
    """Project (T, N, 3) world points into every view: uv (T, V, N, 2), depth (T, V, N)."""
    return project(data.K[None], data.R[None], data.t[None], points[:, None])


class KeypointResidual(eqx.Module):
    """E_J (eq. 4.3-4.4): √(c_i w_i) ρ_σ(Π_K(J_i) - Ĵ_i) per frame, view and keypoint, (T, V, K, 2)."""

    sigma: float = eqx.field(static=True)

    def __call__(self, params, data: CameraData, posed=None) -> Array:
        body = posed_in_views(params, data, posed)
        kp = regress_keypoints(data.regressor, body.vertices, body.joints)
        uv, _ = project_to_views(data, kp)
        scale = jnp.sqrt(data.confidence * data.joint_weights)[..., None]
        return scale * GemanMcClure(self.sigma)(uv - data.keypoints)


def detected(data) -> Array:
    """Keypoints that count: confidence > 0 and finite, (T, V, K) (or (T, K))."""
    return (data.confidence > 0) & jnp.all(jnp.isfinite(data.keypoints), -1)


def keypoint_term(sigma: float = 100.0, weight: float = 1.0) -> Term:
    """E_J (eq. 4.3): confidence-weighted Geman-McClure reprojection error, (T, V, K, 2)."""
    return Term("keypoints", KeypointResidual(float(sigma)), weight, mask=detected, posed=PosedInViews())


def _bilinear(image: Array, uv: Array) -> Array:
    """image (H, W) at continuous pixel coordinates uv (..., 2) (centres at +0.5);
    outside the image the border value plus the distance to the image."""
    H, W = image.shape
    x = uv[..., 0] - 0.5
    y = uv[..., 1] - 0.5
    xc, yc = jnp.clip(x, 0.0, W - 1.0), jnp.clip(y, 0.0, H - 1.0)
    x0 = jnp.clip(jnp.floor(xc), 0, W - 2).astype(jnp.int32)
    y0 = jnp.clip(jnp.floor(yc), 0, H - 2).astype(jnp.int32)
    fx, fy = xc - x0, yc - y0
    v00, v01 = image[y0, x0], image[y0, x0 + 1]
    v10, v11 = image[y0 + 1, x0], image[y0 + 1, x0 + 1]
    inner = (1 - fy) * ((1 - fx) * v00 + fx * v01) + fy * ((1 - fx) * v10 + fx * v11)
    return inner + jnp.abs(x - xc) + jnp.abs(y - yc)


def _nearest(x: Array, y: Array) -> Array:
    """Index of the nearest of the points y (..., N, 2) to each of x (..., M, 2): (..., M).

    The squared distance is summed from the two coordinates explicitly: a reduction
    over a trailing axis of 2 before the argmin made XLA-CPU's argmin 9x slower
    (M = 256, N = 615, 120 images: 388 ms against 43 ms).
    """
    dx = x[..., :, None, 0] - y[..., None, :, 0]
    dy = x[..., :, None, 1] - y[..., None, :, 1]
    return jnp.argmin(dx * dx + dy * dy, -1)


def mask_to_model(uv: Array, silhouettes: Silhouettes, slack: float = 2.0, loss=Huber(1.0)) -> Array:
    """The second sum of eq. 4.5, Σ_{x∈U} l(x, Ŝ): each mask point against the nearest of
    the projected model points uv (T, V, N, 2) -> residuals (T, V, M, 2).

    The argmin is taken without gradient (the derivative of a minimum is that of its
    minimiser almost everywhere); a point within `slack` px of a model point is covered
    (l = 0); each point stands for area/M pixels. Shared by the body (E_S) and rigid
    objects (InterCap's E_O, eq. 5.1).
    """
    x = silhouettes.points  # (T, V, M, 2)
    nearest = _nearest(x, jax.lax.stop_gradient(uv))  # (T, V, M)
    closest = jnp.take_along_axis(uv, nearest[..., None], axis=-2)
    e = x - closest
    d = jnp.sqrt(jnp.sum(e * e, -1, keepdims=True) + 1e-12)
    count = jnp.maximum(jnp.sum(silhouettes.valid, -1), 1)  # (T, V)
    per_point = jnp.sqrt(silhouettes.area / count)[..., None, None]  # each point: area/M px
    return per_point * loss(e * (jnp.maximum(d - slack, 0.0) / d))  # (T, V, M, 2)


class ModelToMask(eqx.Module):
    """First sum of eq. 4.5, Σ_{x∈Ŝ} l(x, U)²: the distance transform of the observed mask
    at each projected model point, (T, V, N, 1) (`silhouette_terms`)."""

    stride: int = eqx.field(static=True, default=1)

    def __call__(self, params, data: CameraData, posed=None) -> Array:
        verts = _model_points(posed_in_views(params, data, posed).vertices, data, self.stride)
        uv, _ = project_to_views(data, verts)  # (T, V, N, 2)
        dist = jax.vmap(jax.vmap(_bilinear))(data.silhouettes.distance, uv)
        per_point = jnp.sqrt(data.silhouettes.area / uv.shape[-2])[..., None]  # each vertex: area/N px
        return (per_point * dist)[..., None]  # (T, V, N, 1)


class MaskToModel(eqx.Module):
    """Second sum of eq. 4.5, Σ_{x∈U} l(x, Ŝ) (`mask_to_model`), (T, V, M, 2)."""

    stride: int = eqx.field(static=True, default=1)
    slack: float = eqx.field(static=True, default=2.0)
    huber: float = eqx.field(static=True, default=1.0)

    def __call__(self, params, data: CameraData, posed=None) -> Array:
        verts = _model_points(posed_in_views(params, data, posed).vertices, data, self.stride)
        uv, _ = project_to_views(data, verts)  # (T, V, N, 2)
        return mask_to_model(uv, data.silhouettes, self.slack, Huber(self.huber))


def has_mask(data: CameraData) -> Array:
    """Views with an observed mask, (T, V, 1)."""
    return jnp.any(data.silhouettes.valid, -1)[..., None]


def mask_point_valid(data: CameraData) -> Array:
    """The sampled mask points that exist, (T, V, M)."""
    return data.silhouettes.valid


def silhouette_terms(
    w_model: float = 1.0, w_mask: float = 1.0, stride: int = 1, slack: float = 2.0, huber: float = 1.0
) -> list[Term]:
    """E_S (eq. 4.5) as two terms: model→mask (squared) and mask→model (L1 tails).

    `stride` keeps every stride-th vertex as a model point (fewer residuals, faster),
    unless the data name their model points (`CameraData.model_points`).
    `slack` (px): a mask point closer than this to a projected vertex counts as inside
    the model silhouette (l = 0). Projected vertices sample Ŝ with gaps of a few pixels;
    without the slack every mask point would pay for its gap and E_S would inflate the
    body to shrink the gaps (measured: +20 mm shape error). `huber` (px): δ of the Huber
    loss of the mask→model distances.
    """
    stride = int(stride)
    return [
        Term("silhouette_model", ModelToMask(stride), w_model, mask=has_mask, posed=PosedInViews()),
        Term(
            "silhouette_mask",
            MaskToModel(stride, float(slack), float(huber)),
            w_mask,
            mask=mask_point_valid,
            posed=PosedInViews(),
        ),
    ]


class Betas(eqx.Module):
    """E_β's residual: β itself, (T, B)."""

    def __call__(self, params, data) -> Array:
        return params["betas"]


def shape_term(weight: float = 1.0) -> Term:
    """E_β = ‖β‖² per frame (stage 1, where every frame has its own β)."""
    return Term("shape", Betas(), weight, reads=(("betas", None),))


def pose_prior_term(weight: float = 1.0) -> Term:
    """E_θ: the Gaussian pose prior over the 23 non-root joints (eq. 4.2)."""
    term = mahalanobis_term(1.0, 1.0)
    return Term("pose_prior", term.fn, weight, reads=term.reads, jacobian=term.jacobian)


def dct_basis(length: int, num: int) -> np.ndarray:
    """B (length, num): the first `num` orthonormal DCT-II basis vectors as columns."""
    n, k = np.arange(length)[:, None], np.arange(num)[None, :]
    B = np.cos(np.pi * (n + 0.5) * k / length) * np.sqrt(2.0 / length)
    B[:, 0] /= np.sqrt(2.0)
    return B


@dataclasses.dataclass(frozen=True)
class DCTBasis:
    """`WindowBasis.basis` of E_T (eq. 4.8): the first `num` DCT vectors of a `length`-frame
    window and a linear trend (ours, both below); a shorter (last) window of n frames gets
    its own n-frame basis of the same bandwidth, max(1, round(num · n / length)) DCT
    vectors and the trend, at most n columns (Huang's windows are all 30 frames, §4.3.3).

    The trend (a ramp, orthogonalised against the DCT vectors): every DCT-II vector has
    zero slope at both ends of its window, so a body moving at constant speed is no DCT
    trajectory, and E_T pulled every joint towards standing still at each window's ends
    (a 1.1 m/s walk, one 30-frame window: 7.9 mm at the ends for the root's path alone;
    the synthetic walk's joints 4.3 mm RMS from the 10-vector span, 3.2 with the trend;
    over 9 frames with 3 vectors 9.5 mm, 4.2 with the trend).

    A short last window in the first n rows of the `length`-frame basis instead, as
    before: those rows are nearly collinear for small n (the low cosines look alike over
    a few frames), so the fit needed huge, cancelling coefficients and, with n <= num,
    reproduced the trajectory exactly: the last window was not smoothed (real data: joint
    jitter 422 m/s² there against 9.9 m/s² in whole windows, issue 47).
    """

    length: int
    num: int

    def __call__(self, n: int) -> np.ndarray:
        k = min(n, max(1, round(self.num * n / self.length)), self.num)
        B = dct_basis(n, k)
        if k == n:
            return B
        ramp = np.linspace(-1.0, 1.0, n)
        ramp = ramp - B @ (B.T @ ramp)
        return np.concatenate([B, (ramp / np.linalg.norm(ramp))[:, None]], 1)


def dct_window(length: int = 30):
    """The per-window unknown of the DCT coefficients: non-overlapping windows of `length`
    frames (Huang §4.3.3: 30-frame units)."""
    return window(length)


class PosedJoints(eqx.Module):
    """E_T's features: the posed joints of each frame, flattened, (T, J·3)."""

    def __call__(self, params, data: CameraData, posed=None) -> Array:
        j = posed_in_views(params, data, posed).joints
        return j.reshape(j.shape[0], -1)


def temporal_term(length: int = 30, num_dct: int = 10, sigma: float = 0.05, weight: float = 1.0) -> Term:
    """E_T (eq. 4.8): joints (T, J, 3) against their reconstruction B c from the per-window
    coefficients params["coef"] (W, K, J, 3), ρ_σ per coordinate (σ in metres); a
    basis term (`jaxmocap.solve.basis`), so the LM eliminates the coefficients by their
    Kronecker structure. Windows of `length` frames, the last one as `DCTBasis` says."""
    basis = WindowBasis("coef", PosedJoints(), DCTBasis(int(length), int(num_dct)), int(length), PosedInViews())
    return basis_term("temporal", basis, (("pose", None), ("trans", None)), weight, GemanMcClure(sigma))


def dct_coefficients(joints: np.ndarray, length: int = 30, num_dct: int = 10) -> np.ndarray:
    """Least-squares DCT coefficients (W, K, J, 3) of joint trajectories (T, J, 3) in
    windows of `length` frames, K the width of `DCTBasis` (num_dct DCT vectors and the
    trend), the last window in its own basis (the coefficients it lacks are 0): starting
    values for E_T."""
    joints = np.asarray(joints)
    basis = DCTBasis(length, num_dct)
    K = basis(length).shape[1]
    out = []
    for start in range(0, joints.shape[0], length):
        seg = joints[start : start + length]
        B = basis(len(seg))
        coef = np.zeros((K, seg[0].size))
        coef[: B.shape[1]] = np.linalg.lstsq(B, seg.reshape(len(seg), -1), rcond=None)[0]
        out.append(coef.reshape(K, *joints.shape[1:]))
    return np.stack(out)
