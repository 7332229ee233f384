"""One file format for every learned model: an npz of the module's array leaves plus a JSON
header (format, version, the model's configuration, each leaf's path and shape, provenance).

Loading rebuilds the module from its configuration (the caller's `skeleton`) and fills it
leaf by leaf, so a file from another version or configuration fails with the caller's error
naming the parameter, instead of a shape error deep inside JAX.
"""

from __future__ import annotations

import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["save_module", "read_header", "fill_module"]


def _leaves(module) -> dict:
    flat, _ = jax.tree_util.tree_flatten_with_path(module)
    return {jax.tree_util.keystr(path): leaf for path, leaf in flat}


def save_module(path, module, header: dict, dtype=np.float32) -> Path:
    """Write `module`'s leaves (as `dtype`) and `header` (+ the leaf table) atomically."""
    path = Path(path)
    leaves = _leaves(module)
    header = {**header, "leaves": {k: [f"w{i}", list(np.shape(v))] for i, (k, v) in enumerate(leaves.items())}}
    arrays = {f"w{i}": np.asarray(v, dtype) for i, v in enumerate(leaves.values())}
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez_compressed(tmp, header=np.asarray(json.dumps(header)), **arrays)
    tmp.replace(path)
    return path


def read_header(path, fmt: str, version: int, error, writer: str) -> tuple[dict, dict]:
    """(header, arrays) of a file of format `fmt` and `version`; `error` (an exception class)
    names what is wrong, `writer` the function that writes such files."""
    path = Path(path)
    if not path.is_file():
        raise error(f"no {fmt} file at {path}.")
    try:
        with np.load(path, allow_pickle=False) as f:
            header = json.loads(str(f["header"]))
            arrays = {k: f[k] for k in f.files if k != "header"}
    except (OSError, ValueError, KeyError) as e:
        raise error(f"{path} is not a {fmt} file ({e}).") from None
    if header.get("format") != fmt or header.get("version") != version:
        raise error(
            f"{path}: format {header.get('format')!r} version {header.get('version')!r}; expected {fmt!r} "
            f"version {version} (save it again with {writer})."
        )
    return header, arrays


def fill_module(skeleton, header: dict, arrays: dict, path, error):
    """`skeleton` (a module of the right configuration) with the file's leaves, as float32."""
    expected = _leaves(skeleton)
    stored = header.get("leaves", {})
    if set(stored) != set(expected):
        raise error(
            f"{path}: its parameters {sorted(set(stored) ^ set(expected))[:4]} do not match this version's "
            f"{type(skeleton).__name__}; retrain, or use the jaxmocap version that wrote it."
        )
    values = []
    for name, leaf in expected.items():
        key, shape = stored[name]
        if tuple(shape) != tuple(leaf.shape) or key not in arrays or arrays[key].shape != tuple(leaf.shape):
            raise error(f"{path}: parameter {name} has shape {shape}; the model needs {list(leaf.shape)}.")
        if not np.isfinite(arrays[key]).all():
            raise error(f"{path}: parameter {name} contains NaN or inf.")
        values.append(jnp.asarray(arrays[key], jnp.float32))
    _, treedef = jax.tree_util.tree_flatten(skeleton)
    return jax.tree_util.tree_unflatten(treedef, values)
