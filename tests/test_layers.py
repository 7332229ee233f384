"""The package's layers: a module imports only from its own layer or the ones below.

Walks every module's imports with `ast` (function bodies included: a lazy import is still
an import), so an upward import fails here rather than in a review.
"""

import ast
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "jaxmocap"

# Bottom to top, as the README's architecture paragraph lists them.
LAYERS = [
    (
        "maths",
        {"rotation", "timeseries", "_checks", "_progress", "_compat", "_threads", "_cache", "_cli_env", "_files"},
    ),
    ("models", {"body", "solve"}),
    ("data", {"motion", "formats", "metrics", "objects"}),
    ("geometry", {"geometry"}),
    ("drawing", {"viz"}),
    ("observation models", {"energies", "sensors", "priors"}),
    ("methods", {"methods", "learned"}),
    ("checks", {"physics"}),
    ("application", {"app"}),
    ("entry points", {"cli", "__main__"}),
]
LAYER = {name: i for i, (_, names) in enumerate(LAYERS) for name in names}


# Imports that run up the layers on purpose: one-release aliases of names that moved up
# (module -> the module its alias imports, lazily). Remove each with its alias.
DEPRECATED_ALIASES = {
    ("jaxmocap.methods.inertial", "jaxmocap.app.scenarios"),  # from_scenario -> inertial_setup
    ("jaxmocap.methods.visual_inertial", "jaxmocap.app.scenarios"),  # from_scenario, tracker/associated_keypoints
    ("jaxmocap.methods.interaction", "jaxmocap.app.scenarios"),  # InteractionObservations.from_scenario
}


def _alias(module: str, target: str) -> bool:
    return any(module == m and (target == t or target.startswith(t + ".")) for m, t in DEPRECATED_ALIASES)


def _unit(module: str) -> str:
    """'jaxmocap.body.io' -> 'body' (the top-level unit a layer lists)."""
    return module.split(".")[1] if module.count(".") else ""


def _absolute(node: ast.ImportFrom, package: str) -> str:
    """The absolute module a `from ... import` in `package` reads from."""
    if not node.level:
        return node.module or ""
    base = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
    return f"{base}.{node.module}" if node.module else base


def _imports(path: Path):
    module = "jaxmocap." + ".".join(path.relative_to(PACKAGE).with_suffix("").parts).removesuffix(".__init__")
    package = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.ImportFrom):
            target = _absolute(node, package)
            names = [target] if node.module else [f"{target}.{a.name}" for a in node.names]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        else:
            continue
        for name in names:
            if name.startswith("jaxmocap.") and name.count(".") >= 1:
                yield module, name, node.lineno


def test_every_unit_has_a_layer():
    units = {
        p.stem if p.is_file() else p.name
        for p in PACKAGE.iterdir()
        if (p.suffix == ".py" or (p / "__init__.py").exists()) and p.name != "__init__.py"
    }
    assert units <= set(LAYER), f"units without a layer (add them to LAYERS): {sorted(units - set(LAYER))}"


def test_no_import_runs_up_the_layers():
    upward = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if path == PACKAGE / "__init__.py":
            continue  # the package's front door re-exports from every layer
        for module, target, line in _imports(path):
            src, dst = _unit(module), _unit(target)
            if _alias(module, target):
                continue
            if src in LAYER and dst in LAYER and LAYER[dst] > LAYER[src]:
                upward.append(
                    f"{path.relative_to(PACKAGE.parent)}:{line}: {src} ({LAYERS[LAYER[src]][0]}) imports {target} ({LAYERS[LAYER[dst]][0]})"
                )
    assert not upward, "imports that run up the layers:\n" + "\n".join(upward)


def test_the_checker_sees_an_upward_import(tmp_path):
    # The walk must find lazy imports inside functions, or the test above proves nothing.
    fake = tmp_path / "jaxmocap" / "body" / "x.py"
    fake.parent.mkdir(parents=True)
    fake.write_text("def f():\n    from ..app import demo\n")
    global PACKAGE
    saved, PACKAGE = PACKAGE, tmp_path / "jaxmocap"
    try:
        assert [(m, t) for m, t, _ in _imports(fake)] == [("jaxmocap.body.x", "jaxmocap.app")]
    finally:
        PACKAGE = saved


@pytest.mark.parametrize("heavy", ["matplotlib", "trimesh", "mujoco", "jaxopt", "scipy.optimize"])
def test_import_jaxmocap_stays_light(heavy):
    code = f"import jaxmocap, sys; print({heavy!r} in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False", f"`import jaxmocap` imports {heavy}"


