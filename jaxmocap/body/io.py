"""Loading and saving body models: SMPL `.pkl`/`.npz`, SMPL-H and SMPL-X `.npz`.

Supported files (dictionary keys as the model authors ship them):

| family | files                                  | joints | what we keep                     |
|--------|----------------------------------------|--------|----------------------------------|
| SMPL   | `.pkl` (chumpy inside is fine), `.npz` | 24     | everything                       |
| SMPL-H | `.npz` (also `.pkl` without chumpy)    | 52     | body; hands reduced, see below   |
| SMPL-X | `.npz` (also `.pkl` without chumpy)    | 55     | body; hands/face reduced         |

SMPL-H and SMPL-X are reduced to SMPL's 24-joint tree: joints 0-21 are identical, the
SMPL hand joints 22/23 are placed at each hand's index-finger base (as SMPL's are), and
the skinning weights of all finger (and jaw/eye) joints are merged onto the hand (head)
joint. With the fingers at rest (flat hand) this reduction is exact: a child joint with
identity rotation has the same skinning transform as its parent. Pose blend shapes keep
the 21 body joints; expression blend shapes (SMPL-X) are dropped, and shape components
are truncated to `num_betas` if given.

MANO (16 joints) and other layouts raise an error that names the file.
"""

from __future__ import annotations

import dataclasses
import io
import os
import pickle
import zipfile
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from .model import SMPL_JOINT_NAMES, SMPL_PARENTS, Body, make_body

__all__ = ["BODY_CHOICES", "BodyFileError", "default_body", "load_body", "resolve_body", "save_body"]

_DATA = Path(__file__).parent / "data"
_REQUIRED = ("v_template", "f", "shapedirs", "J_regressor", "weights", "kintree_table")


class BodyFileError(ValueError):
    """A body model file is missing, unreadable or of an unknown layout."""


class _ChumpyStub:
    """Stands in for chumpy objects while unpickling, so chumpy need not be installed.

    Chumpy arrays pickle their value in the state dict under 'x' (sometimes 'a').
    """

    def __init__(self, *args, **kwargs):
        pass

    def __setstate__(self, state):
        self.__dict__.update(state if isinstance(state, dict) else {"x": state})

    def __array__(self, dtype=None, copy=None):
        for key in ("x", "a", "r"):
            value = self.__dict__.get(key)
            if value is not None and not isinstance(value, _ChumpyStub):
                return np.asarray(value, dtype=dtype)
        raise BodyFileError("a chumpy object in the file carries no array value.")


# What a model pickle may name besides numpy / scipy.sparse / chumpy: anything else (os.system,
# ...) would run code from the file, so it is refused.
_SAFE_GLOBALS = {
    ("copyreg", "_reconstructor"), ("copyreg", "__newobj__"), ("copy_reg", "_reconstructor"),
    ("_codecs", "encode"),
    *(("builtins", n) for n in ("object", "set", "frozenset", "dict", "list", "tuple", "slice",
                                "complex", "bytearray", "int", "float", "str", "bytes", "bool")),
    *(("__builtin__", n) for n in ("object", "set", "frozenset", "dict", "list", "tuple", "slice")),
}  # fmt: skip


# The pure-Python unpickler: its memo is a dict, where the C one grows an array to the
# largest memo index a file names (one damaged byte asked it for 18 GB).
class _ModelUnpickler(pickle._Unpickler):
    def find_class(self, module, name):
        top = module.split(".")[0]
        if top == "chumpy":
            return _ChumpyStub
        if module.startswith("scipy.sparse"):
            import scipy.sparse

            return getattr(scipy.sparse, name)
        if top == "numpy" or (module, name) in _SAFE_GLOBALS:
            return super().find_class(module, name)
        raise pickle.UnpicklingError(f"refusing to load {module}.{name}: not part of a model file")


