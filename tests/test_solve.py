"""Tests for the least-squares engine (jaxmocap.solve): structure, LM, masks, batches.

A three-bone chain with a rigidly attached sensor per bone stands in for the body: it
has the structure of SIP (von Marcard §3.3: per-frame orientation residuals, t-1/t/t+1
acceleration residuals, a prior) at a size that keeps this file fast. Float64 is on
(tests/conftest.py); float32 behaviour is tested explicitly.
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest
import scipy.optimize

from jaxmocap._compat import DIVERGENCE, MAX_STEPS, SUCCESSFUL
from jaxmocap.solve import (
    Cauchy,
    GemanMcClure,
    Huber,
    Problem,
    Term,
    VonMarcardLM,
    pad_sequences,
    result_message,
    solve,
    solve_batch,
)
from jaxmocap.solve import frame, sequence, window
from jaxmocap.solve.basis import WindowBasis, basis_term
from jaxmocap.solve.linearisation import Args
from jaxmocap.solve.options import SOLVERS
from jaxmocap.solve.solver import linear_solver
from jaxmocap.solve.linearisation import residuals
from jaxmocap.solve.unknowns import to_manifold
from solve_chain import (
    e_ori,
    e_acc,
    CHAIN,
    motion,
    rot_error,
    sensors,
    WIN,
    e_heading,
    e_offset,
    e_window,
    _variants,
)

# --- known minimiser, all backends, manifold parametrisations ------------------------


@pytest.mark.parametrize("method", ["lm", "optx_lm", "optx_gn", "jaxopt"])
def test_known_minimiser_recovered(method):
    truth, init, data = motion(8)
    atol = 1e-7 if method == "jaxopt" else 1e-12  # jaxopt: a bound on ‖Jᵀr‖
    sol = solve(CHAIN, init, data, max_steps=60, solver=SOLVERS[method](rtol=1e-10, atol=atol))
    assert int(sol.result) == 0, (method, int(sol.result), float(sol.cost))
    assert rot_error(sol.value["rot"], truth["rot"]) < 1e-6
    np.testing.assert_allclose(sol.value["trans"], truth["trans"], atol=1e-6)
    assert float(sol.cost) < 1e-12
    assert set(sol.costs) == {"ori", "acc", "trans"}


def test_manifold_parametrisations_converge_alike():
    """Re-anchored exp(δ^)R updates ("lm", eq. 2.60) and a fixed anchor (optimistix)."""
    truth, init, data = motion(8, seed=3)
    steps = {}
    for method in ("lm", "optx_lm"):
        sol = solve(CHAIN, init, data, max_steps=60, solver=SOLVERS[method](rtol=1e-10, atol=1e-12))
        assert rot_error(sol.value["rot"], truth["rot"]) < 1e-6
        assert int(sol.result) == 0, (method, int(sol.result))
        steps[method] = int(sol.num_steps)
    # Both stop on their own (optimistix's trust region takes more steps: 41 here).
    assert max(steps.values()) < 60, steps


# --- the structured linear solve: band, border, windows ----------------------------------


_STEP_CASES = (
    [(v, m) for v in ("band", "border", "windows", "all") for m in ("scan", "cyclic")]
    + [(v, m) for v in ("narrow", "narrow_border") for m in ("rows", "cyclic")]
    + [("windows", "rows")]
)


@pytest.mark.parametrize("variant, tridiagonal", _STEP_CASES)
def test_structured_step_equals_dense_step(variant, tridiagonal):
    """The LM step (eq. 2.52) from the structured factorisation equals a dense float64 solve
    of the same normal equations, for frame bands (b = 0, 1, 2 together), a sequence-wide
    border, overlapping windows and all at once; T = 9 is not a multiple of any block.
    Every factorisation of the frame band: sequential scan and cyclic reduction of the
    band, and both in the coupling rows' space (used where the rows are fewer than the coupled unknowns:
    the narrow variants; the band's elsewhere)."""
    has_rows, step, cost = _structured_steps(variant)[tridiagonal]
    assert has_rows == (tridiagonal in ("rows", "cyclic") and variant.startswith("narrow"))
    flat = np.concatenate([np.asarray(p).reshape(-1) for p in step if p is not None])
    dense, half_rr = _dense_step(variant)
    assert abs(float(cost) - half_rr) <= 1e-12 * half_rr
    assert np.max(np.abs(flat - dense)) < 1e-7 * max(np.max(np.abs(dense)), 1.0)


@functools.lru_cache(maxsize=None)
def _structured_steps(variant):
    """{tridiagonal: (has coupling rows, step, ½‖r‖²)} of `variant` for every method it is
    tested with, from one jitted program (once per variant, not per method). `linearise`
    reads `tridiagonal` only to choose the normal equations' form (coupling rows or the
    band): each method's form is taken from its own linearisation's shape, and the methods
    of one form factorise one linearisation instead of compiling it again each."""
    from jaxmocap.solve.linearisation import linearise
    from jaxmocap.solve.factorise import factor, solve_factored

    problems, data = _variants(9)
    problem, params = problems[variant]
    layout = problem.layout(params)
    st = Args(problem, data, None, layout).structure()
    methods = [m for v, m in _STEP_CASES if v == variant]

    def lin(params, data, tridiagonal):
        return linearise(params, Args(problem, data, None, layout), st, jnp.float64, jnp.float64, tridiagonal)

    has_rows = {
        m: jax.eval_shape(functools.partial(lin, tridiagonal=m), params, data)[0].C is not None for m in methods
    }

    @jax.jit  # one compilation instead of op-by-op dispatch of every small product
    def steps_of(params, data):
        out, normals = {}, {}
        for m in methods:
            if has_rows[m] not in normals:
                normals[has_rows[m]] = lin(params, data, m)
            normal, grad, cost = normals[has_rows[m]]
            xF, xW, xG = solve_factored(factor(normal, st, 0.3, tridiagonal=m), *grad)
            out[m] = layout.ravel(layout.unravel(st.from_solver_order(xF), xW, xG)), cost
        return out

    return {m: (has_rows[m], *s) for m, s in steps_of(params, data).items()}


