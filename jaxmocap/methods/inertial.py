"""The inertial posers of von Marcard ch. 3: IT, SOP and SIP, as compositions of terms.

- **SOP** (Sparse Orientation Poser): E_ori + E_anthro over 6 IMUs, frame by frame, each
  frame started from the previous frame's result (§3.4.1).
- **IT** (Inertial Tracker): the same with every available IMU (13 or 17, §3.4.3).
- **SIP** (Sparse Inertial Poser): E_ori + E_acc + E_anthro over the whole sequence at once
  (eq. 3.4-3.5), started from SOP (§3.4.1), minimised by Levenberg-Marquardt.

No solver code lives here: each method builds a `jaxmocap.solve.Problem` from the terms of
`jaxmocap.energies.imu` and calls `solve` / `solve_batch`. Weights (`SIPWeights`) default
to the thesis's (§3.4.1); a weight of 0 switches its term off exactly, without recompiling.

Calibration (§3.2.3, `calibrate`): readings are assumed in the model frame already
(M_i^g applied, eq. 3.2); the sensor-to-bone rotations R_s^b = R_b^g(x₀)ᵀ R_s^g(0) (eq. 3.3)
and the sensor points p^b = R_b^g(x₀)ᵀ (v_s(x₀) - J_b(x₀)) come from the first frame and
the known initial pose x₀, as in the thesis, where initial poses came with the datasets.
"""

from __future__ import annotations

from functools import partial

import dataclasses
from collections.abc import Callable, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from .._checks import check_frames, check_max_steps, check_rate, check_rotations
from ..body.kinematics import forward, shaped_joints
from ..body.model import Body
from ..energies.imu import (
    InertialData,
    acceleration_term,
    global_acceleration,
    joint_limit_term,
    mahalanobis_term,
    orientation_term,
)
from ..priors.pose_prior import PosePrior, default_pose_prior
from .._progress import report
from ..solve import NO_OBSERVATIONS, Problem, Solution, VonMarcardLM, solve, solve_batch
from ..solve.solver import PROGRESS_FRAMES
from .weights import FitResult, Weights

__all__ = [
    "SIPWeights",
    "InertialPreset",
    "PRESETS",
    "preset",
    "InertialSetup",
    "calibrate",
    "from_dip",
    "inertial_problem",
    "orientation_poser",
    "inertial_tracker",
    "sparse_orientation_poser",
    "sparse_inertial_poser",
    "SIPResult",
    "stack_setups",
    "pad_setups",
    "sparse_inertial_poser_batch",
    "BodyScaleEstimate",
    "estimate_body_scale",
    "SCALE_CANDIDATES",
    "SCALE_CRITERIA",
]


@dataclasses.dataclass(frozen=True)
class SIPWeights(Weights):
    """Weights of eq. 3.5 and 3.16 (defaults: von Marcard §3.4.1). 0 switches a term off.

    ori, acc, mahal, limit weight the terms of those names; anthro (w_anthro) scales
    both prior terms (`term_weights`). Floats or arrays (traced: changing them does not
    recompile; differentiable). A negative weight does not switch a term off: it rewards
    the error (acc=-1 used to drop E_acc silently), so each is checked (`Weights`).
    """

    ori: float = 1.0
    acc: float = 0.05
    anthro: float = 1.0
    mahal: float = 0.003
    limit: float = 0.1

    def term_weights(self, num_sensors: int) -> dict:
        """{term: weight} as eq. 3.5 and 3.16 weigh them: w_ori / N_s, w_acc / N_s,
        w_anthro w_mahal, w_anthro w_limit."""
        return {"ori": self.ori / num_sensors, "acc": self.acc / num_sensors,
                "mahal": self.anthro * self.mahal, "limit": self.anthro * self.limit}  # fmt: skip


@dataclasses.dataclass(frozen=True)
class InertialPreset:
    """A named setting of the inertial posers: weights, SIP's stopping rule and SOP's.

    weights: `SIPWeights` of SOP, IT and SIP.
    max_steps, rtol, atol: SIP's LM budget and tolerances (`jaxmocap.solve.solve`): the
        fit stops when an accepted step changes the cost by less than rtol·cost + atol
        and every unknown by less than rtol·|x| + atol, or at max_steps.
    sop_steps, sop_rtol, sop_atol: the same per frame of SOP / IT.
    source: where the values come from.
    """

    weights: SIPWeights
    max_steps: int
    rtol: float
    atol: float
    sop_steps: int = 20
    sop_rtol: float = 1e-6
    sop_atol: float = 1e-10
    source: str = ""


#: The named settings. "thesis": von Marcard §3.4.1's weights and 20 LM steps, exact.
#: "validated" (the default): what won on subjects no part of the project tuned on, chosen
#: on the development subjects only (`experiments/defaults.py`, `jaxmocap.motion.splits`;
#: the numbers in experiments/results/defaults.json; float32 reaches the same error as
#: float64 there, so inputs keep their dtype).
PRESETS = {
    "thesis": InertialPreset(SIPWeights(), max_steps=20, rtol=1e-6, atol=1e-10,
                             source="von Marcard §3.4.1: thesis weights, 20 LM steps"),
    "validated": InertialPreset(SIPWeights(mahal=1e-4), max_steps=30, rtol=1e-3, atol=1e-3,
                                source="experiments/defaults.py on development subjects 02, 131 "
                                       "(experiments/results/defaults.json)"),
}  # fmt: skip


