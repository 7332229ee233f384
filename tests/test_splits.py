"""The data splits (`jaxmocap.motion.splits`) and every result file's record of its split.

Unit tests of `Split` / `check_record`, then the committed results: each JSON under
experiments/results/ that records a "split" must obey it (no evaluated subject tuned or
trained on, the locked subject tuning nothing), as must each entry of provenance.json.
A result file without a split must be listed in `PREDATE_SPLITS` with the reason and the
command that regenerates it: a new result file without a split fails here, and so does a
listed file once it records one (take it off the list).
"""

import json
from fnmatch import fnmatch
from pathlib import Path

import pytest

from jaxmocap.motion.corpus import Clip
from jaxmocap.motion.splits import (
    DEVELOPMENT, EVALUATION, LEAVE_SUBJECT_OUT, LOCKED, SUBJECTS, Split, check_record, fold_training, fold_tuning,
    subject_clips,
)  # fmt: skip

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "experiments" / "results"

# Result files written before the splits existed (2026-11-28), by pattern relative to
# experiments/results: why they carry no split, and what regenerates them (`make tables`
# lists the commands; experiments/make_tables.py TABLES).
PREDATE_SPLITS = {
    "dip_training_curves*.json": "training curves of the DIP folds (leave-subject-out); train_dip.py on the GPU",
    "fuzz.json": "reads no clip: the file readers fuzzed with random bytes (no split applies)",
    "intercap_scene06/metrics.json": "one scene's metrics of intercap_tables.py (GPU)",
    "learn_weights_gradcheck.json": "gradient check on one training clip; learn_weights.py --gradcheck-only",
    "sip_ablation/summary.json": "the sweep's summary (jaxmocap sweep experiments/sweeps/sip_ablation.toml, GPU)",
    "sip_tables.json": "nested tuning let the locked subject 07 tune; sip_tables.py on the GPU",
    "sip_tables_engine_v2_check.json": "compares two sip_tables.json runs (compare_tables.py); no data of its own",
    "vip_association.json": "development seeds drew evaluated subjects' clips; vip_association.py --fusion on the GPU",
    "vip_tables_per_clip/*.json": "vip_tables.py's per-clip cache (its split is vip_tables.json's)",
    "dip_init.json": "dip_init.py on the GPU",
    "learn_weights.json": "trained and tested on subject 02 before 2026-11-28; learn_weights.py (CPU, > 40 min when loaded)",
}


def _clips():
    names = ["02_01.amc", "02_02.amc", "131_01.bvh", "005_01.bvh", "006_02.bvh", "007_03.bvh", "walk"]
    return [Clip(Path(n), n.split("_")[0].lstrip("0").zfill(2) if "_" in n else n) for n in names]


# --- splits.py ------------------------------------------------------------------------


def test_roles_are_disjoint_and_cover_the_subjects():
    assert not set(DEVELOPMENT) & set(EVALUATION)
    assert set(LOCKED) <= set(EVALUATION)
    assert set(DEVELOPMENT) | set(EVALUATION) == set(SUBJECTS)


def test_default_split_records_and_checks():
    s = Split("x")
    r = s.record()
    assert r == {"name": "x", "tuning": ["02", "131"], "training": LEAVE_SUBJECT_OUT,
                 "evaluation": ["05", "06", "07"], "locked": ["07"]}  # fmt: skip
    check_record(json.loads(json.dumps(r)))  # what a result file reads back


def test_subject_ids_are_normalised():
    s = Split("x", tuning=(2, "131"), training=("002",), evaluation=("5",))
    assert s.tuning == ("02", "131") and s.training == ("02",) and s.evaluation == ("05",)


@pytest.mark.parametrize("kwargs, message", [
    ({"tuning": ("02", "05")}, "both tuned and evaluated"),
    ({"training": ("131", "06")}, "both trained and evaluated"),
    ({"tuning": ("07",), "evaluation": ("05",)}, "locked"),
    ({"tuning": ("7",), "evaluation": ()}, "locked"),
    ({"training": "all"}, "training must be"),
])  # fmt: skip
def test_split_refuses_leaks(kwargs, message):
    with pytest.raises(ValueError, match=message):
        Split("leaky", **kwargs)