#: Every variant's terms and unknowns are among those of "all" or of "narrow_border", at
#: the same values (`_variants`): its dense Jacobian is a block of theirs.
_DENSE_SOURCE = {"band": "all", "border": "all", "windows": "all", "all": "all",
                 "narrow": "narrow_border", "narrow_border": "narrow_border"}  # fmt: skip


@functools.lru_cache(maxsize=None)
def _dense_jacobian(source):
    """Each term's dense Jacobian at x ⊕ 0 over the flat tangent of `source`'s unknowns
    ({term: (rows, N)}), its residuals ({term: (rows,)}), and the tangent's flat positions
    of each unknown ({key: index array})."""
    from jaxmocap.solve.unknowns import retract

    problems, data = _variants(9)
    problem, params = problems[source]
    layout = problem.layout(params)
    x = to_manifold(params, layout)
    F, W, G = layout.ravel(layout.zeros(jnp.float64))
    sizes = [p.size for p in (F, W, G) if p is not None]

    def split(d):
        parts, start = [], 0
        for p in (F, W, G):
            if p is None:
                parts.append(None)
                continue
            parts.append(d[start : start + p.size].reshape(p.shape))
            start += p.size
        return layout.unravel(*parts)

    def r_of(d):
        res = problem.residuals_on_manifold(retract(x, split(d), layout), data, None, layout.T)
        return {k: v.reshape(-1) for k, v in res.items()}

    d0 = jnp.zeros(sum(sizes))
    J, r = jax.jit(lambda d: (jax.jacfwd(r_of)(d), r_of(d)))(d0)
    position = {k: np.asarray(v) for k, v in split(np.arange(sum(sizes))).items()}
    return {k: np.asarray(v) for k, v in J.items()}, {k: np.asarray(v) for k, v in r.items()}, position


@functools.lru_cache(maxsize=None)
def _dense_step(variant):
    """Dense float64 reference for `test_structured_step_equals_dense_step` (once per variant):
    the step (JᵀJ + 0.3 I)⁻¹ Jᵀr from J of the residuals at x ⊕ δ over the flat tangent, and ½‖r‖²."""
    problems, _ = _variants(9)
    problem, params = problems[variant]
    layout = problem.layout(params)
    J_all, r_all, position = _dense_jacobian(_DENSE_SOURCE[variant])
    # The variant's columns in its own flat order (F, W, G), and its terms' rows.
    cols = np.concatenate([p.reshape(-1) for p in layout.ravel({k: position[k] for k in layout.keys}) if p is not None])
    names = [t.name for t in problem.terms]
    J = np.concatenate([J_all[k][:, cols] for k in names])
    r = np.concatenate([r_all[k] for k in names])
    return np.linalg.solve(J.T @ J + 0.3 * np.eye(J.shape[1]), J.T @ r), 0.5 * r @ r


def _block_tridiagonal_dense(D, U):
    """The dense symmetric matrix of diagonal blocks D (K, N, N) and super-diagonal U."""
    K, N = D.shape[:2]
    A = np.zeros((K * N, K * N))
    for k in range(K):
        A[k * N : (k + 1) * N, k * N : (k + 1) * N] = D[k]
        if k + 1 < K:
            A[k * N : (k + 1) * N, (k + 1) * N : (k + 2) * N] = U[k]
            A[(k + 1) * N : (k + 2) * N, k * N : (k + 1) * N] = U[k].T
    return A


@pytest.mark.parametrize("K, N", [(1, 3), (2, 3), (3, 3), (6, 3), (13, 3), (65, 40)])
def test_block_tridiagonal_solves_match_dense(K, N):
    """Scan and cyclic reduction against numpy on a random SPD block-tridiagonal matrix
    (K blocks: odd, even and single-block reduction levels; 65 blocks of 40 take both
    factorisations' recursive inverse Cholesky, cyclic reduction's on its first level)."""
    from jaxmocap.solve.tridiagonal import (
        CYCLIC_BASE, CYCLIC_RECURSIVE_BLOCKS, SCAN_BASE, tridiagonal_factor, tridiagonal_solve,
    )  # fmt: skip

    recursive = K // 2 >= CYCLIC_RECURSIVE_BLOCKS and N > max(SCAN_BASE, CYCLIC_BASE)
    assert recursive == (N == 40)
    rng = np.random.default_rng(K)
    D = rng.normal(size=(K, N, N))
    D = D @ np.swapaxes(D, 1, 2) + 2 * N * np.eye(N)
    U = rng.normal(size=(K, N, N))
    A = _block_tridiagonal_dense(D, U)
    b = rng.normal(size=(K, N, 2))
    ref = np.linalg.solve(A, b.reshape(K * N, 2)).reshape(K, N, 2)
    for method in ("scan", "cyclic"):
        # jitted: one program instead of one per eager operation and shape
        x = jax.jit(lambda D, U, b: tridiagonal_solve(tridiagonal_factor(D, U, method), b))(D, U, b)  # noqa: B023
        np.testing.assert_allclose(np.asarray(x), ref, atol=1e-11 * np.abs(ref).max(), err_msg=method)
    with pytest.raises(ValueError, match="tridiagonal"):
        tridiagonal_factor(jnp.asarray(D), jnp.asarray(U), "lu")


