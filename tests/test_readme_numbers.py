"""The README quotes results and configs: each quote is read from the file it names.

`QUOTES` pairs a sentence of the README (a regular expression whose groups are the quoted
numbers) with the JSON file and keys the numbers come from and the rounding the README
uses. A re-run that moves a number, or an edit of the README, fails here until both agree.
A config the README shows "in full" must parse to the same TOML as the file.
"""

import json
import math
import re
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()


def _key(path: str, keys: str):
    value = json.loads((ROOT / path).read_text())
    for k in keys.split("."):
        value = value[k]
    return value


# (README pattern, file, [key per group], [decimals per group])
QUOTES = [
    (
        r"four H200s: ([\d.]+) s on one, ([\d.]+) s on two \(([\d.]+)×\), ([\d.]+) s on four \(\*\*([\d.]+)×\*\*\)",
        "benchmarks/results/sweep_scale_x4.json",
        ["batch.wall_s", "multi_gpu.2.wall_s", "speedup_2_gpus", "multi_gpu.4.wall_s", "speedup_4_gpus"],
        [2, 2, 2, 2, 2],
    ),
    (
        r"SIP \(1000 frames\) ([\d.]+) s cold, ([\d.]+) s warm, run ([\d.]+) s \(([\d.]+) s every run before\)",
        "benchmarks/results/cold_start_gpu.json",
        [
            "entries.sip.cold_compile_s",
            "entries.sip.warm_compile_s",
            "entries.sip.run_s",
            "before.entries.sip.cold_compile_s",
        ],
        [1, 2, 3, 1],
    ),
    (
        r"SIP batch 1000 x 1000 ([\d.]+) s cold, ([\d.]+) s warm, run ([\d.]+) s \(([\d.]+) s every run before\)",
        "benchmarks/results/cold_start_gpu.json",
        [
            "entries.sip_batch.cold_compile_s",
            "entries.sip_batch.warm_compile_s",
            "entries.sip_batch.run_s",
            "before.entries.sip_batch.cold_compile_s",
        ],
        [1, 2, 1, 1],
    ),
    (
        r"SOP ([\d.]+) s cold, ([\d.]+) s warm, run ([\d.]+) s;",
        "benchmarks/results/cold_start_gpu.json",
        ["entries.sop.cold_compile_s", "entries.sop.warm_compile_s", "entries.sop.run_s"],
        [1, 2, 1],
    ),
    (
        r"CPU, 60 frames: SIP ([\d.]+) s cold, ([\d.]+) s warm \(([\d.]+) s at \w+, the commit before, in the same "
        r"run\), SOP ([\d.]+) s cold, ([\d.]+) s warm \(([\d.]+) s\), Multi-view SMPLify ([\d.]+) s cold, ([\d.]+) s "
        r"warm \(([\d.]+) s\); `jaxmocap demo` ([\d.]+) s cold, ([\d.]+) s warm",
        "benchmarks/results/cold_start.json",
        [
            "entries.sip.cold_compile_s",
            "entries.sip.warm_compile_s",
            "before.entries.sip.cold_compile_s",
            "entries.sop.cold_compile_s",
            "entries.sop.warm_compile_s",
            "before.entries.sop.cold_compile_s",
            "entries.multiview.cold_compile_s",
            "entries.multiview.warm_compile_s",
            "before.entries.multiview.cold_compile_s",
            "entries.make_demo.cold_wall_s",
            "entries.make_demo.warm_wall_s",
        ],
        [1, 2, 1, 1, 2, 1, 1, 2, 1, 1, 1],
    ),
    (
        r"MLP macro F1 ([\d.]+), MLP \+ CRF accuracy ([\d.]+) / macro F1 ([\d.]+)\s+\(([\d.]+) on the evaluation"
        r" subjects 05, 06, 07 alone\), against accuracy ([\d.]+) / macro F1\s+([\d.]+) for always",
        "experiments/results/har.json",
        [
            "macro_f1_mlp",
            "accuracy_crf",
            "macro_f1_crf",
            "evaluation_subjects_only.macro_f1_crf",
            "baseline_constant_most_frequent_test_class.accuracy",
            "baseline_constant_most_frequent_test_class.macro_f1",
        ],
        [3, 3, 3, 3, 3, 3],
    ),
    (
        r"The thesis's own input and MLP, same labels and folds, reach\s+macro F1 ([\d.]+) → ([\d.]+)",
        "experiments/results/har.json",
        ["comparison.macro_f1_mlp", "comparison.macro_f1_crf"],
        [3, 3],
    ),
    (
        r"the fit's median reprojection is ([\d.]+) px against ([\d.]+) px for a per-keypoint triangulation\s+"
        r"of the same detections \(`fit_over_triangulation` ([\d.]+); held out: ([\d.]+) / ([\d.]+) px, ([\d.]+)\):",
        "experiments/results/multiview_real.json",
        [
            "recordings.Demo_SinglePerson.reprojection_px.fit_median",
            "recordings.Demo_SinglePerson.reprojection_px.triangulation_median",
            "recordings.Demo_SinglePerson.fit_over_triangulation",
            "recordings.Demo_MultiPerson.reprojection_px.fit_median",
            "recordings.Demo_MultiPerson.reprojection_px.triangulation_median",
            "recordings.Demo_MultiPerson.fit_over_triangulation",
        ],
        [1, 1, 2, 1, 1, 2],
    ),
    (
        r"`Demo_MultiPerson` held out; ([\d.]+) s in all here, 2 cores shared at a load of ([\d.]+)-([\d.]+), of which\s+"
        r"the detector ([\d.]+) and ([\d.]+) s for a recording's 400 frames\)",
        "experiments/results/multiview_real.json",
        [
            "run_time_s",
            "load_average.start",
            "load_average.end",
            "recordings.Demo_SinglePerson.run_time_s.detector",
            "recordings.Demo_MultiPerson.run_time_s.detector",
        ],
        [0, 0, 0, 0, 0],
    ),
    (
        r"up\s+to ([\d.]+) % \(held out ([\d.]+) %: the held-out subject's\s+triangulated legs[^)]*\), while its limb points jitter an\s+"
        r"eighth as much \(([\d.]+) against ([\d.]+) m/s²\)",
        "experiments/results/multiview_real.json",
        [
            "recordings.Demo_SinglePerson.limb_length_error_max_pct",
            "recordings.Demo_MultiPerson.limb_length_error_max_pct",
            "recordings.Demo_SinglePerson.jitter_m_s2.fit_limb_keypoints",
            "recordings.Demo_SinglePerson.jitter_m_s2.triangulated_limb_keypoints",
        ],
        [1, 1, 1, 1],
    ),
    # "at both resolutions": the low- and the high-resolution stage 1 must both read as quoted.
    *(
        (
            r"`experiments/results/muvs_resolution.json`: stage 1 ([\d.]+) mm at both resolutions, stage 2 ([\d.]+)\s+"
            r"against ([\d.]+) mm; in raw pixels ([\d.]+) / ([\d.]+) mm\)",
            "experiments/results/muvs_resolution.json",
            [
                f"mpjpe_mm.{resolution}.stage1",
                "mpjpe_mm.high_resolution.stage2",
                "mpjpe_mm.low_resolution.stage2",
                "mpjpe_mm.high_resolution_raw_pixels.stage1",
                "mpjpe_mm.high_resolution_raw_pixels.stage2",
            ],
            [1, 1, 1, 1, 1],
        )
        for resolution in ("low_resolution", "high_resolution")
    ),
    # The InterCap table's two fitted rows (MPJPE, object ADD-S, contact gap).
    *(
        (
            rf"\| {label} \| [\d /%]+ \| [\d.]+ \| ([\d.]+) \| [\d.]+ \| [\d.]+ \| ([\d.]+) \| ([\d.]+) \|",
            "experiments/results/intercap_tables.json",
            [f"table.{row}.contact_gap_mm", f"table.{row}.mpjpe_mm", f"table.{row}.add_s_mm"],
            [1, 1, 1],
        )
        for label, row in (("separate fits", "separate"), ("joint, detected contact", "joint"))
    ),
    # One view with the floor term (muvs_monocular): stage 2's unaligned error, placed -> floor, and the aligned one.
    (
        r"unaligned error after stage 2 falls from\s+([\d.]+) to ([\d.]+) mm, [\d.]+x the aligned ([\d.]+) mm",
        "experiments/results/muvs_monocular.json",
        [
            "variants.placed.mpjpe.S_T_H.unaligned_mm",
            "variants.floor_term.mpjpe.S_T_H.unaligned_mm",
            "variants.floor_term.mpjpe.S_T_H.aligned_mm",
        ],
        [0, 0, 0],
    ),
    # MuVS with four views, the default column of each stage.
    (
        r"\| 4 \| ([\d.]+) / [\d.]+ \| ([\d.]+) / [\d.]+ \| ([\d.]+) / [\d.]+ \| ([\d.]+) / [\d.]+ \|",
        "experiments/results/muvs_tables.json",
        ["mpjpe_mm.views_4.stage1", "mpjpe_mm.views_4.S", "mpjpe_mm.views_4.S_T", "mpjpe_mm.views_4.S_T_H"],
        [1, 1, 1, 1],
    ),
    (
        r"`make demo`: ([\d.]+) s the first time,\s+([\d.]+) s after",
        "benchmarks/results/cold_start.json",
        ["entries.make_demo.cold_wall_s", "entries.make_demo.warm_wall_s"],
        [1, 1],
    ),
]


