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

On the CPU the scan runs at about 20 GFLOP/s on one core (SIP, T = 1000: 43 ms, 19 of
them the pivots' inverse factors). On a GPU the frame-order scan is latency-bound and
cyclic reduction on the same rows (`rows_cyclic_factor`) is the default. (Eliminating
from both ends at once, each half on its own device, was tried and removed: it won
nowhere, 0.95x on this CPU only with inputs pre-split across two host devices, and
18.9 s against cyclic reduction's 16.1 s for 1000 x 1000 x 20 SIP on one H100.)
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jax import Array

from ..timeseries import shift_frames
from .tridiagonal import (
    CYCLIC_BASE, CYCLIC_RECURSIVE_BLOCKS, SCAN_BASE, CoupledFactor, interleave_blocks, inverse_cholesky, pad_blocks,
    shift_blocks_down,
)  # fmt: skip

__all__ = [
    "RowsFactor", "RowsCyclicFactor", "rows_factor", "rows_solve", "rows_cyclic_factor", "rows_cyclic_solve", "scale_rows",
]  # fmt: skip


class _FrameOrder(CoupledFactor):
    """A factor in the coupling rows' space: right-hand sides per frame as they are
    (T, n, ...), no windows (`uses_rows` excludes them)."""

    def pack(self, xF: Array | None, xW: Array | None) -> Array:
        return xF

    def unpack(self, x: Array):
        return x, None


class RowsFactor(_FrameOrder):
    """L (T, n, n) inverse pivot factors, K (T, n, (2B+1)R), E_o (T, 2BR, n) and
    F (T, (2B+1)R, 2B, n): the rows of groups s-B .. s+B on frames s+1 .. s+2B."""

    L: Array
    K: Array
    Eo: Array
    F: Array

    def solve(self, b: Array) -> Array:
        """H⁻¹ b for b (T, n, k)."""
        return rows_solve(self, b)


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


def _rows_scan(P0: Array, E: Array, o: int):
    """The elimination of frames 0 .. T-1 in order: (M_T, L, K); see the module docstring."""
    R = E.shape[1] - o

    def step(M, PE):
        P, Es = PE
        MEo = M @ Es[:o]
        Linv = inverse_cholesky(P - Es[:o].T @ MEo, SCAN_BASE)
        K = Linv @ (Es - jnp.pad(MEo, ((0, R), (0, 0)))).T
        M_next = K[:, R:].T @ K[:, R:] + jnp.pad(M[R:, R:], ((0, R), (0, R)))
        return M_next, (Linv, K)

    return jax.lax.scan(step, jnp.zeros((o, o), P0.dtype), (P0, E))


def rows_factor(P0: Array, C: Array) -> RowsFactor:
    """Factorise H = blocks P0 (T, n, n) on the diagonal (all of H_ss, the rows' part
    included) and off-diagonal blocks Σ_t C_tᵀ C_t, C (T, 2B+1, R, n)."""
    return _factor_with_fill(P0, C)[1]


def _factor_with_fill(P0: Array, C: Array) -> tuple[Array, RowsFactor]:
    """`rows_factor` of frames [0, h) for P0 (h, n, n) and the groups C (≥ h, ...) that read
    them, with the scan's last M (the fill those frames leave on the frames after them)."""
    h, B, R = P0.shape[0], (C.shape[1] - 1) // 2, C.shape[2]
    o = 2 * B * R
    E = _on_frame(C, 0)[:h]
    F = jnp.stack([_on_frame(C, k)[:h] for k in range(1, 2 * B + 1)], 2)
    M, (L, K) = _rows_scan(P0, E, o)
    return M, RowsFactor(L, K, E[:, :o], F)


def _forward(f: RowsFactor, b: Array) -> tuple[Array, Array]:
    """The forward substitution: (ν after the last frame, w)."""
    o = f.Eo.shape[1]
    R = f.K.shape[-1] - o

    def step(nu, LKEb):
        L, K, Eo, bs = LKEb
        w = L @ (bs - Eo.T @ nu)
        return (jnp.pad(nu, ((0, R), (0, 0))) + K.T @ w)[R:], w

    return jax.lax.scan(step, jnp.zeros((o, b.shape[-1]), b.dtype), (f.L, f.K, f.Eo, b))


def _backward(f: RowsFactor, w: Array, after: Array) -> Array:
    """The back substitution, given x on the 2B frames after the last (`after`, (2B, n, k))."""

    def step(xs, LKFw):
        L, K, F, ws = LKFw
        x = L.T @ (ws - K @ jnp.einsum("rjn,jnk->rk", F, xs))
        return jnp.concatenate([x[None], xs[:-1]], 0), x

    return jax.lax.scan(step, after, (f.L, f.K, f.F, w), reverse=True)[1]


def rows_solve(f: RowsFactor, b: Array) -> Array:
    """H⁻¹ b for b (T, n, k)."""
    n, k = b.shape[1:]
    B = f.F.shape[2] // 2
    _, w = _forward(f, b)
    return _backward(f, w, jnp.zeros((2 * B, n, k), b.dtype))


# --- cyclic reduction on the rows: the same representation, O(log T) depth ----------------


class RowsCyclicLevel(eqx.Module):
    """One level: L_o⁻¹ of the odd super-blocks, their couplings in the rows' space
    (P_o = Pa_o Y_{o-1}, Q_o = Qa_o Z_o, PQ = [Pa Qa]) and those rows' bases."""

    L: Array  # (Ko, N, N)
    PQ: Array  # (Ko, N, 2r)
    Y: Array  # (Ko, r, N) of the even block before each odd one
    Z: Array  # (Ko, r, N) of the even block after it


class RowsCyclicFactor(_FrameOrder):
    """Block cyclic reduction of the 2B-frame super-blocks with off-diagonal blocks kept as
    U_k = Y_kᵀ M_k Z_k (rank r = 2BR); `last` the final block's inverse factor."""

    levels: tuple[RowsCyclicLevel, ...]
    last: Array  # (1, N, N)

    def solve(self, b: Array) -> Array:
        """H⁻¹ b for b (T, n, k)."""
        return rows_cyclic_solve(self, b)


def _band_from_rows(C: Array, e: int) -> Array:
    """H_{s,s+e} = Σ_t C_t[s]ᵀ C_t[s+e] (T, n, n): row t = s + B - j reads s at offset j."""
    B = (C.shape[1] - 1) // 2
    return sum(shift_frames(jnp.einsum("trn,trm->tnm", C[:, j], C[:, j + e]), j - B) for j in range(2 * B + 1 - e))


def _super_blocks(P0: Array, C: Array):
    """Hb: the band H_{s,s+e} (e = 0..G-1) as (Kb, G, n, n) arrays by super-block (for
    `_diagonal`), and Y, Z (Kb, r, N): the 2B·R rows straddling the boundary after block
    k on blocks k and k+1 (U_k = Y_kᵀ Z_k)."""
    T, n = P0.shape[:2]
    B, R = (C.shape[1] - 1) // 2, C.shape[2]
    G = 2 * B
    Kb = -(-T // G)
    pad = Kb * G - T
    eye = jnp.broadcast_to(jnp.eye(n, dtype=P0.dtype), (pad, n, n))
    P0 = jnp.concatenate([P0, eye], 0)
    C = jnp.pad(C, ((0, pad + 2 * B), (0, 0), (0, 0), (0, 0)))  # rows past the end: zero
    H = [P0] + [_band_from_rows(C, e)[: Kb * G] for e in range(1, G)]
    Hb = [h.reshape((Kb, G, n, n)) for h in H]
    # Row q of the boundary after block k is frame t = (k+1)G - B + q; it reads frame i of
    # block k at offset i - q and frame i of block k+1 at offset i - q + 2B.
    rows = C[G - B :][: Kb * G].reshape((Kb, G) + C.shape[1:])  # (Kb, q, 2B+1, R, n)
    zero = jnp.zeros((Kb, R, n), P0.dtype)
    Y = jnp.concatenate([
        jnp.concatenate([rows[:, q, i - q] if 0 <= i - q <= 2 * B else zero for i in range(G)], -1) for q in range(G)
    ], 1)  # fmt: skip
    Z = jnp.concatenate([
        jnp.concatenate([rows[:, q, i - q + 2 * B] if i <= q else zero for i in range(G)], -1) for q in range(G)
    ], 1)  # fmt: skip
    return Hb, Y, Z


def _diagonal(Hb: list, start: int, step: int, count: int) -> Array:
    """D_k (count, N, N) of super-blocks k = start, start + step, ..., built from the band
    where it is needed: each block is factorised once, so the whole D is never written."""
    G = len(Hb)
    Hk = [h[start::step][:count] for h in Hb]
    return jnp.concatenate([
        jnp.concatenate([Hk[i2 - i][:, i] if i2 >= i else Hk[i - i2][:, i2].mT for i2 in range(G)], -1)
        for i in range(G)
    ], -2)  # fmt: skip


def rows_cyclic_factor(P0: Array, C: Array) -> RowsCyclicFactor:
    """Factorise H (as `rows_factor`'s) by block cyclic reduction of its 2B-frame super-blocks.

    The coupling U_k of blocks k and k+1 is Y_kᵀ M_k Z_k with M = I on the first level;
    eliminating the odd block o between even blocks e = o-1 and o+1 gives (L_o L_oᵀ = D_o)

        Pa = L_o⁻¹ Z_{e}ᵀ M_{e}ᵀ,   Qa = L_o⁻¹ Y_oᵀ M_o,
        D_e -= Y_eᵀ (Paᵀ Pa) Y_e,   D_{o+1} -= Z_oᵀ (Qaᵀ Qa) Z_o,   U'_e = Y_eᵀ (-Paᵀ Qa) Z_o,

    so the new coupling keeps the form and its bases, and every product is N × r or
    r × r instead of N × N (SIP: r = 36 against N = 102; "cyclic" in `tridiagonal.py`
    forms the dense U). The same elimination order as that cyclic reduction, so the
    same pivots.

    A block's bases never change (Y of block k is that of its right boundary, Z_{k-1} of its
    left one, at every level), so its updates are summed as r × r matrices A_k, B_k,
    D_k = D⁰_k - Y_kᵀ A_k Y_k - Z_{k-1}ᵀ B_k Z_{k-1}, and D_k is formed once, when it is
    factorised: no N × N array is rewritten per level (on a GPU the time was moving them).
    Level ℓ's blocks are the original ones k·2^ℓ, sliced from Y, Z and the band directly.
    """
    Hb, Y, Z = _super_blocks(P0, C)
    Kb, r, N = Y.shape
    dtype = Y.dtype
    A = Bz = jnp.zeros((Kb, r, r), dtype)  # the summed updates through Y_k and Z_{k-1}
    M = jnp.broadcast_to(jnp.eye(r, dtype=dtype), (Kb, r, r)).at[-1].set(0.0)  # no block after the last
    levels = []
    K, s = Kb, 1  # blocks on this level, their stride in the original ones
    while K > 1:
        Ke, Ko = (K + 1) // 2, K // 2
        W = jnp.concatenate([Z[s - 1 :: 2 * s][:Ko], Y[s :: 2 * s][:Ko]], 1)  # (Ko, 2r, N): Z_{o-1}, Y_o
        D = _diagonal(Hb, s, 2 * s, Ko)
        if s > 1:  # nothing to subtract on the first level
            Sd = _block_diag(Bz[1::2], A[1::2])
            D = D - jnp.einsum("kan,kam->knm", W, jnp.einsum("kab,kbm->kam", Sd, W))
        L = inverse_cholesky(D, CYCLIC_BASE if Ko >= CYCLIC_RECURSIVE_BLOCKS else N)
        Me, Mo = M[0::2][:Ko], M[1::2]
        Md = _block_diag(Me.mT, Mo)
        PQ = jnp.einsum("knm,kam->kna", L, jnp.einsum("kba,kbm->kam", Md, W))  # [Pa Qa]
        S = jnp.einsum("kna,knb->kab", PQ, PQ)  # [[PaᵀPa, PaᵀQa], [., QaᵀQa]]
        levels.append(RowsCyclicLevel(L, PQ, Y[0 :: 2 * s][:Ko], pad_blocks(Z[2 * s - 1 :: 2 * s], Ko)))
        A, Bz, M = (
            A[0::2] + pad_blocks(S[:, :r, :r], Ke),
            Bz[0::2] + shift_blocks_down(S[:, r:, r:], Ke),
            pad_blocks(-S[:, :r, r:], Ke),
        )
        K, s = Ke, 2 * s
    D = _diagonal(Hb, 0, 1, 1) - jnp.einsum("kan,kab,kbm->knm", Y[:1], A, Y[:1])  # block 0: no left boundary
    return RowsCyclicFactor(tuple(levels), inverse_cholesky(D, N))


def _block_diag(a: Array, b: Array) -> Array:
    """[a 0; 0 b] for batches of square blocks (K, r, r): both halves of W in one product."""
    za, zb = jnp.zeros_like(a), jnp.zeros_like(b)
    return jnp.concatenate([jnp.concatenate([a, za], -1), jnp.concatenate([zb, b], -1)], -2)


def rows_cyclic_solve(f: RowsCyclicFactor, b: Array) -> Array:
    """H⁻¹ b for b (T, n, k) with a `RowsCyclicFactor`."""
    T, n, k = b.shape
    N = f.last.shape[-1]
    G = N // n
    Kb = -(-T // G)
    b = jnp.pad(b, ((0, Kb * G - T), (0, 0), (0, 0))).reshape(Kb, N, k)
    zs = []
    for lev in f.levels:
        Ke, r = (b.shape[0] + 1) // 2, lev.Y.shape[1]
        z = lev.L @ b[1::2]
        zs.append(z)
        t = lev.PQ.mT @ z  # [Paᵀ z; Qaᵀ z]
        b = b[0::2] - pad_blocks(lev.Y.mT @ t[:, :r], Ke) - shift_blocks_down(lev.Z.mT @ t[:, r:], Ke)
    x = f.last.mT @ (f.last @ b)
    for lev, z in zip(reversed(f.levels), reversed(zs)):
        Ko = z.shape[0]
        u = jnp.concatenate([lev.Y @ x[:Ko], lev.Z @ pad_blocks(x[1:], Ko)], 1)  # x_{o-1}, x_{o+1} in the rows
        x = interleave_blocks(x, lev.L.mT @ (z - lev.PQ @ u))
    return x.reshape(Kb * G, n, k)[:T]