@pytest.mark.parametrize(
    "T, n, R, B", [(1, 3, 2, 1), (3, 6, 4, 2), (9, 5, 3, 1), (11, 4, 2, 2), (7, 5, 7, 1), (40, 4, 2, 2)]
)
def test_rows_factorisation_matches_dense(T, n, R, B):
    """`rows.py` (frame order, cyclic reduction) against numpy on
    H = blockdiag(A) + CᵀC with coupling rows reading frames t-B .. t+B: bandwidths 1 and 2,
    one frame, fewer frames than the band, R > n, T not a multiple of the super-blocks,
    five levels (T = 40)."""
    from jaxmocap.solve.rows import rows_cyclic_factor, rows_cyclic_solve, rows_factor, rows_solve

    rng = np.random.default_rng(T * 100 + n)
    C = rng.normal(size=(T, 2 * B + 1, R, n))
    A = rng.normal(size=(T, n, n))
    A = A @ np.swapaxes(A, 1, 2) + 0.1 * np.eye(n)
    dense_C = np.zeros((T * R, T * n))
    for t in range(T):
        for j in range(2 * B + 1):
            s = t + j - B
            if 0 <= s < T:
                dense_C[t * R : (t + 1) * R, s * n : (s + 1) * n] = C[t, j]
            else:
                C[t, j] = 0.0  # rows reading past the ends are dropped by the engine
    H = dense_C.T @ dense_C
    for s in range(T):
        H[s * n : (s + 1) * n, s * n : (s + 1) * n] += A[s]
    P0 = np.stack([H[s * n : (s + 1) * n, s * n : (s + 1) * n] for s in range(T)])
    b = rng.normal(size=(T, n, 2))
    ref = np.linalg.solve(H, b.reshape(T * n, 2)).reshape(T, n, 2)
    methods = [(rows_factor, rows_solve), (rows_cyclic_factor, rows_cyclic_solve)]
    for fac, sol in methods:
        x = jax.jit(lambda P0, C, b: sol(fac(P0, C), b))(P0, C, b)  # noqa: B023  (one program)
        np.testing.assert_allclose(np.asarray(x), ref, atol=1e-10 * np.abs(ref).max(), err_msg=fac.__name__)


@pytest.mark.parametrize("W", ["shared", "per_frame", "identity"])
def test_block_jacobian_normal_equations_match_dense(W):
    """A term's `BlockJacobian` kept factored (JᵀJ = s² Dᵀ WᵀW D, Jᵀr = s Dᵀ Wᵀ r) gives the
    normal equations, gradient and cost of its dense form: one W for all frames, a W per
    frame, W = I; a permuted solver order (a coupled term reads items 1 and 3), a padded
    frame, and a masked term that must use the dense form."""
    from jaxmocap.solve import BlockJacobian
    from jaxmocap.solve.linearisation import linearise

    T, J, k, index = 6, 3, 3, (0, 2, 3)
    rng = np.random.default_rng(len(W))
    A = jnp.asarray(rng.normal(size=(J, k, k)))
    m = 5 if W != "identity" else J * k
    Wm = {"shared": rng.normal(size=(m, J * k)), "per_frame": rng.normal(size=(T, m, J * k)), "identity": None}[W]
    Wm = None if Wm is None else jnp.asarray(Wm)

    def x_of(p):  # k-vectors x_j = tanh(A_j a_index[j]), each reading one item
        return jnp.tanh(jnp.einsum("jab,tjb->tja", A, p["a"][:, np.asarray(index)]))

    def fn(p, d):
        x = x_of(p).reshape(T, -1)
        return (x if Wm is None else jnp.einsum("...mp,tp->tm", Wm, x)) - d["y"]

    def jac(p, d):
        D = (1 - x_of(p) ** 2)[..., None] * A
        return {"a": BlockJacobian(D, Wm, index)}

    def dense_jac(p, d):
        return {"a": jac(p, d)["a"].dense((m,), (5, 3))}

    data = {"y": jnp.asarray(rng.normal(size=(T, m)))}
    params = {"a": jnp.asarray(rng.normal(size=(T, 5, 3))), "b": jnp.asarray(rng.normal(size=(T, 1)))}
    mask = jnp.asarray([True] * (T - 1) + [False])
    acc = Term(
        "acc",
        lambda p, d: p["a"][:, 1] - jnp.roll(p["a"][:, 3], 1, 0) + p["b"],
        0.7,
        1,
        reads=(("a", (1, 3)), ("b", None)),
    )
    out = {}
    for name, j, masked in (("factored", jac, False), ("dense", dense_jac, False), ("masked", jac, True)):
        prior = Term(
            "prior", fn, 0.3, 0, None, (lambda d: jnp.ones((T,), bool)) if masked else None, (("a", index),), j
        )
        problem = Problem([acc, prior])
        layout = problem.layout(params)
        args = Args(problem, data, mask, layout)
        st = args.structure()
        assert st.perm is not None
        out[name] = jax.jit(lambda p, args=args, st=st: linearise(p, args, st, jnp.float64, jnp.float64))(params)
    (nf, gf, cf), (nd, gd, cd), (nm, gm, cm) = out["factored"], out["dense"], out["masked"]
    for a, b in ((nf, nd), (nm, nd)):
        for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)):
            np.testing.assert_allclose(np.asarray(x), np.asarray(y), atol=1e-12)
    np.testing.assert_allclose(np.asarray(gf[0]), np.asarray(gd[0]), atol=1e-12)
    np.testing.assert_allclose(np.asarray(gm[0]), np.asarray(gd[0]), atol=1e-12)
    assert abs(float(cf - cd)) < 1e-12 and abs(float(cm - cd)) < 1e-12
    assert float(jnp.abs(nd.FF[0][:-1]).max()) > 0.1  # not vacuous


