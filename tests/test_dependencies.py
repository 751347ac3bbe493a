"""Every third-party package the code imports is declared in pyproject.toml's ``dependencies``, or, for the
modules of an optional extra, in that extra and imported only by the modules :data:`EXTRAS` allows."""

from __future__ import annotations

import ast
import re
import sys
import tomllib
from importlib.metadata import packages_distributions
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: optional extra -> the only source files that may import its packages (lazily, with a hint to install it)
EXTRAS = {"cluster": {"src/trafficgeo/batch/runner.py"}, "openvino": {"src/trafficgeo/video/detectors/backends.py"},
          "test": {"src/trafficgeo/synth/identity.py"}}


def _normal(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def _imported_top_level(src: Path) -> dict[str, set[str]]:
    """Top-level module names imported anywhere under ``src`` (absolute imports), each with the files using it."""
    found: dict[str, set[str]] = {}
    for path in sorted(src.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            else:
                continue
            for name in names:
                found.setdefault(name.split(".")[0], set()).add(str(path.relative_to(ROOT)))
    return found


@pytest.mark.slow
def test_every_third_party_import_is_declared() -> None:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    def names(requirements: list[str]) -> set[str]:
        """Distribution names; an extra named after a package brings it (``dask[distributed]``: distributed)."""
        found = set()
        for d in requirements:
            m = re.match(r"\s*([A-Za-z0-9_.-]+)\s*(?:\[([^\]]*)\])?", d)
            found |= {_normal(n) for n in [m[1], *(m[2] or "").split(",")] if n.strip()}
        return found


    declared = names(project["dependencies"])
    extras = {extra: names(project["optional-dependencies"][extra]) for extra in EXTRAS}
    dists = packages_distributions()
    imported = _imported_top_level(ROOT / "src" / "trafficgeo")
    third_party = {m: f for m, f in imported.items()
                   if m not in sys.stdlib_module_names and m not in ("trafficgeo", "__future__")}
    assert {"numpy", "pandas", "affine", "supervision", "cv2", "sumo"} <= set(third_party)  # the scan sees them
    missing = []
    for module, where in sorted(third_party.items()):
        dist_names = {_normal(d) for d in dists.get(module, [module])}
        if dist_names & declared:
            continue
        if any(dist_names & extras[e] and where <= EXTRAS[e] for e in EXTRAS):
            continue
        missing.append(f"{module} (from {sorted(dist_names)}, imported in {sorted(where)})")
    assert not missing, f"imported but not in pyproject dependencies: {missing}"


def test_the_version_is_written_once() -> None:
    """pyproject.toml takes the version from ``trafficgeo.version.__version__`` (the package's ``__version__``); the
    installed metadata agrees."""
    from importlib.metadata import version

    import trafficgeo

    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    assert "version" not in project["project"] and "version" in project["project"]["dynamic"]
    assert project["tool"]["setuptools"]["dynamic"]["version"] == {"attr": "trafficgeo.version.__version__"}
    assert version("trafficgeo") == trafficgeo.__version__
