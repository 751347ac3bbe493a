"""What a section of the HTML report shows, as plain data for the templates (:mod:`trafficgeo.report.render`):
headings, paragraphs, lists, tables of formatted cells and figures (PNG, base64). Nothing here writes markup; the
templates escape every text.

A :class:`Section` is a sequence of parts, each a sequence of blocks: the blocks of a part follow each other
directly on the page, the parts are separated by a line break.
"""

from __future__ import annotations

import base64
import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from trafficgeo.report import figures as F


@dataclass(frozen=True)
class Cell:
    """A formatted table cell; ``numeric`` cells are right-aligned."""

    text: str
    numeric: bool = False


@dataclass(frozen=True)
class Table:
    """A table: column titles, rows of cells, an optional CSS class per row (``outlier``, ``check``) and caption."""

    columns: tuple[str, ...]
    rows: tuple[tuple[Cell, ...], ...]
    row_classes: tuple[str, ...] = ()
    caption: str = ""
    kind: ClassVar[str] = "table"  # which template block shows it


@dataclass(frozen=True)
class Figure:
    """A figure: the PNG as base64 text, and its caption (also the image's alternative text)."""

    png_base64: str
    caption: str
    kind: ClassVar[str] = "figure"  # which template block shows it


@dataclass(frozen=True)
class Text:
    """A paragraph, with an optional CSS class (``summary``, ``note``)."""

    text: str
    css: str = ""
    kind: ClassVar[str] = "text"  # which template block shows it


@dataclass(frozen=True)
class Items:
    """A bulleted list, with an optional CSS class (``warn``, ``note``, ``left-out``); empty: nothing shown."""

    items: tuple[str, ...]
    css: str = ""
    kind: ClassVar[str] = "items"  # which template block shows it


@dataclass(frozen=True)
class Heading:
    """A sub-heading of a section (level 3 or 4)."""

    text: str
    level: int = 3
    kind: ClassVar[str] = "heading"  # which template block shows it


Block = Table | Figure | Text | Items | Heading
Part = tuple[Block, ...]


@dataclass(frozen=True)
class Section:
    """A section of the page: its anchor (``id``), title and parts."""

    anchor: str
    title: str
    parts: tuple[Part, ...]


# ------------------------------------------------------------------------------------------------ formatting
def num(value: Any, nd: int = 2) -> str:
    """``value`` with ``nd`` decimals; ``-`` for anything that is not a finite number."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        return "-"
    return "-" if not math.isfinite(v) else f"{v:.{nd}f}"


def cell(value: Any) -> Cell:
    """A cell of ``value``: booleans as yes/no, integers as they are, floats with 2 decimals, ``(number, decimals)``
    with those decimals (numbers right-aligned), anything else as text (None: empty)."""
    if isinstance(value, bool | np.bool_):
        return Cell("yes" if value else "no")
    if isinstance(value, int | np.integer):
        return Cell(str(int(value)), True)
    if isinstance(value, float | np.floating):
        return Cell(num(value), True)
    if isinstance(value, tuple) and len(value) == 2 and isinstance(value[1], int):  # (number, decimals)
        return Cell(num(value[0], value[1]), True)
    return Cell(str("" if value is None else value))


def table(columns: list[str], rows: list[list[Any]], *, row_classes: list[str] | None = None,
          caption: str | None = None) -> Table:
    """A table of raw values, each formatted by :func:`cell`."""
    return Table(tuple(str(c) for c in columns), tuple(tuple(cell(v) for v in row) for row in rows),
                 tuple(row_classes or ()), caption or "")


def figure(fig: Any, caption: str, dpi: int) -> Figure:
    """A matplotlib figure rendered to PNG at ``dpi`` (the figure is cleared afterwards)."""
    return Figure(base64.b64encode(F.figure_png(fig, dpi=dpi)).decode("ascii"), caption)


def items(texts: list[str], css: str = "") -> Items:
    return Items(tuple(str(t) for t in texts), css)
