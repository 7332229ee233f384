"""Inference throughput of the Deep Inertial Poser BiRNN, against the SOP start it replaces.

    python benchmarks/birnn_speed.py                 ->  benchmarks/results/birnn_speed.json
    python benchmarks/birnn_speed.py --suffix gpu    ->  benchmarks/results/birnn_speed_gpu.json

Offline BiRNN (the whole sequence at once, as SIP's start), float32, random weights (speed
does not depend on them) at the shipped width and the thesis's 512 units:
  one sequence of T = 1000 frames, and a batch of B sequences of 300 frames (vmapped);
baseline in the same process: SOP (the per-frame orientation poser on 6 IMUs, 20 LM steps,
frame after frame: SIP's usual start) on one 300-frame walk. `ratio_vs_sop` is BiRNN
frames/s over SOP frames/s. The CPU file (no suffix) also holds the last GPU run's
results under "gpu" (copied from `birnn_speed_gpu.json`).
"""

from __future__ import annotations

import argparse
import json

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from _common import machine, time_call, write_json

from jaxmocap import default_body
from jaxmocap.app.scenarios import inertial_setup
from jaxmocap.learned.dip import NUM_INPUTS, DIPConfig, DIPNetwork, load_dip_model, DEFAULT_MODEL_PATH
from jaxmocap.methods import inertial as I
from jaxmocap.sensors import ScenarioConfig, make_scenario


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--suffix", default="", help="results/birnn_speed_<suffix>.json")
    p.add_argument("--batch", type=int, default=None, help="sequences per batch (default: 256 on GPU, 16 on CPU)")
    args = p.parse_args()
    gpu = jax.default_backend() == "gpu"
    B = args.batch or (256 if gpu else 16)
    shipped = load_dip_model(DEFAULT_MODEL_PATH)[0].config.hidden if DEFAULT_MODEL_PATH.is_file() else 128

    body = default_body("low")
    sc = make_scenario(["walk"], ScenarioConfig(fps=30.0, max_frames=300, betas_std=0.0), seed=0, body=body)
    setup = inertial_setup(sc, 0, body)
    sop = lambda s: I.sparse_orientation_poser(s)[0]  # noqa: E731  (jitted inside)
    r = time_call(sop, setup, min_seconds=2.0, max_repeats=20)
    sop_fps = setup.num_frames / r["median_s"]
    results = {"sop": {**r, "frames": setup.num_frames, "frames_per_second": sop_fps}}
    print(f"SOP (20 LM steps per frame, sequential): {sop_fps:9.0f} frames/s", flush=True)

    rng = np.random.default_rng(0)
    for hidden in sorted({shipped, 512}):
        net = DIPNetwork(DIPConfig(hidden=hidden), jax.random.PRNGKey(0))
        one = eqx.filter_jit(lambda n, x: n(x)[0])
        batch = eqx.filter_jit(lambda n, x: jax.vmap(lambda xi: n(xi)[0])(x))
        for name, fn, x in (("one_sequence", one, jnp.asarray(rng.normal(size=(1000, NUM_INPUTS)), jnp.float32)),
                            ("batch", batch, jnp.asarray(rng.normal(size=(B, 300, NUM_INPUTS)), jnp.float32))):  # fmt: skip
            r = time_call(fn, net, x, min_seconds=2.0, max_repeats=200)
            frames = int(np.prod(x.shape[:-1]))
            r.update(
                frames=frames, frames_per_second=frames / r["median_s"], ratio_vs_sop=frames / r["median_s"] / sop_fps
            )
            results[f"birnn_{hidden}_{name}"] = r
            print(f"BiRNN {hidden:3d} units, {name:12s} ({'x'.join(map(str, x.shape[:-1]))} frames): "
                  f"{r['frames_per_second']:11.0f} frames/s ({r['ratio_vs_sop']:.0f}x SOP)", flush=True)  # fmt: skip
    payload = {
        "benchmark": "birnn_speed",
        "setup": {"dtype": "float32", "shipped_hidden": shipped, "batch_sequences": B, "batch_frames": 300,
                  "one_sequence_frames": 1000, "baseline": "SOP on a 300-frame walk, 6 IMUs, 20 LM steps per frame"},
        "results": results,
        "machine": machine(),
    }  # fmt: skip
    if not args.suffix:  # the CPU file also carries the last GPU run, so one file holds both
        from _common import RESULTS

        gpu = RESULTS / "birnn_speed_gpu.json"
        if gpu.is_file():
            payload["gpu"] = json.loads(gpu.read_text())
    print(write_json(f"birnn_speed{'_' + args.suffix if args.suffix else ''}.json", payload))


if __name__ == "__main__":
    main()
