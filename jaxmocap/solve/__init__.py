"""Batched least-squares engine: energies as residual terms, structured LM/GN, vmap.

Every method in jaxmocap is "stack weighted residuals, minimise with Gauss-Newton /
Levenberg-Marquardt" (von Marcard §2.3, §3.3.4). Compose `Term`s into a `Problem`, call
`solve` (one sequence) or `solve_batch` (many, padded with masks).
"""

from .batch import pad_sequences as pad_sequences
from .batch import solve_batch as solve_batch
from .manifold import FrameLayout as FrameLayout
from .manifold import retract as retract
from .residuals import Cauchy as Cauchy
from .residuals import GemanMcClure as GemanMcClure
from .residuals import Huber as Huber
from .residuals import Problem as Problem
from .residuals import RobustLoss as RobustLoss
from .residuals import Term as Term
from .residuals import nan_mask as nan_mask
from .residuals import second_difference as second_difference
from .solver import METHODS as METHODS
from .solver import Solution as Solution
from .solver import result_message as result_message
from .solver import solve as solve
from .structured import BandedNormalCholesky as BandedNormalCholesky