@pytest.mark.parametrize("n", [1, 16, 17, 40, 102])
def test_inverse_cholesky_matches_numpy(n):
    """The recursive inverse Cholesky factor equals numpy's inv(cholesky(S)), batched, on
    either side of the recursion's base (16) and at SIP's block size (102)."""
    from jaxmocap.solve.tridiagonal import inverse_cholesky

    rng = np.random.default_rng(n)
    A = rng.normal(size=(3, n, n))
    S = A @ np.swapaxes(A, 1, 2) + n * np.eye(n)
    ref = np.linalg.inv(np.linalg.cholesky(S))
    for base in (4, 16, 32):
        L_inv = np.asarray(jax.jit(inverse_cholesky, static_argnums=1)(S, base))
        np.testing.assert_allclose(L_inv, ref, atol=1e-12 * np.abs(ref).max(), err_msg=f"base {base}")
        assert np.all(np.triu(L_inv, 1) == 0.0)


def test_solves_use_full_float32_products():
    """Every matrix product of a solve and of its adjoint is traced at HIGHEST precision:
    GPUs' default TF32 products left SIP at 2.5x the cost (structure.full_precision)."""
    import re

    problems, data = _variants(9)  # the structured-step tests' problem (its inputs already computed)
    problem, params = problems["border"]

    def value(p):
        return solve(problem, p, data, max_steps=1).value

    for jaxpr in (jax.make_jaxpr(value)(params),
                  jax.make_jaxpr(jax.grad(lambda p: sum(v.sum() for v in value(p).values())))(params)):  # fmt: skip
        text = str(jaxpr)
        assert text.count("dot_general") > 10
        assert set(re.findall(r"precision=(\([^)]*\)|None)", text)) == {"(Precision.HIGHEST, Precision.HIGHEST)"}


def test_optimistix_solvers_use_the_structure():
    """optx.LevenbergMarquardt / GaussNewton with `StructuredCholesky` (border and windows)."""
    problems, data = _variants(8, seed=2)
    problem, params = problems["all"]
    ref = solve(problem, params, data, max_steps=60, solver=VonMarcardLM(rtol=1e-12, atol=1e-14))
    assert int(ref.result) == 0
    for method in ("optx_lm", "optx_gn"):
        sol = solve(problem, params, data, max_steps=100, solver=SOLVERS[method](rtol=1e-12, atol=1e-14))
        # Gauss-Newton converges only linearly on this non-zero-residual problem.
        assert int(sol.result) == 0 or method == "optx_gn", method
        np.testing.assert_allclose(float(sol.cost), float(ref.cost), rtol=1e-6)
        for k in ("heading", "offset", "coef"):
            np.testing.assert_allclose(sol.value[k], ref.value[k], atol=1e-5)


def test_sequence_unknowns_recovered():
    """Per-sensor headings (angle manifold) and a per-sequence offset are recovered exactly."""
    truth, init, data = motion(8, seed=4)  # the length of the other chain tests (their eager programs)
    gamma, offset = jnp.asarray([0.3, -0.5, 1.2]), jnp.asarray([0.1, -0.2, 0.05])
    # Measurements see the sensors rotated by γ about y and translations shifted.
    c, s_ = jnp.cos(gamma), jnp.sin(gamma)
    z, o = jnp.zeros(3), jnp.ones(3)
    Ry = jnp.stack([jnp.stack([c, z, s_], -1), jnp.stack([z, o, z], -1), jnp.stack([-s_, z, c], -1)], -2)
    data = dict(data, R=Ry @ data["R"], trans=data["trans"] + offset, trans0=data["trans"])
    problem = Problem(
        [Term("heading", e_heading, reads=(("rot", None), ("trans", None), ("heading", None))),
         Term("acc", e_acc, weight=0.05, bandwidth=1),
         Term("pin", lambda x, d: (x["trans"] - d["trans0"])[..., None], weight=1e-2),  # a second, unbiased sensor
         Term("offset", e_offset, weight=1e-2, reads=(("trans", None), ("offset", None)))],
        {"rot": frame("so3"), "heading": sequence("angle"), "offset": sequence()},
    )  # fmt: skip
    params = dict(init, heading=jnp.zeros(3), offset=jnp.zeros(3))
    sol = solve(problem, params, data, max_steps=80, solver=VonMarcardLM(rtol=1e-12, atol=1e-14))
    assert int(sol.result) == 0 and float(sol.cost) < 1e-14
    np.testing.assert_allclose(sol.value["heading"], gamma, atol=1e-6)
    np.testing.assert_allclose(sol.value["offset"], offset, atol=1e-6)
    assert rot_error(sol.value["rot"], truth["rot"]) < 1e-6


def test_se3_unknowns_converge():
    """Rigid poses (SE(3), left-perturbed) per frame fitted to observed points."""
    rng = np.random.default_rng(0)
    pts = jnp.asarray(rng.normal(size=(5, 3)))
    true = jnp.asarray(np.concatenate([rng.normal(0, 0.8, (4, 3)), rng.normal(0, 1.0, (4, 3))], 1))
    from jaxmocap.solve.unknowns import Layout

    lay = Layout.of({"T": true}, {"T": frame("se3")})
    M = to_manifold({"T": true}, lay)["T"]
    obs = jnp.einsum("tab,pb->tpa", M[:, :3, :3], pts) + M[:, None, :3, 3]
    problem = Problem(
        [
            Term(
                "pts",
                lambda x, d: jnp.einsum("tab,pb->tpa", x["T"][:, :3, :3], d["p"]) + x["T"][:, None, :3, 3] - d["obs"],
            )
        ],
        {"T": frame("se3")},
    )
    sol = solve(
        problem, {"T": true + 0.3}, {"p": pts, "obs": obs}, max_steps=50, solver=VonMarcardLM(rtol=1e-12, atol=1e-14)
    )
    assert int(sol.result) == 0 and float(sol.cost) < 1e-20
    M2 = to_manifold(sol.value, lay)["T"]
    np.testing.assert_allclose(M2, M, atol=1e-8)


