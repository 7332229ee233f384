"""The structured factorisation as a lineax solver: `StructuredCholesky`, for optimistix.

Optimistix's own solvers hand it J, or [J; √λ I] for Levenberg-Marquardt; its
`optx.ImplicitAdjoint` hands it the Hessian of the cost. Either way the matrix is
assembled in the banded-plus-border structure (`structure.py`: blocks by colouring in
`colouring.py`, the normal equations in `assembly.py`) and factorised by `factorise.py`.
`full_precision` (products in full float32) is re-exported from `structure.py`.
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.tree_util as jtu
import lineax as lx
import numpy as np
from jax import Array

from .assembly import jt_vector, normal_equations
from .colouring import hessian_normal, jacobian_blocks
from .factorise import factor, solve_factored
from .structure import Structure, full_precision
from .unknowns import Layout

__all__ = ["StructuredCholesky", "full_precision"]


def _damped_parts(operator: lx.AbstractLinearOperator, damped: bool | None):
    """(J.mv, λ) for optimistix's LM operator y ↦ (J y, √λ y); (A.mv, None) otherwise.

    optimistix 0.1 closure-converts the damped map into an opaque jaxpr, so it is
    recognised by structure (a 2-tuple output whose second part is shaped like the
    input) unless `damped` says so explicitly; √λ is read off one probe product.
    """
    out, struct = operator.out_structure(), operator.in_structure()
    if damped is None:
        damped = isinstance(out, tuple) and len(out) == 2 and eqx.tree_equal(out[1], struct) is True
    if not damped:
        return operator.mv, None
    leaves, tree = jtu.tree_flatten(struct)
    probe = [jnp.zeros(s.shape, s.dtype) for s in leaves]
    probe[0] = probe[0].reshape(-1).at[0].set(1.0).reshape(leaves[0].shape)
    sqrt_lambda = jtu.tree_leaves(operator.mv(jtu.tree_unflatten(tree, probe))[1])[0].reshape(-1)[0]
    return (lambda y: operator.mv(y)[0]), sqrt_lambda**2


class StructuredCholesky(lx.AbstractLinearSolver):
    """The structured factorisation as a lineax solver (for optimistix).

    With `hessian=False` the operator is a residual Jacobian J (Gauss-Newton) or
    optimistix's damped [J; √λ I] (Levenberg-Marquardt, recognised and turned into
    JᵀJ + λI without any product of the damping rows), and the solve is the
    least-squares x = (JᵀJ + λI)⁻¹ Jᵀ v. With `hessian=True` the operator is the
    (symmetric) Hessian of the cost, as in `optx.ImplicitAdjoint`, and x = H⁻¹ v (with a
    relative ridge of ~1e-10 in float64 so that gauge freedoms stay solvable).
    The operator's input is the problem's parameter dict.

    Attributes:
        layout: the parameters' `Layout`.
        bandwidths: per residual leaf (in `jtu.tree_leaves` order), its frame coupling.
        columns: per residual leaf, the (frame, window, sequence) columns it reads.
        hessian: whether the operator is the Hessian (see above).
        refinements: rounds of iterative refinement of a Hessian solve against the ridge.
        factor_dtype: dtype in which H is formed and factorised (None: the operator's).
        tridiagonal: "rows", "scan", "cyclic" or None (the backend's default), see `solve`.
        frame_mask: (T,) False for padded frames (pinned to a zero step), or None.
    """

    layout: Layout = eqx.field(static=True)
    bandwidths: tuple[int, ...] = eqx.field(static=True)
    columns: tuple = eqx.field(static=True)
    hessian: bool = eqx.field(static=True, default=False)
    factor_dtype: Any = eqx.field(static=True, default=None)
    frame_mask: Array | None = None
    damped: bool | None = eqx.field(static=True, default=None)
    refinements: int = eqx.field(static=True, default=3)
    tridiagonal: str | None = eqx.field(static=True, default=None)

    @property
    def structure(self) -> Structure:
        return Structure.of(self.layout, self.bandwidths, [c[0] for c in self.columns])

    def _tangent(self, tF, tW, tG):
        return self.layout.unravel(tF, tW, tG)

    @full_precision
    def init(self, operator, options):
        del options
        st, layout = self.structure, self.layout
        struct = operator.in_structure()
        if not isinstance(struct, dict) or set(struct) != set(layout.keys):
            raise ValueError(
                f"StructuredCholesky needs an operator on the parameter dict {list(layout.keys)}, got {struct}."
            )
        in_dtype = jtu.tree_leaves(struct)[0].dtype
        dtype = self.factor_dtype or in_dtype
        if self.hessian:

            def hvp(tF, tW, tG):
                return layout.ravel(operator.mv(self._tangent(tF, tW, tG)))

            normal = hessian_normal(hvp, st, in_dtype, self.frame_mask)
            normal = jtu.tree_map(lambda x: x.astype(dtype), normal)
            # A relative ridge ε·diag(H), ε ≈ 1e-2 √(machine ε), keeps a gauge freedom of the
            # cost (SIP's translation drift, seen by accelerations only: H singular)
            # factorisable; `compute` refines against H itself, so the ridge costs no accuracy.
            ridge = 1e-2 * float(np.sqrt(np.finfo(dtype).eps))
            return factor(normal, st, ridge, True, self.tridiagonal), None, None, operator
        jac_mv, damping = _damped_parts(operator, self.damped)
        out = jtu.tree_leaves(operator.out_structure()[0] if damping is not None else operator.out_structure())
        if len(out) != len(self.bandwidths):
            raise ValueError(
                f"StructuredCholesky has {len(self.bandwidths)} bandwidths but the operator has "
                f"{len(out)} output leaves; give one per residual leaf."
            )
        for leaf in out:
            if leaf.shape[:1] != (st.T,):
                raise ValueError(f"every residual leaf must have the frame axis first (T={st.T}), got {leaf.shape}.")

        def mv(tF, tW, tG):
            return jtu.tree_leaves(jac_mv(self._tangent(tF, tW, tG)))

        blocks = jacobian_blocks(mv, st, in_dtype, self.bandwidths, self.columns, [leaf.shape for leaf in out])
        normal, _, _ = normal_equations(blocks, st, dtype, self.frame_mask, self.tridiagonal)
        return factor(normal, st, 0.0 if damping is None else damping, False, self.tridiagonal), blocks, damping, None

    @full_precision
    def compute(self, state, vector, options):
        del options
        f, blocks, damping, operator = state
        st, layout = f.st, self.layout
        dtype = jtu.tree_leaves(vector)[0].dtype
        cast = lambda x: None if x is None else x.astype(dtype)  # noqa: E731

        def solve(bF, bW, bG):  # solver-order right-hand side -> parameter dict
            xF, xW, xG = solve_factored(f, bF, bW, bG)
            return layout.unravel(cast(st.from_solver_order(xF)), cast(xW), cast(xG))

        def solve_dict(v):
            bF, bW, bG = layout.ravel(v)
            return solve(st.to_solver_order(bF), bW, bG)

        if blocks is None:
            # x = (H + εD)⁻¹ b, then iterative refinement x ← x + (H + εD)⁻¹ (b - H x): each
            # round shrinks the ridge's error by ~ε·cond(H); a gauge (null) component of x
            # stays bounded and does not reach gauge-invariant outputs.
            def refine(_, x):  # a loop, not unrolled: H and the solve traced once
                r = jtu.tree_map(lambda b, hx: b - hx, vector, operator.mv(x))
                return jtu.tree_map(jnp.add, x, solve_dict(r))

            x = jax.lax.fori_loop(0, self.refinements, refine, solve_dict(vector))
            return x, lx.RESULTS.successful, {}
        r = vector if damping is None else vector[0]
        bF, bW, bG = jt_vector(blocks, st, jtu.tree_leaves(r), f.sF.dtype)
        if damping is not None:
            # Aᵀv = Jᵀ v_r + √λ v_y (v_y = 0 in optimistix's LM, honoured anyway).
            yF, yW, yG = layout.ravel(vector[1])
            c = jnp.sqrt(damping).astype(bF.dtype)
            bF = bF + c * st.to_solver_order(yF).astype(bF.dtype)
            bW = None if bW is None else bW + c * yW.astype(bF.dtype)
            bG = None if bG is None else bG + c * yG.astype(bF.dtype)
        return solve(bF, bW, bG), lx.RESULTS.successful, {}

    def transpose(self, state, options):
        if not self.hessian:
            raise NotImplementedError(
                "StructuredCholesky(hessian=False) solves a least-squares problem; differentiate "
                "a solve through optx.ImplicitAdjoint(linear_solver=StructuredCholesky(..., hessian=True))."
            )
        return state, options  # the Hessian is symmetric

    def conj(self, state, options):
        return state, options

    def assume_full_rank(self):
        return True
