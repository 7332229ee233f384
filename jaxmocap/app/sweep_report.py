"""A sweep's summary: tables (markdown, CSV), paired statistics, plots.

Every variant is compared with the baseline variant (the method's default weights, i.e.
the thesis's, with `[sweep] baseline` applied and every term on) on the sequences both
finished: the paired difference of the metric per sequence, its mean with a bootstrap
95 % confidence interval, the Wilcoxon signed-rank and paired t tests
(`scipy.stats.wilcoxon`, `ttest_rel`) and the effect size d_z = mean / sd of the
differences. Lower metrics are better.

The best variant of each (method, dataset, sensor errors) has the lowest mean. The
"flat region" is the set of variants practically as good as the best: the upper end of
the 95 % bootstrap interval of their paired difference to the best is below
`FLAT_TOLERANCE` (2 %) of the best's mean. The summary says whether the baseline lies in it.

The best's own mean is measured on the sequences that chose it, so it is optimistic (the
winner of many noisy comparisons). `best_held_out` is the honest estimate: the variant
chosen on the even-numbered sequences is scored on the odd ones and the other way round
(`held_out_best`); the summary reports both.
"""

from __future__ import annotations

import csv
import io
import json
from collections import defaultdict
from pathlib import Path

import numpy as np

from .._files import atomic_write

__all__ = ["write_summary", "paired_stats", "FLAT_TOLERANCE"]

FLAT_TOLERANCE = 0.02
BOOTSTRAP = 5000


def paired_stats(a: np.ndarray, b: np.ndarray, seed: int = 0) -> dict:
    """Statistics of the paired differences a - b (one entry per sequence)."""
    from scipy import stats

    d = np.asarray(a, float) - np.asarray(b, float)
    n = len(d)
    out = {"n": n, "mean_diff": float(d.mean()) if n else float("nan")}
    if n < 2:
        return {
            **out,
            "ci_low": np.nan,
            "ci_high": np.nan,
            "wilcoxon_p": np.nan,
            "ttest_p": np.nan,
            "effect_dz": np.nan,
        }
    rng = np.random.default_rng(seed)
    boot = d[rng.integers(0, n, (BOOTSTRAP, n))].mean(1)
    lo, hi = np.quantile(boot, [0.025, 0.975])
    sd = d.std(ddof=1)
    if np.all(d == 0):
        w_p = t_p = 1.0
    else:
        w_p = float(stats.wilcoxon(d).pvalue)
        t_p = float(stats.ttest_rel(a, b).pvalue) if sd > 0 else 0.0
    return {**out, "ci_low": float(lo), "ci_high": float(hi), "wilcoxon_p": w_p, "ttest_p": t_p,
            "effect_dz": float(d.mean() / sd) if sd > 0 else (0.0 if d.mean() == 0 else float(np.copysign(np.inf, d.mean())))}  # fmt: skip


def _table(records: list[dict], metric: str):
    """{(method, dataset, errors): {variant: {index: value}}} and failure counts."""
    values = defaultdict(lambda: defaultdict(dict))
    failed = defaultdict(int)
    for r in records:
        key = (r["variant"].split("[")[0], r["dataset"], r["errors"])
        values[key].setdefault(r["variant"], {})  # listed even when every cell failed
        if "error" in r:
            failed[(key, r["variant"])] += 1
            continue
        v = r["metrics"].get(metric)
        if v is None or not np.isfinite(v):
            failed[(key, r["variant"])] += 1
            continue
        values[key][r["variant"]][r["index"]] = float(v)
    return values, failed


def _baseline_id(config: dict, variants: dict, method: str) -> str | None:
    from .sweep_methods import resolve_method

    want = {**resolve_method(method).defaults, **config["baseline"]}
    for vid, v in variants.items():
        if (
            v["method"] == method
            and all(v["terms"].values())
            and all(np.isclose(v["weights"][k], want[k]) for k in want)
        ):
            return vid
    return None


def summary_metrics(config: dict) -> list[str]:
    """The primary metric first, then every other metric the methods report (not "cost",
    which measures a different objective for every weight setting)."""
    from .sweep_methods import resolve_method

    out = [config["metric"]]
    for name in config["methods"]:
        out += [m for m in getattr(resolve_method(name), "metrics", ()) if m not in out and m != "cost"]
    return out