def _to_dense(value) -> np.ndarray:
    if hasattr(value, "toarray"):  # scipy.sparse, as in SMPL's J_regressor
        return value.toarray()
    return np.asarray(value)


def _read_dict(path: Path) -> dict[str, np.ndarray]:
    if not path.exists():
        raise BodyFileError(f"{path}: no such file. Give the path of an SMPL-family model file.")
    suffix = path.suffix.lower()
    try:
        if suffix == ".pkl":
            # From memory, so that a damaged length field cannot ask the file for gigabytes.
            raw = _ModelUnpickler(io.BytesIO(path.read_bytes()), encoding="latin1").load()
            if not isinstance(raw, dict):
                raise BodyFileError(f"{path}: the pickle holds a {type(raw).__name__}, not a model dict.")
        elif suffix == ".npz":
            # numpy unpickles a non-zip file when allow_pickle is on (needed for the
            # object arrays of some SMPL-X files): refuse anything that is not a zip.
            if not zipfile.is_zipfile(path):
                raise BodyFileError(
                    f"{path}: not an .npz file (no zip archive inside); it may be truncated, "
                    "or another format with an .npz name."
                )
            # Our own handle: np.load leaks its file when a truncated zip makes it raise.
            with open(path, "rb") as f, np.load(f, allow_pickle=False) as z:
                raw, pickled = {}, []
                for k in z.files:
                    try:
                        raw[k] = z[k]
                    except ValueError as e:  # an object array (SMPL-X's name tables)
                        if "allow_pickle" not in str(e):
                            raise
                        pickled.append(k)
            needed = [k for k in pickled if k in _REQUIRED]
            if needed:  # a model array stored as a Python object: unpickle just that one
                with open(path, "rb") as f, np.load(f, allow_pickle=True) as z:
                    raw.update({k: z[k] for k in needed})
        else:
            raise BodyFileError(f"{path}: unknown model file type {suffix!r}; expected an SMPL-family .pkl or .npz.")
    except BodyFileError:
        raise
    except Exception as e:  # a corrupt pickle or zip can raise almost anything
        raise BodyFileError(
            f"{path}: cannot read the file ({type(e).__name__}: {e}); it may be corrupt or truncated."
        ) from e
    out = {}
    for k, v in raw.items():
        if not isinstance(k, str):
            continue
        try:
            out[k] = _to_dense(v)
        except Exception:  # metadata we do not need (strings, dicts, ...)
            continue
    missing = [k for k in _REQUIRED if k not in out]
    if missing:
        raise BodyFileError(f"{path}: not an SMPL-family model, missing {missing}. Found keys: {sorted(raw)}.")
    return out


def _reduce_to_smpl_tree(path: Path, d: dict[str, np.ndarray]) -> tuple[dict, str]:
    """Map a 24/52/55-joint model onto SMPL's 24 joints (see the module docstring)."""
    num_joints = d["weights"].shape[1]
    if num_joints == 24:
        return d, "smpl"
    if num_joints not in (52, 55):
        raise BodyFileError(
            f"{path}: a model with {num_joints} joints is not supported; jaxmocap reads SMPL "
            "(24), SMPL-H (52) and SMPL-X (55) files."
        )
    kind = "smplh" if num_joints == 52 else "smplx"
    parents = d["kintree_table"][0].astype(np.int64)
    parents[0] = -1
    left_base, right_base = (22, 37) if num_joints == 52 else (25, 40)

    def hand_of(j: int) -> int:
        # Walk up the tree to the body joint this joint hangs off; wrists 20/21 -> 22/23.
        while j >= 22:
            j = int(parents[j])
        return {20: 22, 21: 23}.get(j, j)

    weights = np.zeros((d["weights"].shape[0], 24), d["weights"].dtype)
    for j in range(num_joints):
        weights[:, j if j < 22 else hand_of(j)] += d["weights"][:, j]
    regressor = np.concatenate([d["J_regressor"][:22], d["J_regressor"][[left_base, right_base]]], 0)
    posedirs = d["posedirs"].reshape(d["posedirs"].shape[0], 3, -1)
    posedirs = np.concatenate([posedirs[..., : 21 * 9], np.zeros_like(posedirs[..., :18])], -1)
    shapedirs = d["shapedirs"]
    if kind == "smplx" and shapedirs.shape[-1] > 300:
        shapedirs = shapedirs[..., :300]  # the rest are expression directions
    reduced = dict(d, weights=weights, J_regressor=regressor, posedirs=posedirs, shapedirs=shapedirs)
    return reduced, kind


