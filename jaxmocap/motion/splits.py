"""Which subjects may shape what: the one place that decides the project's data splits.

A number we publish must come from subjects that shaped nothing it depends on. The corpus
(`jaxmocap.motion.corpus`) holds five CMU subjects; they play three roles:

- **development** (02, 131): everything chosen by looking at results — preset weights,
  tolerances, thresholds, model selection, hyperparameters — is chosen on these only;
- **evaluation** (05, 06, 07): the subjects tables report on;
- **locked** (07): never tunes anything, not even inside a leave-subject-out fold; it is
  the recording kept out of all tuning, so its numbers test the defaults as a new user's
  data would.

Priors and networks are trained leave-subject-out (`fold_training`): a number on subject s
uses a prior or network built without s (`jaxmocap.priors.build.evaluation_prior`, the
DIP folds). A choice made inside such a fold (early stopping on validation clips) may read
the fold's training subjects but never the locked one (`fold_tuning`): `Split(tuning=
LEAVE_SUBJECT_OUT)` records that. Every experiment takes its subjects from a `Split` and writes
`split.record()` into its result file, so a test can check that no table's evaluated
subjects met its tuning or training subjects.

    >>> s = Split("sip_defaults", tuning=DEVELOPMENT, training="leave-subject-out")
    >>> s.evaluation
    ('05', '06', '07')
    >>> s.record()["tuning"]
    ['02', '131']
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Sequence

from .corpus import Clip, corpus

__all__ = [
    "SUBJECTS", "DEVELOPMENT", "EVALUATION", "LOCKED", "LEAVE_SUBJECT_OUT",
    "Split", "fold_training", "fold_tuning", "check_record", "subject_clips",
]  # fmt: skip

SUBJECTS = ("02", "05", "06", "07", "131")
DEVELOPMENT = ("02", "131")
EVALUATION = ("05", "06", "07")
LOCKED = ("07",)
#: `Split.training` value: each evaluated subject's model is trained on every other subject.
LEAVE_SUBJECT_OUT = "leave-subject-out"


def _ids(subjects: Iterable) -> tuple[str, ...]:
    out = []
    for s in subjects:
        s = str(s)
        out.append(f"{int(s):02d}" if s.isdigit() else s)
    return tuple(out)


def fold_training(evaluated: str | Iterable[str], subjects: Sequence[str] = SUBJECTS) -> tuple[str, ...]:
    """The subjects a leave-subject-out fold may train on: every subject but the evaluated."""
    held = set(_ids([evaluated] if isinstance(evaluated, str) else evaluated))
    return tuple(s for s in _ids(subjects) if s not in held)


def fold_tuning(evaluated: str | Iterable[str], subjects: Sequence[str] = SUBJECTS) -> tuple[str, ...]:
    """The subjects a choice inside a leave-subject-out fold may read: the fold's training
    subjects less the locked ones."""
    return tuple(s for s in fold_training(evaluated, subjects) if s not in LOCKED)


@dataclasses.dataclass(frozen=True)
class Split:
    """The subjects one experiment tunes, trains and evaluates on.

    tuning: subjects whose results chose anything (weights, thresholds, settings), or
        `LEAVE_SUBJECT_OUT` (per evaluated subject, inside its fold: `fold_tuning`).
    training: subjects a prior/network/weight was fitted on, or `LEAVE_SUBJECT_OUT`
        (per evaluated subject, every other subject: `fold_training`).
    evaluation: subjects the reported numbers come from.
    Raises ValueError when an evaluated subject is also tuned or trained on, or when a
    locked subject tunes anything.
    """

    name: str
    tuning: tuple[str, ...] | str = DEVELOPMENT
    training: tuple[str, ...] | str = LEAVE_SUBJECT_OUT
    evaluation: tuple[str, ...] = EVALUATION

    def __post_init__(self):
        if self.tuning != LEAVE_SUBJECT_OUT:
            if isinstance(self.tuning, str):
                raise ValueError(
                    f"Split {self.name!r}: tuning must be subjects or {LEAVE_SUBJECT_OUT!r}, got {self.tuning!r}."
                )
            object.__setattr__(self, "tuning", _ids(self.tuning))
        object.__setattr__(self, "evaluation", _ids(self.evaluation))
        if self.training != LEAVE_SUBJECT_OUT:
            if isinstance(self.training, str):
                raise ValueError(
                    f"Split {self.name!r}: training must be subjects or {LEAVE_SUBJECT_OUT!r}, got {self.training!r}."
                )
            object.__setattr__(self, "training", _ids(self.training))
        check_record(self.record())

    def training_for(self, evaluated: str) -> tuple[str, ...]:
        """The subjects a model evaluated on `evaluated` may be trained on."""
        return fold_training(evaluated) if self.training == LEAVE_SUBJECT_OUT else self.training

    def tuning_for(self, evaluated: str) -> tuple[str, ...]:
        """The subjects a choice for `evaluated` may be made on."""
        return fold_tuning(evaluated) if self.tuning == LEAVE_SUBJECT_OUT else self.tuning

    def clips(self, role: str = "evaluation", clips: Sequence[Clip] | None = None) -> list[Clip]:
        """The corpus clips of a role's subjects ("tuning" or "evaluation"), sorted by name."""
        if role not in ("tuning", "evaluation"):
            raise ValueError(f"role must be 'tuning' or 'evaluation', got {role!r}.")
        if getattr(self, role) == LEAVE_SUBJECT_OUT:
            raise ValueError(f"Split {self.name!r}: tuning is per fold; take fold_tuning(evaluated) subjects' clips.")
        return subject_clips(getattr(self, role), clips)

    def record(self) -> dict:
        """What a result file stores under "split" (read back by `check_record`)."""
        training = self.training if isinstance(self.training, str) else list(self.training)
        tuning = self.tuning if isinstance(self.tuning, str) else list(self.tuning)
        return {"name": self.name, "tuning": tuning, "training": training,
                "evaluation": list(self.evaluation), "locked": list(LOCKED)}  # fmt: skip