# --- weights are data ------------------------------------------------------------------------

TRACES = {"n": 0}


def e_counted(x, data):  # counts how often JAX traces the problem (Python runs only then)
    TRACES["n"] += 1
    return e_ori(x, data)


def test_new_weights_and_new_data_do_not_recompile():
    from jaxmocap.solve.batch import with_weights

    problem = Problem([Term("ori", e_counted), *CHAIN.terms[1:]], rotations=("rot",))
    costs = []
    for k in range(10):
        _, init, data = motion(6, seed=10 + k)  # new observations each time
        w = with_weights(problem, {"acc": jnp.asarray(0.01 * (k + 1)), "trans": jnp.asarray(1e-2)})
        costs.append(float(solve(w, init, data, max_steps=5).cost))
        if k == 0:
            after_first = TRACES["n"]
    assert TRACES["n"] == after_first > 0
    assert len(set(costs)) == 10


def test_per_member_weights_in_solve_batch():
    """An ablation grid is a batch axis: member b solves with weights[b], one compilation."""
    _, init, data = motion(6, seed=7)
    B = 3
    ws = jnp.asarray([0.0, 0.05, 5.0])
    batch = jax.tree_util.tree_map(lambda x: jnp.broadcast_to(x, (B,) + x.shape), (init, data))
    sol = solve_batch(CHAIN, *batch, weights={"acc": ws}, max_steps=40, solver=VonMarcardLM(rtol=1e-10, atol=1e-12))
    from jaxmocap.solve.batch import with_weights

    for b in range(B):
        one = solve(
            with_weights(CHAIN, {"acc": ws[b]}), init, data, max_steps=40, solver=VonMarcardLM(rtol=1e-10, atol=1e-12)
        )
        np.testing.assert_allclose(sol.value["rot"][b], one.value["rot"], atol=1e-10)
        np.testing.assert_allclose(sol.costs["acc"][b], one.costs["acc"], rtol=1e-8, atol=1e-14)
    assert float(sol.costs["acc"][0]) == 0.0 < float(sol.costs["acc"][2])
    with pytest.raises(ValueError, match="lacks"):
        solve_batch(CHAIN, *batch, weights={"nope": ws})


# --- LM acceptance --------------------------------------------------------------------


def test_optx_lm_never_accepts_a_cost_increase():
    truth, init, data = motion(6, seed=2)
    init = {"rot": init["rot"] * 4.0, "trans": init["trans"]}  # far start: rejections happen
    losses = []

    def record(**kw):
        jax.debug.callback(lambda v: losses.append(float(v)), kw["loss_last_accepted_step"][1])

    args = Args(CHAIN, data, None, CHAIN.layout(init))
    solver = optx.LevenbergMarquardt(rtol=1e-10, atol=1e-12, verbose=record, linear_solver=linear_solver(args))
    optx.least_squares(residuals, solver, init, args, max_steps=40, throw=False)
    losses = losses[1:]  # the first entry is optimistix's placeholder before any evaluation
    assert len(losses) > 5 and losses[-1] < 1e-2 * losses[0]
    assert all(b <= a for a, b in zip(losses, losses[1:])), losses


def test_lm_never_accepts_a_cost_increase():
    truth, init, data = motion(6, seed=2)
    init = {"rot": init["rot"] * 4.0, "trans": init["trans"]}
    costs = [float(jax.jit(CHAIN.cost)(init, data))]  # one program, not one per eager operation
    for steps in range(1, 9):  # max_steps is a traced loop bound for "lm": one compilation
        sol = solve(CHAIN, init, data, max_steps=steps, solver=VonMarcardLM(rtol=0.0, atol=0.0))
        costs.append(float(sol.cost))
    # A rejected step leaves the cost unchanged, but costs[0] comes from `Problem.cost`
    # and the rest from the solver's own evaluation: allow their last-bit difference.
    assert all(b <= a * (1 + 1e-12) for a, b in zip(costs, costs[1:])), costs
    assert costs[-1] < 1e-2 * costs[0]


# --- padding, batches, dtypes ---------------------------------------------------------


@pytest.mark.parametrize("method", ["lm", "optx_lm"])
def test_padded_frames_do_not_change_the_result(method):
    # The reference is `test_known_minimiser_recovered`'s solve (same shapes and settings:
    # its compiled program); the padded one adds 3 junk frames.
    truth, init, data = motion(8)
    ref = solve(CHAIN, init, data, max_steps=60, solver=SOLVERS[method](rtol=1e-10, atol=1e-12))
    rng = np.random.default_rng(5)
    junk = lambda x: jnp.concatenate([x, jnp.asarray(rng.normal(size=(3,) + x.shape[1:]))])  # noqa: E731
    init_p = jax.tree_util.tree_map(junk, init)
    data_p = jax.tree_util.tree_map(junk, data)
    mask = jnp.arange(11) < 8
    sol = solve(CHAIN, init_p, data_p, frame_mask=mask, max_steps=60, solver=SOLVERS[method](rtol=1e-10, atol=1e-12))
    for k in ref.value:
        np.testing.assert_allclose(sol.value[k][:8], ref.value[k], atol=1e-8)
        np.testing.assert_allclose(sol.value[k][8:], init_p[k][8:], atol=1e-12)  # padded: untouched
    assert abs(float(sol.cost) - float(ref.cost)) < 1e-10


