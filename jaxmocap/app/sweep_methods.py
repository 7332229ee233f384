"""What a sweep can run: methods that solve many (sequence, weights) cells in one batch.

A sweep method (`SweepMethod`) names its weights (with defaults), the terms a config
may switch off (each by zeroing weights, which is exact for a least-squares term), how
to turn a dataset into sequences, and how to solve a list of cells, one weight setting
per cell, in one batched solve. The weights reach the solver as traced (B,) arrays
(`solve_batch(weights=...)`), so every weight setting of a grid shares one compiled
program per sequence length.

Built in: "sip" (von Marcard eq. 3.4-3.5, started from SOP with the thesis weights) and
"sop" / "it" (the per-frame orientation poser on the dataset's sensors). A config may
also name any object as "module:attribute" (tests use a toy problem this way).
"""

from __future__ import annotations

import dataclasses
import importlib
import inspect
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Protocol

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["SweepMethod", "Cell", "InertialMethod", "METHODS", "resolve_method", "scenario_for"]


@dataclasses.dataclass(frozen=True)
class Cell:
    """One unit of sweep work: sequence `index` of (dataset, sensor-error preset) under `weights`."""

    variant: str
    dataset: str
    errors: str
    index: int
    weights: tuple[tuple[str, float], ...]

    @property
    def key(self) -> str:
        return f"{self.variant}|{self.dataset}|{self.errors}|{self.index}"


class SweepMethod(Protocol):
    name: str
    #: weight names and defaults (the thesis's for the built-in methods)
    defaults: dict[str, float]
    #: switchable terms -> the weights that switching the term off sets to 0
    terms: dict[str, tuple[str, ...]]
    #: per-cell numbers `solve` returns that a summary may compare (lower is better)
    metrics: tuple[str, ...]

    def sequences(self, dataset: dict, errors: dict | None, cache: Path) -> list[Any]:
        """The dataset's sequences under a sensor-error preset; each has `.length`.

        An item with an `error` attribute (e.g. `FailedItem`) is a sequence that failed
        to prepare: its cells record that error and the sweep goes on.
        """

    def solve(self, items: Sequence[Any], weights: dict[str, np.ndarray], options: dict) -> list[dict]:
        """Per item i (all of one padded length), solve with weights[k][i]; return metrics."""


# --- datasets ---------------------------------------------------------------------------


def error_model(errors: dict | None):
    from ..sensors import IMUErrorModel

    if errors is None:
        return None
    spec = dict(errors)
    preset = spec.pop("preset", "off")
    scale = float(spec.pop("scale", 1.0))
    if preset not in ("off", "xsens"):
        raise ValueError(f"sensor-error preset must be 'off' or 'xsens', got {preset!r}.")
    base = dataclasses.asdict(getattr(IMUErrorModel, preset)())
    fields = set(base)
    unknown = sorted(set(spec) - fields)
    if unknown:
        raise ValueError(f"unknown IMU error field(s) {unknown}; IMUErrorModel has {sorted(fields)}.")
    base.update({k: float(v) for k, v in spec.items()})
    # `scale` multiplies the magnitudes, not the shape parameters of dropouts.
    scaled = {k: (v * scale if k not in ("dropout_length",) else v) for k, v in base.items()}
    scaled["dropout_rate"] = min(scaled["dropout_rate"], 1.0)
    return IMUErrorModel(**scaled)


def _library_motions(names, count: int, frames: int, fps: float, seed: int, body):
    """`count` varied library motions: tempo ×0.75-1.3 and twice the frames (random crops)."""
    from ..motion import library

    rng = np.random.default_rng(seed)
    out = []
    for i in range(count):
        name = names[i % len(names)]
        fn = library.MOTIONS[name]
        params = inspect.signature(fn).parameters
        kw = {"num_frames": 2 * frames, "fps": fps, "body": body}
        tempo = rng.uniform(0.75, 1.3)
        if "frequency" in params:
            kw["frequency"] = params["frequency"].default * tempo
        elif "period" in params:
            kw["period"] = params["period"].default / tempo
        m = fn(**kw)
        out.append(m.replace(name=f"{name} x{tempo:.2f}"))
    return out


def _motion_items(spec: dict) -> list:
    from ..motion import library

    items = []
    for m in spec["motions"]:
        if m in library.MOTIONS:
            items.append(m)
            continue
        p = Path(m)
        if p.is_dir():
            items += sorted(str(f) for f in p.iterdir() if f.suffix.lower() in (".amc", ".bvh", ".npz"))
        else:
            items.append(str(p))
    return items


