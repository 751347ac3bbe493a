"""Shared helper of the CLI tests: run ``trafficgeo`` in-process and capture what it prints."""

from __future__ import annotations

import contextlib
import io

from trafficgeo import cli


def invoke(*args: object) -> tuple[int, str, str]:
    """Run ``trafficgeo ARGS`` in-process; returns (exit code, stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            cli.main([str(a) for a in args])
            code = 0
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    return code, out.getvalue(), err.getvalue()
