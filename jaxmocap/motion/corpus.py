"""The motion clips the project can read, with subject and activity: the one place that says
which clips may shape a prior and which a number is measured on.

Every clip belongs to one CMU subject. Evaluation is subject-disjoint: a number measured
on subject s comes from a prior (or weight, or network) built without any clip of s
(`training_clips(exclude=...)`, `jaxmocap.priors.held_out_prior`). The bundled prior uses
every clip, so it must never be evaluated on them.

    >>> clips = corpus()                      # ../shared/data/cmu and cmu_cc, where present
    >>> sorted({c.subject for c in clips})
    ['02', '05', '06', '07', '131']

Activities: `activity` is what the clip shows (walk, run, dance, basketball, ...);
`group` is the Table 3.4 category of von Marcard's TotalCapture evaluation it stands in
for: walking; freestyle (fast, whole-body motion: run, jump, swordplay, dance,
basketball); acting (slow upper-body actions: punch, bend and lift, wash).
"""

from __future__ import annotations

import csv
import dataclasses
import re
from pathlib import Path
from typing import Iterable, Sequence

__all__ = [
    "Clip",
    "corpus",
    "subject_of",
    "training_clips",
    "interleave",
    "find_cmu_cc_dir",
    "GROUPS",
    "MOTION_SUFFIXES",
]

MOTION_SUFFIXES = (".amc", ".bvh", ".npz")
GROUPS = ("walking", "freestyle", "acting")

#: The subject-02 and 131 clips of ../shared/data/cmu (its README lists them).
_CMU_ACTIVITIES = {
    "02_01": "walk", "02_02": "walk", "02_03": "run", "02_04": "jump", "02_05": "punch",
    "02_06": "bend and lift", "02_07": "swordplay", "02_09": "wash", "131_01": "walk",
}  # fmt: skip
_GROUP_OF = {
    "walk": "walking", "slow walk": "walking", "brisk walk": "walking", "run": "freestyle", "jump": "freestyle",
    "swordplay": "freestyle", "dance": "freestyle", "basketball": "freestyle", "punch": "acting",
    "bend and lift": "acting", "wash": "acting",
}  # fmt: skip


@dataclasses.dataclass(frozen=True)
class Clip:
    """One motion file: path, CMU subject (zero-padded to 2 digits), activity and group."""

    path: Path
    subject: str
    activity: str = "unknown"
    group: str = "unknown"

    @property
    def name(self) -> str:
        return self.path.name


def subject_of(path) -> str:
    """The CMU subject of a clip named like `02_01.amc` or `005_12.bvh`: '02', '05'.

    Raises ValueError for a name without the SUBJECT_TRIAL pattern (pass `subject=`
    explicitly, or rename the file).
    """
    m = re.match(r"^(\d+)_(\d+)", Path(path).stem)
    if m is None:
        raise ValueError(
            f"cannot tell the subject of {Path(path).name}: expected a CMU name SUBJECT_TRIAL (e.g. 02_01.amc); "
            "rename the file or build the Clip yourself."
        )
    return f"{int(m.group(1)):02d}"


def _cc_activities(folder: Path) -> dict[str, str]:
    """Trial -> activity from the cmu_cc index.csv ("dance - ...", "walk", "basketball - ...")."""
    index = folder / "index.csv"
    if not index.is_file():
        return {}
    out = {}
    with index.open(newline="") as f:
        for row in csv.DictReader(f):
            stem = f"{int(row['Subject']):03d}_{int(row['Trial #']):02d}"
            out[stem] = row["Motion Description"].split(" - ")[0].strip().lower()
    return out


def find_cmu_cc_dir() -> Path | None:
    """The CMU clips on the CC rig: $JAXMOCAP_CMU_CC, else `shared/data/cmu_cc` beside the repository."""
    from .io import find_data_dir

    return find_data_dir("JAXMOCAP_CMU_CC", "cmu_cc")


def corpus(folders: Iterable | None = None) -> list[Clip]:
    """Every motion file in `folders` (default: the CMU and CMU-CC folders found), sorted.

    Files whose name does not follow CMU's SUBJECT_TRIAL pattern get the subject of their
    file stem (each is its own subject).
    """
    if folders is None:
        from .io import find_cmu_dir

        folders = [d for d in (find_cmu_dir(), find_cmu_cc_dir()) if d is not None]
    clips = []
    for folder in folders:
        folder = Path(folder)
        if not folder.is_dir():
            raise FileNotFoundError(f"motion folder {folder} does not exist.")
        cc = _cc_activities(folder)
        for path in sorted(p for p in folder.rglob("*") if p.suffix.lower() in MOTION_SUFFIXES):
            try:
                subject = subject_of(path)
            except ValueError:
                subject = path.stem
            activity = _CMU_ACTIVITIES.get(path.stem) or cc.get(path.stem, "unknown")
            clips.append(Clip(path, subject, activity, _GROUP_OF.get(activity, "unknown")))
    return clips


def training_clips(clips: Sequence[Clip], exclude: Iterable[str] = ()) -> list[Clip]:
    """The clips whose subject is not in `exclude` (subject ids as `subject_of` gives them)."""
    exclude = {f"{int(s):02d}" if str(s).isdigit() else str(s) for s in exclude}
    return [c for c in clips if c.subject not in exclude]


def interleave(items: Iterable, n: int, key=lambda c: c.subject) -> list:
    """The first `n` items taking one per group in turn (groups by `key`, sorted; order kept
    within a group): an evaluation set that spreads over subjects before repeating one."""
    groups: dict = {}
    for item in items:
        groups.setdefault(key(item), []).append(item)
    queues = [groups[k] for k in sorted(groups)]
    order = []
    while len(order) < n and any(queues):
        for q in queues:
            if q and len(order) < n:
                order.append(q.pop(0))
    return order