@pytest.mark.parametrize("record, message", [
    ({"name": "a", "tuning": ["05"], "training": LEAVE_SUBJECT_OUT, "evaluation": ["5"]}, "both tuned and evaluated"),
    ({"name": "a", "tuning": [], "training": ["06"], "evaluation": ["06"]}, "both trained and evaluated"),
    ({"name": "a", "tuning": ["07"], "training": [], "evaluation": []}, "locked"),
    ({"name": "a", "tuning": ["02"], "evaluation": ["05"]}, "lacks"),
])  # fmt: skip
def test_check_record_refuses_leaky_records(record, message):
    with pytest.raises(ValueError, match=message):
        check_record(record)


def test_locked_defaults_when_a_record_omits_it():
    with pytest.raises(ValueError, match="locked"):
        check_record({"name": "a", "tuning": ["07"], "training": [], "evaluation": []})


def test_leave_subject_out_folds():
    assert fold_training("05") == ("02", "06", "07", "131")
    assert fold_training(["5", "131"]) == ("02", "06", "07")
    s = Split("folds", training=LEAVE_SUBJECT_OUT)
    for subject in s.evaluation:
        assert subject not in s.training_for(subject)
        assert set(s.training_for(subject)) | {subject} == set(SUBJECTS)
    fixed = Split("fixed", training=DEVELOPMENT)
    assert fixed.training_for("06") == DEVELOPMENT


def test_clips_by_role():
    s = Split("x")
    clips = _clips()
    assert [c.name for c in s.clips("tuning", clips)] == ["02_01.amc", "02_02.amc", "131_01.bvh"]
    assert [c.name for c in s.clips("evaluation", clips)] == ["005_01.bvh", "006_02.bvh", "007_03.bvh"]
    assert [c.name for c in subject_clips(["131"], clips)] == ["131_01.bvh"]
    with pytest.raises(ValueError, match="role"):
        s.clips("training", clips)


# --- the committed results ------------------------------------------------------------


def _result_files():
    return sorted(p for p in RESULTS.rglob("*.json") if p.name != "provenance.json")


def _listed(rel: str) -> str | None:
    return next((k for k in PREDATE_SPLITS if fnmatch(rel, k)), None)


def test_there_are_results():
    assert len(_result_files()) > 10


@pytest.mark.parametrize("path", _result_files(), ids=lambda p: str(p.relative_to(RESULTS)))
def test_every_result_obeys_its_split(path):
    rel = str(path.relative_to(RESULTS))
    data = json.loads(path.read_text())
    if isinstance(data, dict) and "split" in data and isinstance(data["split"], dict) and "evaluation" in data["split"]:
        check_record(data["split"])
        assert _listed(rel) is None, f"{rel} now records its split: take {_listed(rel)!r} off PREDATE_SPLITS"
    else:
        assert _listed(rel), (
            f"{rel} records no split: write it with experiments/_provenance.write_json(..., split=Split(...)) "
            "(or, for a file that predates the splits, list it in PREDATE_SPLITS with the command that regenerates it)"
        )


def test_predate_list_names_existing_files():
    rels = [str(p.relative_to(RESULTS)) for p in _result_files()]
    stale = [k for k in PREDATE_SPLITS if not any(fnmatch(r, k) for r in rels)]
    assert not stale, f"PREDATE_SPLITS lists files that are gone: {stale}"


def test_provenance_entries():
    prov = RESULTS / "provenance.json"
    assert prov.exists(), "experiments/results/provenance.json is missing: make tables writes it"
    files = json.loads(prov.read_text())["files"]
    for rel, entry in files.items():
        assert (ROOT / rel).exists(), f"provenance.json lists {rel}, which does not exist"
        assert {"commit", "command", "split", "data", "date", "machine"} <= set(entry), rel
        assert entry["command"].startswith("python "), rel
        if entry["split"] is not None:
            check_record(entry["split"])
        path = ROOT / rel
        if path.suffix == ".json" and entry["split"] is not None:
            recorded = json.loads(path.read_text()).get("split")
            assert recorded == entry["split"], f"{rel}: its split differs from its provenance entry's"


