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


_ON_A_FULL_DISK = """
import resource, signal, sys
limit = int(sys.argv[1])
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
from trafficgeo.cli import main
main(sys.argv[2:])
"""


def invoke_on_a_full_disk(limit_bytes: int, *args: object):
    """Run ``trafficgeo ARGS`` in its own process where no file may grow past ``limit_bytes`` (RLIMIT_FSIZE, with
    SIGXFSZ ignored: a write past it fails with EFBIG, as one to a full disk fails with ENOSPC); returns the
    :class:`subprocess.CompletedProcess` (text output)."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    src = Path(__file__).resolve().parents[1] / "src"
    env = {**os.environ, "PYTHONPATH": str(src), "PYTHONDONTWRITEBYTECODE": "1"}
    return subprocess.run([sys.executable, "-c", _ON_A_FULL_DISK, str(limit_bytes), *map(str, args)], env=env,
                          capture_output=True, text=True, timeout=600)
