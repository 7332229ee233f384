"""Block Cholesky in frame order with the fill kept in the coupling rows' space.

H = D + Σ_t C_tᵀ C_t on T frames of n unknowns, where D is block-diagonal (n × n per
frame: everything frame-local) and C_t, the R rows of the frame-coupling terms at frame
t, reads frames t-B .. t+B (`C[t, j]` acts on frame t + j - B). When R < n (SIP: 18
acceleration rows against 51 coupled unknowns per frame) the Schur complement left after
eliminating frames < s differs from H only inside the span of the 2B·R rows that still
straddle frame s,

    S_s = H_{≥s} - Y_sᵀ M_s Y_s,     Y_s: rows of groups s-B .. s+B-1 on frames ≥ s,

so the elimination carries the small M_s (2BR × 2BR) instead of dense (2B·n)-wide
super-blocks. With E the (2B+1)R rows of groups s-B .. s+B on frame s (E_o its first
2BR), the pivot and the update are

    P_s = H_ss - E_oᵀ M_s E_o = L_s L_sᵀ,    K_s = L_s⁻¹ (E - [M_s E_o; 0])ᵀ,
    M_{s+1} = ([M_s 0; 0 0] + K_sᵀ K_s)[R:, R:]       (group s-B leaves the window).

P_s are exactly the pivots of the frame-order block Cholesky of H (`tridiagonal.py`'s
"scan" with B-frame super-blocks), so the numerics are that factorisation's; the flops
per frame drop from ≈ 6 (Bn)³ to ≈ n³ + 3 n² (2B+1) R (SIP: 3.0 → 0.5 Mflop), and the
off-diagonal blocks of H are never formed. Substitution carries the rows' part of the
right-hand side forward (ν) and the last 2B frames of x backward.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jax import Array

from ..timeseries import shift_frames
from .tridiagonal import SCAN_BASE, inverse_cholesky

__all__ = ["RowsFactor", "rows_factor", "rows_solve", "scale_rows"]


class RowsFactor(eqx.Module):
    """L (T, n, n) inverse pivot factors, K (T, n, (2B+1)R), E_o (T, 2BR, n) and
    F (T, (2B+1)R, 2B, n): the rows of groups s-B .. s+B on frames s+1 .. s+2B."""

    L: Array
    K: Array
    Eo: Array
    F: Array


def _on_frame(C: Array, k: int) -> Array:
    """(T, 2B+1, R, n) -> (T, (2B+1)R, n): at s, the rows of groups s-B .. s+B on frame s + k."""
    B = (C.shape[1] - 1) // 2
    parts = []
    for i in range(2 * B + 1):  # group t = s - B + i reads frame s + k at offset j = 2B - i + k
        j = 2 * B - i + k
        parts.append(shift_frames(C[:, j], B - i) if j <= 2 * B else jnp.zeros_like(C[:, 0]))
    return jnp.concatenate(parts, 1)


def scale_rows(C: Array, s: Array) -> Array:
    """C[t, j] ← C[t, j] diag(s of frame t + j - B): the Jacobi scaling of the unknowns."""
    B = (C.shape[1] - 1) // 2
    return jnp.stack([C[:, j] * shift_frames(s, B - j)[:, None, :] for j in range(2 * B + 1)], 1)


def rows_factor(P0: Array, C: Array) -> RowsFactor:
    """Factorise H = blocks P0 (T, n, n) on the diagonal (all of H_ss, the rows' part
    included) and off-diagonal blocks Σ_t C_tᵀ C_t, C (T, 2B+1, R, n)."""
    B, R = (C.shape[1] - 1) // 2, C.shape[2]
    o = 2 * B * R
    E = _on_frame(C, 0)
    F = jnp.stack([_on_frame(C, k) for k in range(1, 2 * B + 1)], 2)

    def step(M, PE):
        P, Es = PE
        MEo = M @ Es[:o]
        Linv = inverse_cholesky(P - Es[:o].T @ MEo, SCAN_BASE)
        K = Linv @ (Es - jnp.pad(MEo, ((0, R), (0, 0)))).T
        M_next = K[:, R:].T @ K[:, R:] + jnp.pad(M[R:, R:], ((0, R), (0, R)))
        return M_next, (Linv, K)

    _, (L, K) = jax.lax.scan(step, jnp.zeros((o, o), P0.dtype), (P0, E))
    return RowsFactor(L, K, E[:, :o], F)


def rows_solve(f: RowsFactor, b: Array) -> Array:
    """H⁻¹ b for b (T, n, k)."""
    n, k = b.shape[1:]
    B = f.F.shape[2] // 2
    R = f.K.shape[-1] // (2 * B + 1)

    def forward(nu, LKEb):
        L, K, Eo, bs = LKEb
        w = L @ (bs - Eo.T @ nu)
        nu_next = (jnp.pad(nu, ((0, R), (0, 0))) + K.T @ w)[R:]
        return nu_next, w

    _, w = jax.lax.scan(forward, jnp.zeros((2 * B * R, k), b.dtype), (f.L, f.K, f.Eo, b))

    def backward(xs, LKFw):
        L, K, F, ws = LKFw
        x = L.T @ (ws - K @ jnp.einsum("rjn,jnk->rk", F, xs))
        return jnp.concatenate([x[None], xs[:-1]], 0), x

    _, x = jax.lax.scan(backward, jnp.zeros((2 * B, n, k), b.dtype), (f.L, f.K, f.F, w), reverse=True)
    return x