def _module_graph() -> dict[str, set[str]]:
    """module -> the package modules it imports.

    Every import counts, at module level or inside a function: a lazy import only
    postpones the circle to the first call, and two modules that import each other can
    be neither read nor moved apart. A package is a module too (its __init__): `from
    ..solve import Term` is an edge to `jaxmocap.solve`, whose re-exports are edges to
    its submodules, so a circle through a package's front door is found. Left out is the
    implicit import of a module's parent packages (importing jaxmocap.solve.batch runs
    jaxmocap/solve/__init__.py first): every package that re-exports its submodules
    would close a harmless circle with each of them.
    """
    files = {p: ".".join(("jaxmocap",) + p.relative_to(PACKAGE).with_suffix("").parts).removesuffix(".__init__")
             for p in PACKAGE.rglob("*.py")}  # fmt: skip
    modules = set(files.values())
    graph: dict[str, set[str]] = {m: set() for m in modules}
    for path, module in files.items():
        for _, target, _ in _imports(path):
            while target not in modules and "." in target:
                target = target.rsplit(".", 1)[0]  # `from .sweep import atomic_write` -> the module
            if target in modules and target != module and not _alias(module, target):
                graph[module].add(target)
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


# Old public names (module, name) -> where they live now; they resolve until the next release.
MOVED = {
    ("jaxmocap.sensors.camera", "project"): ("jaxmocap.geometry.camera", "project"),
    ("jaxmocap.sensors.camera", "undistort_pixels"): ("jaxmocap.geometry.camera", "undistort_pixels"),
    ("jaxmocap.sensors.camera", "camera_imu"): ("jaxmocap.sensors.moving_camera", "camera_imu"),
    ("jaxmocap.sensors.camera", "handheld_trajectory"): ("jaxmocap.sensors.moving_camera", "handheld_trajectory"),
    ("jaxmocap.sensors.keypoints", "keypoint_regressor"): ("jaxmocap.geometry.keypoints", "keypoint_regressor"),
    ("jaxmocap.sensors.keypoints", "KEYPOINT_FORMATS"): ("jaxmocap.geometry.keypoints", "KEYPOINT_FORMATS"),
    ("jaxmocap.sensors.keypoints", "detect"): ("jaxmocap.sensors.detector", "detect"),
    ("jaxmocap.sensors.keypoints", "person_track"): ("jaxmocap.sensors.detector", "person_track"),
    ("jaxmocap.sensors.triangulation", "select_person"): ("jaxmocap.geometry.triangulation", "select_person"),
    ("jaxmocap.sensors.calibration", "normalize_to_root"): ("jaxmocap.geometry.imu_calibration", "normalize_to_root"),
    ("jaxmocap.sensors.silhouette", "rasterize_views"): ("jaxmocap.geometry.raster", "rasterize_views"),
    ("jaxmocap.sensors.depth", "visible_vertices"): ("jaxmocap.geometry.raster", "visible_vertices"),
    ("jaxmocap.sensors.segmentation", "select_candidate"): ("jaxmocap.geometry.masks", "select_candidate"),
    ("jaxmocap.sensors.imu", "ray_vertex"): ("jaxmocap.geometry.surface", "ray_vertex"),
    ("jaxmocap.methods.inertial", "from_scenario"): ("jaxmocap.app.scenarios", "inertial_setup"),
    ("jaxmocap.methods.visual_inertial", "from_scenario"): ("jaxmocap.app.scenarios", "vip_sequence"),
    ("jaxmocap.methods.visual_inertial", "associated_keypoints"): ("jaxmocap.app.scenarios", "associated_keypoints"),
}


@pytest.mark.parametrize("old", sorted(MOVED), ids=".".join)
def test_moved_names_still_resolve(old):
    import importlib

    new = MOVED[old]
    assert getattr(importlib.import_module(old[0]), old[1]) is getattr(importlib.import_module(new[0]), new[1])


def test_no_import_circles():
    assert _cycles({"a": {"b"}, "b": {"a"}, "c": {"a"}}) == [["a", "b"]]  # the checker sees one
    cycles = _cycles(_module_graph())
    assert not cycles, "modules that import each other (directly or round a circle):\n" + "\n".join(
        " <-> ".join(c) for c in cycles
    )


def test_the_checker_sees_a_circle_through_a_package(tmp_path):
    # a/x.py imports b's front door in a function; b/y.py imports a's: a circle that only
    # counting packages (and lazy imports) as modules finds.
    files = {"__init__.py": "", "a/__init__.py": "from .x import f\n", "a/x.py": "def f():\n    from ..b import g\n",
             "b/__init__.py": "from .y import g\n", "b/y.py": "from ..a import f\ng = f\n"}  # fmt: skip
    for name, text in files.items():
        (tmp_path / "jaxmocap" / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / "jaxmocap" / name).write_text(text)
    global PACKAGE
    saved, PACKAGE = PACKAGE, tmp_path / "jaxmocap"
    try:
        assert _cycles(_module_graph()) == [["jaxmocap.a", "jaxmocap.a.x", "jaxmocap.b", "jaxmocap.b.y"]]
    finally:
        PACKAGE = saved


# Underscored names imported from another module that are allowed (none: the owner makes a
# public name instead).
PRIVATE_IMPORTS_ALLOWED: set = set()


def _private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def _is_module(qualified: str, package: Path) -> bool:
    """Whether 'jaxmocap.a.b' names a module or package of the tree rooted at `package`."""
    path = package.joinpath(*qualified.split(".")[1:])
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


