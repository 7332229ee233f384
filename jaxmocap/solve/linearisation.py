"""A problem linearised in the tangent of its manifold: the LM's normal equations.

`Args` is what the residual function reads besides the unknowns (optimistix's `args`);
`residuals` is that function. `linearise` evaluates the residuals at an iterate and their
Jacobian blocks with respect to a left perturbation x ⊕ δ of every unknown (analytic
`Term.jacobian`s, else forward-mode AD by colouring, `colouring.py`), and returns the
normal equations (`assembly.py`): a `factorise.Normal`, or a `basis.BasisNormal` for a
problem with a basis term.
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from .assembly import FactoredBlocks, TermBlocks, half_squared_norm, normal_equations
from .basis import basis_normal
from .colouring import jacobian_blocks
from .residuals import BlockJacobian, Params, Problem, sanitise
from .structure import Structure
from .unknowns import Layout, retract, to_manifold

__all__ = ["Args", "residuals", "linearise"]


class Args(eqx.Module):
    """What the residual function reads besides the unknowns: `optx.least_squares`'s args."""

    problem: Problem
    data: Any
    frame_mask: Array | None
    layout: Layout = eqx.field(static=True)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(sorted(t.name for t in self.problem.terms))

    def leaf_structure(self):
        """(bandwidths, (frame, window, sequence) columns) per residual leaf (sorted names)."""
        terms = {t.name: t for t in self.problem.terms}
        bw = tuple(terms[k].bandwidth for k in self.names)
        cols = tuple(
            tuple(self.layout.columns(terms[k].reads, kind) for kind in ("frame", "window", "sequence"))
            for k in self.names
        )
        return bw, cols

    def structure(self) -> Structure:
        bw, cols = self.leaf_structure()
        return Structure.of(self.layout, bw, [c[0] for c in cols])


def residuals(y: dict, args: Args) -> dict[str, Array]:
    """The weighted residuals of every term at stored parameters y: optimistix's `fn`."""
    x = to_manifold(y, args.layout)
    return args.problem.residuals_on_manifold(x, args.data, args.frame_mask, args.layout.T)


# --- linearisation in the tangent of the manifold (the LM's own) -------------------------


def _analytic_blocks(term, x, clean, data, frame_mask, layout: Layout, st: Structure, dtype, plain=False, posed=None):
    """Residual (T, m) and frame blocks (T, 2b+1, m, n) of a term with an analytic Jacobian.

    The term supplies ∂e/∂δ of its raw output; weight, robust loss and masks (which act
    row by row) are applied by pushing each column through their linearisation. A lone
    `BlockJacobian` of a term without loss or mask stays factored (`FactoredBlocks`)
    unless `plain` (the term has window or sequence blocks to join).
    """
    T = layout.T
    e = term.raw(x, clean, data, posed)
    jac = dict(term.raw_jacobian(x, clean, data, posed))
    C = 2 * term.bandwidth + 1
    factored = [k for k, v in jac.items() if isinstance(v, BlockJacobian)]
    if factored and term.bandwidth:
        raise ValueError(
            f"Term {term.name!r}: a BlockJacobian needs a per-frame term (bandwidth 0), got {term.bandwidth}."
        )
    if len(jac) == 1 and factored and term.loss is None and term.mask is None and not plain:
        # r = √w · keep_t · e: one scale per frame, so JᵀJ = s² Dᵀ (WᵀW) D (`FactoredBlocks`).
        (key,) = factored
        bj = jac[key]
        layout_cols = [c for i in bj.index for c in layout.columns(((key, (i,)),))]  # in the blocks' order
        solver_pos = np.arange(st.n) if st.perm is None else np.argsort(st.perm)
        e = e.astype(dtype)
        r = term.finish(e, data, frame_mask, T)
        s = term.finish(jnp.ones_like(e), data, frame_mask, T)[:, 0]
        return r, FactoredBlocks(r, s, bj.D.astype(dtype), bj.W, tuple(int(solver_pos[c]) for c in layout_cols))
    parts = []
    frame_keys = [(k, s) for k, kind, s in zip(layout.keys, layout.kinds, layout.shapes) if kind == "frame"]
    for key, shape in frame_keys:
        size = int(np.prod(shape))
        if isinstance(jac.get(key), BlockJacobian):
            jac[key] = jac[key].dense(e.shape[1:], shape)
        if key in jac:
            parts.append(jnp.asarray(jac[key], dtype).reshape((T, C) + e.shape[1:] + (size,)))
        else:
            parts.append(jnp.zeros((T, C) + e.shape[1:] + (size,), dtype))
    J = jnp.concatenate(parts, -1)  # (T, C, *e, n)
    e = e.astype(dtype)
    if term.loss is None:
        # finish is then linear, r = √w · keep · e: its Jacobian is r's of a unit e.
        r = term.finish(e, data, frame_mask, T)
        row_scale = term.finish(jnp.ones_like(e), data, frame_mask, T)  # (T, m)
        blocks = row_scale[:, None, :, None] * J.reshape(T, C, -1, J.shape[-1])
    else:
        r, lin = jax.linearize(lambda e_: term.finish(e_, data, frame_mask, T), e)
        tangents = jnp.moveaxis(jnp.moveaxis(J, -1, 0), 2, 1)  # (n, C, T, *e)
        cols = jax.vmap(jax.vmap(lin))(tangents)  # (n, C, T, m)
        blocks = jnp.transpose(cols, (2, 1, 3, 0))
    return r, st.to_solver_order(blocks)