def scenario_for(dataset: dict, errors: dict | None, cache: Path, body=None):
    """The `Scenario` of a dataset spec under an error preset (cached as .npz in `cache`).

    A spec with `scenario = PATH` loads that file (its sensor errors are baked in: the
    preset must be None); a spec with `motions` generates `sequences` sequences of at
    most `frames` frames with `make_scenario`, the preset's IMU errors and `seed`.
    """
    from ..sensors import ScenarioConfig, load_scenario, make_scenario, save_scenario

    if "scenario" in dataset:
        return load_scenario(dataset["scenario"])
    cache.mkdir(parents=True, exist_ok=True)
    path = cache / f"{dataset['_name']}__{dataset['_errors_name']}.npz"
    if path.exists():
        return load_scenario(path)
    from ..body import default_body

    body = default_body("low") if body is None else body
    fps, frames = float(dataset.get("fps", 30.0)), int(dataset.get("frames", 120))
    count = int(dataset.get("sequences", len(dataset["motions"])))
    items = _motion_items(dataset)
    from ..motion import library

    if dataset.get("vary", True) and all(isinstance(m, str) and m in library.MOTIONS for m in items):
        items = _library_motions(items, count, frames, fps, int(dataset.get("seed", 0)), body)
    config = ScenarioConfig(
        fps=fps, max_frames=frames, imu_set=dataset.get("imu_set", "sip6"), imu_errors=error_model(errors),
        betas_std=float(dataset.get("betas_std", 1.0)),
    )  # fmt: skip
    s = make_scenario(items, config, seed=int(dataset.get("seed", 0)), body=body, num_sequences=count)
    save_scenario(s, path)  # atomic (temp + rename)
    return s


# --- the inertial posers ------------------------------------------------------------------


def _prior(spec: str, name: str):
    """A dataset's pose prior: the bundled one (None), the clip's leave-subject-out fold, or a file."""
    from ..priors import PosePrior
    from ..priors.build import evaluation_prior

    if spec == "bundled":
        return None
    if spec == "held_out":
        return evaluation_prior(name)
    return PosePrior.load(spec)


@dataclasses.dataclass
class FailedItem:
    """A sequence that could not be prepared: its cells record `error` and are not solved."""

    error: str
    length: int


@dataclasses.dataclass
class InertialItem:
    setup: Any
    truth: np.ndarray  # (T, 24, 3)
    betas: np.ndarray
    init: np.ndarray  # (T, 24, 3) SOP with the thesis weights
    name: str

    @property
    def length(self) -> int:
        return int(self.truth.shape[0])


@eqx.filter_jit
def _errors(body, pred, true, betas, mask):
    """Per member: mean MPJPE (mm, Procrustes) and MPJAE (°) over real frames."""
    from .. import metrics
    from ..body.kinematics import forward

    def one(p, t, b, m):
        fp, ft = forward(body, p, b), forward(body, t, b)
        pe = metrics.position_errors(fp.joints, ft.joints) * 1000.0
        ae = metrics.angle_errors(fp.joint_rotations, ft.joint_rotations)
        w = m.astype(pe.dtype)
        return (pe.mean(-1) * w).sum() / w.sum(), (ae.mean(-1) * w).sum() / w.sum()

    return jax.vmap(one)(pred, true, betas, mask)


