"""Sum up a `JAXMOCAP_COMPILE_REPORT` file (see conftest.py): where the suite's time goes.

JAXMOCAP_COMPILE_REPORT=/tmp/c.jsonl make test
python tests/compile_report.py /tmp/c.jsonl [--top 30]
"""

import argparse
import json
from collections import defaultdict

KEYS = ("wall_s", "cpu_s", "trace_s", "lower_s", "compile_s", "programs", "cache_hits", "cache_misses")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("report")
    ap.add_argument("--top", type=int, default=25)
    args = ap.parse_args(argv)
    rows = [json.loads(line) for line in open(args.report) if line.strip()]
    files = defaultdict(lambda: defaultdict(float))
    for r in rows:
        f = files[r["test"].split("::")[0]]
        for k in KEYS:
            f[k] += r.get(k, 0)
        f["tests"] += 1
    total = {k: sum(f[k] for f in files.values()) for k in KEYS}
    print(f"{len(rows)} tests: " + ", ".join(f"{k} {total[k]:.0f}" for k in KEYS))
    head = f"{'file':40s} {'tests':>5s} " + " ".join(f"{k:>12s}" for k in KEYS)
    print(head)
    for name, f in sorted(files.items(), key=lambda kv: -kv[1]["wall_s"]):
        print(f"{name:40s} {int(f['tests']):5d} " + " ".join(f"{f[k]:12.1f}" for k in KEYS))
    print(f"\nslowest {args.top} tests")
    for r in sorted(rows, key=lambda r: -r["wall_s"])[: args.top]:
        print(f"{r['wall_s']:7.1f} s  compile {r.get('compile_s', 0):6.1f} s  programs {r.get('programs', 0):4d}  "
              f"hits {r.get('cache_hits', 0):3d}  {r['test']}")  # fmt: skip


if __name__ == "__main__":
    main()
