"""The docs site tells the truth: its examples run, every command and option it names exists, the API reference
lists every public name. (`make docs` builds the site itself with --strict: a broken link or reference fails.)

Code blocks in docs/ are marked by the HTML comment on the line before them:
``<!-- docs-test: run -->`` runs the block here (bash or python, in a fresh folder holding a link to tests/, as a
user runs it from the root of a checkout); ``<!-- docs-test: skip REASON -->`` says why a block is not run. Every
python block carries one of the two.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from test_cli_help import _commands, _options

ROOT = Path(__file__).parents[1]
DOCS = ROOT / "docs"
PAGES = sorted(DOCS.rglob("*.md"))
FENCE = re.compile(r"(?:<!-- docs-test: (?P<mark>[^>]*?) -->\n)?```(?P<lang>\w*)[^\n]*\n(?P<code>.*?)^```",
                   flags=re.S | re.M)


def _blocks_of_text(text: str) -> list[tuple[str, str, str]]:
    """(language, mark, code) of each fenced block of a Markdown text (blocks indented in lists included)."""
    text = re.sub(r"^ {2,}(?=(```|<!-- docs-test))", "", text, flags=re.M)
    return [(m["lang"], (m["mark"] or "").strip(), m["code"]) for m in FENCE.finditer(text)]


def _blocks(page: Path) -> list[tuple[str, str, str]]:
    """(language, mark, code) of each fenced block of a page (blocks indented in lists included)."""
    return _blocks_of_text(page.read_text(encoding="utf-8"))


def _runnable() -> list[str]:
    """Pages with blocks to run."""
    return [str(p.relative_to(DOCS)) for p in PAGES if any(mark == "run" for _, mark, _ in _blocks(p))]


def test_every_page_is_found_and_every_python_block_is_marked() -> None:
    assert {"index.md", "getting-started.md", "tutorials/calibrate.md", "reference/cli.md"} <= {
        str(p.relative_to(DOCS)) for p in PAGES}
    unmarked = [f"{p.relative_to(DOCS)} block {i}" for p in PAGES for i, (lang, mark, _) in enumerate(_blocks(p))
                if lang == "python" and not (mark == "run" or mark.startswith("skip "))]
    assert not unmarked, "python blocks without <!-- docs-test: run --> or <!-- docs-test: skip REASON -->: " + \
        ", ".join(unmarked)
    assert len(_runnable()) >= 2


@pytest.mark.slow
@pytest.mark.parametrize("page", _runnable())
def test_docs_examples_run(page: str, tmp_path: Path) -> None:
    """A page's examples run as written, in order in one folder (a tutorial builds on its earlier steps), where
    ``tests/data`` is where a checkout has it."""
    (tmp_path / "tests").symlink_to(ROOT / "tests")
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"}
    for lang, mark, code in _blocks(DOCS / page):
        if mark == "run":
            _run(lang, code, tmp_path, env)


def _run(lang: str, code: str, cwd: Path, env: dict[str, str]) -> None:
    cmd = [sys.executable, "-c", code] if lang == "python" else ["bash", "-euo", "pipefail", "-c", code]
    assert lang in ("python", "bash"), lang
    done = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, f"exit {done.returncode}\n{done.stdout[-2000:]}\n{done.stderr[-3000:]}"


def _command_lines(text: str) -> list[str]:
    """The ``trafficgeo ...`` command lines of bash blocks (continuations joined, comments cut)."""
    out = []
    for lang, _, code in _blocks_of_text(text):
        if lang not in ("bash", "sh", "console", ""):
            continue
        joined = re.sub(r"\\\n\s*", " ", code)
        for line in joined.splitlines():
            line = re.sub(r"\s#.*$", "", line).strip().removeprefix("$ ")
            if line.startswith("trafficgeo "):
                out.append(line)
    return out


def test_every_command_and_option_the_docs_and_readme_name_exists() -> None:
    commands = _commands()
    wrong, seen = [], 0
    for page in [*PAGES, ROOT / "README.md"]:
        if page.name == "cli.md":
            continue
        for line in _command_lines(page.read_text(encoding="utf-8")):
            words = line.split()[1:]
            name = " ".join(words[:2]) if " ".join(words[:2]) in commands else (words[0] if words else "")
            if name not in commands:
                wrong.append(f"{page.name}: unknown command in {line!r}")
                continue
            seen += 1
            opts = _options(commands[name])
            wrong += [f"{page.name}: {name} has no {flag} ({line[:80]!r})"
                      for flag in re.findall(r"(?<![\w-])--[a-z][a-z0-9-]*", line) if flag not in opts]
    assert seen >= 40, seen
    assert not wrong, "\n".join(wrong)


def test_the_api_reference_lists_every_public_name() -> None:
    import trafficgeo as tg

    text = (DOCS / "reference" / "api.md").read_text(encoding="utf-8")
    listed = {m.split(".")[-1] for m in re.findall(r"^::: ([\w.]+)$", text, flags=re.M)}
    missing = sorted(set(tg.__all__) - listed - {"__version__"})
    assert not missing, f"docs/reference/api.md lacks {missing}"
    for target in re.findall(r"^::: ([\w.]+)$", text, flags=re.M):  # each entry names where the object lives
        module, name = target.rsplit(".", 1)
        assert hasattr(__import__(module, fromlist=[name]), name), target


def test_the_readme_is_short_and_points_to_the_docs() -> None:
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(readme.splitlines()) <= 200
    assert "make docs" in readme and "## Quick start" in readme
    quick = readme.split("## Quick start", 1)[1].split("\n## ", 1)[0]
    assert re.findall(r"^make \w+$", quick, flags=re.M) == ["make demo", "make test"]
