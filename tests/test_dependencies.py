"""Every third-party package the code imports is declared in pyproject.toml's ``dependencies``."""

from __future__ import annotations

import ast
import re
import sys
import tomllib
from importlib.metadata import packages_distributions
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _normal(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def _imported_top_level(src: Path) -> dict[str, str]:
    """Top-level module names imported anywhere under ``src`` (absolute imports), each with one file using it."""
    found: dict[str, str] = {}
    for path in sorted(src.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            else:
                continue
            for name in names:
                found.setdefault(name.split(".")[0], str(path.relative_to(ROOT)))
    return found


@pytest.mark.slow
def test_every_third_party_import_is_declared() -> None:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    declared = {_normal(re.split(r"[\[<>=!~; ]", d, maxsplit=1)[0]) for d in project["dependencies"]}
    dists = packages_distributions()
    imported = _imported_top_level(ROOT / "src" / "trafficgeo")
    third_party = {m: f for m, f in imported.items()
                   if m not in sys.stdlib_module_names and m not in ("trafficgeo", "__future__")}
    assert {"numpy", "pandas", "affine", "supervision", "cv2", "sumo"} <= set(third_party)  # the scan sees them
    missing = []
    for module, where in sorted(third_party.items()):
        names = {_normal(d) for d in dists.get(module, [module])}
        if not names & declared:
            missing.append(f"{module} (from {sorted(names)}, imported in {where})")
    assert not missing, f"imported but not in pyproject dependencies: {missing}"
