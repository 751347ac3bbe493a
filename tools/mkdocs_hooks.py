"""mkdocs hooks of the docs site (mkdocs.yml ``hooks:``): the command-line reference generated from the commands.

``<!-- cli-reference -->`` in a page becomes the Markdown of every ``trafficgeo`` command, its arguments and
options, written by Typer's own docs generator (what ``typer trafficgeo.cli utils docs`` prints), in process.
"""

from __future__ import annotations

from typing import Any

MARKER = "<!-- cli-reference -->"


def cli_reference_markdown() -> str:
    """Every command of ``trafficgeo`` as Markdown (headings from level 2 down)."""
    import typer
    from typer.cli import get_docs_for_click

    from trafficgeo.cli import app

    command = typer.main.get_command(app)
    text = get_docs_for_click(obj=command, ctx=typer.Context(command), name="trafficgeo", title="trafficgeo")
    lines = text.strip().splitlines()
    if lines and lines[0].startswith("# "):
        lines = lines[1:]  # the page has its own title
    out, fenced = [], False
    for line in lines:
        fenced ^= line.startswith("```")
        if not fenced and not line.startswith("```"):
            parts = line.split("`")  # help texts such as "id,x,y[,role]" are text, not Markdown links
            parts[::2] = [p.replace("[", "\\[").replace("]", "\\]") for p in parts[::2]]
            line = "`".join(parts)
        out.append(line)
    return "\n".join(out)


def on_page_markdown(markdown: str, **_: Any) -> str:
    return markdown.replace(MARKER, cli_reference_markdown()) if MARKER in markdown else markdown
