"""Batched least-squares engine: energies as residual terms, structured LM/GN, vmap.

Every method in jaxmocap is "stack weighted residuals, minimise with Gauss-Newton /
Levenberg-Marquardt" (von Marcard §2.3, §3.3.4). Declare the unknowns (per frame, per
sequence, per window; vectors, angles, SO(3), SE(3)), compose `Term`s into a `Problem`,
call `solve` (one sequence, through `optx.least_squares`) or `solve_batch` (many,
padded with masks, per-member weights), choosing the solver and its options with a
solver object (`VonMarcardLM(rtol=..., atol=...)`, the default). Solves are
differentiable (implicit adjoint).

This front door holds what a problem's author needs; the engine's parts stay importable
from their modules (`jaxmocap.solve.batch.plan_batch`, `jaxmocap.solve.basis.WindowBasis`,
`jaxmocap.solve.options.OptxGaussNewton`, ...).
"""

import importlib
import warnings

from .batch import pad_sequences as pad_sequences
from .batch import solve_batch as solve_batch
from .batch import with_weights as with_weights
from .lm import VonMarcardLM as VonMarcardLM
from .residuals import BlockJacobian as BlockJacobian
from .residuals import Cauchy as Cauchy
from .residuals import GemanMcClure as GemanMcClure
from .residuals import Huber as Huber
from .residuals import Problem as Problem
from .residuals import Term as Term
from .residuals import nan_mask as nan_mask
from .solver import NO_OBSERVATIONS as NO_OBSERVATIONS
from .solver import Solution as Solution
from .solver import result_message as result_message
from .solver import solve as solve
from .unknowns import Windows as Windows
from .unknowns import frame as frame
from .unknowns import sequence as sequence
from .unknowns import window as window

__all__ = [
    # a problem: terms, their unknowns, robust losses
    "Problem", "Term", "frame", "sequence", "window", "Windows", "BlockJacobian", "nan_mask",
    "Huber", "Cauchy", "GemanMcClure",
    # solving it
    "solve", "solve_batch", "VonMarcardLM", "Solution", "result_message", "NO_OBSERVATIONS",
    "with_weights", "pad_sequences",
]  # fmt: skip

# Names this module exported in the last release, and the module each lives in: they
# resolve here for one more release, with a DeprecationWarning naming that module.
_MOVED = {
    "WindowBasis": "basis", "basis_term": "basis",
    "BatchPlan": "batch", "bytes_per_sequence": "batch", "free_memory_bytes": "batch",
    "length_buckets": "batch", "plan_batch": "batch",
    "Args": "linearisation", "linearise": "linearisation",
    "Params": "residuals", "RobustLoss": "residuals",
    "METHODS": "solver", "check_bandwidths": "solver", "measure_bandwidths": "solver", "linear_solver": "solver",
    "StructuredCholesky": "structured",
    "Layout": "unknowns", "Unknown": "unknowns",
}  # fmt: skip


def __getattr__(name):
    if name in _MOVED:
        where = f"{__name__}.{_MOVED[name]}"
        warnings.warn(
            f"importing {name} from {__name__} is deprecated and stops working in the next release: "
            f"import it from {where} (from {where} import {name}).",
            DeprecationWarning,
            stacklevel=2,
        )
        return getattr(importlib.import_module(where), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
