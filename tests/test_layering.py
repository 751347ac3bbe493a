"""The import layering docs/architecture.md states: camera -> calibration -> geo -> site -> traffic / video
(siblings) -> pipeline / simulation -> synth/report/ui -> batch/demo -> cli, with errors, version, crs, groups and io
at the bottom; no module imports a layer above its own or a sibling (imports inside functions and under
TYPE_CHECKING count too, and a name of the package's namespace is its ``__init__``), and synth, report and ui do not
import each other; no private name crosses a module and no module re-exports what it imports (package ``__init__``
namespaces aside)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "trafficgeo"
# Each top-level part of the package and its layer; a part may import only parts of a lower layer.
LAYER = {"errors": 0, "version": 0, "crs": 1, "groups": 1, "io": 2, "camera": 3, "calibration": 4, "geo": 5,
         "site": 6, "run": 7, "traffic": 8, "registration": 8, "video": 8, "simulation": 9, "pipeline": 9,
         "synth": 10, "report": 10, "ui": 10, "batch": 11, "demo": 11, "cli": 12, "__init__": 13}


def part_of(path: Path) -> str:
    """The top-level part of the package a file belongs to (``geo`` for geo/surface.py, ``crs`` for crs.py)."""
    rel = path.relative_to(PACKAGE).parts
    return rel[0].removesuffix(".py")


def imported_parts(path: Path) -> set[tuple[str, int]]:
    """(part, line) of every trafficgeo part that ``path`` imports, absolute or relative."""
    return parts_in(path.read_text(encoding="utf-8"), path.relative_to(PACKAGE).parts)


def parts_in(text: str, rel: tuple[str, ...]) -> set[tuple[str, int]]:
    """(part, line) of every trafficgeo part imported by source ``text`` of the file at ``rel`` in the package."""
    found = set()
    for node in ast.walk(ast.parse(text)):
        names: list[str] = []
        if isinstance(node, ast.ImportFrom):
            if node.level:  # relative: resolve against the file's package
                base = ["trafficgeo", *rel[:-1]][: len(rel) + 1 - node.level]
                names.append(".".join(base + ([node.module] if node.module else [])))
                if not node.module:
                    names += [".".join([*base, a.name]) for a in node.names]
            elif node.module:
                names.append(node.module)
                if node.module == "trafficgeo":  # a part, or a name of the package's namespace (its __init__)
                    names += [f"trafficgeo.{a.name if a.name in LAYER else '__init__'}" for a in node.names]
        elif isinstance(node, ast.Import):
            names += [a.name for a in node.names]
        for name in names:
            bits = name.split(".")
            if bits[0] == "trafficgeo" and len(bits) > 1 and bits[1] in LAYER:
                found.add((bits[1], node.lineno))
    return found


def test_every_part_has_a_layer() -> None:
    parts = {part_of(p) for p in PACKAGE.rglob("*.py")}
    assert parts <= set(LAYER), f"parts without a layer in this test: {sorted(parts - set(LAYER))}"


@pytest.mark.parametrize("path", sorted(PACKAGE.rglob("*.py")), ids=lambda p: str(p.relative_to(PACKAGE)))
def test_no_import_goes_up_a_layer(path: Path) -> None:
    src = part_of(path)
    bad = [f"line {line}: {src} imports {dst}" for dst, line in sorted(imported_parts(path))
           if dst != src and LAYER[dst] >= LAYER[src]]
    assert not bad, f"{path.relative_to(PACKAGE)}: " + "; ".join(bad)


def test_the_checker_sees_every_form_of_import() -> None:
    """The checker itself: imports inside a function, relative ones and ``from trafficgeo import x`` are found."""
    text = ("import numpy\nfrom trafficgeo.errors import InputError\ndef f():\n"
            "    from trafficgeo.video import detectors\n    from ..traffic import lanes\n"
            "    from . import raster\n    from trafficgeo import synth\n")
    assert {p for p, _ in parts_in(text, ("geo", "surface.py"))} == {"errors", "video", "traffic", "geo", "synth"}


def _module_name(path: Path) -> str:
    return ".".join(("trafficgeo", *path.relative_to(PACKAGE).with_suffix("").parts)).removesuffix(".__init__")


def _top_level_names(tree: ast.Module) -> set[str]:
    """Names a module defines itself (functions, classes, assignments), not those it imports."""
    names: set[str] = set()
    for node in tree.body:
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            names.add(node.name)
        elif isinstance(node, ast.Assign | ast.AnnAssign):
            for target in node.targets if isinstance(node, ast.Assign) else [node.target]:
                names |= {n.id for n in ast.walk(target) if isinstance(n, ast.Name)}
    return names


def _absolute_imports(tree: ast.Module) -> list[tuple[str, str, int]]:
    """(module, name, line) of every ``from trafficgeo.x import name`` in ``tree``."""
    return [(node.module, a.name, node.lineno) for node in ast.walk(tree)
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module
            and node.module.startswith("trafficgeo.") for a in node.names]


def test_no_private_name_crosses_a_module() -> None:
    """A helper another module needs is public in the module that defines it (no ``from m import _helper``)."""
    bad = [f"{path.relative_to(PACKAGE)}:{line} imports {name} from {module}"
           for path in sorted(PACKAGE.rglob("*.py"))
           for module, name, line in _absolute_imports(ast.parse(path.read_text(encoding="utf-8")))
           if name.startswith("_") and not name.startswith("__")]
    assert not bad, "; ".join(bad)


def test_names_are_imported_from_the_module_that_defines_them() -> None:
    """No module passes on names it imports (a re-export facade): importers name the defining module. Package
    ``__init__`` files are the curated namespaces and may re-export."""
    trees = {_module_name(p): (ast.parse(p.read_text(encoding="utf-8")), p.name == "__init__.py")
             for p in PACKAGE.rglob("*.py")}
    own = {module: _top_level_names(tree) for module, (tree, _) in trees.items()}
    bad = []
    for path in sorted(PACKAGE.rglob("*.py")):
        for module, name, line in _absolute_imports(trees[_module_name(path)][0]):
            if module in trees and not trees[module][1] and name not in own[module] \
                    and f"{module}.{name}" not in trees:
                bad.append(f"{path.relative_to(PACKAGE)}:{line} imports {name} from {module}, which only imports it")
    assert not bad, "; ".join(bad)


def test_the_facade_checks_see_a_facade() -> None:
    tree = ast.parse("from trafficgeo.geo.raster import _to_pyproj, open_raster\nx = 1\ndef f():\n    pass\n")
    assert [n for _, n, _ in _absolute_imports(tree) if n.startswith("_")] == ["_to_pyproj"]
    assert _top_level_names(tree) == {"x", "f"}


def _runtime_imports(tree: ast.AST) -> set[str]:
    """The trafficgeo modules a module imports when it runs (module level and inside functions; not under
    ``if TYPE_CHECKING:``, which are for type checkers only). ``from trafficgeo.ui import live`` imports the package
    ``trafficgeo.ui`` (its ``__init__``)."""
    found: set[str] = set()

    class Visit(ast.NodeVisitor):
        def visit_If(self, node: ast.If) -> None:
            if "TYPE_CHECKING" in ast.unparse(node.test):
                for child in node.orelse:
                    self.visit(child)
                return
            self.generic_visit(node)

        def visit_ImportFrom(self, node: ast.ImportFrom) -> None:
            if node.level == 0 and node.module and node.module.split(".")[0] == "trafficgeo":
                found.add(node.module)

    Visit().visit(tree)
    return found


def _circles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The import circles of a module graph: its strongly connected components of two modules or more (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in edges.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return out


def test_no_import_circles() -> None:
    """No two modules need each other when they run (a circle means neither can be understood, tested or moved
    alone; imports inside functions count, those for type checkers only do not)."""
    edges = {_module_name(p): _runtime_imports(ast.parse(p.read_text(encoding="utf-8")))
             for p in PACKAGE.rglob("*.py")}
    assert _circles(edges) == []


def test_the_circle_check_sees_a_circle() -> None:
    assert _circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    tree = ast.parse("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from trafficgeo.a import X\n"
                     "def f():\n    from trafficgeo.b import Y\nfrom trafficgeo import c\n")
    assert _runtime_imports(tree) == {"trafficgeo.b", "trafficgeo"}
