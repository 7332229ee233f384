"""What the terms of one problem share: the posed body and the data.

Every term is `fn(params, data)`, or `fn(params, data, posed)` when it reads the posed
body (below), with `params["pose"]` local rotation matrices (T, J, 3, 3) (a rotation key
of the `Problem`) and optional `params["trans"]` (T, 3).

- `PosedBody`: a term that reads vertices, joints or global rotations (ground, contact,
  objects, keypoints, silhouettes) is `Term(..., posed=PosedBody())` and is called as
  `fn(params, data, posed)`; its `Problem` computes the one SMPL forward pass per
  evaluation for all such terms. Under `jit`, what no term reads (e.g. vertices when only
  joints are used) is dropped by XLA. `posed_body` (deprecated) is the same pass for a
  term that computes it itself.
- `CombinedData`: terms read their data by attribute (`data.orientation`,
  `data.body`, `data.ground`, ...); a problem mixing kinds of terms (IMU and physics)
  gets one `data` joining the containers of each kind.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping

import equinox as eqx

from ..body.kinematics import BodyOutput, forward_rotations
from ..body.model import Body

__all__ = ["PosedBody", "posed_body", "CombinedData"]


class PosedBody(eqx.Module):
    """`Problem.posed` of the SMPL body `data.body` with shape `data.betas` (None: the
    mean shape; (B,) or (T, B)): vertices (T, V, 3), joints (T, J, 3), global
    joint_rotations (T, J, 3, 3) from params["pose"] (T, J, 3, 3) local rotations and
    params.get("trans") (T, 3)."""

    def __call__(self, params, data) -> BodyOutput:
        return forward_rotations(data.body, params["pose"], getattr(data, "betas", None), params.get("trans"))


def posed_body(params, body: Body, betas=None) -> BodyOutput:
    """The posed body of `params` (see `PosedBody`), computed on each call.

    Deprecated: give the term `posed=PosedBody()` and take the posed body as `fn`'s third
    argument, so that the pass is computed once for all terms; this helper goes in the
    next release.
    """
    warnings.warn(
        "posed_body is deprecated: declare Term(..., posed=PosedBody()) (jaxmocap.energies.posed) "
        "and take the posed body as fn's third argument.",
        DeprecationWarning,
        stacklevel=2,
    )
    return forward_rotations(body, params["pose"], betas, params.get("trans"))


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