# r_t = exp(x_t) - target_t: a minimiser iff target > 0; for target < 0 the infimum is at
# x → -∞ (no minimiser); a NaN target without a mask poisons the cost.
EXP = Problem([Term("exp", lambda p, d: (jnp.exp(p["x"]) - d["target"])[..., None])])


def _exp_problem():
    return EXP


@pytest.mark.parametrize("method", ["lm", "optx_lm"])
def test_batch_reports_converging_and_diverging_problems(method):
    problem = _exp_problem()
    seqs = [{"x": jnp.zeros((4, 1))}, {"x": jnp.zeros((3, 1))}, {"x": jnp.zeros((4, 1))}]
    datas = [{"target": jnp.full((T, 1), v)} for T, v in ((4, 2.0), (3, -1.0), (4, np.nan))]
    params, mask = pad_sequences(seqs)
    data, _ = pad_sequences(datas)
    sol = solve_batch(problem, params, data, mask, max_steps=15, solver=SOLVERS[method](rtol=1e-8, atol=1e-10))
    assert sol.result.shape == (3,) and sol.num_steps.shape == (3,) and sol.cost.shape == (3,)
    ok, no_minimum, nan = (int(r) for r in sol.result)
    assert ok == SUCCESSFUL
    assert no_minimum == MAX_STEPS
    assert nan == DIVERGENCE  # non-finite cost
    assert result_message(no_minimum).startswith("The maximum number of steps")
    np.testing.assert_allclose(sol.value["x"][0], np.log(2.0), atol=1e-6)
    assert int(sol.num_steps[0]) < int(sol.num_steps[1]) == 15
    assert np.isfinite(np.asarray(sol.value["x"][:2])).all()


def test_batch_of_one_equals_unbatched():
    truth, init, data = motion(6)
    one = solve(CHAIN, init, data, max_steps=40)
    init1, data1 = jax.tree_util.tree_map(lambda x: x[None], (init, data))
    batch = solve_batch(CHAIN, init1, data1, max_steps=40)
    for k in one.value:
        np.testing.assert_allclose(batch.value[k][0], one.value[k], rtol=1e-12, atol=1e-12)
    assert int(batch.num_steps[0]) == int(one.num_steps) and int(batch.result[0]) == int(one.result)


def test_long_solves_report_progress(capfd):
    # One stderr line per LM step (step, cost, s/step, ETA); the same answer as without.
    params = {"x": jnp.zeros((3, 1))}
    data = {"target": jnp.full((3, 1), 2.0)}
    quiet = solve(_exp_problem(), params, data, max_steps=8, solver=VonMarcardLM(rtol=0.0, atol=0.0))
    assert capfd.readouterr().err == ""  # 3 frames: below PROGRESS_FRAMES, silent
    loud = solve(_exp_problem(), params, data, max_steps=8, solver=VonMarcardLM(rtol=0.0, atol=0.0), progress=True)
    err = capfd.readouterr().err
    assert "LM step 1/8: cost" in err and "LM step 8/8" in err and "ETA" in err and err.endswith("\n")
    np.testing.assert_array_equal(np.asarray(loud.value["x"]), np.asarray(quiet.value["x"]))


def test_per_sequence_tolerances():
    params = {"x": jnp.zeros((2, 3, 1))}
    data = {"target": jnp.full((2, 3, 1), 2.0)}
    sol = solve_batch(_exp_problem(), params, data, max_steps=40,
                      solver=VonMarcardLM(rtol=jnp.array([1e-1, 1e-12]), atol=jnp.array([1e-1, 1e-14])))  # fmt: skip
    assert int(sol.num_steps[0]) < int(sol.num_steps[1])
    assert (np.asarray(sol.result) == 0).all()


def test_float32_default_and_float64_on_request():
    # float32 inputs cast from the float64 motion (the other tests' eager programs, not a float32 set)
    truth, init, data = jax.tree_util.tree_map(lambda x: x.astype(jnp.float32), motion(6))
    data32 = data
    sol = solve(CHAIN, init, data32, max_steps=40)
    assert sol.value["rot"].dtype == jnp.float32 and bool(jnp.isfinite(sol.cost))
    assert rot_error(sol.value["rot"], truth["rot"]) < 1e-3
    x32 = {"x": jnp.zeros((3, 1), jnp.float32)}
    sol64 = solve(_exp_problem(), x32, {"target": jnp.full((3, 1), 2.0)}, dtype=jnp.float64)
    assert sol64.value["x"].dtype == jnp.float64 and sol64.cost.dtype == jnp.float64


# --- robust losses and masks ----------------------------------------------------------


@pytest.mark.parametrize("loss", [GemanMcClure(0.5), Huber(0.3), Cauchy(0.4)])
def test_robust_minimiser_matches_robust_cost(loss):
    rng = np.random.default_rng(0)
    points = np.concatenate([rng.normal(scale=0.1, size=(20, 2)), rng.normal(loc=3.0, size=(5, 2))])
    problem = Problem([Term("fit", lambda p, d: p["x"][:, None, :] - d["pts"], loss=loss)])
    data = {"pts": jnp.asarray(points)[None]}
    x0 = {"x": jnp.asarray([[0.3, -0.2]])}
    sol = solve(problem, x0, data, max_steps=100, solver=VonMarcardLM(rtol=1e-12, atol=1e-14))

    def robust_cost(x):
        return 0.5 * np.sum(np.asarray(loss.rho(jnp.asarray(np.sum((x - points) ** 2, 1)))))

    ref = scipy.optimize.minimize(robust_cost, np.array([0.3, -0.2]), method="Nelder-Mead",
                                  options={"xatol": 1e-10, "fatol": 1e-14, "maxiter": 4000})  # fmt: skip
    np.testing.assert_allclose(np.asarray(sol.value["x"][0]), ref.x, atol=1e-6)
    np.testing.assert_allclose(float(sol.cost), robust_cost(ref.x), rtol=1e-8)
    # Robust: far from the least-squares mean, which the outliers drag towards (3, 3).
    assert np.linalg.norm(np.asarray(sol.value["x"][0])) < 0.1 < np.linalg.norm(points.mean(0))


