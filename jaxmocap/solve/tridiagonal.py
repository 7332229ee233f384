"""Symmetric positive definite block-tridiagonal solves, sequential or parallel in time.

A has diagonal blocks D_k and super-diagonal blocks U_k = A_{k,k+1} (k = 0..K-1, U_{K-1}
unused). Two factorisations with one interface (`tridiagonal_factor`, then the factor's
`solve`):

- **"scan"**: block Cholesky along the sequence, one `lax.scan` step per block. Fewest
  flops (≈ 3 N³ per block) but K dependent steps: on a GPU each step is a handful of
  tiny kernels, so a 500-block sequence is launch-bound (issue 20: 1.1 s for SIP's 20
  steps on one H200).
- **"rows"**: the scan's factorisation in frame order with the fill kept in the
  coupling terms' row space (`rows.py`), used by `factorise.py` where the coupling terms
  have fewer rows per frame than coupled unknowns and there are no windows; a band given
  to `tridiagonal_factor` with "rows" is factorised by "scan".
- **"cyclic"**: block cyclic reduction (with coupling rows as for "rows", `rows.py`'s
  version, which keeps the off-diagonal blocks in the rows' space). The odd blocks are
  eliminated at once, leaving a block-tridiagonal Schur complement on the even blocks
  (half as many), and so on:
  ⌈log₂ K⌉ levels of batched work, ≈ 6 N³ per block. It is Cholesky of A with the
  blocks reordered (odd ones first, level by level), hence as stable as the scan for SPD A.

With L_o the Cholesky factor of an odd block o, P_o = L_o⁻¹ A_{o,o-1} and
Q_o = L_o⁻¹ A_{o,o+1}, the even system is

    D'_j = D_{2j} - Q_{2j-1}ᵀ Q_{2j-1} - P_{2j+1}ᵀ P_{2j+1},     U'_j = -P_{2j+1}ᵀ Q_{2j+1},

its right-hand side b'_j = b_{2j} - Q_{2j-1}ᵀ z_{2j-1} - P_{2j+1}ᵀ z_{2j+1} with
z_o = L_o⁻¹ b_o, and after solving it x_o = L_o⁻ᵀ (z_o - P_o x_{o-1} - Q_o x_{o+1}).

Both keep inverse Cholesky factors so that every substitution is a matrix product, which
XLA runs several times faster than triangular solves on CPU and GPU alike.

`CoupledFactor` is the interface through which `factorise.py` uses any factorisation of
the coupled unknowns: `superblocks.BandFactor` (this module's, on super-blocks of frames
and windows) and `rows.py`'s two (frames as they are).
"""

from __future__ import annotations

import abc

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
from jax import Array

__all__ = [
    "TRIDIAGONAL_METHODS", "CoupledFactor", "tridiagonal_factor", "tridiagonal_solve", "default_tridiagonal_method",
    "inverse_cholesky",
]  # fmt: skip

TRIDIAGONAL_METHODS = ("rows", "scan", "cyclic")

#: `inverse_cholesky`'s base size in the scan, where each step factorises one block and
#: every extra operation costs its dispatch: the whole scan factorisation of SIP's 500
#: blocks of 102 on a 2-core CPU took 70 ms with 32, 87 ms with 16, 107 ms with none.
SCAN_BASE = 32

#: Its base in cyclic reduction, on levels of at least `CYCLIC_RECURSIVE_BLOCKS` odd blocks
#: (per sequence; the deeper levels are few blocks and launch-bound: SIP's single 1000-frame
#: solve on one H100 took 0.066 s without the recursion, 0.088 s with it on every level).
CYCLIC_BASE = 16
CYCLIC_RECURSIVE_BLOCKS = 32


def default_tridiagonal_method() -> str:
    """ "rows" on the CPU (fewest flops, no launch cost), "cyclic" on accelerators.

    Read from JAX's default backend at trace time: the choice changes speed, not results.
    """
    return "rows" if jax.default_backend() == "cpu" else "cyclic"


