"""Per-window basis terms: e_t = f(x_t) − B_t c_w(t), solved with their Kronecker structure.

A basis term pulls per-frame features f(x_t) ∈ R^Q (MuVS: the 72 joint coordinates)
towards their reconstruction from a small basis per window of L frames (Huang eq. 4.8:
the first K DCT vectors, coefficients c_w ∈ R^{K×Q}). Every frame of a window is then
tied to every other through the K·Q coefficients. The generic window elimination
(`factorise.py`) would take those columns by K·Q Jacobian-vector products and fill the
window block with dense n × K·Q products per frame. The structure is Kronecker: row
(t, q) reads x_t and only the K coefficients of coordinate q of t's window, with
∂r_tq/∂c_wkq = −g_tq b_tk (g the slope of the weighted robust loss, b_t the basis row of
frame t in its window), so with U_t = J_tᵀ diag(g_t) (n × Q, J_t = ∂f/∂x_t):

    H_cc[w] = blockdiag_q(Σ_t g_tq² b_t b_tᵀ),    H_xc[t] = −U_t ⊗ b_tᵀ,

and eliminating the frames (A_t = H_t + λI, H_t = the per-frame terms' block + J_tᵀ
diag(g_t²) J_t) fills each window's K·Q block with Σ_t M_t ⊗ b_t b_tᵀ, M_t = U_tᵀ A_t⁻¹ U_t
(Q × Q): Q² products per frame where the generic path takes (K·Q)². MuVS, 30 frames on a
CPU: a step 25 ms against 300 ms.

`VonMarcardLM` takes this path when a problem has a basis term (`linearise` returns a
`BasisNormal`): same damping, stopping rules and result codes as every other solve.
The other terms must be per-frame (bandwidth 0) and the problem may have no unknowns
but per-frame ones and the term's windows (anything else: a ValueError naming it).

Windows do not overlap (stride = length). A last window of n < L frames gets
`basis(n)`, a basis of its own length (`WindowBasis`); coefficients it lacks are pinned
(no row reads them, their step is 0).
"""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from .residuals import Term
from .structure import Factorisation, NormalEquations, Structure

__all__ = ["WindowBasis", "basis_term", "BasisNormal", "BasisFactor", "basis_normal", "basis_factor", "basis_solve"]


class WindowBasis(eqx.Module):
    """The per-window basis of a basis term (static).

    Attributes:
        key: the per-window unknown holding the coefficients, (W, K, ...) with
            prod(...) = Q, declared `window(length)`.
        features: `features(params, data) -> (T, Q)`, per frame (row t reads x_t only).
        basis: `basis(n) -> (n, k)`, k <= K = basis(length).shape[1]: the basis of a
            window of n frames (n = length but for a shorter last window).
        length: L, frames per window.
        posed: the posed body `features` reads as `features(params, data, posed)`, or None
            (`Term.posed`).
    """

    key: str = eqx.field(static=True)
    features: Callable = eqx.field(static=True)
    basis: Callable[[int], np.ndarray] = eqx.field(static=True)
    length: int = eqx.field(static=True)
    posed: Callable | None = eqx.field(static=True, default=None)

    @property
    def width(self) -> int:
        """K, coefficients per window and feature."""
        return int(np.shape(self.basis(self.length))[1])

    def table(self, T: int) -> tuple[np.ndarray, np.ndarray]:
        """(window of each frame (T,), basis row of each frame (T, K), zero-padded)."""
        L, K = self.length, self.width
        rows = np.zeros((T, K))
        for start in range(0, T, L):
            n = min(L, T - start)
            B = np.asarray(self.basis(n), np.float64)
            if B.ndim != 2 or B.shape[0] != n or B.shape[1] > K:
                raise ValueError(f"basis({n}) must be ({n}, k <= {K}), got shape {B.shape}.")
            rows[start : start + n, : B.shape[1]] = B
        return np.arange(T) // L, rows

    def fit(self, coef: Array, T: int) -> Array:
        """B_t c_w(t) (T, Q) of coefficients (W, K, ...)."""
        window, rows = self.table(T)
        c = coef.reshape(coef.shape[0], self.width, -1)
        return jnp.einsum("tk,tkq->tq", jnp.asarray(rows, coef.dtype), c[window])

    def residual(self, params, data, *posed) -> Array:
        """e = f(x) − B c as rows (T, 1 window slot, Q, 1): ρ acts per coordinate
        (`posed`: the posed body, when the basis reads one)."""
        f = self.features(params, data, *posed)
        return (f - self.fit(params[self.key], f.shape[0]))[:, None, :, None]