@pytest.mark.parametrize("loss", [GemanMcClure(0.5), Huber(0.3), Cauchy(0.4)])
def test_robust_residual_gradients_finite_at_zero(loss):
    e = jnp.zeros(3)
    assert np.isfinite(np.asarray(jax.jacfwd(loss)(e))).all()
    np.testing.assert_allclose(jax.jacfwd(loss)(e + 0.2), jax.jacrev(loss)(e + 0.2), atol=1e-12)
    np.testing.assert_allclose(jax.jacfwd(loss)(e), np.eye(3), atol=1e-12)


def test_masks_drop_nan_observations():
    truth, init, data = motion(8)
    holey = dict(data)
    holey["R"] = data["R"].at[2, 1].set(jnp.nan).at[5].set(jnp.nan)
    holey["acc"] = data["acc"].at[3, 0].set(jnp.nan)
    costs = jax.jit(CHAIN.costs)(init, holey)
    assert all(np.isfinite(float(c)) for c in costs.values())
    grads = jax.jit(jax.grad(lambda p: CHAIN.cost(p, holey)))(init)
    assert all(np.isfinite(np.asarray(g)).all() for g in grads.values())
    # Dropping = excluding exactly those rows: same costs as explicit boolean masks.
    explicit = Problem(
        [
            Term("ori", e_ori, mask=lambda d: jnp.ones((8, 3), bool).at[2, 1].set(False).at[5].set(False)),
            Term("acc", e_acc, weight=0.05, bandwidth=1, mask=lambda d: jnp.ones((8, 3), bool).at[3, 0].set(False)),
            CHAIN.terms[2],
        ],
        rotations=("rot",),
    )
    for k, c in jax.jit(explicit.costs)(init, data).items():
        np.testing.assert_allclose(float(costs[k]), float(c), rtol=1e-12)
    sol = solve(CHAIN, init, holey, max_steps=60, solver=VonMarcardLM(rtol=1e-10, atol=1e-12))
    assert int(sol.result) == 0 and float(sol.cost) < 1e-12
    assert np.isfinite(np.asarray(sol.value["rot"])).all()
    # Frame 5 lost all orientations (only accelerations and the chain see it); the others
    # are recovered exactly.
    keep = np.arange(8) != 5
    assert rot_error(sol.value["rot"][keep], truth["rot"][keep]) < 1e-6


# --- errors ---------------------------------------------------------------------------


def test_clear_errors():
    truth, init, data = motion(6)
    with pytest.raises(ValueError, match="leading frame axis"):
        solve(CHAIN, {"rot": init["rot"], "trans": init["trans"][:4]}, data)
    with pytest.raises(ValueError, match="solver must be a solver object"):
        solve(CHAIN, init, data, solver="bfgs")
    with pytest.raises(ValueError, match="unique"):
        Problem([Term("a", e_ori), Term("a", e_acc)])
    bad = Problem([Term("flat", lambda p, d: jnp.zeros((3,)))])
    with pytest.raises(ValueError, match="one row per frame"):
        bad.cost({"x": jnp.zeros((4, 1))}, None)


def test_unknown_kinds_reject_misuse():
    _, init, data = motion(6)
    seq = dict(init, heading=jnp.zeros(3))
    # A term reading a per-sequence unknown it does not declare.
    sneaky = Problem([Term("h", e_heading), Term("keep", e_offset, reads=(("trans", None), ("heading", None)))],
                     {"rot": frame("so3"), "heading": sequence("angle")})  # fmt: skip
    with pytest.raises(ValueError, match="add \\('heading', None\\) to the term's reads"):
        sneaky.cost(seq, data)
    # A per-sequence unknown no term reads: a singular border.
    with pytest.raises(ValueError, match="singular border"):
        Problem(list(CHAIN.terms), {"rot": frame("so3"), "heading": sequence("angle")})
    # Windows that do not cover the sequence.
    wp = Problem([*CHAIN.terms, Term("w", e_window, reads=(("trans", None), ("coef", None)))],
                 {"rot": frame("so3"), "coef": WIN})  # fmt: skip
    with pytest.raises(ValueError, match="use 2 windows for T = 6"):
        solve(wp, dict(init, coef=jnp.zeros((4, 2, 3))), data)
    # A window term that couples frames.
    with pytest.raises(ValueError, match="bandwidth 0"):
        Problem([Term("w", e_window, bandwidth=1, reads=(("coef", None),))], {"coef": WIN})
    with pytest.raises(ValueError, match="stride"):
        window(4, 5)
    with pytest.raises(ValueError, match="so3 unknown 'rot'"):
        solve(Problem([Term("o", e_ori)], {"rot": frame("so3")}), {"rot": jnp.zeros((6, 3, 4))}, data)


def test_reads_name_columns_and_are_validated():
    layout = Problem([Term("a", e_ori)]).layout({"pose": jnp.zeros((2, 24, 3)), "trans": jnp.zeros((2, 3))})
    assert layout.columns((("pose", (0, 2)), ("trans", None))) == (0, 1, 2, 6, 7, 8, 72, 73, 74)
    assert layout.columns(None) == tuple(range(75))
    assert layout.columns((("missing", None),)) == ()
    with pytest.raises(ValueError, match="out of range"):
        layout.columns((("pose", (24,)),))
    with pytest.raises(ValueError, match="pairs"):
        Term("a", e_ori, reads=("pose",))


# --- basis terms (jaxmocap.solve.basis): the Kronecker elimination against the generic one --