def held_out_best(by_var: dict) -> dict | None:
    """Choose on one half of the sequences, score on the other, both ways (cross-fitting).

    by_var: {variant: {sequence index: value}}. Returns the variants chosen on each half, the
    pooled mean over every scored sequence, and n; None when a half is empty.
    """
    index = sorted(set().union(*(set(x) for x in by_var.values())))
    halves = (index[0::2], index[1::2])
    chosen, scored = [], []
    for pick, score in (halves, halves[::-1]):
        means = {
            v: float(np.mean([x[i] for i in pick if i in x])) for v, x in by_var.items() if any(i in x for i in pick)
        }
        if not means or not score:
            return None
        b = min(means, key=means.get)
        chosen.append(b)
        scored += [by_var[b][i] for i in score if i in by_var[b]]
    if not scored:
        return None
    return {"chosen": chosen, "mean": float(np.mean(scored)), "n": len(scored),
            "rule": "chosen on the even-numbered sequences, scored on the odd ones, and the other way round"}  # fmt: skip


def _analyse(records, metric, config, variants):
    values, failed = _table(records, metric)
    rows, analysis = [], {}
    for key, by_var in sorted(values.items()):
        method, dataset, errors = key
        base = _baseline_id(config, variants, method)
        means = {v: float(np.mean(list(x.values()))) for v, x in by_var.items() if x}
        if not means:
            analysis["|".join(key)] = {"baseline": base, "best": None, "variants": {}, "flat_region": [],
                                       "baseline_in_flat_region": None, "all_failed": True}  # fmt: skip
            continue
        best = min(means, key=means.get)
        res = {"baseline": base, "best": best, "best_mean": means[best], "best_held_out": held_out_best(by_var),
               "variants": {}}  # fmt: skip
        for vid, x in sorted(by_var.items()):
            arr = np.asarray(list(x.values()))
            stat = lambda f, arr=arr: float(f(arr)) if len(arr) else float("nan")  # noqa: E731
            row = {"metric": metric, "method": method, "dataset": dataset, "errors": errors, "variant": vid,
                   "n": len(arr), "failed": failed.get((key, vid), 0), "mean": stat(np.mean), "std": stat(np.std),
                   "median": stat(np.median), **{f"w_{k}": w for k, w in variants[vid]["weights"].items()},
                   **{f"term_{t}": on for t, on in variants[vid]["terms"].items()}}  # fmt: skip
            for ref_name, ref in (("baseline", base), ("best", best)):
                if ref is None or not by_var.get(ref) or not len(arr):
                    continue
                common = sorted(set(x) & set(by_var[ref]))
                st = paired_stats([x[i] for i in common], [by_var[ref][i] for i in common])
                row.update({f"vs_{ref_name}_{k}": v for k, v in st.items() if k != "n"})
            row["flat"] = bool(row.get("vs_best_ci_high", np.inf) < FLAT_TOLERANCE * means[best]) or vid == best
            rows.append(row)
            res["variants"][vid] = row
        res["flat_region"] = [v for v, r in res["variants"].items() if r["flat"]]
        res["baseline_in_flat_region"] = None if base is None else base in res["flat_region"]
        analysis["|".join(key)] = res
    return values, rows, analysis


def write_summary(root, config: dict, records: list[dict], variants: dict, log=print) -> dict:
    """Write summary.md, summary.csv, summary.json, cells.csv and the plots into `root`.

    Every metric of `summary_metrics` gets its section; the plots show the primary metric
    (`boxplot.png`, `weights.png`) and the others against the weights (`weights_<metric>.png`).
    """
    root = Path(root)
    metrics = summary_metrics(config)
    analysis, all_rows, text = {}, [], []
    for k, metric in enumerate(metrics):
        values, rows, analysis[metric] = _analyse(records, metric, config, variants)
        all_rows += rows
        text.append(_markdown(config, analysis[metric], metric, len(records), primary=k == 0))
        _plots(root, config, values, variants, metric, analysis[metric], primary=k == 0)
    _write_csv(root / "summary.csv", all_rows)
    _write_csv(root / "cells.csv", [_cell_row(r) for r in records])
    atomic_write(root / "summary.md", "\n".join(text))
    atomic_write(root / "summary.json", json.dumps(analysis, indent=1, default=float))
    log(f"summary: {root / 'summary.md'}")
    return analysis


def _cell_row(r: dict) -> dict:
    row = {k: r.get(k) for k in ("variant", "dataset", "errors", "index")}
    row.update(r.get("metrics", {}))
    row["seconds"] = r.get("seconds")
    row["error"] = r.get("error", "")
    return row


