"""A trained recogniser (standardiser, MLP, CRF, class names) and its file."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from .._weights import fill_module, read_header, save_module
from .crf import ActivityCRF, decode
from .features import WINDOW, Standardiser, window_features
from .mlp import ActivityMLP, mlp_log_probs
from .readings import NUM_CHANNELS, WATCH_RATE

__all__ = ["ActivityClassifier", "ActivityModelError", "save_classifier", "load_classifier"]


FORMAT = "jaxmocap-activity"
FORMAT_VERSION = 1


class ActivityModelError(ValueError):
    """A classifier file that cannot be read or does not match (names the file and the fix)."""


class ActivityClassifier(eqx.Module):
    """A trained recogniser: standardiser, MLP, CRF and the class names."""

    standardiser: Standardiser
    mlp: ActivityMLP
    crf: ActivityCRF
    classes: tuple[str, ...] = eqx.field(static=True)
    window: int = eqx.field(static=True, default=WINDOW)
    rate: float = eqx.field(static=True, default=WATCH_RATE)

    def __check_init__(self):
        C = len(self.classes)
        if self.mlp.num_classes != C or self.crf.transitions.shape != (C, C):
            raise ValueError(
                f"{C} class names, but the MLP has {self.mlp.num_classes} outputs and the CRF "
                f"{self.crf.transitions.shape} transitions."
            )
        if self.mlp.in_size != NUM_CHANNELS * self.window:
            raise ValueError(
                f"the MLP takes {self.mlp.in_size} inputs; a window of {self.window} frames gives {NUM_CHANNELS * self.window}."
            )

    def features(self, readings) -> Array:
        """Standardised window features (N, 6 · window) of (N, 6) raw readings."""
        return window_features(self.standardiser(readings), self.window)

    def log_probs(self, readings) -> Array:
        """Per-frame log p_MLP (N, C) of one sequence of (N, 6) raw readings."""
        return mlp_log_probs(self.mlp, self.features(readings))

    def predict(self, readings, use_crf: bool = True) -> np.ndarray:
        """(N,) class indices: Viterbi over the CRF (or the per-frame argmax)."""
        lp = self.log_probs(readings)
        if not use_crf:
            return np.asarray(jnp.argmax(lp, -1), np.int32)
        return decode(self.crf, [lp])[0]


def save_classifier(path, classifier: ActivityClassifier, meta: dict | None = None) -> Path:
    """Write the classifier (weights, standardisation, CRF, class names, `meta` as JSON)
    to an npz file, atomically."""
    path = Path(path)
    if path.suffix != ".npz":
        path = path.with_name(path.name + ".npz")
    header = {
        "format": FORMAT,
        "version": FORMAT_VERSION,
        "classes": list(classifier.classes),
        "window": classifier.window,
        "rate": classifier.rate,
        "hidden": list(classifier.mlp.hidden),
        "dropout": classifier.mlp.dropout,
        "meta": meta or {},
    }
    return save_module(path, classifier, header)


def load_classifier(path, classes: Sequence[str] | None = None) -> tuple[ActivityClassifier, dict]:
    """(classifier, meta) from a `save_classifier` file. With `classes`, the file's class
    names must equal them (in order). `ActivityModelError` names what does not match."""
    header, arrays = read_header(path, FORMAT, FORMAT_VERSION, ActivityModelError,
                                 "jaxmocap.learned.activity.save_classifier")  # fmt: skip
    names = tuple(header.get("classes", ()))
    if classes is not None and tuple(classes) != names:
        raise ActivityModelError(f"{path}: the classifier knows classes {list(names)}, not {list(classes)}.")
    try:
        window, C = int(header["window"]), len(names)
        skeleton = ActivityClassifier(
            Standardiser(jnp.zeros(NUM_CHANNELS), jnp.ones(NUM_CHANNELS)),
            ActivityMLP(C, jax.random.PRNGKey(0), NUM_CHANNELS * window, header["hidden"], header["dropout"]),
            ActivityCRF(jnp.zeros((C, C)), jnp.zeros(())),
            names,
            window,
            float(header["rate"]),
        )
    except (KeyError, TypeError, ValueError) as e:
        raise ActivityModelError(f"{path}: bad classifier configuration ({e}).") from None
    return fill_module(skeleton, header, arrays, path, ActivityModelError), header.get("meta", {})
