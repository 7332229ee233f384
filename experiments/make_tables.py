"""Regenerate every committed table under experiments/results/ from the current code.

    python experiments/make_tables.py              # the CPU tables, one after another (`make tables`)
    python experiments/make_tables.py --list       # every table: where it runs, its command, its time
    python experiments/make_tables.py --only muvs_resolution,retarget_check
    python experiments/make_tables.py --gpu        # also the GPU tables (on a machine whose JAX sees a GPU)

Each entry of `TABLES` names the files it writes, the command (run from the repository
root, `../shared/data` beside it), where it runs in reasonable time ("cpu": this 2-core
machine, under ~15 min; "cpu-long": CPU only but long; "gpu": one H200) and the time it
took. Every experiment records its split and provenance when it writes (experiments/
_provenance.py -> experiments/results/provenance.json), so after a run each file says which
commit, command, split and data made it; `tests/test_splits.py` checks the splits.
CPU commands run under `nice -n 10` (the machine is shared).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import shlex
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = "experiments/results"


@dataclasses.dataclass(frozen=True)
class Table:
    name: str
    outputs: tuple[str, ...]  # relative to experiments/results
    command: str  # from the repository root; "python" is this interpreter
    where: str  # "cpu", "cpu-long" or "gpu"
    minutes: str  # measured or estimated wall time there
    note: str = ""


TABLES = (
    # --- CPU, each under ~15 min on 2 shared cores -----------------------------------------
    Table("retarget_check", ("retarget_check.json", "retarget_check.md", "retarget_dance/"),
          "python experiments/retarget_check.py", "cpu", "~3"),
    Table("muvs_tuning", ("muvs_tuning.json",), "python experiments/muvs_tuning.py --out experiments/results",
          "cpu", "~12", "chooses MuVSWeights on the development subjects: run before muvs_tables"),
    Table("muvs_resolution", ("muvs_resolution.json",),
          "python experiments/muvs_resolution.py --out experiments/results", "cpu", "~10"),
    Table("learn_weights", ("learn_weights.json", "learn_weights.png"),
          "python experiments/learn_weights.py --out experiments/results", "cpu", "~10"),
    Table("learn_weights_gradcheck", ("learn_weights_gradcheck.json",),
          "python experiments/learn_weights.py --gradcheck-only --frames 24 --out experiments/results", "cpu", "~2"),
    Table("physics_cleanup", ("physics_cleanup.json",), "python experiments/physics_cleanup.py", "cpu", "~2"),
    Table("multiview_layout_margins", ("multiview_layout_margins.json",),
          "python experiments/multiview_layout_margins.py", "cpu", "<1"),
    Table("sop_start", ("sop_start.json", "sop_start.md"), "python experiments/sop_start.py --clips 9", "cpu", "~10",
          "README quotes it (tests/test_readme_numbers.py)"),
    Table("har", ("har.json", "har.md", "har_confusion.png"),
          "python experiments/har.py --features raw --hidden 1024,512,60 --out out/har_raw && "
          "python experiments/har.py --out experiments/results --compare out/har_raw/har.json", "cpu", "~30",
          "the first run (the thesis's input and MLP, into out/) is the comparison row the README quotes; "
          "both share the simulated data in out/har_cache"),
    # --- CPU, long ----------------------------------------------------------------------
    Table("defaults", ("defaults.json", "defaults.md", "defaults.png"),
          "python experiments/defaults.py --out experiments/results", "cpu-long", "~30",
          "chooses the inertial posers' validated preset on 02/131, then measures it on 05-07; "
          "PRESETS['validated'] in jaxmocap/methods/inertial.py must equal its choice (tests/test_presets.py)"),
    Table("muvs_monocular", ("muvs_monocular.json", "muvs_monocular.md"),
          "python experiments/muvs_monocular.py --out experiments/results", "cpu-long", "~35",
          "README quotes it (tests/test_readme_numbers.py); 33 min at a load of 3-15 on 2026-12-07"),
    Table("fuzz", ("fuzz.json",), "nice -n 19 python experiments/fuzz.py", "cpu-long", "~110",
          "reads no motion data"),
    Table("train_association", (),
          "python experiments/train_association.py --scenes 8 --frames 150", "cpu-long", "~20",
          "writes jaxmocap/methods/association_weights.json (the model vip_association and vip_tables use)"),
    # --- GPU (one H200) -------------------------------------------------------------------
    Table("muvs_tables", ("muvs_tables.json", "muvs_tables.md", "muvs_tables.png"),
          "python experiments/muvs_tables.py --out experiments/results", "gpu", "~5", "after muvs_tuning"),
    Table("muvs_tables_as_written", ("muvs_tables_as_written.json", "muvs_tables_as_written.md",
                                     "muvs_tables_as_written.png"),
          "python experiments/muvs_tables.py --keep-swaps --out experiments/results", "gpu", "~5"),
    Table("sip_tables", ("sip_tables.json", "sip_tables.md", "sip_tables_*.png"),
          "python experiments/sip_tables.py --out experiments/results", "gpu", "~15",
          "`--prepare` first on a CPU (clips, IMUs, priors) and carry out/…/cache"),
    Table("train_dip", ("dip_training_curves.json", "dip_training_curves.png"),
          "python experiments/train_dip.py --out out/dip", "gpu", "~10",
          "then copy out/dip/curves.json and training_curves.png to dip_training_curves.*"),
    Table("dip_init", ("dip_init.json", "dip_init.md", "dip_init.png"),
          "python experiments/dip_init.py --models out/dip --out experiments/results", "gpu", "~10",
          "after sip_tables and train_dip"),
    Table("prior_forms", ("prior_forms.json", "prior_forms.md"),
          "python experiments/prior_forms.py --out experiments/results", "gpu", "~25",
          "or one fold per core with --only SUBJECT (see its docstring)"),
    Table("vip_association", ("vip_association.json", "vip_association.md"),
          "python experiments/vip_association.py --development --scenes 12 --frames 150 --seed 0 --fusion "
          "--cache out/va && python experiments/vip_association.py --scenes 12,4 --frames 150 --seed 55,56 --fusion "
          "--dev-seed 0 --cache out/va", "gpu", "~30",
          "re-select the penalty window on the development scenes first; fresh test seeds"),
    Table("vip_tables", ("vip_tables.json", "vip_tables.md", "vip_tables_per_clip/"),
          "python experiments/vip_tables.py --clips 10 --frames 300 --out experiments/results", "gpu", "~60",
          "several processes: --shard k/n, then --finished-only"),
    Table("intercap_tables", ("intercap_tables.json", "intercap_tables.md", "intercap_scene06/"),
          "python experiments/intercap_tables.py --scenes 10 --frames 60 --out experiments/results", "gpu", "~10",
          "2026-12-07 on an H100: five processes of `--only i,j` (3.5 min for every row) then the gathering run; "
          "set XLA_FLAGS=--xla_gpu_autotune_level=0 when processes share a GPU (ten autotuning at once took minutes each)"),
    Table("sip_ablation", ("sip_ablation/",),
          "jaxmocap sweep experiments/sweeps/sip_ablation.toml --out experiments/results/sip_ablation", "gpu", "~15"),
    Table("sip_ablation_library", ("sip_ablation_library/",),
          "jaxmocap sweep experiments/sweeps/sip_ablation_library.toml --out experiments/results/sip_ablation_library",
          "gpu", "~15"),
    Table("sip_tables_engine_v2_check", ("sip_tables_engine_v2_check.json",),
          "python experiments/compare_tables.py OLD/sip_tables.json experiments/results/sip_tables.json "
          "--out experiments/results/sip_tables_engine_v2_check.json", "gpu", "<1",
          "after an engine change: compares the sip_tables run before it (OLD) with the one after"),
    Table("sip_body_scale", ("sip_body_scale.json", "sip_body_scale.md"),
          "python experiments/sip_body_scale.py --out experiments/results", "gpu", "?",
          "experiments/sip_body_scale.py's own docstring has the command"),
)  # fmt: skip


def _listing(tables) -> str:
    lines = [f"{'name':28s} {'where':9s} {'min':>5s}  command"]
    for t in tables:
        lines.append(f"{t.name:28s} {t.where:9s} {t.minutes:>5s}  {t.command}" + (f"   # {t.note}" if t.note else ""))
    return "\n".join(lines)


def _run(t: Table, log: Path) -> dict:
    parts = shlex.split(t.command.replace("nice -n 19 ", ""))
    cmds, cmd = [], []
    for p in parts + ["&&"]:  # "a && b": run one after another, stop at the first failure
        if p == "&&":
            cmds.append(cmd)
            cmd = []
        else:
            cmd.append(sys.executable if p == "python" else p)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    t0 = time.perf_counter()
    with log.open("w") as f:
        for c in cmds:
            rc = subprocess.run(
                ["nice", "-n", "10", *c], cwd=ROOT, env=env, stdout=f, stderr=subprocess.STDOUT
            ).returncode
            if rc:
                break
    return {"name": t.name, "returncode": rc, "minutes": round((time.perf_counter() - t0) / 60, 1), "log": str(log)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--list", action="store_true", help="list every table with where it runs and its command")
    ap.add_argument("--only", default="", help="comma-separated table names")
    ap.add_argument("--gpu", action="store_true", help="also run the GPU tables (JAX must see a GPU)")
    ap.add_argument("--long", action="store_true", help="also run the long CPU tables")
    ap.add_argument("--logs", type=Path, default=ROOT / "out" / "make_tables")
    args = ap.parse_args(argv)
    only = [n for n in args.only.split(",") if n]
    unknown = set(only) - {t.name for t in TABLES}
    if unknown:
        raise SystemExit(f"--only: no table named {sorted(unknown)}; see --list.")
    if args.list:
        print(_listing(TABLES))
        return 0
    wanted = {"cpu"} | ({"cpu-long"} if args.long else set()) | ({"gpu"} if args.gpu else set())
    run = [t for t in TABLES if (t.name in only if only else t.where in wanted)]
    if any(t.where == "gpu" for t in run):
        import jax

        if jax.default_backend() != "gpu":
            raise SystemExit(
                f"the GPU tables need a GPU; JAX's backend here is {jax.default_backend()!r} (see --list)."
            )
    args.logs.mkdir(parents=True, exist_ok=True)
    done = []
    for t in run:
        print(f"{t.name}: {t.command}", flush=True)
        r = _run(t, args.logs / f"{t.name}.log")
        print(
            f"  -> {'ok' if r['returncode'] == 0 else 'FAILED (see ' + r['log'] + ')'} in {r['minutes']} min",
            flush=True,
        )
        done.append(r)
    left = [t for t in TABLES if t not in run]
    if left:
        print("\nNot run here (run them where they fit):\n" + _listing(left))
    (args.logs / "summary.json").write_text(json.dumps(done, indent=1) + "\n")
    return 1 if any(r["returncode"] for r in done) else 0


if __name__ == "__main__":
    sys.exit(main())