def preset(weights: SIPWeights | str = "validated") -> InertialPreset:
    """The `InertialPreset` a `weights` argument means: a preset name, or `SIPWeights` with
    the validated stopping rule."""
    if isinstance(weights, str):
        if weights not in PRESETS:
            raise ValueError(f"weights={weights!r}: pass a preset name {sorted(PRESETS)} or SIPWeights(...).")
        return PRESETS[weights]
    if not isinstance(weights, SIPWeights):
        raise ValueError(
            f"weights must be SIPWeights or a preset name {sorted(PRESETS)}, got {type(weights).__name__}."
        )
    return dataclasses.replace(PRESETS["validated"], weights=weights, source="user weights, validated stopping rule")


def _limits(p: InertialPreset, max_steps, rtol, atol, sop: bool = False, tridiagonal: str | None = None) -> dict:
    """The solve limits (`solve`'s max_steps and solver): the preset's, unless given."""
    ms, rt, at = (p.sop_steps, p.sop_rtol, p.sop_atol) if sop else (p.max_steps, p.rtol, p.atol)
    ms = ms if max_steps is None else max_steps
    check_max_steps(ms)
    lm = VonMarcardLM(rtol=rt if rtol is None else rtol, atol=at if atol is None else atol, tridiagonal=tridiagonal)
    return dict(max_steps=ms, solver=lm)


class InertialSetup(eqx.Module):
    """One calibrated sequence: the data the energies read plus the static sensor layout.

    data: `InertialData` (measurements, calibration, prior).
    bones: static, the bone carrying each sensor.
    fps: static frame rate.
    pose0: (24, 3) the known initial pose x₀ (axis-angle); trans0: (3,) its translation.
    """

    data: InertialData
    pose0: Array
    trans0: Array
    bones: tuple[int, ...] = eqx.field(static=True)
    fps: float = eqx.field(static=True)

    @property
    def num_frames(self) -> int:
        return self.data.num_frames

    def subset(self, sensors: Sequence[int]) -> InertialSetup:
        """The same sequence seen by the sensors with indices `sensors` only."""
        idx = np.asarray(sensors)
        d = self.data
        data = InertialData(
            d.orientation[:, idx], d.acceleration[:, idx], d.sensor_to_bone[idx], d.sensor_point[idx],
            d.rest_joints, d.prior,
        )  # fmt: skip
        return InertialSetup(data, self.pose0, self.trans0, tuple(self.bones[i] for i in idx), self.fps)


