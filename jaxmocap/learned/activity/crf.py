"""The linear-chain CRF over the MLP's log-probabilities (eq. 7.2; package docstring, step 4):
score, forward algorithm, Viterbi, its parameters and their training."""

from __future__ import annotations

import math
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array, lax

from ..._checks import check_finite
from .scores import TrainingCurve

__all__ = [
    "crf_score",
    "crf_log_partition",
    "crf_log_likelihood",
    "viterbi",
    "ActivityCRF",
    "transition_counts",
    "init_crf",
    "decode",
    "train_crf",
]


def _check_chain(unary, transitions, mask, labels=None):
    unary = jnp.asarray(unary)
    transitions = jnp.asarray(transitions)
    if unary.ndim != 2 or unary.shape[0] < 1:
        raise ValueError(f"unary has shape {unary.shape}; expected (T, C) with T >= 1.")
    C = unary.shape[1]
    if transitions.shape != (C, C):
        raise ValueError(f"transitions has shape {transitions.shape}; expected ({C}, {C}) for C = {C} classes.")
    check_finite("unary", unary)
    check_finite("transitions", transitions)
    mask = jnp.ones(unary.shape[0], bool) if mask is None else jnp.asarray(mask)
    if mask.shape != unary.shape[:1] or mask.dtype != jnp.bool_:
        raise ValueError(f"mask has shape {mask.shape} and dtype {mask.dtype}; expected ({unary.shape[0]},) bool.")
    if labels is not None:
        labels = jnp.asarray(labels)
        if labels.shape != unary.shape[:1] or not jnp.issubdtype(labels.dtype, jnp.integer):
            raise ValueError(
                f"labels has shape {labels.shape} and dtype {labels.dtype}; expected ({unary.shape[0]},) int."
            )
        v = np.asarray(labels) if not isinstance(labels, jax.core.Tracer) else None
        if v is not None and ((v < 0) | (v >= C))[np.asarray(mask)].any():
            raise ValueError(f"labels must lie in 0 .. {C - 1} at the unmasked frames; got {sorted(set(v.tolist()))}.")
    return unary, transitions, mask, labels


def crf_score(unary, transitions, labels, mask=None) -> Array:
    """score(S) = Σ_t u_t(S_t) + Σ_t A_{S_t, S_t'} over the unmasked frames, t' the next
    unmasked frame (masked frames are skipped: the chain links their neighbours)."""
    unary, transitions, mask, labels = _check_chain(unary, transitions, mask, labels)

    def step(carry, inp):
        prev, started = carry
        u, l, m = inp
        s = u[l] + jnp.where(started, transitions[prev, l], 0.0)
        return (jnp.where(m, l, prev), started | m), jnp.where(m, s, 0.0)

    _, s = lax.scan(step, (jnp.zeros((), labels.dtype), jnp.zeros((), bool)), (unary, labels, mask))
    return s.sum()


def crf_log_partition(unary, transitions, mask=None) -> Array:
    """log Z = log Σ_S exp score(S) by the forward algorithm:
    α_0 = u_0, α_t(j) = u_t(j) + logsumexp_i(α_{t-1}(i) + A_ij), log Z = logsumexp_j α_T(j).
    Masked frames are skipped (as in `crf_score`); 0 if every frame is masked."""
    unary, transitions, mask, _ = _check_chain(unary, transitions, mask)

    def step(carry, inp):
        alpha, started = carry
        u, m = inp
        new = jnp.where(started, jax.nn.logsumexp(alpha[:, None] + transitions, axis=0), 0.0) + u
        return (jnp.where(m, new, alpha), started | m), None

    C = unary.shape[1]
    (alpha, started), _ = lax.scan(step, (jnp.zeros(C, unary.dtype), jnp.zeros((), bool)), (unary, mask))
    return jnp.where(started, jax.nn.logsumexp(alpha), 0.0)