def test_tuning_inside_the_folds_never_reads_the_locked_subject():
    s = Split("dip", tuning=LEAVE_SUBJECT_OUT, training=LEAVE_SUBJECT_OUT)
    assert s.record()["tuning"] == LEAVE_SUBJECT_OUT
    for subject in SUBJECTS:
        assert subject not in s.tuning_for(subject) and not set(LOCKED) & set(s.tuning_for(subject))
    assert fold_tuning("05") == ("02", "06", "131")
    with pytest.raises(ValueError, match="per fold"):
        s.clips("tuning", _clips())
    with pytest.raises(ValueError, match="tuning must be"):
        check_record({"name": "a", "tuning": "everyone", "training": [], "evaluation": ["05"]})


# Experiments that write no result file through experiments/_provenance.py: why.
WITHOUT_PROVENANCE = {
    "make_datasets.py": "writes benchmark datasets into a cache folder, no result",
    "build_default_body.py": "builds the shipped default body (jaxmocap/body/data/*.npz), no result; the files "
    "record their source and the data README how they were made",
    "vip_association_unseen.py": "adds its blocks, each with its own split record, into vip_association.json "
    "(and retrains the shipped weights file); not yet recorded in provenance.json",
}


def test_every_experiment_writes_through_the_provenance_helper():
    missing = [p.name for p in sorted((ROOT / "experiments").glob("*.py"))
               if not p.name.startswith("_") and p.name not in WITHOUT_PROVENANCE and p.name != "make_tables.py"
               and "_provenance" not in p.read_text()]  # fmt: skip
    assert not missing, f"{missing} write results without experiments/_provenance.py (write_json / write_text / record)"


# --- the helpers that write results -----------------------------------------------------


def _provenance_module():
    import importlib.util

    spec = importlib.util.spec_from_file_location("_provenance", ROOT / "experiments" / "_provenance.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_results_are_written_with_their_split_and_provenance(tmp_path):
    prov = _provenance_module()
    folder = tmp_path / "results" / "sub"
    split = Split("unit", tuning=DEVELOPMENT, training=LEAVE_SUBJECT_OUT)
    path = prov.write_json(
        folder / "table.json", {"x": 1.0}, split=split, data={"clips": ["005_01.bvh"]}, argv=["--n", "2"]
    )
    prov.write_text(tmp_path / "results" / "table.md", "# t\n", split=split, data={"clips": []})
    assert json.loads(path.read_text()) == {"x": 1.0, "split": split.record()}
    files = json.loads((tmp_path / "results" / "provenance.json").read_text())["files"]
    entry = files[str(path.resolve())]
    assert entry["split"] == split.record() and entry["data"] == {"clips": ["005_01.bvh"]}
    assert entry["command"].endswith("--n 2") and entry["command"].startswith("python ")
    assert len(entry["commit"].split("+")[0]) in (40, len("unknown")) and entry["date"].endswith("+00:00")
    assert str((tmp_path / "results" / "table.md").resolve()) in files
    with pytest.raises(ValueError, match="both tuned and evaluated"):
        prov.write_json(folder / "leaky.json", {}, split={"name": "l", "tuning": ["05"], "training": [], "evaluation": ["05"]},
                        data={})  # fmt: skip
    assert not (folder / "leaky.json").exists()


def test_a_sweeps_best_is_scored_on_sequences_that_did_not_choose_it():
    from jaxmocap.app.sweep_report import held_out_best

    # "a" wins on the even sequences by luck, "b" on the odd ones: neither is scored where it won.
    by_var = {"a": {0: 1.0, 1: 3.0, 2: 1.0, 3: 3.0}, "b": {0: 2.0, 1: 2.0, 2: 2.0, 3: 2.0}}
    h = held_out_best(by_var)
    assert h["chosen"] == ["a", "b"] and h["n"] == 4 and h["mean"] == pytest.approx(2.5)
    assert held_out_best({"a": {0: 1.0}}) is None