@pytest.mark.parametrize(
    "pattern, path, keys, decimals", QUOTES, ids=[q[1].split("/")[-1] + ":" + q[2][0] for q in QUOTES]
)
def test_quoted_numbers_match_their_files(pattern, path, keys, decimals):
    matches = re.findall(pattern, README)
    assert matches, f"the README no longer says {pattern!r}; update QUOTES with the sentence that quotes {path}"
    for found in matches:
        found = (found,) if isinstance(found, str) else found
        for text, key, d in zip(found, keys, decimals, strict=True):
            assert f"{_key(path, key):.{d}f}" == text, (
                f"README says {text} for {path}:{key}, the file has {_key(path, key)}"
            )


def _toml_block_after(marker: str) -> dict:
    tail = README[README.index(marker) :]
    block = re.search(r"```toml\n(.*?)```", tail, re.S)
    return tomllib.loads(block.group(1))


def test_the_sweep_config_shown_in_full_is_the_file():
    shown = _toml_block_after("(`experiments/sweeps/sip_ablation.toml` in full)")
    with open(ROOT / "experiments" / "sweeps" / "sip_ablation.toml", "rb") as f:
        assert shown == tomllib.load(f)


def test_sop_start_quotes():
    gpu = _key("benchmarks/results/cold_start_gpu.json", "entries.sop_batched.run_s")
    res = json.loads((ROOT / "experiments/results/sop_start.json").read_text())
    m = re.search(r"takes ([\d.]+) s there, but on (\d+) held-out cmu_cc clips SIP.*?from that\s+start is ([\d.]+) % worse in\s+"
                  r"MPJPE.*?SIP from x₀\s+itself is ([\d.]+) % worse", README, re.S)  # fmt: skip
    assert m, "the README's paragraph on the batched SOP start changed; update this test"
    assert m.group(1) == f"{gpu:.3f}" and int(m.group(2)) == len(res["clips"])
    assert m.group(3) == f"{res['sip_batched_vs_sequential_mpjpe_percent']:.1f}"
    assert m.group(4) == f"{res['sip_x0_vs_sequential_mpjpe_percent']:.1f}"