def _private_uses(path: Path, package: Path):
    """(line, 'jaxmocap.module._name') for each underscored name this file takes from
    another module: `from X import _name`, or `X._name` with X an imported module.
    Private modules themselves (`from .. import _compat`) are the package's own and allowed."""
    module = ".".join(("jaxmocap",) + path.relative_to(package).with_suffix("").parts).removesuffix(".__init__")
    pkg = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
    tree = ast.parse(path.read_text(), str(path))
    modules = {}  # local name -> the jaxmocap module it is bound to
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            target = _absolute(node, pkg)
            if target != "jaxmocap" and not target.startswith("jaxmocap."):
                continue
            for a in node.names:
                qualified = f"{target}.{a.name}"
                if _is_module(qualified, package):
                    modules[a.asname or a.name] = qualified
                elif _private(a.name):
                    yield node.lineno, qualified
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name.startswith("jaxmocap.") and a.asname:
                    modules[a.asname] = a.name
    for node in ast.walk(tree):
        if (isinstance(node, ast.Attribute) and _private(node.attr) and isinstance(node.value, ast.Name)
                and node.value.id in modules and modules[node.value.id] != module):  # fmt: skip
            qualified = f"{modules[node.value.id]}.{node.attr}"
            if not _is_module(qualified, package):
                yield node.lineno, qualified


def test_no_private_name_crosses_modules():
    # A helper two modules share is a public (documented) name of its owner, or lives in a
    # private module (`_checks`, `_files`, ...): an underscored name promises "only here".
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE).as_posix()
        for line, name in _private_uses(path, PACKAGE):
            if (rel, name) not in PRIVATE_IMPORTS_ALLOWED:
                found.append(f"jaxmocap/{rel}:{line}: uses {name}")
    assert not found, "underscored names used outside their module (make them public there):\n" + "\n".join(found)


def test_the_checker_sees_a_private_name(tmp_path):
    package = tmp_path / "jaxmocap"
    (package / "solve").mkdir(parents=True)
    for name in ("__init__.py", "_checks.py", "solve/__init__.py", "solve/solver.py"):
        (package / name).write_text("")
    user = package / "solve" / "batch.py"
    user.write_text("from .solver import _check, solve\nfrom .. import _checks\nfrom . import solver as S\n"
                    "def f():\n    from jaxmocap.solve import solver\n    return S._core, solver._x, _checks.check\n")  # fmt: skip
    assert sorted(_private_uses(user, package)) == [
        (1, "jaxmocap.solve.solver._check"),
        (6, "jaxmocap.solve.solver._core"),
        (6, "jaxmocap.solve.solver._x"),
    ]


def _jax_internals(path: Path):
    """Lines that reach into `jax._src`: imports and attribute reads."""
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            if (
                node.module == "jax._src"
                or node.module.startswith("jax._src.")
                or (node.module == "jax" and any(a.name == "_src" for a in node.names))
            ):
                yield node.lineno
        elif isinstance(node, ast.Import) and any(
            a.name == "jax._src" or a.name.startswith("jax._src.") for a in node.names
        ):
            yield node.lineno
        elif (
            isinstance(node, ast.Attribute)
            and node.attr == "_src"
            and isinstance(node.value, ast.Name)
            and node.value.id == "jax"
        ):
            yield node.lineno


def test_jax_internals_only_in_compat():
    # JAX's private modules move between releases: every use sits in `_compat.py`, where
    # tests/test_compat.py names the break.
    assert list(_jax_internals(Path(__file__))) == []  # this file only names them in strings
    found = [f"{p.relative_to(PACKAGE.parent)}:{line}" for p in sorted(PACKAGE.rglob("*.py"))
             if p != PACKAGE / "_compat.py" for line in _jax_internals(p)]  # fmt: skip
    assert not found, "jax._src used outside jaxmocap/_compat.py (move it there):\n" + "\n".join(found)


def test_the_checker_sees_jax_internals(tmp_path):
    fake = tmp_path / "x.py"
    fake.write_text("import jax\nfrom jax._src import xla_bridge\nfrom jax import _src\nimport jax._src.core\n"
                    "def f():\n    return jax._src.config\n")  # fmt: skip
    assert sorted(_jax_internals(fake)) == [2, 3, 4, 6]


@pytest.mark.parametrize("command", [["check"], ["format", "--check"]])
def test_tree_passes_ruff(command):
    # The pinned ruff (constraints.txt) with pyproject.toml's rules and format: CI runs the
    # suite, so it refuses what `make lint` would.
    root = PACKAGE.parent
    run = subprocess.run([sys.executable, "-m", "ruff", *command, "jaxmocap", "tests", "benchmarks", "experiments"],
                         cwd=root, capture_output=True, text=True)  # fmt: skip
    assert run.returncode == 0, (
        f"ruff {' '.join(command)} (fix: make lint's commands without --check):\n{run.stdout[-3000:]}"
    )
