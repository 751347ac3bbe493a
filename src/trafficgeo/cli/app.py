"""The command tree every command registers on, the console they print to, and option parsers they share (one
module below the commands, so that they import it and not the package that imports them)."""

from __future__ import annotations

import typer
from rich.console import Console

from trafficgeo.errors import InputError

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                  help="Georeferenced, lane-level traffic data from a fixed camera and common GIS data.")
console = Console()


def parse_image_size(text: str) -> tuple[int, int]:
    """'1920x1080' -> (1920, 1080)."""
    parts = text.lower().replace("*", "x").split("x")
    try:
        w, h = (int(p) for p in parts)
    except ValueError:
        raise InputError(f"--image-size '{text}' is not WIDTHxHEIGHT; give e.g. --image-size 1920x1080") from None
    if w <= 0 or h <= 0:
        raise InputError(f"--image-size '{text}' must be positive, e.g. 1920x1080")
    return w, h


__all__ = ["app", "console", "parse_image_size"]
