"""Batched least-squares engine: energies as residual terms, structured LM/GN, vmap.

Every method in jaxmocap is "stack weighted residuals, minimise with Gauss-Newton /
Levenberg-Marquardt" (von Marcard §2.3, §3.3.4). Declare the unknowns (per frame, per
sequence, per window; vectors, angles, SO(3), SE(3)), compose `Term`s into a `Problem`,
call `solve` (one sequence, through `optx.least_squares`) or `solve_batch` (many,
padded with masks, per-member weights). Solves are differentiable (implicit adjoint).
"""

from .basis import WindowBasis as WindowBasis
from .basis import basis_term as basis_term
from .batch import BatchPlan as BatchPlan
from .batch import bytes_per_sequence as bytes_per_sequence
from .batch import free_memory_bytes as free_memory_bytes
from .batch import length_buckets as length_buckets
from .batch import pad_sequences as pad_sequences
from .batch import plan_batch as plan_batch
from .batch import solve_batch as solve_batch
from .batch import with_weights as with_weights
from .linearisation import Args as Args
from .linearisation import linearise as linearise
from .residuals import BlockJacobian as BlockJacobian
from .residuals import Cauchy as Cauchy
from .residuals import GemanMcClure as GemanMcClure
from .residuals import Huber as Huber
from .residuals import Params as Params
from .residuals import Problem as Problem
from .residuals import RobustLoss as RobustLoss
from .residuals import Term as Term
from .residuals import nan_mask as nan_mask
from .solver import METHODS as METHODS
from .solver import NO_OBSERVATIONS as NO_OBSERVATIONS
from .solver import check_bandwidths as check_bandwidths
from .solver import measure_bandwidths as measure_bandwidths
from .solver import Solution as Solution
from .solver import VonMarcardLM as VonMarcardLM
from .solver import linear_solver as linear_solver
from .solver import result_message as result_message
from .solver import solve as solve
from .structured import StructuredCholesky as StructuredCholesky

from .unknowns import Layout as Layout
from .unknowns import Unknown as Unknown
from .unknowns import Windows as Windows
from .unknowns import frame as frame
from .unknowns import sequence as sequence
from .unknowns import window as window
