"""The per-frame classifier (Fig. 7.6) and its training (package docstring, step 3)."""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..._checks import check_finite
from .features import WINDOW
from .readings import NUM_CHANNELS
from .scores import TrainingCurve, classification_scores, confusion_matrix

__all__ = ["ActivityMLP", "mlp_log_probs", "class_weights", "train_mlp"]


class ActivityMLP(eqx.Module):
    """The per-frame classifier of Fig. 7.6: 360 → 1024 → 512 → 60 → C; each hidden layer
    followed by ReLU and Dropout (rate 0.5)."""

    layers: tuple[eqx.nn.Linear, ...]
    dropout: float = eqx.field(static=True)

    def __init__(
        self,
        num_classes: int,
        key: Array,
        in_size: int = NUM_CHANNELS * WINDOW,
        hidden: Sequence[int] = (1024, 512, 60),
        dropout: float = 0.5,
    ):
        if not (isinstance(num_classes, int) and num_classes >= 2):
            raise ValueError(f"num_classes must be an int >= 2, got {num_classes!r}.")
        if not 0.0 <= dropout < 1.0:
            raise ValueError(f"dropout is a rate in [0, 1), got {dropout}.")
        sizes = (int(in_size), *(int(h) for h in hidden), num_classes)
        keys = jax.random.split(key, len(sizes) - 1)
        self.layers = tuple(eqx.nn.Linear(a, b, key=k) for a, b, k in zip(sizes[:-1], sizes[1:], keys))
        self.dropout = float(dropout)

    @property
    def in_size(self) -> int:
        return self.layers[0].in_features

    @property
    def num_classes(self) -> int:
        return self.layers[-1].out_features

    @property
    def hidden(self) -> tuple[int, ...]:
        return tuple(layer.out_features for layer in self.layers[:-1])

    def __call__(self, x: Array, key: Array | None = None) -> Array:
        """Logits (C,) of one input vector x (in_size,); dropout only when `key` is given."""
        keys = [None] * len(self.layers) if key is None else list(jax.random.split(key, len(self.layers)))
        for layer, k in zip(self.layers[:-1], keys[:-1]):
            x = jax.nn.relu(layer(x))
            if k is not None and self.dropout > 0:
                keep = jax.random.bernoulli(k, 1.0 - self.dropout, x.shape)
                x = jnp.where(keep, x / (1.0 - self.dropout), 0.0)
        return self.layers[-1](x)


@eqx.filter_jit
def _log_probs_batch(mlp: ActivityMLP, x: Array) -> Array:
    return jax.nn.log_softmax(jax.vmap(mlp)(x), -1)


