"""Test data carries its licence: every folder in tests/data has a SOURCE.txt with a licence line, the licence
agrees with the shared copy it was taken from (where that copy is beside the project), and the README's data
credits name the same licence."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

DATA = Path(__file__).parent / "data"
SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
README = Path(__file__).parents[1] / "README.md"

# The licence names we recognise, as they are written in SOURCE.txt files and the README.
LICENCES = {
    "CC BY-SA 3.0": r"CC BY-SA 3\.0",
    "CC BY-SA 4.0": r"CC BY-SA 4\.0",
    "CC BY 4.0": r"CC BY 4\.0",
    "MIT": r"\bMIT\b",
    "Apache-2.0": r"Apache-2\.0",
    "EPL-2.0": r"EPL-2\.0",
    "BSD": r"\bBSD\b",
    "public domain": r"public domain",
}


def _licence_line(path: Path) -> str:
    """The text of the first ``License:`` statement (up to the next blank line or field)."""
    text = path.read_text(encoding="utf-8")
    m = re.search(r"License:\s*(.+?)(?:\n\s*\n|\n[A-Z][A-Za-z ]+:|\Z)", text, flags=re.S)
    assert m, f"{path}: no 'License:' line"
    return " ".join(m.group(1).split())


def _named(text: str) -> set[str]:
    """Licences the text states; 'public domain' only where it is not the correction note about it."""
    text = re.sub(r"earlier version of this file said public domain", "", text)
    return {name for name, pattern in LICENCES.items() if re.search(pattern, text)}


FOLDERS = sorted(p for p in DATA.iterdir() if p.is_dir())


@pytest.mark.parametrize("folder", FOLDERS, ids=[p.name for p in FOLDERS])
def test_every_data_folder_states_a_licence(folder: Path) -> None:
    source = folder / "SOURCE.txt"
    assert source.is_file(), f"{folder} has no SOURCE.txt"
    assert _named(_licence_line(source)), f"{source}: licence not recognised: {_licence_line(source)!r}"


@pytest.mark.parametrize("folder", FOLDERS, ids=[p.name for p in FOLDERS])
def test_licence_matches_the_shared_copy(folder: Path) -> None:
    shared = SHARED / folder.name / "SOURCE.txt"
    if not shared.is_file():
        pytest.skip(f"no shared copy of {folder.name} beside the project")
    assert _named(_licence_line(folder / "SOURCE.txt")) == _named(_licence_line(shared))


def test_ngsim_is_cc_by_sa_everywhere() -> None:
    """The US DOT portal lists the NGSIM trajectory table as CC BY-SA 3.0; an older copy said public domain."""
    assert _named(_licence_line(DATA / "ngsim-peachtree-subset" / "SOURCE.txt")) == {"CC BY-SA 3.0"}
    credit = next(line for line in README.read_text(encoding="utf-8").splitlines() if "NGSIM Peachtree" in line
                  and line.startswith("- "))
    assert _named(credit) == {"CC BY-SA 3.0"}, credit