def _write_csv(path: Path, rows: list[dict]) -> None:
    keys = []
    for r in rows:
        keys += [k for k in r if k not in keys]
    buf = io.StringIO()
    w = csv.DictWriter(buf, keys)
    w.writeheader()
    for r in rows:
        w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})
    atomic_write(path, buf.getvalue())


def _markdown(config, analysis, metric, n_records, primary=True) -> str:
    if not primary:
        L = [f"# {metric}", "", "The same comparisons for this metric.", ""]
    else:
        L = [f"# Sweep {config['name']!r}: {metric}", "",
         f"{n_records} cells. Lower is better. Paired statistics over sequences against the baseline "
         "(default weights, every term on): mean difference with bootstrap 95 % CI, Wilcoxon signed-rank "
         f"and paired t p-values, effect size d_z. Flat region: variants whose paired difference to the best "
         f"has a 95 % CI upper end below {FLAT_TOLERANCE:.0%} of the best's mean.", ""]  # fmt: skip
    for key, res in analysis.items():
        method, dataset, errors = key.split("|")
        vs = res["variants"]
        base = res["baseline"]
        L += [f"## {metric}: {method} on {dataset}, sensor errors {errors}", ""]
        if res.get("all_failed"):
            L += ["Every cell failed; see the errors in cells.csv.", ""]
            continue
        L.append(f"- best: `{res['best']}`, mean {metric} {res['best_mean']:.3f} on the sequences that chose it")
        h = res.get("best_held_out")
        if h:
            L.append(f"- the best chosen on half the sequences and scored on the other half (both ways): mean {metric} "
                     f"{h['mean']:.3f} over {h['n']} (chosen: {', '.join(f'`{v}`' for v in dict.fromkeys(h['chosen']))})")  # fmt: skip
        if base in vs:
            b = vs[base]
            L.append(f"- baseline `{base}`: mean {b['mean']:.3f}; vs best {b.get('vs_best_mean_diff', 0):+.3f} "
                     f"(95 % CI {b.get('vs_best_ci_low', 0):+.3f} .. {b.get('vs_best_ci_high', 0):+.3f}, "
                     f"Wilcoxon p = {b.get('vs_best_wilcoxon_p', 1):.2g}) — "
                     f"**{'in' if res['baseline_in_flat_region'] else 'not in'} the flat region**")  # fmt: skip
        else:
            L.append("- the grid has no baseline variant (default weights, all terms on)")
        L.append(f"- flat region: {len(res['flat_region'])} of {len(vs)} variants")
        L += ["", "| variant | n | failed | mean | median | Δ vs baseline [95 % CI] | Wilcoxon p | t-test p | d_z | flat |",
              "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]  # fmt: skip
        order = sorted(vs, key=lambda v: (np.isnan(vs[v]["mean"]), vs[v]["mean"]))
        for vid in order:
            r = vs[vid]
            d = (f"{r['vs_baseline_mean_diff']:+.3f} [{r['vs_baseline_ci_low']:+.3f}, {r['vs_baseline_ci_high']:+.3f}]"
                 if "vs_baseline_mean_diff" in r else "")  # fmt: skip
            L.append(f"| `{vid}` | {r['n']} | {r['failed']} | {r['mean']:.3f} | {r['median']:.3f} | {d} | "
                     f"{r.get('vs_baseline_wilcoxon_p', float('nan')):.2g} | {r.get('vs_baseline_ttest_p', float('nan')):.2g} | "
                     f"{r.get('vs_baseline_effect_dz', float('nan')):+.2f} | {'yes' if r['flat'] else ''} |")  # fmt: skip
        L.append("")
    if primary:
        L += ["Plots: `boxplot.png` (per variant), `weights.png` (mean against each swept weight).", ""]
    else:
        L += [f"Plot: `weights_{metric}.png`.", ""]
    return "\n".join(L)


def _plots(root, config, values, variants, metric, analysis, primary=True) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = sorted(values)
    if primary:
        _boxplot(plt, root, keys, values, metric, analysis)
    _weight_plot(
        plt, root / ("weights.png" if primary else f"weights_{metric}.png"), config, keys, values, variants, metric
    )


#: Axis labels with units of the built-in methods' metrics (others are shown by name).
METRIC_LABELS = {
    "mpjpe": "MPJPE (mm, Procrustes-aligned)",
    "mpjae": "MPJAE (degrees)",
    "cost": "final cost (objective units)",
}


def _metric_label(metric: str, prefix: str = "") -> str:
    return prefix + METRIC_LABELS.get(metric, metric)


def _variant_label(v: str) -> str:
    """'sip[acc=1,ori=2][-limit]' -> 'acc=1 ori=2 -limit' (the method is in the title)."""
    return v.split("[", 1)[-1].rstrip("]").replace("][", " ").replace(",", " ") if "[" in v else v


def _boxplot(plt, root, keys, values, metric, analysis) -> None:
    # About 0.3 inch per variant: labels at a readable size do not overlap.
    n = max(len(values[k]) for k in keys)
    fig, axes = plt.subplots(len(keys), 1, figsize=(max(6.0, 0.3 * n + 2), 4.5 * len(keys)), squeeze=False)
    for ax, key in zip(axes[:, 0], keys):
        by_var = {v: x for v, x in values[key].items() if x}
        if not by_var:
            continue
        order = sorted(by_var, key=lambda v: np.mean(list(by_var[v].values())))
        ax.boxplot([list(by_var[v].values()) for v in order], showfliers=False, widths=0.6)
        ax.set_xticks(range(1, len(order) + 1))
        ax.set_xticklabels(
            [_variant_label(v) for v in order], rotation=60, ha="right", rotation_mode="anchor", fontsize=8
        )
        base = analysis["|".join(key)]["baseline"]
        if base in order:
            ax.axvline(order.index(base) + 1, color="r", lw=0.8, ls="--", label="baseline")
            ax.legend(fontsize=8)
        ax.set(ylabel=_metric_label(metric), xlabel="variant (weights; -term: switched off)",
               title=" / ".join(key) + " (sorted by mean)")  # fmt: skip
    fig.tight_layout()
    fig.savefig(root / "boxplot.png", dpi=110)
    plt.close(fig)


def _weight_plot(plt, path, config, keys, values, variants, metric) -> None:
    swept = list(config["grid"]["weights"])
    if not swept:
        return
    fig, axes = plt.subplots(len(keys), len(swept), figsize=(6.0 * len(swept), 3.4 * len(keys)), squeeze=False)
    for row, key in enumerate(keys):
        means = {v: np.mean(list(x.values())) for v, x in values[key].items() if x}
        for col, w in enumerate(swept):
            ax = axes[row, col]
            others = [o for o in swept if o != w]
            lines = defaultdict(list)
            for v, mval in means.items():
                info = variants[v]
                if w not in info["grid"]:
                    continue
                off = tuple(t for t, on in info["terms"].items() if not on)
                lines[(off, tuple(info["grid"].get(o) for o in others))].append((info["grid"][w], mval))
            cmap = plt.get_cmap("viridis")
            for k, (label, pts) in enumerate(sorted(lines.items(), key=lambda kv: str(kv[0]))):
                pts.sort()
                x, y = zip(*pts)
                # A weight whose term is off has no value ("-term" says so instead).
                parts = [f"{o}={_g(v)}" for o, v in zip(others, label[1]) if v is not None] + [
                    f"-{t}" for t in label[0]
                ]
                ax.plot(
                    x,
                    y,
                    "o-",
                    ms=2.5,
                    lw=0.8,
                    color=cmap(k / max(1, len(lines) - 1)),
                    label=", ".join(parts) or "all on",
                )
            xs = sorted({x for pts in lines.values() for x, _ in pts})
            if xs and min(xs) > 0:
                ax.set_xscale("log")
            elif xs and max(xs) > 0:
                ax.set_xscale("symlog", linthresh=min(x for x in xs if x > 0))
            if xs:
                # Ticks at the swept values only: a log axis over a decade or less labels
                # its minor ticks too, and those labels ran into each other.
                from matplotlib.ticker import NullLocator

                ax.xaxis.set_minor_locator(NullLocator())
                ax.set_xticks(xs, [_g(x) for x in xs], rotation=45 if len(xs) > 4 else 0, fontsize=8)
            ax.set(xlabel=f"weight w_{w}", ylabel=_metric_label(metric, "mean "),
                   title=" / ".join(key))  # fmt: skip
            if lines and len(lines) <= 10:
                ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0)  # off the curves
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _g(v):
    return "" if v is None else f"{v:g}"
