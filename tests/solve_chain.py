"""The engine tests' stand-in body: a three-bone chain with a rigidly attached sensor per
bone, with the structure of SIP (von Marcard §3.3: per-frame orientation residuals,
t-1/t/t+1 acceleration residuals, a prior) at a size that keeps the tests fast, and its
variants with per-sequence and per-window unknowns (tests/test_solve.py and
tests/test_solve_gradients.py).
"""

import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap.body import forward_kinematics
from jaxmocap.rotation import axis_angle_to_matrix, matrix_to_axis_angle
from jaxmocap.solve import Problem, Term, nan_mask
from jaxmocap.solve import frame, sequence, window
from jaxmocap.timeseries import second_difference
from jaxmocap.solve.unknowns import to_manifold

PARENTS = (-1, 0, 1)
REST = jnp.array([[0.0, 0.0, 0.0], [0.0, 0.4, 0.0], [0.3, 0.6, 0.1]])
OFFSETS = jnp.array([[0.05, 0.0, 0.02], [0.0, 0.1, 0.03], [0.02, 0.05, 0.0]])
DT = 1.0 / 30.0


def sensors(x):
    """Sensor orientations (T, 3, 3, 3) and positions (T, 3, 3) of the chain; x on SO(3)."""
    T = x["rot"].shape[0]
    R, p = forward_kinematics(PARENTS, x["rot"], jnp.broadcast_to(REST, (T, 3, 3)))
    return R, p + jnp.einsum("tjab,jb->tja", R, OFFSETS) + x["trans"][:, None]


def e_ori(x, data):  # von Marcard eq. 3.7
    R, _ = sensors(x)
    return matrix_to_axis_angle(R @ jnp.swapaxes(data["R"], -1, -2))


def e_acc(x, data):  # eq. 3.10-3.12
    _, p = sensors(x)
    return second_difference(p) / DT**2 - data["acc"]


def e_prior(x, data):
    return 0.1 * matrix_to_axis_angle(x["rot"]).reshape(x["rot"].shape[0], -1, 1)


def e_smooth2(x, data):  # bandwidth 2: couples t-2 .. t+2 (tests a wider band)
    w = matrix_to_axis_angle(x["rot"])
    pad = jnp.concatenate([w[:2], w, w[-2:]])
    return (pad[:-4] - pad[4:]).reshape(w.shape[0], -1, 3)


def e_smooth2_root(x, data):  # bandwidth 2 on two angles of the root: few rows per frame
    return e_smooth2(x, data)[:, :1, :2]


CHAIN = Problem(
    [
        Term("ori", e_ori, weight=1.0, mask=lambda d: nan_mask(d["R"], (-2, -1))),
        Term("acc", e_acc, weight=0.05, bandwidth=1, mask=lambda d: nan_mask(d["acc"])),
        # Accelerations leave translation free up to a constant velocity; pin it weakly.
        Term("trans", lambda x, d: (x["trans"] - d["trans"])[..., None], weight=1e-2),
    ],
    rotations=("rot",),
)


@jax.jit  # one program per length, not one per eager operation
def _measurements(truth):
    R, p = sensors(to_manifold(truth, CHAIN.layout(truth)))
    return {"R": R, "acc": second_difference(p) / DT**2, "trans": truth["trans"]}


def motion(T, seed=0, dtype=jnp.float64):
    """Smooth ground truth, its synthetic measurements and a perturbed start."""
    rng = np.random.default_rng(seed)
    t = np.arange(T)[:, None] * DT
    rot = 0.6 * np.sin(2 * np.pi * rng.uniform(0.3, 1.0, (1, 9)) * t + rng.uniform(0, 6, (1, 9)))
    trans = np.concatenate([np.sin(t), np.cos(2 * t), 0.3 * t], 1)
    truth = {"rot": jnp.asarray(rot.reshape(T, 3, 3), dtype), "trans": jnp.asarray(trans, dtype)}
    data = _measurements(truth)
    init = {
        "rot": truth["rot"] + jnp.asarray(rng.normal(scale=0.3, size=(T, 3, 3)), dtype),
        "trans": truth["trans"] + jnp.asarray(rng.normal(scale=0.05, size=(T, 3)), dtype),
    }
    return truth, init, data


