"""Every use of a dependency's private internals, in one place.

optimistix keeps a result's integer code in `RESULTS.<member>._value` and its message in
`RESULTS._index_to_message`, and its damped LM operator in a private class; MuJoCo MJX keeps the contacts of `mjx.collision` in
`Data._impl.contact`. JAX keeps its distributed client and its started backends in
`jax._src` (no public accessor). The solver's lineax adapter (`solve.structured._damped_parts`)
also recognises optimistix's damped operator by its structure, not by a public type.
An upgrade that moves any of these fails in `tests/test_compat.py`, which names the
versions below, instead of deep inside a solve.
"""

from __future__ import annotations

import numpy as np
import optimistix as optx

__all__ = [
    "DIVERGENCE",
    "MAX_STEPS",
    "SUCCESSFUL",
    "TESTED_WITH",
    "cpu_backend_started",
    "damped_operator",
    "distributed_client",
    "mjx_contacts",
    "result_code",
    "result_message",
]

#: The versions whose internals these hooks were written against.
TESTED_WITH = {"optimistix": "0.1.0", "mujoco-mjx": "3.17.0"}


def result_code(member) -> int:
    """The integer code of an `optx.RESULTS` member (or of a `Solution.result`)."""
    return member._value


SUCCESSFUL = int(np.asarray(result_code(optx.RESULTS.successful)))
MAX_STEPS = int(np.asarray(result_code(optx.RESULTS.nonlinear_max_steps_reached)))
DIVERGENCE = int(np.asarray(result_code(optx.RESULTS.nonlinear_divergence)))


def result_message(code) -> str:
    """optimistix's message for an integer result code ("" for success)."""
    return optx.RESULTS._index_to_message[int(code)]


def damped_operator(operator, lam):
    """optimistix's Levenberg-Marquardt operator y -> (J y, sqrt(lam) y) (private `_Damped`)."""
    from optimistix._solver.levenberg_marquardt import _Damped

    return _Damped(operator, lam)


def mjx_contacts(data):
    """The contact set `mjx.collision` wrote into an MJX `Data`."""
    return data._impl.contact


def distributed_client():
    """The `jax.distributed` coordination client of this process, or None before
    `jax.distributed.initialize` (JAX keeps it in a private module)."""
    from jax._src import distributed

    return distributed.global_state.client


def cpu_backend_started() -> bool:
    """Whether JAX's CPU backend already runs (`_threads` must act before it starts). JAX
    keeps no public flag, only a private dict, read defensively: False when it cannot tell."""
    try:
        from jax._src import xla_bridge

        return "cpu" in getattr(xla_bridge, "_backends", {})
    except Exception:  # another JAX's internals: no warning rather than a wrong one
        return False
