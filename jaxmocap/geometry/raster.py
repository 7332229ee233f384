"""A small z-buffer triangle rasteriser in JAX: label and depth images, silhouettes.

Method (one view, one frame): project the scene's vertices (eq. 4.4); for every triangle
test the pixel centres (i + 0.5, j + 0.5) of a fixed `window` x `window` block anchored at
the triangle's bounding box with edge functions; interpolate 1/z with the screen-space
barycentrics (perspective-correct depth); keep the nearest surface per pixel with a
scatter-min, then its label with a second scatter. The window is a static size chosen on
the host from the largest projected triangle (`window_for`), so a triangle larger than
`max_window` pixels is clipped to its top-left block; with the default image sizes used
by jaxmocap's data sets (≤ 256 x 192 px, people 3-6 m away) body triangles span < 8 px.

A ground plane y = floor_height is added analytically (per-pixel ray-plane intersection)
when `floor=True`.

Label image: -1 background, -2 floor, otherwise the label of the winning triangle
(people 0 .. P-1, objects after them). A silhouette is `label == person`.
Resolution is the caller's choice; cost is O(F · window²) per view and frame.

`visible_vertices` marks mesh vertices whose depth agrees with the z-buffer (within a
tolerance), which is what a point-to-body term over visible vertices needs (InterCap
E_D, Huang eq. 5.2-5.5).
"""

from __future__ import annotations

import functools
import os

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from .camera import project

_project_jit = jax.jit(project)  # window_for's projection: one program, not ~10 eager ones per shape

__all__ = ["rasterize", "rasterize_views", "window_for", "visible_vertices", "BACKGROUND", "FLOOR"]

BACKGROUND = -1
FLOOR = -2


def window_for(K, R, t, vertices, faces, max_window: int = 32) -> int:
    """Smallest power-of-two window covering every projected triangle (host-side, NumPy).

    K (3, 3); R (..., 3, 3); t (..., 3); vertices (..., N, 3) broadcast with R, t.
    """
    uv, z = _project_jit(jnp.asarray(K), jnp.asarray(R), jnp.asarray(t), jnp.asarray(vertices))
    uv = np.asarray(uv)[..., faces, :]  # (..., F, 3, 2)
    front = np.all(np.asarray(z)[..., faces] > 0, -1)
    extent = np.where(front, np.ceil((uv.max(-2) - uv.min(-2)).max(-1)) + 1, 0).max()
    w = 1
    while w < min(extent, max_window):
        w *= 2
    return int(w)


def _floor_depth(K, R, t, width, height, floor_height, floor_extent, near):
    """Camera depth of the plane y = floor_height at each pixel centre (inf if not hit)."""
    u, v = jnp.meshgrid(jnp.arange(width) + 0.5, jnp.arange(height) + 0.5)
    Kinv = jnp.linalg.inv(K)
    rays_c = jnp.stack([u, v, jnp.ones_like(u)], -1) @ Kinv.T  # camera-frame, z = 1
    rays_g = rays_c @ R  # Rᵀ · ray for row vectors
    centre = -R.T @ t
    s = (floor_height - centre[1]) / jnp.where(jnp.abs(rays_g[..., 1]) < 1e-12, 1e-12, rays_g[..., 1])
    hit = centre + s[..., None] * rays_g
    ok = (s > near) & (jnp.abs(hit[..., 0]) < floor_extent) & (jnp.abs(hit[..., 2]) < floor_extent)
    return jnp.where(ok, s, jnp.inf)  # s is the camera z because rays_c has z = 1


def rasterize(
    K: Array,
    R: Array,
    t: Array,
    vertices: Array,
    faces: np.ndarray,
    face_labels: np.ndarray,
    width: int,
    height: int,
    window: int,
    near: float = 0.05,
    floor: bool = False,
    floor_height: float = 0.0,
    floor_extent: float = 10.0,
) -> tuple[Array, Array]:
    """Depth (H, W) (inf where empty) and label (H, W) int32 images of one view.

    Args:
        K (3, 3), R (3, 3), t (3,): camera; vertices (N, 3) world; faces (F, 3) NumPy;
        face_labels (F,) int label per triangle; width, height, window: static ints.
    """
    uv, z = project(K, R, t, vertices)
    faces = np.asarray(faces)
    tu, tz = uv[faces], z[faces]  # (F, 3, 2), (F, 3)
    x0 = jnp.ceil(tu[..., 0].min(-1) - 0.5)
    y0 = jnp.ceil(tu[..., 1].min(-1) - 0.5)
    off = jnp.arange(window, dtype=uv.dtype)
    px = x0[:, None, None] + off[None, None, :] + 0.5  # (F, 1, w)
    py = y0[:, None, None] + off[None, :, None] + 0.5  # (F, w, 1)
    a, b, c = tu[:, 0], tu[:, 1], tu[:, 2]

    def edge(p, q):  # (q - p) x (pixel - p), broadcast to (F, w, w)
        return (q[:, 0, None, None] - p[:, 0, None, None]) * (py - p[:, 1, None, None]) - (
            q[:, 1, None, None] - p[:, 1, None, None]
        ) * (px - p[:, 0, None, None])

    area = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    w0, w1, w2 = edge(b, c), edge(c, a), edge(a, b)
    sgn = jnp.sign(area)[:, None, None]
    inside = (w0 * sgn >= 0) & (w1 * sgn >= 0) & (w2 * sgn >= 0) & (jnp.abs(area) > 1e-12)[:, None, None]
    safe_area = jnp.where(jnp.abs(area) > 1e-12, area, 1.0)[:, None, None]
    safe_z = jnp.where(tz > near, tz, 1.0)
    inv_z = (w0 / safe_z[:, 0, None, None] + w1 / safe_z[:, 1, None, None] + w2 / safe_z[:, 2, None, None]) / safe_area
    depth = 1.0 / jnp.where(inv_z > 0, inv_z, 1e-12)
    ix, iy = px - 0.5, py - 0.5
    valid = (
        inside
        & jnp.all(tz > near, -1)[:, None, None]
        & (ix >= 0) & (ix < width) & (iy >= 0) & (iy < height)
    )  # fmt: skip
    flat = jnp.where(valid, iy * width + ix, 0).astype(jnp.int32).reshape(-1)
    zval = jnp.where(valid, depth, jnp.inf).reshape(-1)
    zbuf = jnp.full((height * width,), jnp.inf, depth.dtype).at[flat].min(zval)
    labels = jnp.broadcast_to(jnp.asarray(face_labels, jnp.int32)[:, None, None], valid.shape).reshape(-1)
    win = valid.reshape(-1) & (zval <= zbuf[flat])
    label = jnp.full((height * width,), BACKGROUND, jnp.int32).at[flat].max(jnp.where(win, labels, BACKGROUND))
    zbuf, label = zbuf.reshape(height, width), label.reshape(height, width)
    if floor:
        fz = _floor_depth(K, R, t, width, height, floor_height, floor_extent, near).astype(zbuf.dtype)
        use_floor = fz < zbuf
        zbuf = jnp.where(use_floor, fz, zbuf)
        label = jnp.where(use_floor, FLOOR, label)
    return zbuf, label