def test_defaults_quotes():
    res = json.loads((ROOT / "experiments/results/defaults.json").read_text())
    v = res["evaluation"]["mean"]["sip_validated"]
    row = re.search(r"\| \*\*validated \(default\)\*\* \| ([\d.]+) \| ([\d.]+) \| (\d+) % \|", README)
    assert row, "the README's defaults table changed; update this test"
    assert row.groups() == (f"{v['mpjpe_mm']:.1f}", f"{v['mpjae_deg']:.2f}", f"{100 * v['converged']:.0f}")
    m = re.search(r"With the defaults SIP is ([\d.]+) % better than SOP in MPJPE.*?and ([\d.]+) % better than the\s+converged",
                  README, re.S)  # fmt: skip
    assert m and res["sip_vs_sop_percent"] < 0 and res["sip_default_vs_best_percent"] < 0
    assert m.groups() == (f"{-res['sip_vs_sop_percent']:.1f}", f"{-res['sip_default_vs_best_percent']:.1f}")


def _range(values, d: int = 2) -> str:
    """The README's way of quoting several values: "0.05" when they round alike, else "lo-hi"."""
    lo, hi = f"{min(values):.{d}f}", f"{max(values):.{d}f}"
    return lo if lo == hi else f"{lo}-{hi}"