def inverse_cholesky(S: Array, base: int = CYCLIC_BASE) -> Array:
    """L⁻¹ for S = L Lᵀ, batched over leading axes, by recursive halving.

    With S = [[A, Bᵀ], [B, C]], A = L₁ L₁ᵀ, L₂₁ = B L₁⁻ᵀ and C - L₂₁ L₂₁ᵀ = L₂ L₂ᵀ:
    L⁻¹ = [[L₁⁻¹, 0], [-L₂⁻¹ L₂₁ L₁⁻¹, L₂⁻¹]], each half the same way down to `base`
    (LAPACK-style Cholesky and a triangular solve against I). The same flops as that
    solve done whole, but nearly all of them in matrix products, which run several
    times faster than batched triangular solves (102 × 102 blocks: 20.2 → 8.7 ms for
    31 250 of them on one H100, 67 → 19 ms for 250 on a 2-core CPU;
    benchmarks/inverse_cholesky.py). `base` ≥ n: no recursion.
    """
    n = S.shape[-1]
    if n <= base:
        eye = jnp.broadcast_to(jnp.eye(n, dtype=S.dtype), S.shape)
        return jsl.solve_triangular(jnp.linalg.cholesky(S), eye, lower=True)
    k = n // 2
    L1_inv = inverse_cholesky(S[..., :k, :k], base)
    L21 = S[..., k:, :k] @ L1_inv.mT
    L2_inv = inverse_cholesky(S[..., k:, k:] - L21 @ L21.mT, base)
    top = jnp.concatenate([L1_inv, jnp.zeros(L1_inv.shape[:-1] + (n - k,), S.dtype)], -1)
    return jnp.concatenate([top, jnp.concatenate([-(L2_inv @ (L21 @ L1_inv)), L2_inv], -1)], -2)


class CoupledFactor(eqx.Module):
    """A factorised SPD matrix A of the coupled unknowns (the frames a frame-coupling term
    reads, and the windows), as `factorise.py` uses it: a right-hand side's frame and
    window parts packed into the factor's own blocks, solved, unpacked."""

    @abc.abstractmethod
    def pack(self, xF: Array | None, xW: Array | None) -> Array:
        """Frame (T, nc, ...) and window (W, m, ...) parts -> the factor's vector (K, N, ...)."""

    @abc.abstractmethod
    def unpack(self, x: Array) -> tuple[Array | None, Array | None]:
        """`pack`'s inverse: (frame part, window part or None)."""

    @abc.abstractmethod
    def solve(self, b: Array) -> Array:
        """A⁻¹ b for packed b (K, N, k)."""


class ScanFactor(eqx.Module):
    """Sequential block Cholesky: L (K, N, N) inverse factors, W (K, N, N) = L_k⁻¹ U_k."""

    L: Array
    W: Array

    def solve(self, b: Array) -> Array:
        """A⁻¹ b for b (K, N, k)."""
        return _scan_solve(self, b)


class CyclicLevel(eqx.Module):
    """One level of cyclic reduction: inverse factors of the odd blocks and their couplings."""

    L: Array  # (Ko, N, N) L_o⁻¹
    P: Array  # (Ko, N, N) L_o⁻¹ A_{o,o-1}
    Q: Array  # (Ko, N, N) L_o⁻¹ A_{o,o+1} (0 past the end)


class CyclicFactor(eqx.Module):
    """Cyclic reduction: the levels (finest first) and the last block's inverse factor."""

    levels: tuple[CyclicLevel, ...]
    last: Array  # (1, N, N)

    def solve(self, b: Array) -> Array:
        """A⁻¹ b for b (K, N, k)."""
        return _cyclic_solve(self, b)


def _scan_factor(D: Array, U: Array) -> ScanFactor:
    def step(W_prev, DU):
        Dk, Uk = DU
        Lk_inv = inverse_cholesky(Dk - W_prev.T @ W_prev, SCAN_BASE)
        Wk = Lk_inv @ Uk
        return Wk, (Lk_inv, Wk)

    _, (L, W) = jax.lax.scan(step, jnp.zeros_like(D[0]), (D, U))
    return ScanFactor(L, W)