def linearise(y: dict, args: Args, st: Structure, dtype, factor_dtype, tridiagonal: str | None = None):
    """Residuals at y and their blocks in the left-perturbation tangent: (Normal, grad, cost).

    One Gauss-Newton linearisation of `args.problem` (st = `args.structure()`), for
    `factor` / `solve_factored` (the LM's step, benchmarks); `dtype` of the residuals,
    `factor_dtype` of the normal blocks; `tridiagonal` as `solve`'s ("rows" keeps the
    frame band as coupling rows).

    Terms with an analytic `jacobian` supply their frame blocks; everything else (other
    terms, and any term's window and sequence blocks) comes from forward-mode AD by
    colouring over the columns the term reads. A problem with a basis term
    (`Term.basis`) gives a `basis.BasisNormal` instead (`_linearise_basis`).
    """
    problem, layout = args.problem, args.layout
    if any(t.basis is not None for t in problem.terms):
        return _linearise_basis(y, args, dtype, factor_dtype)
    x = to_manifold(y, layout)
    terms = {t.name: t for t in problem.terms}
    names = args.names
    bw, cols = args.leaf_structure()
    clean = sanitise(args.data)
    blocks: dict[str, TermBlocks] = {}
    views = problem.views(x)
    with_jacobian = [terms[k] for k in names if terms[k].jacobian is not None]
    posed = problem.posed_of(x, clean, with_jacobian)  # once for all the analytic terms
    analytic = {}
    for t in with_jacobian:
        k = t.name
        plain = any(cols[names.index(k)][1:])  # window or sequence blocks to join
        analytic[k] = _analytic_blocks(t, views[k], clean, args.data, args.frame_mask, layout, st, dtype, plain, posed)
    ad = [k for k in names if k not in analytic or any(cols[names.index(k)][1:])]
    zero = layout.ravel(layout.zeros(dtype))
    # One linearisation per kind of term (bandwidth, window and sequence columns read): each
    # linear map is traced once per colouring it needs, with only the terms that need it.
    kinds = {}
    for k in ad:
        i = names.index(k)
        kinds.setdefault((bw[i], bool(cols[i][1]), bool(cols[i][2])), []).append(k)
    for group in kinds.values():

        def at(dF, dW, dG, group=group):
            moved = retract(x, layout.unravel(dF, dW, dG), layout)
            return problem.residuals_on_manifold(moved, args.data, args.frame_mask, layout.T, group)

        res, lin = jax.linearize(at, *zero)
        idx = [names.index(k) for k in group]
        ad_cols = [(() if k in analytic else cols[i][0], cols[i][1], cols[i][2]) for k, i in zip(group, idx)]
        found = jacobian_blocks(lambda *t, lin=lin, group=group: [lin(*t)[k] for k in group], st, dtype,
                                [bw[i] for i in idx], ad_cols, [res[k].shape for k in group])  # fmt: skip
        for k, b in zip(group, found):
            blocks[k] = TermBlocks(res[k], b.JF, b.JW, b.JG)
    for k, (r, JF) in analytic.items():
        extra = blocks.get(k)
        if isinstance(JF, FactoredBlocks):
            blocks[k] = JF
            continue
        blocks[k] = TermBlocks(r, JF, None if extra is None else extra.JW, None if extra is None else extra.JG)
    return normal_equations([blocks[k] for k in names], st, factor_dtype, args.frame_mask, tridiagonal)