def calibrate(
    body: Body,
    bones: Sequence[int],
    vertices: Sequence[int],
    orientation,
    acceleration,
    pose0,
    fps: float,
    betas=None,
    trans0=None,
    prior: PosePrior | None = None,
    acceleration_frame: str = "sensor",
    dtype=None,
) -> InertialSetup:
    """Calibrate raw IMU readings against a known initial pose (eq. 3.2-3.3, 3.9, 3.11).

    Args:
        body: the actor's body model; betas (B,) its shape.
        bones, vertices: per sensor, the carrying bone (joint index) and the mesh vertex.
        orientation: (T, S, 3, 3) measured R_s^g, already in the model frame (eq. 3.2).
        acceleration: (T, S, 3) accelerometer readings a^s in the sensor frame
            (`acceleration_frame="sensor"`, eq. 3.9 applied here) or a^g already in the
            world frame without gravity (`"global"`, DIP's layout).
        pose0: (24, 3) the pose at frame 0; trans0 (3,) its translation (default 0).
        fps: frame rate of the readings.
        prior: pose prior (default: the shipped one).
    Returns:
        An `InertialSetup` for the methods below.
    """
    if acceleration_frame not in ("sensor", "global"):
        raise ValueError(f"acceleration_frame must be 'sensor' or 'global', got {acceleration_frame!r}.")
    check_rate("fps", fps)  # E_acc divides by dt²: a negative or zero rate is silently wrong
    orientation = jnp.asarray(orientation)
    if orientation.ndim != 4:
        raise ValueError(f"orientation has shape {orientation.shape}; expected (T, S, 3, 3).")
    dtype = orientation.dtype if dtype is None else dtype
    orientation = orientation.astype(dtype)
    acceleration = jnp.asarray(acceleration, dtype)
    T, S = orientation.shape[:2]
    if orientation.shape != (T, S, 3, 3) or acceleration.shape != (T, S, 3):
        raise ValueError(
            f"orientation must be (T, S, 3, 3) and acceleration (T, S, 3); got {orientation.shape} "
            f"and {acceleration.shape}."
        )
    if len(bones) != S or len(vertices) != S:
        raise ValueError(f"{S} sensors in the readings but {len(bones)} bones and {len(vertices)} vertices.")
    check_frames("orientation", T)
    # Dropped samples are NaN; what is present must be a rotation (an all-zero matrix is not).
    check_rotations("orientation", orientation, atol=1e-2, allow_nan=True)
    bad = [int(b) for b in bones if not 0 <= int(b) < body.num_joints]
    if bad:
        raise ValueError(f"bones {bad} are not joints of this body (0 .. {body.num_joints - 1}).")
    pose0 = jnp.asarray(pose0, dtype)
    if pose0.shape != (body.num_joints, 3):
        raise ValueError(f"pose0 has shape {pose0.shape}; expected ({body.num_joints}, 3) axis-angle.")
    trans0 = jnp.zeros(3, dtype) if trans0 is None else jnp.asarray(trans0, dtype)
    betas = jnp.zeros((body.num_betas,), dtype) if betas is None else jnp.asarray(betas, dtype)
    R_s0 = orientation[0]
    if not bool(jnp.all(jnp.isfinite(R_s0))):
        missing = [int(i) for i in np.flatnonzero(~np.isfinite(np.asarray(R_s0)).all(axis=(1, 2)))]
        first = first_complete_frame(orientation)
        hint = (
            f"the first frame where every sensor reports is {first}: pass the readings from "
            f"there on (orientation[{first}:], acceleration[{first}:]) with the pose of that frame"
            if first is not None
            else "no frame has every sensor"
        )
        raise ValueError(
            f"orientation: frame 0 has dropped samples (sensors {missing}); calibration needs "
            f"every sensor at the frame whose pose is pose0. {hint}."
        )
    out = forward(body, pose0, betas, trans0)
    bones_idx, verts_idx = np.asarray(bones), np.asarray(vertices)
    R_b0 = out.joint_rotations[bones_idx]  # R_b^g(x₀)
    sensor_to_bone = jnp.swapaxes(R_b0, -1, -2) @ R_s0  # eq. 3.3
    rel = out.vertices[verts_idx] - out.joints[bones_idx]
    sensor_point = jnp.einsum("sba,sb->sa", R_b0, rel)  # R_b0ᵀ (v - J_b)
    acc = global_acceleration(orientation, acceleration) if acceleration_frame == "sensor" else acceleration
    prior = default_pose_prior(dtype) if prior is None else prior
    rest = shaped_joints(body, betas)
    data = InertialData(orientation, acc, sensor_to_bone, sensor_point, rest, prior)
    return InertialSetup(data, pose0, trans0, tuple(int(b) for b in bones), float(fps))


def first_complete_frame(orientation) -> int | None:
    """The first frame of (T, S, 3, 3) readings where every sensor reports (no NaN), or None."""
    ok = np.isfinite(np.asarray(orientation)).all(axis=(-1, -2)).all(axis=-1)
    return int(np.argmax(ok)) if ok.any() else None


def from_dip(
    path_or_dict, body: Body, bones, vertices, pose0=None, fps: float = 60.0, sensors=None, **kw
) -> InertialSetup:
    """Calibrate a DIP-IMU-layout pickle (keys imu_ori (T, S, 3, 3), imu_acc (T, S, 3) global).

    DIP stores accelerations in the world frame with gravity removed, so eq. 3.9 is
    already applied. `pose0` defaults to the file's first `gt` pose (SMPL axis-angle).
    `sensors` picks a subset (e.g. DIP's 17 → 6: [7, 8, 11, 12, 0, 2]).
    """
    if isinstance(path_or_dict, dict):
        d = path_or_dict
        missing = [k for k in ("imu_ori", "imu_acc") if k not in d]
        if missing:
            raise ValueError(f"path_or_dict misses key(s) {missing}; a DIP-IMU dict has imu_ori, imu_acc, gt.")
    else:
        from ..formats.dip import load_dip

        d = load_dip(path_or_dict)
    ori, acc = np.asarray(d["imu_ori"]), np.asarray(d["imu_acc"])
    if sensors is not None:
        ori, acc = ori[:, sensors], acc[:, sensors]
    if pose0 is None:
        if "gt" not in d:
            raise ValueError("the file has no 'gt' poses; pass pose0, the known initial pose.")
        pose0 = np.asarray(d["gt"])[0].reshape(24, 3)
    return calibrate(body, bones, vertices, ori, acc, pose0, fps, acceleration_frame="global", **kw)


def inertial_problem(
    setup: InertialSetup, weights: SIPWeights | str = "validated", acceleration: bool = True
) -> Problem:
    """E_motion (eq. 3.5) for `setup` as a `Problem`.

    Which terms exist is structure (E_acc only with `acceleration`); how much each counts
    is data: the weights become arrays, so an ablation (a weight of 0 switches its term
    off exactly) or a batch of weight settings reuses one compilation.
    """
    S = len(setup.bones)
    w = preset(weights).weights
    f = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    terms = [
        orientation_term(setup.bones, S, f(w.ori)),
        mahalanobis_term(f(w.anthro), f(w.mahal)),
        joint_limit_term(f(w.anthro), f(w.limit)),
    ]
    if acceleration:
        terms.append(acceleration_term(setup.bones, setup.fps, S, f(w.acc)))
    return Problem(terms, rotations=("pose",))