def test_multiview_layout_margins_quotes():
    res = json.loads((ROOT / "experiments/results/multiview_layout_margins.json").read_text())
    m = re.search(r"multiview_layout_margins\.py`: on a simulated walk with 3 px noise the\s+true layout scores "
                  r"([\d.-]+) against ([\d.-]+) for the other, one camera ([\d.-]+) against ([\d.-]+),\s+and the "
                  r"other scores at least ([\d.]+)x the true one", README)  # fmt: skip
    assert m, "the README's sentence on the layout margins changed; update this test"
    four, one = ([r for r in res["rows"] if r["case"] == "noise 3 px" and r["views"] == v] for v in (4, 1))
    assert m.groups() == (
        _range([r["score_true"] for r in four]),
        _range([r["score_other"] for r in four]),
        _range([r["score_true"] for r in one]),
        _range([r["score_other"] for r in one]),
        f"{math.floor(10 * res['min_ratio']) / 10:.1f}",
    )


def test_vip_tables_quotes():
    res = json.loads((ROOT / "experiments/results/vip_tables.json").read_text())
    rows, cfg, a = res["rows"], res["config"], res["association"]
    m = re.search(r"\*\*(\d+) of the (\d+)\s+clips\*\*.*?IT ([\d.]+) mm → VIP ([\d.]+) mm \(−([\d.]+) %; thesis −53 %\), "
                  r"VIP-2D ([\d.]+) < VIP < VIP-vanilla ([\d.]+) and\s+6 IMUs ([\d.]+) mm.*?bystanders reaches "
                  r"([\d.]+) % / ([\d.]+) %", README, re.S)  # fmt: skip
    assert m, "the README's sentence on experiments/vip_tables.py changed; update this test"
    mm = lambda k: f"{rows[k]['mpjpe_mm']:.1f}"  # noqa: E731
    assert m.groups() == (
        str(cfg["clips"]), str(cfg["requested_clips"]), mm("IT"), mm("VIP"),
        f"{-res['vip_vs_it_relative_change_percent']['mpjpe']:.1f}", mm("VIP-2D"), mm("VIP-vanilla"), mm("VIP-6IMU"),
        f"{100 * a['precision']:.1f}", f"{100 * a['recall']:.1f}",
    )  # fmt: skip


def test_vip_association_fresh_set_quotes():
    res = json.loads((ROOT / "experiments/results/vip_association.json").read_text())
    fresh, first = res["defaults_unseen_seed1"], res["defaults_unseen"]
    m = re.search(r"\(([\d.]+) % / ([\d.]+) % there, [\d.]+ % / [\d.]+ % before the check\).*?final association reaches "
                  r"([\d.]+) % precision and\s+([\d.]+) % recall over (\d+) scenes", README, re.S)  # fmt: skip
    assert m, "the README's sentence on the association's evaluation sets changed; update this test"
    pct = lambda x: f"{100 * x:.1f}"  # noqa: E731
    assert m.groups() == (
        pct(first["final_round"]["precision"]), pct(first["final_round"]["recall"]),
        pct(fresh["final_round"]["precision"]), pct(fresh["final_round"]["recall"]), str(fresh["scenes"]),
    )  # fmt: skip