def crf_log_likelihood(unary, transitions, labels, mask=None) -> Array:
    """log P(labels) = score(labels) - log Z of the linear-chain CRF (exact).

    Args:
        unary: (T, C) per-frame scores u_t (here λ log p_MLP).
        transitions: (C, C) A_ij, the score of class i followed by class j.
        labels: (T,) int class per frame.
        mask: (T,) bool, frames to use (default all); masked frames are skipped.
    """
    return crf_score(unary, transitions, labels, mask) - crf_log_partition(unary, transitions, mask)


def viterbi(unary, transitions, mask=None) -> Array:
    """argmax_S score(S) (max-product recursion, then backtracking), (T,) int32.

    δ_t(j) = u_t(j) + max_i(δ_{t-1}(i) + A_ij), with back-pointers; masked frames are
    skipped and get the label of the previous unmasked frame (the first one's if none
    precedes), so padding at the end repeats the last label.
    """
    unary, transitions, mask, _ = _check_chain(unary, transitions, mask)
    C = unary.shape[1]
    identity = jnp.arange(C)

    def forward(carry, inp):
        delta, started = carry
        u, m = inp
        scores = delta[:, None] + transitions
        new = jnp.where(started, scores.max(0), 0.0) + u
        pointer = jnp.where(m & started, scores.argmax(0), identity)
        return (jnp.where(m, new, delta), started | m), pointer

    (delta, _), pointers = lax.scan(forward, (jnp.zeros(C, unary.dtype), jnp.zeros((), bool)), (unary, mask))

    def back(label, pointer):
        return pointer[label], label

    _, labels = lax.scan(back, jnp.argmax(delta), pointers, reverse=True)
    return labels.astype(jnp.int32)


class ActivityCRF(eqx.Module):
    """The CRF's parameters: transition scores A (C, C) and log λ (unary weight)."""

    transitions: Array
    log_weight: Array

    @property
    def weight(self) -> Array:
        return jnp.exp(self.log_weight)

    def unary(self, log_probs) -> Array:
        """u_t = λ log p_t, (T, C)."""
        return self.weight * jnp.asarray(log_probs)


def transition_counts(label_sequences: Sequence, num_classes: int) -> np.ndarray:
    """(C, C) counts of class i followed by class j over the sequences (negative labels
    are skipped, breaking the chain there)."""
    counts = np.zeros((num_classes, num_classes))
    for seq in label_sequences:
        seq = np.asarray(seq)
        a, b = seq[:-1], seq[1:]
        ok = (a >= 0) & (b >= 0)
        if (seq >= num_classes).any():
            raise ValueError(f"labels go up to {int(seq.max())}; expected < {num_classes} classes.")
        np.add.at(counts, (a[ok], b[ok]), 1.0)
    return counts


def init_crf(label_sequences: Sequence, num_classes: int, smoothing: float = 1.0, weight: float = 1.0) -> ActivityCRF:
    """A from the log transition frequencies of training labels, log P(j | i) with add-
    `smoothing` counts (the thesis's T, Fig. 7.5); λ = `weight`."""
    counts = transition_counts(label_sequences, num_classes) + smoothing
    A = np.log(counts / counts.sum(1, keepdims=True))
    return ActivityCRF(jnp.asarray(A, jnp.float32), jnp.asarray(np.log(weight), jnp.float32))


def _bucket(n: int) -> int:
    return max(64, 1 << int(math.ceil(math.log2(max(n, 1)))))


@eqx.filter_jit
def _viterbi_batch(crf: ActivityCRF, log_probs: Array, mask: Array) -> Array:
    return jax.vmap(lambda lp, m: viterbi(crf.unary(lp), crf.transitions, m))(log_probs, mask)


def _pad_sequences(sequences: Sequence, length: int, fill=0.0):
    out = []
    for s in sequences:
        s = np.asarray(s)
        pad = [(0, length - s.shape[0])] + [(0, 0)] * (s.ndim - 1)
        out.append(np.pad(s, pad, constant_values=fill))
    return np.stack(out)