def _linearise_basis(y: dict, args: Args, dtype, factor_dtype):
    """`linearise` of a problem with one basis term (`jaxmocap.solve.basis`): the other
    (per-frame) terms by the engine's own blocks, the basis term's rows by one
    forward-mode pass over the per-frame tangent; (BasisNormal, grad, cost)."""
    problem, layout = args.problem, args.layout
    (bt, *more) = [t for t in problem.terms if t.basis is not None]
    key = bt.basis.key
    others = [t for t in problem.terms if t.basis is None]
    spec = {k: u for k, u in problem.spec.items() if k != key}
    bad = [t.name for t in others if t.bandwidth or (t.reads is not None and key in t.read_keys())]
    kinds = {k: c for k, c in zip(layout.keys, layout.kinds) if k != key}
    if more or bad or set(kinds.values()) != {"frame"} or layout.windows.stride != layout.windows.length:
        raise ValueError(
            f"a basis term ({bt.name!r}) is solved with per-frame terms and per-frame unknowns only, one basis "
            f"term, windows that do not overlap; got other basis terms {[t.name for t in more]}, coupled terms "
            f"{bad}, unknowns {kinds}, windows {layout.windows}."
        )  # fmt: skip
    yf = {k: v for k, v in y.items() if k != key}
    lf = Layout.of(yf, spec)
    T, n = lf.T, lf.n
    if others:
        sub = Args(Problem(others, spec, posed=problem.posed), args.data, args.frame_mask, lf)
        normal, (gF, _, _), cost = linearise(yf, sub, sub.structure(), dtype, factor_dtype)
        H = normal.FF[0]
    else:
        H, gF, cost = jnp.zeros((T, n, n), factor_dtype), jnp.zeros((T, n), factor_dtype), jnp.zeros((), factor_dtype)
    x = to_manifold(yf, lf)
    clean = sanitise(args.data)
    coef = y[key]

    def features(dF):
        view = Params(retract(x, lf.unravel(dF), lf), term=bt.name)
        if bt.posed is None:
            return bt.basis.features(view, bt._input(clean, args.data)).astype(dtype)
        posed = problem.posed(view, clean)
        return bt.basis.features(view, bt._input(clean, args.data), posed).astype(dtype)

    f, lin = jax.linearize(features, jnp.zeros((T, n), dtype))
    # Bandwidth 0: one tangent e_k on every frame gives column k of every frame's block.
    Jf = jnp.moveaxis(jax.vmap(lin)(jnp.broadcast_to(jnp.eye(n, dtype=dtype)[:, None], (n, T, n))), 0, -1)
    e = f - bt.basis.fit(coef.astype(dtype), T)
    finish = lambda e_: bt.finish(e_[:, None, :, None], args.data, args.frame_mask, T)  # noqa: E731
    r, g = jax.jvp(finish, (e,), (jnp.ones_like(e),))  # ρ per coordinate: g = ∂r/∂e elementwise
    normal, grad = basis_normal(H.astype(factor_dtype), gF.astype(factor_dtype), r, g, Jf, bt.basis, factor_dtype)
    return normal, grad, cost + half_squared_norm([r], factor_dtype)