def _frame_data(data: InertialData, t) -> InertialData:
    """Frame t of `data` as a one-frame sequence."""
    take = lambda x: jax.lax.dynamic_slice_in_dim(x, t, 1, axis=0)  # noqa: E731
    return eqx.tree_at(
        lambda d: (d.orientation, d.acceleration), data, (take(data.orientation), take(data.acceleration))
    )


def orientation_poser(
    setup: InertialSetup,
    weights: SIPWeights | str = "validated",
    init=None,
    sequential: bool = True,
    max_steps: int | None = None,
    rtol: float | None = None,
    atol: float | None = None,
    progress: bool | None = None,
) -> tuple[Array, Array]:
    """E_ori + E_anthro per frame: the pose of every frame (SOP with 6 IMUs, IT with all).

    Args:
        setup: the calibrated sequence.
        weights: a preset name ("validated", the default, or "thesis") or `SIPWeights`
            (w_acc is ignored); see `PRESETS`.
        init: (24, 3) start of the first frame (default: x₀).
        sequential: True (the thesis): frame t starts from frame t-1's result, one
            frame after the other (`lax.scan`). False: every frame starts from `init`
            and all frames are solved at once (`solve_batch`), much faster, and equally
            good when the sensors pin the pose down (IT on 13 or 17 IMUs).
        max_steps, rtol, atol: LM limits per frame (default: the preset's).
        progress: report frames done and the ETA on stderr while the sequential scan runs
            (default: for `PROGRESS_FRAMES` frames or more).
    Returns:
        (poses (T, 24, 3) axis-angle, per-frame `optx.RESULTS` codes (T,)).
    """
    if not isinstance(setup, InertialSetup):
        raise ValueError(f"setup must be an InertialSetup (from calibrate), got {type(setup).__name__}.")
    kw = _limits(preset(weights), max_steps, rtol, atol, sop=True)
    if init is not None and jnp.shape(init) != setup.pose0.shape:
        raise ValueError(f"init has shape {jnp.shape(init)}; expected {setup.pose0.shape}, one pose.")
    problem = inertial_problem(setup, weights, acceleration=False)
    data = setup.data
    x0 = setup.pose0 if init is None else jnp.asarray(init, setup.pose0.dtype)
    T = setup.num_frames
    if not sequential:
        batch = jax.vmap(lambda t: _frame_data(data, t))(jnp.arange(T))
        params = {"pose": jnp.broadcast_to(x0, (T, 1) + x0.shape)}
        sol = solve_batch(problem, params, batch, **kw)
        return sol.value["pose"][:, 0], sol.result
    progress = T >= PROGRESS_FRAMES if progress is None else bool(progress)
    return solve_frames_sequentially(problem, data, x0, progress=progress, **kw)