def mlp_log_probs(mlp: ActivityMLP, features, chunk: int = 4096) -> Array:
    """log p_MLP (N, C) of (N, in_size) features, evaluated in fixed-size chunks."""
    x = jnp.asarray(features, jnp.float32)
    if x.ndim != 2 or x.shape[1] != mlp.in_size:
        raise ValueError(f"features has shape {x.shape}; this MLP needs (N, {mlp.in_size}).")
    check_finite("features", features)
    n = x.shape[0]
    size = min(chunk, max(256, -(-n // 256) * 256))
    out = []
    for s in range(0, n, size):
        part = x[s : s + size]
        pad = size - part.shape[0]
        if pad:
            part = jnp.concatenate([part, jnp.zeros((pad, x.shape[1]), x.dtype)])
        out.append(_log_probs_batch(mlp, part)[: size - pad])
    return jnp.concatenate(out, 0)


def class_weights(labels, num_classes: int, power: float = 1.0) -> np.ndarray:
    """w_c ∝ (1 / frequency_c)^power, normalised to mean 1 over the frames (classes with
    no frames get 0): balances the cross-entropy over classes."""
    labels = np.asarray(labels)
    counts = np.bincount(labels[labels >= 0], minlength=num_classes).astype(np.float64)
    w = np.where(counts > 0, 1.0 / np.maximum(counts, 1.0) ** power, 0.0)
    return (w * counts.sum() / max((w * counts).sum(), 1e-12)).astype(np.float32)


def _check_training(features, labels, num_inputs: int, num_classes: int, name: str = "features"):
    x = np.asarray(features, np.float32)
    y = np.asarray(labels)
    if x.ndim != 2 or x.shape[1] != num_inputs:
        raise ValueError(f"{name} has shape {x.shape}; expected (n, {num_inputs}).")
    if y.shape != (x.shape[0],) or not np.issubdtype(y.dtype, np.integer):
        raise ValueError(f"labels has shape {y.shape} and dtype {y.dtype}; expected ({x.shape[0]},) int.")
    if x.shape[0] == 0:
        raise ValueError(f"{name} has no samples.")
    if not np.isfinite(x).all():
        raise ValueError(f"{name} contains NaN or inf (sample {int(np.argmax(~np.isfinite(x).all(1)))}).")
    if (y < 0).any() or (y >= num_classes).any():
        raise ValueError(f"labels must lie in 0 .. {num_classes - 1}; got values {sorted(set(y.tolist()))[:10]}.")
    return x, y.astype(np.int32)


def _weighted_ce(mlp, x, y, w, key):
    keys = None if key is None else jax.random.split(key, x.shape[0])
    logits = jax.vmap(mlp)(x) if keys is None else jax.vmap(mlp)(x, keys)
    nll = -jnp.take_along_axis(jax.nn.log_softmax(logits, -1), y[:, None], 1)[:, 0]
    return jnp.sum(w[y] * nll) / jnp.sum(w[y])


def train_mlp(
    mlp: ActivityMLP,
    features,
    labels,
    key: Array,
    epochs: int = 20,
    batch_size: int = 256,
    learning_rate: float = 1e-3,
    weights=None,
    validation: tuple | None = None,
    on_epoch=None,
    verbose: bool = False,
) -> tuple[ActivityMLP, TrainingCurve]:
    """Adam on the (class-weighted) cross-entropy with dropout, `epochs` passes over the data.

    Args:
        mlp: the initial network.
        features: (n, in_size) standardised window features; labels (n,) int.
        key: JAX key (shuffling and dropout).
        weights: (C,) per-class loss weights (default 1; see `class_weights`).
        validation: optional (features, labels) scored after every epoch (no dropout).
        on_epoch: optional `on_epoch(epoch, mlp)` called after every epoch (1-based), e.g.
            to keep the held-out predictions of each epoch.
    Returns:
        (trained network, TrainingCurve per epoch).
    """
    import optax

    x, y = _check_training(features, labels, mlp.in_size, mlp.num_classes)
    if not (isinstance(epochs, int) and epochs >= 0) or not (isinstance(batch_size, int) and batch_size >= 1):
        raise ValueError(f"epochs must be an int >= 0 and batch_size an int >= 1; got {epochs!r}, {batch_size!r}.")
    C = mlp.num_classes
    w = jnp.ones(C, jnp.float32) if weights is None else jnp.asarray(weights, jnp.float32)
    if w.shape != (C,) or not bool(jnp.all(jnp.isfinite(w) & (w >= 0))):
        raise ValueError(f"weights must be ({C},) finite and >= 0, got shape {w.shape}.")
    if validation is not None:
        vx, vy = _check_training(*validation, mlp.in_size, C, name="validation features")
    optimiser = optax.adam(learning_rate)
    state = optimiser.init(eqx.filter(mlp, eqx.is_array))

    @eqx.filter_jit
    def step(mlp, state, xb, yb, k):
        loss, grads = eqx.filter_value_and_grad(_weighted_ce)(mlp, xb, yb, w, k)
        updates, state = optimiser.update(grads, state, eqx.filter(mlp, eqx.is_array))
        return eqx.apply_updates(mlp, updates), state, loss

    n = x.shape[0]
    bs = min(batch_size, n)
    per_epoch = max(1, n // bs)  # full batches only (one compiled shape); the rest reshuffles
    losses, val_losses, val_acc, val_f1 = [], [], [], []
    for epoch in range(epochs):
        key, shuffle_key = jax.random.split(key)
        order = np.asarray(jax.random.permutation(shuffle_key, n))
        total = 0.0
        for b in range(per_epoch):
            idx = order[b * bs : (b + 1) * bs]
            key, k = jax.random.split(key)
            mlp, state, loss = step(mlp, state, jnp.asarray(x[idx]), jnp.asarray(y[idx]), k)
            total += float(loss)
        losses.append(total / per_epoch)
        if validation is not None:
            lp = mlp_log_probs(mlp, vx)
            val_losses.append(float(-jnp.mean(jnp.take_along_axis(lp, jnp.asarray(vy)[:, None], 1))))
            scores = classification_scores(confusion_matrix(vy, np.asarray(jnp.argmax(lp, -1)), C))
            val_acc.append(scores["accuracy"])
            val_f1.append(scores["macro_f1"])
        if on_epoch is not None:
            on_epoch(epoch + 1, mlp)
        if verbose:
            extra = (
                f", validation loss {val_losses[-1]:.3f} accuracy {val_acc[-1]:.3f} macro F1 {val_f1[-1]:.3f}"
                if validation is not None
                else ""
            )
            print(f"  epoch {epoch + 1}/{epochs}: loss {losses[-1]:.3f}{extra}", flush=True)
    nan = np.full(len(losses), np.nan)
    val = [np.asarray(v) if v else nan for v in (val_losses, val_acc, val_f1)]
    return mlp, TrainingCurve(np.asarray(losses), *val)
