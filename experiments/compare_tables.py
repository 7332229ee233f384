"""Compare two runs of experiments/sip_tables.py number by number (engine changes).

    python experiments/compare_tables.py OLD.json NEW.json [--out experiments/results/X.json]

Every mean (MPJPE mm, MPJAE °) in both files is compared; the output lists each with
its relative change and the largest one (key `max_rel_change`).
"""

from __future__ import annotations

import sys as _sys
from pathlib import Path as _Path

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import _provenance  # noqa: E402,F401  (its commit is taken now, at the start of the run)

import argparse
import json
from pathlib import Path


def _numbers(x, path=""):
    if isinstance(x, dict):
        for k, v in x.items():
            yield from _numbers(v, f"{path}/{k}")
    elif isinstance(x, (int, float)) and not isinstance(x, bool) and path.rsplit("/", 1)[-1] != "std":
        yield path, float(x)


def compare(old: dict, new: dict) -> dict:
    a, b = dict(_numbers(old)), dict(_numbers(new))
    rows = {k: {"old": a[k], "new": b[k], "rel_change": (b[k] - a[k]) / abs(a[k]) if a[k] else 0.0}
            for k in sorted(set(a) & set(b)) if k.startswith(("/table", "/ablations"))}  # fmt: skip
    worst = max(rows, key=lambda k: abs(rows[k]["rel_change"]))
    return {"compared": len(rows), "max_rel_change": abs(rows[worst]["rel_change"]), "worst": worst, "rows": rows}


def _split_of(result: dict):
    """The result's split record, or None where it predates the splits."""
    split = result.get("split")
    return split if isinstance(split, dict) and "evaluation" in split else None


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("old")
    p.add_argument("new")
    p.add_argument("--out")
    args = p.parse_args(argv)
    out = compare(json.loads(Path(args.old).read_text()), json.loads(Path(args.new).read_text()))
    for k, r in out["rows"].items():
        print(f"{k:55s} {r['old']:9.3f} {r['new']:9.3f} {100 * r['rel_change']:+7.3f} %")
    print(f"{out['compared']} numbers; largest relative change {100 * out['max_rel_change']:.3f} % ({out['worst']})")
    if args.out:
        import sys

        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from _provenance import write_json

        # The comparison inherits the newer run's split (none for a run that predates the splits).
        write_json(
            args.out,
            out,
            split=_split_of(json.loads(Path(args.new).read_text())),
            argv=argv,
            indent=2,
            data={"compared": [args.old, args.new]},
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