def decode(crf: ActivityCRF, log_probs: Sequence) -> list[np.ndarray]:
    """Viterbi labels of each (T_i, C) log-probability sequence (padded to a power-of-two
    length in one batch, so few shapes compile)."""
    if len(log_probs) == 0:
        return []
    lengths = [int(np.shape(lp)[0]) for lp in log_probs]
    L = _bucket(max(lengths))
    lp = _pad_sequences(log_probs, L)
    mask = np.arange(L)[None, :] < np.asarray(lengths)[:, None]
    out = np.asarray(_viterbi_batch(crf, jnp.asarray(lp, jnp.float32), jnp.asarray(mask)))
    return [o[:n] for o, n in zip(out, lengths)]


def train_crf(
    crf: ActivityCRF,
    log_probs: Sequence,
    labels: Sequence,
    steps: int = 200,
    learning_rate: float = 0.05,
    prior_weight: float = 0.01,
    fit_transitions: bool = True,
) -> tuple[ActivityCRF, TrainingCurve]:
    """Maximise the CRF log-likelihood of labelled sequences with the MLP fixed.

    Loss: -Σ_i log P(S_i) / Σ_i T_i (mean per frame) + prior_weight · ||A - A_0||² / C,
    A_0 the initial transitions (the log transition frequencies), a Gaussian prior that
    keeps transitions seen rarely (or never) in these sequences near their frequency.

    Args:
        crf: initial parameters (`init_crf`).
        log_probs: list of (T_i, C) MLP log-probabilities of sequences the MLP was not
            trained on (otherwise λ learns the MLP's over-confidence on its training set).
        labels: list of (T_i,) int labels; negative labels are masked (skipped).
        fit_transitions: False learns λ only.
    Returns:
        (trained CRF, TrainingCurve per step).
    """
    import optax

    if len(log_probs) == 0 or len(log_probs) != len(labels):
        raise ValueError(
            f"train_crf needs as many label sequences as log-probability sequences (>= 1); got {len(log_probs)} and {len(labels)}."
        )
    C = crf.transitions.shape[0]
    lengths = []
    for i, (lp, lab) in enumerate(zip(log_probs, labels)):
        if np.shape(lp) != (np.shape(lab)[0], C) or np.ndim(lab) != 1:
            raise ValueError(
                f"sequence {i}: log_probs {np.shape(lp)} and labels {np.shape(lab)}; expected (T, {C}) and (T,)."
            )
        check_finite(f"log_probs[{i}]", lp)
        if (np.asarray(lab) >= C).any():
            raise ValueError(f"labels[{i}] go up to {int(np.max(lab))}; the CRF has {C} classes.")
        lengths.append(len(lab))
    L = _bucket(max(lengths))
    lp = jnp.asarray(_pad_sequences(log_probs, L), jnp.float32)
    lab_np = _pad_sequences(labels, L, fill=-1)
    mask = jnp.asarray(lab_np >= 0)
    lab = jnp.asarray(np.maximum(lab_np, 0), jnp.int32)
    frames = float(np.maximum(np.asarray(mask).sum(), 1))
    A0 = crf.transitions

    def loss_fn(params):
        A, log_w = params
        A = A if fit_transitions else lax.stop_gradient(A)
        ll = jax.vmap(lambda u, y, m: crf_log_likelihood(jnp.exp(log_w) * u, A, y, m))(lp, lab, mask)
        return -ll.sum() / frames + prior_weight * jnp.sum((A - A0) ** 2) / C

    optimiser = optax.adam(learning_rate)
    params = (crf.transitions, crf.log_weight)
    state = optimiser.init(params)

    @jax.jit
    def step(params, state):
        loss, grads = jax.value_and_grad(loss_fn)(params)
        updates, state = optimiser.update(grads, state, params)
        return optax.apply_updates(params, updates), state, loss

    losses = []
    for _ in range(steps):
        params, state, loss = step(params, state)
        losses.append(float(loss))
    nan = np.full(len(losses), np.nan)
    return ActivityCRF(*params), TrainingCurve(np.asarray(losses), nan, nan, nan)