def _scan_solve(f: ScanFactor, b: Array) -> Array:
    def forward(z_prev, LWb):
        Lk, Wk_prev, bk = LWb
        z = Lk @ (bk - Wk_prev.T @ z_prev)
        return z, z

    W_prev = jnp.concatenate([jnp.zeros_like(f.W[:1]), f.W[:-1]], 0)
    _, z = jax.lax.scan(forward, jnp.zeros(b.shape[1:], b.dtype), (f.L, W_prev, b))

    def backward(x_next, LWz):
        Lk, Wk, zk = LWz
        x = Lk.T @ (zk - Wk @ x_next)
        return x, x

    _, x = jax.lax.scan(backward, jnp.zeros(b.shape[1:], b.dtype), (f.L, f.W, z), reverse=True)
    return x


# Block helpers of cyclic reduction, shared with `rows.py`'s cyclic reduction on rows.


def shift_blocks_down(x: Array, length: int) -> Array:
    """x_{j-1} for j = 0..length-1 (zero at j = 0), from x of any length ≥ length - 1."""
    x = jnp.concatenate([jnp.zeros_like(x[:1]), x], 0)[:length]
    return pad_blocks(x, length)


def pad_blocks(x: Array, length: int) -> Array:
    """x cut or zero-padded to `length` along the first axis."""
    if x.shape[0] >= length:
        return x[:length]
    return jnp.concatenate([x, jnp.zeros((length - x.shape[0],) + x.shape[1:], x.dtype)], 0)


def _cyclic_factor(D: Array, U: Array) -> CyclicFactor:
    levels = []
    while D.shape[0] > 1:
        K = D.shape[0]
        Ke, Ko = (K + 1) // 2, K // 2
        # Few blocks per level: the recursion's extra launches outweigh its faster products.
        L = inverse_cholesky(D[1::2], CYCLIC_BASE if Ko >= CYCLIC_RECURSIVE_BLOCKS else D.shape[-1])
        P = L @ U[0::2][:Ko].mT  # A_{o,o-1} = U_{o-1}ᵀ
        Q = L @ U[1::2]  # A_{o,o+1} = U_o (zero for the last block)
        levels.append(CyclicLevel(L, P, Q))
        QtQ = Q.mT @ Q  # subtracted from the even block after each odd one
        PtP = P.mT @ P  # ... and before it
        D = D[0::2] - shift_blocks_down(QtQ, Ke) - pad_blocks(PtP, Ke)
        U = pad_blocks(-(P.mT @ Q), Ke)
    return CyclicFactor(tuple(levels), inverse_cholesky(D, D.shape[-1]))


def _cyclic_solve(f: CyclicFactor, b: Array) -> Array:
    zs = []
    for lev in f.levels:
        Ke = (b.shape[0] + 1) // 2
        z = lev.L @ b[1::2]
        zs.append(z)
        b = b[0::2] - shift_blocks_down(lev.Q.mT @ z, Ke) - pad_blocks(lev.P.mT @ z, Ke)
    x = f.last.mT @ (f.last @ b)
    for lev, z in zip(reversed(f.levels), reversed(zs)):
        Ko = z.shape[0]
        x_prev, x_next = x[:Ko], pad_blocks(x[1:], Ko)
        x = interleave_blocks(x, lev.L.mT @ (z - lev.P @ x_prev - lev.Q @ x_next))
    return x


def interleave_blocks(even: Array, odd: Array) -> Array:
    """Blocks back in sequence order: even ones at 0, 2, ..., odd ones at 1, 3, ..."""
    out = jnp.zeros((even.shape[0] + odd.shape[0],) + even.shape[1:], even.dtype)
    return out.at[0::2].set(even).at[1::2].set(odd)


def tridiagonal_factor(D: Array, U: Array, method: str | None = None) -> ScanFactor | CyclicFactor:
    """Factorise the SPD block-tridiagonal A (D (K, N, N), U (K, N, N), U[-1] ignored).

    method: "scan", "cyclic", "rows" (here "scan") or None (`default_tridiagonal_method`).
    """
    method = method or default_tridiagonal_method()
    if method not in TRIDIAGONAL_METHODS:
        raise ValueError(f"tridiagonal method {method!r}: use one of {TRIDIAGONAL_METHODS}.")
    if method in ("scan", "rows"):
        return _scan_factor(D, U)
    return _cyclic_factor(D, U.at[-1].set(0.0))


def tridiagonal_solve(f: ScanFactor | CyclicFactor, b: Array) -> Array:
    """A⁻¹ b for b (K, N, k), with the factor of `tridiagonal_factor`."""
    return f.solve(b)