@eqx.filter_jit
def solve_frames_sequentially(problem, data, x0, progress=False, **kw):
    """SOP's frame-by-frame solve (`orientation_poser(sequential=True)`) of a one-frame
    `problem`: frame t of `data` starts from frame t-1's result, frame 0 from the pose `x0`;
    `kw` are `solve`'s limits. Returns (poses (T, 24, 3), per-frame result codes (T,))."""
    T = data.num_frames
    every = max(1, T // 100)

    def step(pose, t):
        sol = solve(problem, {"pose": pose[None]}, _frame_data(data, t), **kw)
        new = sol.value["pose"][0]
        if progress:
            jax.lax.cond(
                ((t + 1) % every == 0) | (t == T - 1),
                lambda: jax.debug.callback(partial(report, "SOP frame"), t + 1, T, final=t == T - 1),  # noqa: B023
                lambda: None,
            )
        return new, (new, sol.result)

    _, (poses, results) = jax.lax.scan(step, x0, jnp.arange(T))
    return poses, results


def sparse_orientation_poser(
    setup: InertialSetup, weights: SIPWeights | str = "validated", **kw
) -> tuple[Array, Array]:
    """SOP (§3.4.2): `orientation_poser`, sequential, on the sensors of `setup` (6 IMUs)."""
    return orientation_poser(setup, weights, **kw)


def inertial_tracker(setup: InertialSetup, weights: SIPWeights | str = "validated", **kw) -> tuple[Array, Array]:
    """IT (§3.4.3): `orientation_poser` with every available IMU (13 or 17)."""
    return orientation_poser(setup, weights, **kw)


class SIPResult(eqx.Module, FitResult):
    """Outcome of `sparse_inertial_poser`.

    poses (T, 24, 3), trans (T, 3): the fitted trajectory (translation is up to the
    constant and linear drift accelerations cannot see); init: the SOP poses it started
    from; solution: the engine's `Solution` (result code, steps, per-term costs).
    """

    poses: Array
    trans: Array
    init: Array
    solution: Solution

    @property
    def params(self) -> dict:
        return {"pose": self.poses, "trans": self.trans}


def sparse_inertial_poser(
    setup: InertialSetup,
    weights: SIPWeights | str = "validated",
    init: Array | str | None = None,
    init_trans: Array | None = None,
    max_steps: int | None = None,
    rtol: float | None = None,
    atol: float | None = None,
    sop_steps: int | None = None,
) -> SIPResult:
    """SIP (eq. 3.4-3.5): every frame at once, all three terms, started from SOP.

    Args:
        setup: the calibrated sequence.
        weights: a preset name or `SIPWeights` (`acc=0` gives a whole-sequence SOP):
            "validated" (the default: w_mahal and the stopping rule that won on subjects
            nothing was tuned on, `PRESETS`) or "thesis" (§3.4.1's weights, 20 steps).
        init: (T, 24, 3) initial poses, or how to make them: "sop" (the default, the
            thesis's `sparse_orientation_poser(setup, weights)`) or "birnn" (the poses of
            the shipped Deep Inertial Poser network, `jaxmocap.learned.dip.birnn_poses`;
            6 "sip6" sensors).
        init_trans: (T, 3) initial translation (default: x₀'s translation on every frame).
        max_steps, rtol, atol: LM budget and tolerances (default: the preset's). The
            solution's `result` is 0 when the tolerance was met, and `decrease` says how
            fast the cost was still falling when the budget ran out.
        sop_steps: LM iterations per frame of the SOP start (default: the preset's).
    Returns:
        `SIPResult`.
    """
    if not isinstance(setup, InertialSetup):
        raise ValueError(f"setup must be an InertialSetup (from calibrate), got {type(setup).__name__}.")
    T = setup.num_frames
    if isinstance(init, str):
        if init not in ("sop", "birnn"):
            raise ValueError(f"init={init!r}: pass 'sop', 'birnn' or (T, 24, 3) poses.")
        if init == "birnn":
            from ..learned.dip import birnn_poses

            init = birnn_poses(setup)
        else:
            init = None
    if init is not None and jnp.shape(init) != (T, 24, 3):
        raise ValueError(f"init has shape {jnp.shape(init)}; expected (T, 24, 3) = ({T}, 24, 3).")
    if init_trans is not None and jnp.shape(init_trans) != (T, 3):
        raise ValueError(f"init_trans has shape {jnp.shape(init_trans)}; expected (T, 3) = ({T}, 3).")
    limits = _limits(preset(weights), max_steps, rtol, atol)
    if init is None:
        init, _ = sparse_orientation_poser(setup, weights, max_steps=sop_steps)
    trans = jnp.broadcast_to(setup.trans0, (T, 3)) if init_trans is None else jnp.asarray(init_trans)
    problem = inertial_problem(setup, weights, acceleration=True)
    # Only E_acc sees the translation; with w_acc = 0 it stays where it started.
    params = {"pose": jnp.asarray(init, setup.pose0.dtype), "trans": trans.astype(setup.pose0.dtype)}
    sol = solve(problem, params, setup.data, **limits)
    sol = eqx.tree_at(lambda s: s.result, sol, _unless_observed(setup.data, sol.result))
    return SIPResult(sol.value["pose"], sol.value["trans"], jnp.asarray(init), sol)


def _unless_observed(data: InertialData, result: Array, frame_mask: Array | None = None) -> Array:
    """`result`, or NO_OBSERVATIONS where no sensor sample exists after the calibration frame.

    Frame 0 is the known pose x₀; with nothing measured after it the fit is the prior's
    alone, which must not read as a success. Works batched: (..., T, S, ...) readings.
    """
    ori = jnp.isfinite(data.orientation).all((-1, -2)).any(-1)  # (..., T)
    acc = jnp.isfinite(data.acceleration).all(-1).any(-1)
    seen = ori | acc
    if frame_mask is not None:
        seen = seen & frame_mask
    T = seen.shape[-1]
    observed = jnp.any(seen[..., 1:] if T > 1 else seen, axis=-1)
    return jnp.where(observed, result, NO_OBSERVATIONS)


def stack_setups(setups: Sequence[InertialSetup]) -> InertialSetup:
    """B calibrated sequences of equal length and sensor layout as one batched setup."""
    _check_setups("stack_setups", setups)
    first = setups[0]
    for s in setups[1:]:
        if s.bones != first.bones or s.fps != first.fps or s.num_frames != first.num_frames:
            raise ValueError(
                "stack_setups needs equal sensor bones, fps and frame counts; pad sequences first "
                f"(got bones {s.bones} vs {first.bones}, {s.num_frames} vs {first.num_frames} frames)."
            )
    return jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *setups)


def _check_setups(who: str, setups) -> None:
    if isinstance(setups, InertialSetup) or len(setups) == 0:
        raise ValueError(
            f"{who}: setups must be a non-empty list of InertialSetup (from calibrate), got {setups!r:.80}."
        )
    bad = [type(s).__name__ for s in setups if not isinstance(s, InertialSetup)]
    if bad:
        raise ValueError(f"{who}: setups must hold InertialSetup objects (from calibrate), got {bad}.")