def _poly_basis(n: int) -> np.ndarray:
    """Orthonormal polynomials 1, t, t² over n frames (fewer for a short window)."""
    t = np.linspace(-1.0, 1.0, n) if n > 1 else np.zeros(1)
    q, _ = np.linalg.qr(np.stack([t**0, t, t**2], 1)[:, : min(3, n)])
    return q * np.sign(np.diag(q))[None]  # fixed signs: one basis per length


def _chain_features(x, data):
    _, p = sensors(x)
    return p.reshape(p.shape[0], -1)  # sensor positions (T, 9)


_BASIS_TERM = basis_term("smooth", WindowBasis("coef", _chain_features, _poly_basis, 5), (("rot", None), ("trans", None)),
                         weight=30.0, loss=GemanMcClure(0.2))  # fmt: skip
_PER_FRAME = [t for t in CHAIN.terms if t.bandwidth == 0]  # orientations and the translation pin
_BASIS = Problem([*_PER_FRAME, _BASIS_TERM], {"rot": frame("so3"), "coef": window(5)})
# The same energy as an ordinary window term: the generic elimination of factorise.py.
_GENERIC = Problem([*_PER_FRAME, Term("smooth", _BASIS_TERM.fn, 30.0, loss=GemanMcClure(0.2), reads=_BASIS_TERM.reads)],
                   {"rot": frame("so3"), "coef": window(5)})  # fmt: skip


def _basis_start(T=12):
    """The chain's perturbed start, coefficients fitted to its sensor paths and disturbed."""
    truth, init, data = motion(T)
    f = np.asarray(jax.jit(lambda p: _chain_features(to_manifold(p, CHAIN.layout(p)), data))(init))  # one program
    coef = np.random.default_rng(3).normal(scale=0.02, size=(-(-T // 5), 3, 9))
    for w, start in enumerate(range(0, T, 5)):
        B = _poly_basis(len(f[start : start + 5]))
        coef[w, : B.shape[1]] += np.linalg.lstsq(B, f[start : start + 5], rcond=None)[0]
    return truth, dict(init, coef=jnp.asarray(coef.reshape(-1, 3, 3, 3))), data


def test_basis_term_steps_equal_the_generic_window_elimination():
    """12 frames in windows of 5: the last window has 2 frames and a 2-vector basis."""
    _, p0, data = _basis_start()
    window_of, rows = _BASIS_TERM.basis.table(12)
    np.testing.assert_array_equal(window_of, np.arange(12) // 5)
    np.testing.assert_allclose(rows[10:, :2], _poly_basis(2)) and np.testing.assert_array_equal(rows[10:, 2], 0.0)
    fast = solve(_BASIS, p0, data, max_steps=3, solver=VonMarcardLM(rtol=0.0, atol=0.0))
    slow = solve(_GENERIC, p0, data, max_steps=3, solver=VonMarcardLM(rtol=0.0, atol=0.0))
    assert float(fast.cost) < 0.5 * float(jax.jit(_BASIS.cost)(p0, data))
    for k in p0:
        np.testing.assert_allclose(fast.value[k], slow.value[k], atol=1e-9, err_msg=k)
    # The coefficient the 2-frame window lacks is read by no row: pinned, not singular.
    np.testing.assert_array_equal(fast.value["coef"][2, 2], p0["coef"][2, 2])


def test_basis_term_converges_to_the_least_squares_minimiser():
    _, p0, data = _basis_start()
    sol = solve(_BASIS, p0, data, max_steps=200, solver=VonMarcardLM(rtol=1e-9, atol=1e-12))
    assert int(sol.result) == SUCCESSFUL and int(sol.num_steps) < 200, result_message(sol.result)
    # Independent reference: SciPy on the same (robust, square-root) residual vector, in the
    # stored parameters; the pinned coefficient (column 2 of the last window) is left out.
    keys, shapes = sorted(p0), {k: p0[k].shape for k in p0}
    pinned = np.zeros(shapes["coef"], bool)
    pinned[2, 2] = True

    def unflat(v):
        out, i = {}, 0
        for k in keys:
            n = int(np.prod(shapes[k])) - (int(pinned.sum()) if k == "coef" else 0)
            if k == "coef":
                c = np.asarray(p0["coef"]).copy()
                c[~pinned] = v[i : i + n]
                out[k] = jnp.asarray(c)
            else:
                out[k] = jnp.asarray(v[i : i + n].reshape(shapes[k]))
            i += n
        return out

    fun = jax.jit(lambda p: jnp.concatenate([r.ravel() for r in _BASIS.residuals(p, data).values()]))
    v0 = np.concatenate(
        [np.asarray(sol.value[k])[~pinned] if k == "coef" else np.asarray(sol.value[k]).ravel() for k in keys]
    )
    ref = scipy.optimize.least_squares(lambda v: np.asarray(fun(unflat(v))), v0, xtol=1e-14, ftol=1e-14, gtol=1e-14)
    np.testing.assert_allclose(float(sol.cost), 0.5 * float(np.sum(ref.fun**2)), rtol=1e-6)
    np.testing.assert_allclose(np.asarray(sol.value["trans"]), np.asarray(unflat(ref.x)["trans"]), atol=1e-5)


def test_basis_terms_refuse_coupled_problems():
    _, p0, data = _basis_start()
    coupled = Problem([*CHAIN.terms, _BASIS_TERM], {"rot": frame("so3"), "coef": window(5)})  # E_acc couples frames
    with pytest.raises(ValueError, match="per-frame terms"):
        solve(coupled, p0, data, max_steps=1)
    with pytest.raises(ValueError, match="reads=\\(\\('pose', None\\),\\)"):
        basis_term("b", _BASIS_TERM.basis, None)
