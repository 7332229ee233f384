"""What the terms of one problem share: the posed body and the data.

Every term is `fn(params, data)` with `params["pose"]` local rotation matrices
(T, J, 3, 3) (a rotation key of the `Problem`) and optional `params["trans"]` (T, 3).

- `posed_body`: one SMPL forward pass per residual evaluation, shared by all terms that
  read vertices, joints or global rotations (ground, contact, objects, keypoints,
  silhouettes). When the engine hands `params` with a `shared(key, compute)` memo, the
  pass is computed once and reused; otherwise each call computes it. Under `jit`, what no
  term reads (e.g. vertices when only joints are used) is dropped by XLA.
- `CombinedData`: terms read their data by attribute (`data.orientation`,
  `data.body`, `data.ground`, ...); a problem mixing kinds of terms (IMU and physics)
  gets one `data` joining the containers of each kind.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

import equinox as eqx

from ..body.kinematics import BodyOutput, forward_rotations
from ..body.model import Body

__all__ = ["POSED_BODY", "posed_body", "shared", "CombinedData"]

#: Memo key of the shared forward pass.
POSED_BODY = "posed_body"


def shared(params, key: str, compute: Callable[[], object]):
    """`params.shared(key, compute)` when the engine provides it (memoised for one
    residual evaluation), else `compute()`."""
    memo = getattr(params, "shared", None)
    return compute() if memo is None else memo(key, compute)


def posed_body(params, body: Body, betas=None) -> BodyOutput:
    """The posed body of `params`: vertices (T, V, 3), joints (T, J, 3), global
    joint_rotations (T, J, 3, 3), from params["pose"] (T, J, 3, 3) local rotations,
    params.get("trans") (T, 3) and betas (B,) or (T, B).

    Memoised under one key per evaluation: every term of a problem must pose the same
    body and betas (they come from the problem's one `data`).
    """

    def compute():
        return forward_rotations(body, params["pose"], betas, params.get("trans"))

    return shared(params, POSED_BODY, compute)


class CombinedData(eqx.Module):
    """The data of a problem mixing kinds of terms, e.g.
    `CombinedData((inertial_data, physics_data))`.

    `data.name` is the first part's attribute `name` that is not None, `data[key]` the
    first dict part's item `key`; the parts stay pytrees (arrays are traced, so new data
    of the same shapes does not recompile).
    """

    parts: tuple

    def __init__(self, parts):
        self.parts = tuple(parts)

    def __getattr__(self, name):
        if name.startswith("__") or name == "parts":
            raise AttributeError(name)
        for part in self.parts:
            value = getattr(part, name, None)
            if value is not None:
                return value
        kinds = [type(p).__name__ for p in self.parts]
        raise AttributeError(f"no part of this CombinedData has {name!r} (parts: {kinds}).")

    def __getitem__(self, key):
        for part in self.parts:
            if isinstance(part, Mapping) and key in part:
                return part[key]
        raise KeyError(key)