#: The rasteriser does F·w² work per view (each triangle's window of candidate pixels), so
#: it is compiled at XLA's defaults whatever the process asks of other programs (a test
#: suite's JAX_DISABLE_MOST_OPTIMIZATIONS, XLA_FLAGS): unoptimised, 64 views of a two-person
#: 64x48 scene (window 16 and 32) ran in 20-39 CPU-s instead of 4. Only the options the
#: process changed are reset: an XLA that lacks one (jax >= 0.4.30 is allowed) is never asked.
def _optimised() -> dict:
    flags = os.environ.get("XLA_FLAGS", "")
    unoptimised = os.environ.get("JAX_DISABLE_MOST_OPTIMIZATIONS", "").lower() in ("1", "true")
    options = {}
    if unoptimised or "xla_backend_optimization_level" in flags:
        options["xla_backend_optimization_level"] = 3
    if unoptimised or "xla_llvm_disable_expensive_passes" in flags:
        options["xla_llvm_disable_expensive_passes"] = False
    if "xla_cpu_use_fusion_emitters" in flags:
        options["xla_cpu_use_fusion_emitters"] = True
    return options


@functools.partial(
    jax.jit,
    static_argnames=("faces_key", "width", "height", "window", "floor", "batch_size"),
    compiler_options=_optimised() or None,
)
def _rasterize_batch(K, R, t, vertices, face_labels, faces_key, width, height, window, floor, floor_height, batch_size):
    faces = _FACES[faces_key]

    def one(args):
        Rv, tv, verts = args
        return rasterize(
            K, Rv, tv, verts, faces, face_labels, width, height, window, floor=floor, floor_height=floor_height
        )

    return jax.lax.map(one, (R, t, vertices), batch_size=batch_size)


_FACES: dict = {}


def rasterize_views(
    K,
    R,
    t,
    vertices,
    faces: np.ndarray,
    face_labels: np.ndarray,
    width: int,
    height: int,
    window: int | None = None,
    floor: bool = False,
    floor_height: float = 0.0,
    batch_size: int = 8,
) -> tuple[Array, Array]:
    """Rasterise a batch of (view, frame) pairs: R (B, 3, 3), t (B, 3), vertices (B, N, 3).

    Returns depth (B, H, W) and label (B, H, W). One compiled function per (mesh, image
    size, window); `batch_size` frames are rasterised at once (memory ∝ batch·F·window²).
    """
    faces = np.ascontiguousarray(np.asarray(faces, np.int32))
    key = (faces.shape, hash(faces.tobytes()))
    _FACES.setdefault(key, faces)
    if window is None:
        window = window_for(K, R, t, vertices, faces)
    # The batch padded to a power of two by repeating its last pair (each pair is rasterised
    # on its own, so the results are unchanged): one program serves many batch sizes.
    B = len(R)
    pad = (1 << max(B - 1, 0).bit_length()) - B
    ext = lambda x: np.concatenate([x, np.repeat(x[-1:], pad, 0)]) if pad else x  # noqa: E731
    R, t, vertices = (ext(np.asarray(x)) for x in (R, t, vertices))  # host-side: no eager programs
    depth, label = _rasterize_batch(
        jnp.asarray(K), jnp.asarray(R), jnp.asarray(t), jnp.asarray(vertices),
        jnp.asarray(face_labels, jnp.int32), key, int(width), int(height), int(window), bool(floor),
        float(floor_height), int(batch_size),
    )  # fmt: skip
    return (depth[:B], label[:B]) if pad else (depth, label)


def visible_vertices(K: Array, R: Array, t: Array, vertices: Array, depth: Array, tolerance: float = 0.02) -> Array:
    """(N,) bool: the vertex projects inside the image and is within `tolerance` of the z-buffer."""
    H, W = depth.shape
    uv, z = project(K, R, t, vertices)
    col = jnp.floor(uv[..., 0]).astype(jnp.int32)
    row = jnp.floor(uv[..., 1]).astype(jnp.int32)
    inside = (col >= 0) & (col < W) & (row >= 0) & (row < H) & (z > 0)
    zbuf = depth[jnp.clip(row, 0, H - 1), jnp.clip(col, 0, W - 1)]
    return inside & (z <= zbuf + tolerance)
