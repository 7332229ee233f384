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
    ("maths", {"rotation", "timeseries", "_checks", "_progress", "_compat", "_threads", "_cache", "_cli_env", "_files"}),
    ("models", {"body", "solve"}),
    ("data", {"motion", "formats", "metrics", "objects"}),
    ("drawing", {"viz"}),
    ("observation models", {"energies", "sensors", "priors"}),
    ("methods", {"methods", "learned"}),
    ("checks", {"physics"}),
    ("application", {"app"}),
    ("entry points", {"cli", "__main__"}),
]
LAYER = {name: i for i, (_, names) in enumerate(LAYERS) for name in names}


def _unit(module: str) -> str:
    """'jaxmocap.body.io' -> 'body' (the top-level unit a layer lists)."""
    return module.split(".")[1] if module.count(".") else ""


def _imports(path: Path):
    module = "jaxmocap." + ".".join(path.relative_to(PACKAGE).with_suffix("").parts).removesuffix(".__init__")
    package = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                target = f"{base}.{node.module}" if node.module else base
            else:
                target = node.module or ""
            names = [target] if node.module else [f"{target}.{a.name}" for a in node.names]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        else:
            continue
        for name in names:
            if name.startswith("jaxmocap.") and name.count(".") >= 1:
                yield module, name, node.lineno


def test_every_unit_has_a_layer():
    units = {p.stem if p.is_file() else p.name for p in PACKAGE.iterdir() if (p.suffix == ".py" or (p / "__init__.py").exists()) and p.name != "__init__.py"}
    assert units <= set(LAYER), f"units without a layer (add them to LAYERS): {sorted(units - set(LAYER))}"


def test_no_import_runs_up_the_layers():
    upward = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if path == PACKAGE / "__init__.py":
            continue  # the package's front door re-exports from every layer
        for module, target, line in _imports(path):
            src, dst = _unit(module), _unit(target)
            if src in LAYER and dst in LAYER and LAYER[dst] > LAYER[src]:
                upward.append(f"{path.relative_to(PACKAGE.parent)}:{line}: {src} ({LAYERS[LAYER[src]][0]}) imports {target} ({LAYERS[LAYER[dst]][0]})")
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
    """module -> the package modules it imports (lazy imports included), packages' own
    __init__ re-exports left out (they import their submodules by design)."""
    files = {p: "jaxmocap." + ".".join(p.relative_to(PACKAGE).with_suffix("").parts) for p in PACKAGE.rglob("*.py")}
    modules = {m for p, m in files.items() if p.name != "__init__.py"}
    graph: dict[str, set[str]] = {m: set() for m in modules}
    for path in files:
        if path.name == "__init__.py":
            continue
        for module, target, _ in _imports(path):
            while target and target not in modules and "." in target:
                target = target.rsplit(".", 1)[0]  # `from .sweep import atomic_write` -> the module
            if target in modules and target != module:
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


def test_no_import_circles():
    assert _cycles({"a": {"b"}, "b": {"a"}, "c": {"a"}}) == [["a", "b"]]  # the checker sees one
    cycles = _cycles(_module_graph())
    assert not cycles, "modules that import each other (directly or round a circle):\n" + "\n".join(" <-> ".join(c) for c in cycles)
