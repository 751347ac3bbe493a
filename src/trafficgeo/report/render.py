"""The report page as HTML: the templates in ``templates/`` (Jinja2, autoescaped: every value is shown as text)
filled with the sections of :mod:`trafficgeo.report.blocks`."""

from __future__ import annotations

from functools import cache

import jinja2

from trafficgeo.report.blocks import Section


@cache
def environment() -> jinja2.Environment:
    """The template environment (templates shipped in the package; autoescaping on; strict about names)."""
    return jinja2.Environment(
        loader=jinja2.PackageLoader("trafficgeo.report", "templates"),
        autoescape=jinja2.select_autoescape(enabled_extensions=("html", "html.j2"), default_for_string=True,
                                            default=True),
        undefined=jinja2.StrictUndefined, trim_blocks=True, lstrip_blocks=True, keep_trailing_newline=True)


def render_page(title: str, header: list[tuple[str, str]], sections: list[Section],
                left_out: list[tuple[str, str]]) -> str:
    """The whole page: ``header`` (label, value) rows, the sections, and (section, reason) of those left out."""
    return environment().get_template("page.html.j2").render(title=title, header=header, sections=sections,
                                                             left_out=left_out)