@dataclasses.dataclass
class InertialMethod:
    """SIP (`name="sip"`) or the per-frame orientation poser (`"sop"`, `"it"`)."""

    name: str = "sip"
    metrics: tuple = ("mpjae", "mpjpe", "cost")
    defaults: dict = dataclasses.field(default_factory=lambda: _thesis_weights().to_dict())
    terms: dict = dataclasses.field(
        default_factory=lambda: dict(ori=("ori",), acc=("acc",), mahal=("mahal",), limit=("limit",))
    )

    def __post_init__(self):
        if self.name not in ("sip", "sop", "it"):
            raise ValueError(f"InertialMethod name must be 'sip', 'sop' or 'it', got {self.name!r}.")
        if self.name != "sip":
            self.defaults = {k: v for k, v in self.defaults.items() if k != "acc"}
            self.terms = {k: v for k, v in self.terms.items() if k != "acc"}
        from ..body import default_body

        self.body = default_body("low")

    def prepare(self, dataset, errors, cache):
        """Generate and cache the dataset's scenario (once, before any process solves)."""
        scenario_for(dataset, errors, cache, self.body)

    def sequences(self, dataset, errors, cache):
        from ..methods import inertial as I
        from .scenarios import inertial_setup

        sc = scenario_for(dataset, errors, cache, self.body)
        out = []
        for i in range(sc.num_sequences):
            seq = sc.sequence(i)
            try:
                setup = inertial_setup(
                    sc, i, self.body, prior=_prior(dataset.get("prior", "bundled"), sc.meta["names"][i])
                )
            except ValueError as e:  # e.g. a dropout at frame 0: no calibration, this sequence only
                out.append(FailedItem(f"{type(e).__name__}: {e}", int(sc["length"][i])))
                continue
            out.append(InertialItem(setup, np.asarray(seq["poses"][0]), np.asarray(seq["betas"][0]), None,
                                    sc.meta["names"][i]))  # fmt: skip
        # SOP with the thesis weights starts every SIP variant: one shared start per
        # sequence, so variants differ by their weights alone (paired comparisons).
        if self.name == "sip":
            from ..solve.batch import length_buckets

            ok = [it for it in out if isinstance(it, InertialItem)]
            for T, members in length_buckets([it.length for it in ok]):
                stacked, _ = I.pad_setups([ok[i].setup for i in members], T)
                poses = np.asarray(_sop_batch(stacked))
                for j, i in enumerate(members):
                    ok[i].init = poses[j, : ok[i].length]
        return out

    def fit(self, items, weights, options):
        """Solve `items` (padded to the longest) with per-item `weights` ({name: (B,) array}).

        Returns (poses (B, T, 24, 3), result codes (B,), steps (B,), costs (B,), frame mask
        (B, T)); the solve runs in the setups' dtype (float64 setups: a float64 solve).
        """
        from ..methods import inertial as I
        from ..solve import VonMarcardLM, solve_batch

        T = max(it.length for it in items)
        stacked, mask = I.pad_setups([it.setup for it in items], T)
        dtype = stacked.pose0.dtype
        w = {k: jnp.asarray(weights.get(k, np.full(len(items), v)), dtype) for k, v in self.defaults.items()}
        term_w = I.SIPWeights(**w).term_weights(len(stacked.bones))
        if self.name != "sip":
            del term_w["acc"]  # SOP / IT: no E_acc
        steps = int(options.get("max_steps", 20))
        pad = lambda x: np.concatenate([x, np.repeat(x[-1:], T - len(x), 0)]) if len(x) < T else x  # noqa: E731
        if self.name == "sip":
            problem = I.inertial_problem(stacked, "thesis", acceleration=True)  # weights replaced below
            init = jnp.asarray(np.stack([pad(it.init) for it in items]), dtype)
            trans = jnp.broadcast_to(stacked.trans0[:, None], (len(items), T, 3))
            sol = solve_batch(problem, {"pose": init, "trans": trans}, stacked.data, mask, weights=term_w,
                              max_steps=steps, solver=VonMarcardLM(rtol=options.get("rtol", 1e-6), atol=options.get("atol", 1e-10)),
                              memory_fraction=options.get("memory_fraction", 0.6))  # fmt: skip
            return sol.value["pose"], np.asarray(sol.result), np.asarray(sol.num_steps), np.asarray(sol.cost), mask
        poses, codes = _sop_batch(stacked, term_w, steps)
        ok = np.asarray(codes) == 0
        result = np.where(np.asarray(mask) & ~ok, 1, 0).max(1)
        return poses, result, np.full(len(items), steps), np.full(len(items), np.nan), mask

    def solve(self, items, weights, options):
        poses, result, nsteps, cost, mask = self.fit(items, weights, options)
        T = mask.shape[1]
        pad = lambda x: np.concatenate([x, np.repeat(x[-1:], T - len(x), 0)]) if len(x) < T else x  # noqa: E731
        truth = jnp.asarray(np.stack([pad(it.truth) for it in items]), jnp.float32)
        betas = jnp.asarray(np.stack([it.betas for it in items]), jnp.float32)
        mpjpe, mpjae = _errors(self.body, jnp.asarray(poses, jnp.float32), truth, betas, mask)
        out = []
        for i, it in enumerate(items):
            out.append({
                "mpjpe": float(mpjpe[i]), "mpjae": float(mpjae[i]), "cost": float(cost[i]),
                "result": int(result[i]), "steps": int(nsteps[i]), "frames": it.length,
            })  # fmt: skip
        return out


def _thesis_weights():
    from ..methods.inertial import SIPWeights

    return SIPWeights()


@eqx.filter_jit
def _sop_batch(stacked, term_weights=None, steps=20):
    """The sequential orientation poser on a stacked batch; (B, T, 24, 3), (B, T) codes."""
    from ..methods import inertial as I
    from ..solve import VonMarcardLM, with_weights

    def one(setup, w):
        problem = I.inertial_problem(setup, "thesis", acceleration=False)
        if w is not None:
            problem = with_weights(problem, w)
        return I.solve_frames_sequentially(
            problem, setup.data, setup.pose0, max_steps=steps, solver=VonMarcardLM(rtol=1e-6, atol=1e-10)
        )

    poses, codes = jax.vmap(one)(stacked, term_weights)
    return poses if term_weights is None else (poses, codes)


METHODS = {
    "sip": lambda: InertialMethod("sip"),
    "sop": lambda: InertialMethod("sop"),
    "it": lambda: InertialMethod("it"),
}


def resolve_method(name: str) -> SweepMethod:
    """A built-in method by name, or `module:attribute` (an object or a no-argument factory)."""
    if name in METHODS:
        return METHODS[name]()
    if ":" in name:
        module, attr = name.split(":", 1)
        try:
            obj = getattr(importlib.import_module(module), attr)
        except (ImportError, AttributeError) as e:
            raise ValueError(f"method {name!r}: cannot import {attr!r} from {module!r} ({e}).") from None
        obj = obj() if inspect.isclass(obj) or inspect.isfunction(obj) else obj
        for need in ("name", "defaults", "terms", "sequences", "solve"):
            if not hasattr(obj, need):
                raise ValueError(f"method {name!r} lacks {need!r}; see jaxmocap.app.sweep_methods.SweepMethod.")
        return obj
    raise ValueError(f"unknown method {name!r}; built in: {sorted(METHODS)}, or give 'module:attribute'.")