def _gender_from(path: Path) -> str:
    name = path.name.lower()
    for key, gender in (
        ("female", "female"),
        ("_f_", "female"),
        ("neutral", "neutral"),
        ("male", "male"),
        ("_m_", "male"),
    ):
        if key in name or key in str(path.parent.name).lower():
            return gender
    return "neutral"


def _find_in_directory(path: Path, gender: str) -> Path:
    tags = {"neutral": ("neutral", "_neu"), "male": ("_male", "male/", "_m_"), "female": ("female", "_f_")}[gender]
    candidates = sorted(p for p in path.rglob("*") if p.suffix.lower() in (".pkl", ".npz"))
    for p in candidates:
        rel = str(p.relative_to(path)).lower().replace(os.sep, "/")
        if any(t in "/" + rel for t in tags) and not (gender == "male" and "female" in rel):
            return p
    raise BodyFileError(
        f"{path}: no {gender} model file (.pkl/.npz) in this directory; found "
        f"{[str(p.name) for p in candidates] or 'none'}."
    )


def load_body(path, gender: str | None = None, num_betas: int | None = None, dtype=jnp.float32) -> Body:
    """Load an SMPL, SMPL-H or SMPL-X model file (or our own `.npz`) as a `Body`.

    Args:
        path: a model file, or a directory holding per-gender files (then `gender`
            picks one, e.g. `SMPL_FEMALE.pkl`, `smplh/female/model.npz`).
        gender: "neutral", "male" or "female". For a file, recorded as given (inferred
            from the file name when None).
        num_betas: keep this many shape components (default: all in the file).
        dtype: leaf dtype, float32 (default) or float64.
    Raises:
        BodyFileError: missing, corrupt, or unknown file, naming the file and the problem.
    """
    path = Path(path)
    if gender is not None and gender not in ("neutral", "male", "female"):
        raise ValueError(f"gender must be 'neutral', 'male' or 'female', got {gender!r}.")
    if path.is_dir():
        path = _find_in_directory(path, gender or "neutral")
    if num_betas is not None and (not isinstance(num_betas, (int, np.integer)) or num_betas < 1):
        raise ValueError(f"num_betas must be an int >= 1 (or None for all), got {num_betas!r}.")
    d = _read_dict(path)
    try:
        return _body_from_dict(path, d, gender, num_betas, dtype)
    except BodyFileError:
        raise
    except (ValueError, TypeError, IndexError, KeyError, AttributeError) as e:
        # Arrays of the wrong rank or kind (a damaged file that still unpickles).
        raise BodyFileError(f"{path}: inconsistent model arrays ({type(e).__name__}: {e}).") from e


