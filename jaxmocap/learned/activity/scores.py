"""How well a classifier does: training curves, confusion matrices and their scores."""

from __future__ import annotations

import equinox as eqx
import numpy as np

__all__ = ["TrainingCurve", "confusion_matrix", "classification_scores"]


class TrainingCurve(eqx.Module):
    """Per epoch (MLP) or per step (CRF): training loss, and validation loss, accuracy and
    macro F1 of the per-frame argmax (NaN without validation data)."""

    loss: np.ndarray
    val_loss: np.ndarray
    val_accuracy: np.ndarray
    val_macro_f1: np.ndarray


def confusion_matrix(truth, predicted, num_classes: int) -> np.ndarray:
    """(C, C) counts, rows the true class, columns the predicted one (negative truth skipped)."""
    truth, predicted = np.asarray(truth), np.asarray(predicted)
    if truth.shape != predicted.shape:
        raise ValueError(f"truth {truth.shape} and predicted {predicted.shape} differ in shape.")
    ok = truth >= 0
    m = np.zeros((num_classes, num_classes), np.int64)
    np.add.at(m, (truth[ok], predicted[ok]), 1)
    return m


def classification_scores(confusion: np.ndarray) -> dict:
    """Accuracy, per-class precision / recall / F1 and macro F1 (mean over classes with
    any true frame) of a confusion matrix."""
    m = np.asarray(confusion, np.float64)
    tp = np.diag(m)
    support = m.sum(1)
    predicted = m.sum(0)
    precision = np.where(predicted > 0, tp / np.maximum(predicted, 1), 0.0)
    recall = np.where(support > 0, tp / np.maximum(support, 1), 0.0)
    f1 = np.where(precision + recall > 0, 2 * precision * recall / np.maximum(precision + recall, 1e-12), 0.0)
    present = support > 0
    return {
        "accuracy": float(tp.sum() / max(m.sum(), 1)),
        "macro_f1": float(f1[present].mean()) if present.any() else float("nan"),
        "precision": precision.tolist(),
        "recall": recall.tolist(),
        "f1": f1.tolist(),
        "support": support.astype(int).tolist(),
    }
