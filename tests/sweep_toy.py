"""A toy sweep method for the sweep tests: smoothing noisy 3-D tracks (one compile, ~1 s).

Unknown x (T, 3) per frame; terms "data" (x_t - y_t, weight w_data) and "smooth"
(x_{t-1} - 2 x_t + x_{t+1}, bandwidth 1, weight w_smooth). Sequences are random walks
of ragged lengths with Gaussian noise of std `noise` (the sensor-error preset's
acc_noise). A cell with w_data = 0 raises (x is then undetermined up to a line), and
sequence 2 at noise >= 0.2 fails to prepare: the tests' two kinds of failing cells. Environment: SWEEP_TOY_LOG appends each solved cell's
sequence, noise and weights to a file; SWEEP_TOY_SLEEP sleeps per call (kill tests).
"""

from __future__ import annotations

import dataclasses
import os
import time

import jax.numpy as jnp
import numpy as np

from jaxmocap.app.sweep_methods import FailedItem
from jaxmocap.solve import Problem, Term, solve_batch
from jaxmocap.timeseries import second_difference


@dataclasses.dataclass
class Track:
    y: np.ndarray
    truth: np.ndarray
    index: int
    noise: float

    @property
    def length(self) -> int:
        return len(self.y)


PROBLEM = Problem([
    Term("data", lambda p, d: p["x"] - d["y"], 1.0),
    Term("smooth", lambda p, d: second_difference(p["x"]), 1.0, bandwidth=1),
])  # fmt: skip


class ToyMethod:
    name = "toy"
    defaults = {"data": 1.0, "smooth": 1.0}
    terms = {"smooth": ("smooth",)}
    metrics = ("rmse",)

    def sequences(self, dataset, errors, cache):
        rng = np.random.default_rng(int(dataset.get("seed", 0)))
        noise = float((errors or {}).get("acc_noise", 0.1))
        out = []
        for i in range(int(dataset["sequences"])):
            T = int(dataset["frames"]) - (i % 3) * 2  # ragged: T, T-2, T-4
            truth = np.cumsum(rng.normal(scale=0.1, size=(T, 3)), 0)
            if i == 2 and noise >= 0.2:
                out.append(FailedItem("simulated calibration failure", T))
                continue
            out.append(Track(truth + rng.normal(scale=noise, size=truth.shape), truth, i, noise))
        return out

    def solve(self, items, weights, options):
        if np.any(weights["data"] == 0):
            raise ValueError("w_data = 0 leaves the track undetermined")
        T = max(it.length for it in items)
        pad = lambda a: np.concatenate([a, np.repeat(a[-1:], T - len(a), 0)])  # noqa: E731
        y = jnp.asarray(np.stack([pad(it.y) for it in items]))
        mask = jnp.asarray(np.arange(T)[None] < np.asarray([it.length for it in items])[:, None])
        sol = solve_batch(PROBLEM, {"x": y}, {"y": y}, mask, weights={k: jnp.asarray(v) for k, v in weights.items()},
                          max_steps=5, chunk_size=options.get("chunk_size", "auto"))  # fmt: skip
        x = np.asarray(sol.value["x"])
        if os.environ.get("SWEEP_TOY_LOG"):
            with open(os.environ["SWEEP_TOY_LOG"], "a") as f:
                for it, wd, ws in zip(items, weights["data"], weights["smooth"]):
                    f.write(f"{it.index} {it.noise:g} {wd:g} {ws:g}\n")
        time.sleep(float(os.environ.get("SWEEP_TOY_SLEEP", "0")))
        return [{"rmse": float(np.sqrt(np.mean((x[i, : it.length] - it.truth) ** 2)))} for i, it in enumerate(items)]