def _body_from_dict(path: Path, d: dict, gender, num_betas, dtype) -> Body:
    """The body of `load_body` once the file's arrays are read."""
    d, kind = _reduce_to_smpl_tree(path, d)
    if "kind" in d and d["kind"].ndim == 0:  # written by save_body or our converter
        kind = str(d["kind"])
    shapedirs = d["shapedirs"]  # SMPL file layout (V, 3, B)
    if num_betas is not None:
        if num_betas > shapedirs.shape[-1]:
            raise ValueError(f"{path}: num_betas={num_betas} but the file has {shapedirs.shape[-1]} shape components.")
        shapedirs = shapedirs[..., :num_betas]
    V = d["v_template"].shape[0]
    posedirs = d.get("posedirs", np.zeros((V, 3, 207)))
    names = tuple(str(n) for n in d["joint_names"]) if "joint_names" in d else SMPL_JOINT_NAMES
    if "gender" in d and d["gender"].ndim == 0 and gender is None:
        gender = str(d["gender"])
    try:
        return make_body(
            v_template=d["v_template"],
            faces=d["f"].astype(np.int64),
            shapedirs=shapedirs,
            posedirs=posedirs.reshape(V, 3, -1),
            J_regressor=d["J_regressor"],
            weights=d["weights"],
            parents=SMPL_PARENTS,
            joint_names=names,
            kind=kind,
            gender=gender or _gender_from(path),
            dtype=dtype,
        )
    except ValueError as e:
        raise BodyFileError(f"{path}: inconsistent model arrays: {e}") from e


def save_body(body: Body, path) -> Path:
    """Write `body` as an SMPL-layout `.npz` that `load_body` reads back unchanged
    (`.npz` appended to other names; an existing folder is refused)."""
    from .._checks import output_npz

    if not isinstance(body, Body):
        raise ValueError(f"save_body: body must be a jaxmocap Body, got {type(body).__name__}.")
    path = output_npz(path, "save_body", "body.npz")
    kintree = np.stack([np.array(body.parents), np.arange(body.num_joints)])
    np.savez_compressed(
        path,
        v_template=np.asarray(body.v_template),
        f=body.faces,
        shapedirs=np.moveaxis(np.asarray(body.shapedirs), 0, -1),
        posedirs=np.moveaxis(np.asarray(body.posedirs), 0, -1),
        J_regressor=np.asarray(body.J_regressor),
        weights=np.asarray(body.weights),
        kintree_table=kintree,
        joint_names=np.array(body.joint_names),
        kind=np.array(body.kind),
        gender=np.array(body.gender),
    )
    return path


_DEFAULT_CACHE: dict = {}


def default_body(resolution: str = "low", dtype=jnp.float32) -> Body:
    """The bundled open (CC0) body derived from MakeHuman, in SMPL's layout.

    Args:
        resolution: "low" (~1.5k vertices; default for tests and batches) or "full"
            (~14k vertices).
    See `jaxmocap/body/data/README.md` for how it differs from SMPL.
    """
    if resolution not in ("low", "full"):
        raise ValueError(f"resolution must be 'low' or 'full', got {resolution!r}.")
    key = (resolution, jnp.dtype(dtype).name)
    if key not in _DEFAULT_CACHE:
        body = load_body(_DATA / f"default_body_{resolution}.npz", gender="neutral", dtype=dtype)
        _DEFAULT_CACHE[key] = dataclasses.replace(body, kind="default")
    return _DEFAULT_CACHE[key]


#: Short names accepted wherever a body is asked for (or give a model file path).
BODY_CHOICES = ("default-low", "default-full", "mannequin")


def resolve_body(spec: str | os.PathLike | Body | None = "default-low") -> Body:
    """A body from "default-low", "default-full", "mannequin", or a model file path.

    Raises:
        BodyFileError (a ValueError) for a missing or unreadable model file.
    """
    if isinstance(spec, Body):
        return spec
    spec = "default-low" if spec is None else spec
    if spec in ("default-low", "default-full"):
        return default_body(str(spec).split("-")[1])
    if spec == "mannequin":
        from .mannequin import mannequin_body

        return mannequin_body(detail=2)
    path = Path(spec)
    if not path.exists() and path.suffix.lower() not in (".pkl", ".npz"):
        raise BodyFileError(
            f"{spec}: not a body name or a model file; use default-low, default-full, mannequin, "
            "or the path of an SMPL / SMPL-H / SMPL-X .pkl or .npz file."
        )
    return load_body(spec)