class BasisNormal(NormalEquations):
    """A basis problem linearised: H (T, n, n) per frame (every term), U (T, n, Q),
    Hcc (W, Q, K, K), the basis rows (T, K) and the pinned coefficients (W, Q, K)."""

    H: Array
    U: Array
    Hcc: Array
    rows: Array
    unused: Array
    length: int = eqx.field(static=True)

    def factor(self, st: Structure, damping, marquardt: bool = False, tridiagonal: str | None = None) -> BasisFactor:
        del st, tridiagonal  # its own structure: no frame band
        return basis_factor(self, damping, marquardt)


class BasisFactor(Factorisation):
    """`BasisNormal` + damping factorised: per-frame Cholesky factors A (T, n, n),
    Y = A⁻¹ U, the windows' Schur complements' factors (W, QK, QK)."""

    A: Array
    Y: Array
    U: Array
    S: Array
    rows: Array
    length: int = eqx.field(static=True)

    def solve(self, bF: Array, bW: Array | None = None, bG: Array | None = None):
        return basis_solve(self, bF, bW, bG)


def _by_window(x: Array, L: int) -> Array:
    """(T, ...) -> (W, L, ...), zeros past the end."""
    T = x.shape[0]
    W = -(-T // L)
    pad = W * L - T
    if pad:
        x = jnp.concatenate([x, jnp.zeros((pad,) + x.shape[1:], x.dtype)])
    return x.reshape((W, L) + x.shape[1:])


def basis_normal(H: Array, gF: Array, r: Array, g: Array, Jf: Array, basis: WindowBasis, dtype):
    """The basis term's rows joined to the per-frame normal equations.

    H (T, n, n), gF (T, n): the per-frame terms' block and gradient; r, g (T, Q): the
    basis term's residual and its slope ∂r/∂e (elementwise); Jf (T, Q, n) = ∂f/∂x_t.
    Returns (`BasisNormal`, (gF, gW (W, K·Q) in the layout's order, None)).
    """
    T = H.shape[0]
    L = basis.length
    _, rows = basis.table(T)
    rows = jnp.asarray(rows, dtype)
    r, g, Jf = r.astype(dtype), g.astype(dtype), Jf.astype(dtype)
    Jx = g[..., None] * Jf  # ∂r/∂x_t (T, Q, n)
    H = H + jnp.einsum("tqi,tqj->tij", Jx, Jx)
    gF = gF + jnp.einsum("tqi,tq->ti", Jx, r)
    U = jnp.swapaxes(Jx, 1, 2) * g[:, None, :]  # H_xc = −U ⊗ b_tᵀ
    bw = _by_window(rows, L)  # (W, L, K)
    Hcc = jnp.einsum("wlq,wlk,wlm->wqkm", _by_window(g * g, L), bw, bw)
    gc = -jnp.einsum("wlq,wlk->wkq", _by_window(g * r, L), bw)
    # Coefficients no row reads (a short last window's, a window of padded frames): pinned.
    unused = (jnp.diagonal(Hcc, axis1=-2, axis2=-1) == 0).astype(dtype)  # (W, Q, K)
    normal = BasisNormal(H, U, Hcc, rows, unused, L)
    return normal, (gF, gc.reshape(gc.shape[0], -1), None)


def basis_factor(normal: BasisNormal, lam, marquardt: bool = False) -> BasisFactor:
    """Factorise H + λI (or H + λ diag(H), eq. 2.54): frames by Cholesky, then each
    window's Schur complement S_w = H_cc[w] + λ − Σ_t M_t ⊗ b_t b_tᵀ."""
    H, U, Hcc, L = normal.H, normal.U, normal.Hcc, normal.length
    dtype = H.dtype
    n, Q, K = H.shape[-1], U.shape[-1], Hcc.shape[-1]
    lam = jnp.asarray(lam, dtype)
    dH = jnp.diagonal(H, axis1=-2, axis2=-1)
    dC = jnp.diagonal(Hcc, axis1=-2, axis2=-1)  # (W, Q, K)
    if marquardt:  # floored as in `factorise._damp_scale`
        dH = jnp.maximum(dH, 1e-12 * jnp.maximum(jnp.max(dH), 1.0))
        dC = jnp.maximum(dC, 1e-12 * jnp.maximum(jnp.max(dC), 1.0))
    else:
        dH, dC = jnp.ones_like(dH), jnp.ones_like(dC)
    A = jnp.linalg.cholesky(H + lam * dH[..., None] * jnp.eye(n, dtype=dtype))
    Y = jax.vmap(lambda a, b: jax.scipy.linalg.cho_solve((a, True), b))(A, U)  # (T, n, Q)
    M = jnp.einsum("tiq,tip->tqp", U, Y)
    bw = _by_window(normal.rows, L)
    fill = jnp.einsum("wlqp,wlk,wlm->wqkpm", _by_window(M, L), bw, bw)
    diag = lam * dC + normal.unused  # pinned coefficients: identity
    C = Hcc + diag[..., None] * jnp.eye(K, dtype=dtype)
    S = jnp.einsum("qp,wqkm->wqkpm", jnp.eye(Q, dtype=dtype), C) - fill
    S = jnp.linalg.cholesky(S.reshape(S.shape[0], Q * K, Q * K))
    return BasisFactor(A, Y, U, S, normal.rows, L)


def basis_solve(f: BasisFactor, bF: Array, bW: Array, bG=None):
    """Solve (H + λI) x = b with a `BasisFactor`; b and x as (F (T, n), W (W, K·Q), None)."""
    del bG
    L, rows = f.length, f.rows
    T, Q = f.U.shape[0], f.U.shape[-1]
    W, K = f.S.shape[0], rows.shape[-1]
    cho = jax.vmap(lambda a, b: jax.scipy.linalg.cho_solve((a, True), b))
    yv = cho(f.A, bF.astype(f.A.dtype))  # A⁻¹ b_x
    bc = jnp.swapaxes(bW.astype(f.A.dtype).reshape(W, K, Q), 1, 2)  # (W, Q, K)
    rhs = bc + jnp.einsum("wlq,wlk->wqk", _by_window(jnp.einsum("tiq,ti->tq", f.U, yv), L), _by_window(rows, L))
    z = cho(f.S, rhs.reshape(W, Q * K)).reshape(W, Q, K)
    window = np.arange(T) // L
    v = jnp.einsum("tqk,tk->tq", z[window], rows)
    xF = yv + jnp.einsum("tiq,tq->ti", f.Y, v)
    return xF, jnp.swapaxes(z, 1, 2).reshape(W, K * Q), None


def basis_term(name: str, basis: WindowBasis, reads, weight: float | Array = 1.0, loss=None) -> Term:
    """A `Term` e = f(x) − B c (`WindowBasis.residual`), ρ per coordinate.

    reads: the per-frame unknowns `basis.features` reads, as `Term.reads`; the
    coefficients' key is added.
    """
    if reads is None:
        raise ValueError(
            f"basis term {name!r}: give the per-frame keys its features read, e.g. reads=(('pose', None),)."
        )
    return Term(
        name,
        basis.residual,
        weight,
        loss=loss,
        reads=tuple(reads) + ((basis.key, None),),
        basis=basis,
        posed=basis.posed,
    )
