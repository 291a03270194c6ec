"""Check that bifid's imports flow one way and form no cycles.

The layers (DESIGN.md): errors → systems → io, signal, simulate → data → continuation →
cbc → identify → report → demo → cli. A module may import modules of its own layer or of a
lower one, never of a higher one — at module level or inside a function. Tests import
bifid's public modules and names only.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "bifid"
RANK = {
    "errors": 0,
    "systems": 1,
    "io": 2,
    "signal": 2,
    "simulate": 2,
    "data": 3,
    "continuation": 4,
    "cbc": 5,
    "identify": 6,
    "parallel": 6,
    "report": 7,
    "demo": 8,
    "cli": 9,
    "__main__": 10,
}


def _layer(module: str) -> str | None:
    parts = module.split(".")
    if parts[0] != "bifid" or len(parts) < 2:
        return None
    return parts[1]


def _module_name(path: Path) -> str:
    rel = path.relative_to(SRC.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _typing_only(tree: ast.AST) -> set[ast.AST]:
    """Nodes inside ``if TYPE_CHECKING:`` blocks (never imported at run time)."""
    nodes: set[ast.AST] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            for stmt in node.body:
                nodes.update(ast.walk(stmt))
    return nodes


def _imports(path: Path, runtime_only: bool = False) -> list[tuple[str, int]]:
    tree = ast.parse(path.read_text(), filename=str(path))
    package = (
        _module_name(path) if path.name == "__init__.py" else _module_name(path).rpartition(".")[0]
    )
    skip = _typing_only(tree) if runtime_only else set()
    out = []
    for node in ast.walk(tree):
        if node in skip:
            continue
        if isinstance(node, ast.Import):
            out += [(a.name, node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            out.append((mod, node.lineno))
    return out


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in SRC.rglob("*.py")}


def test_every_package_has_a_layer() -> None:
    """Check that each subpackage / module of bifid is placed in a layer."""
    missing = sorted({_layer(m) for m in _modules()} - set(RANK) - {None})
    assert not missing, f"modules with no layer in DESIGN.md's order: {missing}"


def test_imports_flow_one_way() -> None:
    """Check that no module imports a module of a higher layer."""
    bad = []
    for name, path in _modules().items():
        own = _layer(name)
        if own is None:
            continue
        for target, line in _imports(path):
            layer = _layer(target)
            if layer is not None and RANK.get(layer, -1) > RANK[own]:
                bad.append(f"{path.relative_to(SRC.parent)}:{line} ({own}) imports {target}")
    assert not bad, "imports against the layer order:\n" + "\n".join(bad)


def test_no_import_cycles() -> None:
    """Check that the run-time import graph (module-level and local imports) is acyclic."""
    mods = _modules()
    graph: dict[str, set[str]] = {m: set() for m in mods}
    for name, path in mods.items():
        for target, _ in _imports(path, runtime_only=True):
            # an import of a.b.c depends on the module a.b.c if it exists, else on a.b
            while target and target not in mods:
                target = target.rpartition(".")[0]
            if target and target != name and not name.startswith(target + "."):
                graph[name].add(target)
    # packages' __init__ re-export their submodules: edges into a package's own
    # submodules from its __init__ are expected, cycles through them are not
    colour: dict[str, int] = {}
    stack: list[str] = []

    def visit(m: str) -> list[str] | None:
        colour[m] = 1
        stack.append(m)
        for t in sorted(graph[m]):
            if colour.get(t) == 1:
                return [*stack[stack.index(t) :], t]
            if colour.get(t) is None:
                found = visit(t)
                if found:
                    return found
        stack.pop()
        colour[m] = 2
        return None

    for m in sorted(graph):
        if colour.get(m) is None:
            cycle = visit(m)
            if cycle:
                pytest.fail("import cycle: " + " -> ".join(cycle))


#: white-box tests of numerical kernels that have no public entry point of their own
#: (GMRES with a stale factorisation, fold measures without SVDs, the homoclinic test);
#: their public behaviour is tested through the continuation functions elsewhere
WHITE_BOX = {"test_continuation_krylov.py"}


def test_tests_use_the_public_api() -> None:
    """Check that tests import bifid's public modules and names only (no ``_private``)."""
    tests = Path(__file__).resolve().parent
    bad = []
    for path in sorted(tests.rglob("*.py")):
        if path.name in WHITE_BOX:
            continue
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                names = [(a.name, "") for a in node.names]
            elif isinstance(node, ast.ImportFrom) and not node.level:
                names = [(node.module or "", a.name) for a in node.names]
            else:
                continue
            for module, name in names:
                private = any(p.startswith("_") for p in module.split(".")[1:])
                if module.split(".")[0] == "bifid" and (private or name.startswith("_")):
                    where = path.relative_to(tests.parent)
                    bad.append(f"{where}:{node.lineno} imports {module} {name}".rstrip())
    assert not bad, "tests importing private modules or names:\n" + "\n".join(bad)