@jax.jit  # one program per shape, not one per eager operation
def _rot_error(a, b):
    Ra, Rb = axis_angle_to_matrix(a), axis_angle_to_matrix(b)
    return jnp.max(jnp.linalg.norm(matrix_to_axis_angle(Ra @ jnp.swapaxes(Rb, -1, -2)), axis=-1))


def rot_error(a, b):
    return float(_rot_error(a, b))


WIN = window(4, 2)  # overlapping windows: every frame in K = 2 of them


def e_heading(x, data):
    """Orientations seen through a per-sequence heading error γ_s about y (von Marcard §4.2.4)."""
    R, _ = sensors(x)
    g = x["heading"]
    c, s_, z, o = jnp.cos(g), jnp.sin(g), jnp.zeros_like(g), jnp.ones_like(g)
    Ry = jnp.stack([jnp.stack([c, z, s_], -1), jnp.stack([z, o, z], -1), jnp.stack([-s_, z, c], -1)], -2)
    return matrix_to_axis_angle(Ry @ R @ jnp.swapaxes(data["R"], -1, -2))


def e_offset(x, data):  # a per-sequence translation offset seen by every frame
    return (x["trans"] + x["offset"] - data["trans"])[..., None]


def e_window(x, data):  # translation pulled towards a per-window linear trend (DCT-like, 2 coefficients)
    T = x["trans"].shape[0]
    frames, _ = WIN.windows.frames(x["trans"])  # (W, 4, 3)
    basis = jnp.stack([jnp.ones(4), jnp.linspace(-1.0, 1.0, 4)], 1)  # (4, 2)
    fit = jnp.einsum("lk,wkc->wlc", basis.astype(frames.dtype), x["coef"])
    return WIN.windows.rows(frames - fit, T)  # (T, K, 3)


def _variants(T, seed=1):
    _, init, data = motion(T, seed=seed)
    rng = np.random.default_rng(seed)
    W = WIN.windows.count(T)
    base = list(CHAIN.terms) + [Term("prior", e_prior, weight=0.5), Term("smooth2", e_smooth2, weight=0.3, bandwidth=2)]
    border = [Term("heading", e_heading, weight=0.7, reads=(("rot", None), ("trans", None), ("heading", None))),
              Term("offset", e_offset, weight=0.2, reads=(("trans", None), ("offset", None)))]  # fmt: skip
    windows = [Term("window", e_window, weight=0.4, reads=(("trans", None), ("coef", None)))]
    # 9 + 2 coupling rows per frame against 12 coupled unknowns: the "rows" factorisation.
    narrow = list(CHAIN.terms) + [
        Term("prior", e_prior, weight=0.5),
        Term("smooth2", e_smooth2_root, weight=0.3, bandwidth=2),
    ]
    seq = {"heading": jnp.asarray(rng.normal(0, 0.2, 3)), "offset": jnp.asarray(rng.normal(0, 0.1, 3))}
    coef = {"coef": jnp.asarray(rng.normal(0, 0.3, (W, 2, 3)))}
    u_seq = {"heading": sequence("angle"), "offset": sequence()}
    return {
        "band": (Problem(base, rotations=("rot",)), init),
        "border": (Problem(base + border, {"rot": frame("so3"), **u_seq}), {**init, **seq}),
        "windows": (Problem(base + windows, {"rot": frame("so3"), "coef": WIN}), {**init, **coef}),
        "all": (Problem(base + border + windows, {"rot": frame("so3"), **u_seq, "coef": WIN}), {**init, **seq, **coef}),
        "narrow": (Problem(narrow, rotations=("rot",)), init),
        "narrow_border": (Problem(narrow + border, {"rot": frame("so3"), **u_seq}), {**init, **seq}),
    }, data