def check_record(record: dict) -> None:
    """Raise ValueError if a split record lets an evaluated subject shape its own numbers."""
    missing = {"name", "tuning", "training", "evaluation"} - set(record)
    if missing:
        raise ValueError(f"split record lacks {sorted(missing)}: write Split(...).record().")
    for role in ("tuning", "training"):
        if isinstance(record[role], str) and record[role] != LEAVE_SUBJECT_OUT:
            raise ValueError(
                f"split {record['name']!r}: {role} must be subjects or {LEAVE_SUBJECT_OUT!r}, got {record[role]!r}."
            )
    name, ev = record["name"], set(_ids(record["evaluation"]))
    # Per-fold tuning (fold_tuning) never reads the evaluated subject nor the locked one.
    tu = set() if record["tuning"] == LEAVE_SUBJECT_OUT else set(_ids(record["tuning"]))
    if ev & tu:
        raise ValueError(f"split {name!r}: subjects {sorted(ev & tu)} are both tuned and evaluated on.")
    locked = tu & set(_ids(record.get("locked", LOCKED)))
    if locked:
        raise ValueError(f"split {name!r}: the locked subject(s) {sorted(locked)} must not tune anything.")
    if record["training"] != LEAVE_SUBJECT_OUT:
        tr = set(_ids(record["training"]))
        if ev & tr:
            raise ValueError(f"split {name!r}: subjects {sorted(ev & tr)} are both trained and evaluated on.")


def subject_clips(subjects: Iterable[str], clips: Sequence[Clip] | None = None) -> list[Clip]:
    """The clips of `subjects` (default corpus: ../shared/data/cmu and cmu_cc), sorted by name."""
    want = set(_ids(subjects))
    clips = corpus() if clips is None else clips
    return sorted((c for c in clips if c.subject in want), key=lambda c: c.name)