def pad_setups(setups: Sequence[InertialSetup], length: int | None = None) -> tuple[InertialSetup, Array]:
    """Sequences of any lengths as one batch: (stacked setup, (B, T) frame mask).

    Readings are padded to `length` (default: the longest) by repeating their last
    frame; padded frames drop out of every term of `sparse_inertial_poser_batch` (pass
    the mask as `frame_mask`) and keep their initial pose.
    """
    _check_setups("pad_setups", setups)
    T = max(s.num_frames for s in setups) if length is None else int(length)
    padded = []
    for s in setups:
        extra = T - s.num_frames
        if extra < 0:
            raise ValueError(f"length={T} is shorter than a sequence of {s.num_frames} frames.")

        def rep(x, extra=extra):
            return jnp.concatenate([x, jnp.repeat(x[-1:], extra, axis=0)], 0) if extra else x

        d = s.data
        data = eqx.tree_at(lambda d: (d.orientation, d.acceleration), d, (rep(d.orientation), rep(d.acceleration)))
        padded.append(InertialSetup(data, s.pose0, s.trans0, s.bones, s.fps))
    mask = jnp.arange(T)[None, :] < jnp.asarray([s.num_frames for s in setups])[:, None]
    return stack_setups(padded), mask


def sparse_inertial_poser_batch(
    setups: InertialSetup,
    init: Array,
    init_trans: Array | None = None,
    weights: SIPWeights | str = "validated",
    frame_mask: Array | None = None,
    max_steps: int | None = None,
    rtol: float | None = None,
    atol: float | None = None,
    tridiagonal: str | None = None,
) -> Solution:
    """SIP on a batch (`stack_setups`) in one vmapped solve; init (B, T, 24, 3).

    Returns the engine's batched `Solution` (value["pose"], value["trans"], per-sequence
    result codes and costs); `frame_mask` (B, T) marks real frames of padded sequences.
    `weights`, `max_steps`, `rtol`, `atol` as `sparse_inertial_poser`'s (preset by default).
    `tridiagonal`: how the frame band is factorised (`VonMarcardLM`'s option; speed only).
    """
    if not isinstance(setups, InertialSetup) or setups.pose0.ndim != 3:
        raise ValueError("setups must be one batched InertialSetup (from stack_setups or pad_setups).")
    init = jnp.asarray(init)
    if init.shape[:1] + init.shape[2:] != (setups.pose0.shape[0], 24, 3) or init.shape[1] != setups.num_frames:
        raise ValueError(
            f"init has shape {init.shape}; expected (B, T, 24, 3) = "
            f"({setups.pose0.shape[0]}, {setups.num_frames}, 24, 3)."
        )
    B, T = init.shape[:2]
    trans = jnp.broadcast_to(setups.trans0[:, None], (B, T, 3)) if init_trans is None else jnp.asarray(init_trans)
    problem = inertial_problem(setups, weights, acceleration=True)
    dtype = setups.pose0.dtype
    params = {"pose": jnp.asarray(init, dtype), "trans": trans.astype(dtype)}
    limits = _limits(preset(weights), max_steps, rtol, atol, tridiagonal=tridiagonal)
    sol = solve_batch(problem, params, setups.data, frame_mask, **limits)
    return eqx.tree_at(lambda s: s.result, sol, _unless_observed(setups.data, sol.result, frame_mask))


#: Default candidate scales of `estimate_body_scale`, relative to the model: -30 % to +40 % in 10 % steps
#: (estimates lean large; 1.0, 1.1, 1.2 are Table 3.2's models).
SCALE_CANDIDATES = (0.7, 0.8, 0.9, 1.0, 1.1, 1.2, 1.3, 1.4)


@dataclasses.dataclass(frozen=True)
class BodyScaleEstimate:
    """Outcome of `estimate_body_scale`.

    scale: the estimate (parabola vertex through the best candidate and its neighbours).
    scales: (K,) the candidates, ascending, the grid's and the bisection's; profile: (K,)
    the compared cost of each.
    costs: per-term final costs (K,) of every candidate's fit ("ori", "acc", "mahal", "limit").
    criterion: which terms `profile` sums (see `estimate_body_scale`).
    best: index of the lowest-profile candidate; at_edge: the grid's first or last
    candidate won (the true scale may lie outside the candidates: widen them).
    solution: the batched `Solution` of the candidate fits (value["pose"] (K, T, 24, 3)).
    """

    scale: float
    scales: np.ndarray
    profile: np.ndarray
    costs: dict
    criterion: str
    best: int
    at_edge: bool
    solution: Solution

    def scale_by(self, criterion: str) -> float:
        """The estimate another criterion gives from the same candidate fits."""
        profile = _profile(self.costs, criterion)
        return _parabola_vertex(self.scales, profile, int(np.argmin(profile)))


#: The final-cost terms each criterion of `estimate_body_scale` compares.
SCALE_CRITERIA = {"ori": ("ori",), "data": ("ori", "acc"), "acc": ("acc",), "total": ("ori", "acc", "mahal", "limit")}


