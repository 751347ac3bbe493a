"""What users read (the README, CLI and demo output, the web app and report) says what they need to know, not the
numbers of the project's internal issues."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).parents[1]
ISSUE_REF = re.compile(r"\bissues? ?#\d+|\(#\d+\)|\bsee #\d+", flags=re.I)


def _product_files() -> list[Path]:
    files = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    for ext in ("*.py", "*.html", "*.js", "*.css", "*.j2"):
        files += sorted((ROOT / "src" / "trafficgeo").rglob(ext))
    return files


def test_no_internal_issue_numbers_in_product_text() -> None:
    hits = [f"{p.relative_to(ROOT)}:{i}: {line.strip()}"
            for p in _product_files()
            for i, line in enumerate(p.read_text(encoding="utf-8", errors="replace").splitlines(), 1)
            if ISSUE_REF.search(line)]
    assert not hits, "product text cites issue numbers:\n" + "\n".join(hits)


def test_the_pattern_finds_what_it_is_for() -> None:
    assert ISSUE_REF.search("short of the target (issue #6)")
    assert ISSUE_REF.search("see issue #12 for details")
    assert not ISSUE_REF.search("colour #222 and pixel 6")