def _profile(costs: dict, criterion: str) -> np.ndarray:
    if criterion not in SCALE_CRITERIA:
        raise ValueError(f"criterion must be one of {sorted(SCALE_CRITERIA)}, got {criterion!r}.")
    c = sum(np.asarray(costs[k], float) for k in SCALE_CRITERIA[criterion])
    return np.where(np.isfinite(c), c, np.inf)  # a failed (non-finite) fit cannot be the minimum


def estimate_body_scale(
    make_setup: Callable[[float], InertialSetup],
    init=None,
    scales: Sequence[float] = SCALE_CANDIDATES,
    weights: SIPWeights = SIPWeights(),
    criterion: str = "ori",
    init_trans=None,
    max_steps: int = 100,
    rtol: float = 1e-4,
    atol: float = 1e-4,
    refine: int = 1,
) -> BodyScaleEstimate:
    """One uniform body scale s from the IMU data, by profiling SIP's cost over candidates.

    Not in the thesis (its Table 3.2 only shows what a wrong size costs): our choice. For
    each candidate s the readings are calibrated on the body scaled by s (`make_setup(s)`),
    every candidate is fitted by SIP (eq. 3.4-3.5) from the same start in one batched solve
    (one compilation), and s minimises the compared final cost of eq. 3.5's terms.

    Search: the candidate grid, then `refine` rounds of bisection (each fits the two
    midpoints between the best candidate and its neighbours, one more batched solve of
    two), then the vertex of the parabola through the best point and its two neighbours.
    Over a 0.1 grid the profile is skewed: a parabola through points 0.1 apart has a mean
    absolute error of 2.2 %, one through points 0.05 apart 1.35 % (development subjects,
    experiments/sip_body_scale.py --role tuning, criterion "ori"); one round gives the
    latter for 2 fits where a 0.05 grid over the same range costs 7 more. When a bound of the grid wins, `at_edge` is set and
    nothing is refined: the true scale may lie beyond it, widen `scales`.

    Which terms are compared (`criterion`): at fixed poses only E_acc depends on s
    (rotations, hence E_ori, the sensor-to-bone calibration, SOP and the prior are the same
    on every scaled body; the sensor lever arms, hence the modelled accelerations, grow
    with s). Through the fit, a wrong s bends the poses away from the orientation readings
    to explain the accelerations: on the true body the poses that agree with the
    orientations also explain the accelerations, so "ori" (default) compares the final
    E_ori alone. E_acc is a poor judge of its own lever arm: the fitted poses absorb part
    of the acceleration noise, and a larger body absorbs more with less bending, so "acc"
    (E_acc alone), "data" (E_ori + E_acc) and "total" (with the prior, which prefers the
    little motion a larger body needs) lean large, by 9 to 16 % on average and up to 55 %
    on a punching clip, where "ori" is within 2.4 % (development subjects, 0.05 grid:
    mean absolute error 1.35 % for "ori", 8.9 % "data", 16.2 % "acc", 10.2 % "total").
    Every term's final cost is in `costs`, and `BodyScaleEstimate.scale_by` gives any
    criterion's estimate from the same solves.

    Accuracy: noise-free and with w_mahal = 0, a 1.1 × subject comes out within 1 % (the
    test). With Xsens-like errors, a held-out prior and 90-frame windows
    (experiments/results/sip_body_scale.md), the mean absolute error is 5.8 % on the
    evaluation subjects (6 clips × true scales 0.9, 1.0, 1.1; none at a bound), against
    1.35 % on the development subjects. The error is one factor per clip, the same for every
    true scale (-10 % to +8 %): the sensors' 2 cm placement error moves the lever arms the
    estimate measures. Without it (experiments/results/sip_body_scale_no_placement_error.md)
    the first 3 of those clips err by 1.07 % on average, with it by 8.9 %. The 1.35 % was one
    draw of the sensor errors: with a second draw, 6 development clips × 2 draws err by
    4.4 % (experiments/results/sip_body_scale_variants.md, issue 46). Tried there against the
    placement error, none better on the development subjects: each sensor's offset along its
    limb fitted as a sequence-wide unknown (free it absorbs the scale: 10.5 %, biased large;
    with a prior no better than this estimate on the same clips), the pelvis sensor's
    accelerations left out (4.5 %), 200 LM steps instead of 60 (the same estimates on the 2
    clips tried); a closed-form lever-arm fit at fixed poses returns the size SIP's poses were
    fitted with and drowns in SOP's noise (-87 %). So the estimate helps when the size is
    unknown or off by 10 % or more; a known size is better given.

    Args:
        make_setup: s -> the `InertialSetup` calibrated with the body scaled by s
            (`jaxmocap.body.scaled_body`) on the same readings, e.g.
            `lambda s: app.scenarios.inertial_setup(sc, i, scaled_body(body, s), ...)`.
        init: (T, 24, 3) start poses of every candidate (default: SOP, size-free).
        scales: at least 3 distinct positive candidates, relative to the body of
            `make_setup(1.0)`.
        weights: `SIPWeights` of the fits; init_trans (T, 3) as in `sparse_inertial_poser`.
        max_steps, rtol, atol: LM limits; costs are compared at convergence, so the
            defaults allow more steps than SIP's 20.
        refine: rounds of bisection around the best candidate (0: the grid alone).
    Returns:
        `BodyScaleEstimate`.
    """
    if not callable(make_setup):
        raise ValueError(f"make_setup must be a callable s -> InertialSetup, got {type(make_setup).__name__}.")
    if criterion not in SCALE_CRITERIA:
        raise ValueError(f"criterion must be one of {sorted(SCALE_CRITERIA)}, got {criterion!r}.")
    s = np.asarray(scales, dtype=float) if np.ndim(scales) == 1 else None
    if s is None or len(s) < 3:
        raise ValueError(
            f"scales must be a 1-D sequence of at least 3 candidates (a parabola needs 3), got {scales!r}."
        )
    if not (np.all(np.isfinite(s)) and np.all(s > 0)):
        raise ValueError(f"scales must be finite and > 0 (a body scale), got {s.tolist()}.")
    if len(np.unique(s)) != len(s):
        raise ValueError(f"scales must be distinct, got {s.tolist()}.")
    if not (isinstance(refine, int) and refine >= 0):
        raise ValueError(f"refine must be an int >= 0 (rounds of bisection around the best candidate), got {refine!r}.")
    s = np.sort(s)
    setups = [make_setup(float(x)) for x in s]
    bad = [type(x).__name__ for x in setups if not isinstance(x, InertialSetup)]
    if bad:
        raise ValueError(f"make_setup must return InertialSetup objects (from calibrate), got {bad[0]}.")
    T = setups[0].num_frames
    stack_setups(setups)  # checks equal frames, sensors and rate before any solve
    if init is None:
        # E_ori and the prior are size-free, so SOP is the same on every candidate body.
        init, _ = sparse_orientation_poser(setups[0], weights)
    init = jnp.asarray(init, setups[0].pose0.dtype)
    if init.shape != (T, 24, 3):
        raise ValueError(f"init has shape {init.shape}; expected (T, 24, 3) = ({T}, 24, 3).")
    if init_trans is not None and jnp.shape(init_trans) != (T, 3):
        raise ValueError(f"init_trans has shape {jnp.shape(init_trans)}; expected (T, 3) = ({T}, 3).")

    def fits(setups):  # every candidate from the same start: their costs compare
        K = len(setups)
        trans = None if init_trans is None else jnp.broadcast_to(jnp.asarray(init_trans), (K, T, 3))
        return sparse_inertial_poser_batch(
            stack_setups(setups), jnp.broadcast_to(init, (K,) + init.shape), trans, weights,
            max_steps=max_steps, rtol=rtol, atol=atol,
        )  # fmt: skip

    sol = fits(setups)
    profile = _profile({k: np.asarray(v, float) for k, v in sol.costs.items()}, criterion)
    if not np.isfinite(profile).any():
        raise ValueError(
            "estimate_body_scale: no candidate fit ended with a finite cost (non-finite readings or start?)."
        )
    lo, hi = s[0], s[-1]
    at_edge = s[int(np.argmin(profile))] in (lo, hi)
    for _ in range(refine if not at_edge else 0):
        # Bisect towards the best candidate's neighbours: the vertex is then fitted through
        # points half as far apart, where the profile is closer to a parabola.
        best = int(np.argmin(profile))
        new = np.asarray([(s[best - 1] + s[best]) / 2, (s[best] + s[best + 1]) / 2])
        more = fits([make_setup(float(x)) for x in new])
        s = np.concatenate([s, new])
        sol = jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a, b]), sol, more)
        order = np.argsort(s)
        s, sol = s[order], jax.tree_util.tree_map(lambda a, o=order: a[o], sol)
        profile = _profile({k: np.asarray(v, float) for k, v in sol.costs.items()}, criterion)
    costs = {k: np.asarray(v, float) for k, v in sol.costs.items()}
    best = int(np.argmin(profile))
    scale = _parabola_vertex(s, profile, best)
    return BodyScaleEstimate(scale, s, profile, costs, criterion, best, at_edge, sol)


def _parabola_vertex(s: np.ndarray, c: np.ndarray, best: int) -> float:
    """The minimiser of the parabola through the best candidate and its neighbours (the
    last three at an edge), kept within those three; the best candidate if not convex."""
    k = min(max(best, 1), len(s) - 2)
    x, y = s[k - 1 : k + 2], c[k - 1 : k + 2]
    if not np.isfinite(y).all():
        return float(s[best])
    a, b, _ = np.polyfit(x - s[k], y, 2)  # centred: well conditioned
    if not a > 0:
        return float(s[best])
    return float(np.clip(s[k] - b / (2 * a), x[0], x[-1]))


# Moved to the app layer (`jaxmocap.app.scenarios`, the adapters over a scenario's named
# arrays); the old name resolves there until the next release.
def __getattr__(name: str):
    if name == "from_scenario":
        from ..app.scenarios import inertial_setup

        return inertial_setup
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
