"""SUMO programs (``sumo``, ``netconvert``, ``duarouter``) and python tools (``sumo/tools/*.py``) from the installed
``eclipse-sumo`` wheel, run headless as subprocesses with ``SUMO_HOME`` (and SUMO's own PROJ database) set.

Python tools run with the interpreter running trafficgeo (:data:`sys.executable`), so they find the ``sumolib`` and
``scipy`` installed with it. A failure or a timeout raises :class:`~trafficgeo.errors.TrafficgeoError` with one line:
the program and the tail of its error output.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from trafficgeo.errors import InputError, TrafficgeoError
from trafficgeo.io.environment import environment

__all__ = ["run_sumo_program", "run_sumo_tool", "sumo_binary", "sumo_env", "sumo_home", "sumo_tool"]


#: variables the eclipse-sumo package sets in ``os.environ`` on import when they are unset; its PROJ database is
#: older than pyproj's and rasterio's, so a process that inherits PROJ_DATA from it (a Dask worker, a subprocess)
#: fails to transform coordinates. SUMO's own programs get them through :func:`sumo_env` only.
_SUMO_IMPORT_VARIABLES = ("SUMO_HOME", "PROJ_LIB", "PROJ_DATA")


def sumo_home() -> Path:
    """SUMO_HOME of the installed ``eclipse-sumo`` wheel (this process's environment left as it was)."""
    try:
        with environment(keep=_SUMO_IMPORT_VARIABLES):
            import sumo  # the eclipse-sumo wheel
    except ImportError:
        raise InputError("SUMO is not installed (Python package eclipse-sumo missing); "
                         "install it with: pip install eclipse-sumo") from None
    return Path(sumo.SUMO_HOME)


def sumo_binary(name: str) -> str:
    """Path of a SUMO program (``sumo``, ``netconvert``, ``duarouter``, ...) from the eclipse-sumo wheel."""
    folder = sumo_home() / "bin"
    exe = folder / (f"{name}.exe" if os.name == "nt" else name)
    if not exe.is_file():
        raise InputError(f"SUMO program {name!r} not found in {folder}; "
                         "reinstall SUMO with: pip install --force-reinstall eclipse-sumo")
    return str(exe)


def sumo_tool(script: str) -> str:
    """Path of a SUMO python tool, e.g. ``sumo_tool("routeSampler.py")`` (``sumo/tools/routeSampler.py``)."""
    folder = sumo_home() / "tools"
    path = folder / script
    if not path.is_file():
        raise InputError(f"SUMO tool {script!r} not found in {folder}; "
                         "reinstall SUMO with: pip install --force-reinstall eclipse-sumo")
    return str(path)


def sumo_env() -> dict[str, str]:
    """Environment for SUMO subprocesses: SUMO_HOME of the wheel, its ``bin`` first on PATH (tools call
    duarouter), and its own PROJ database (PROJ_LIB)."""
    home = sumo_home()
    env = dict(os.environ)
    env["SUMO_HOME"] = str(home)
    env["PATH"] = os.pathsep.join([str(home / "bin"), env.get("PATH", "")])
    proj = home / "data" / "proj"
    if (proj / "proj.db").is_file():
        env["PROJ_LIB"] = str(proj)  # otherwise SUMO's PROJ prints "Cannot find proj.db"
    return env


def _tail(text: str, lines: int = 4) -> str:
    kept = [ln.strip() for ln in text.splitlines() if ln.strip()][-lines:]
    return " | ".join(kept) if kept else "(no output)"


def _run(what: str, cmd: list[str], timeout_s: float, cwd: str | os.PathLike[str] | None) -> str:
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, env=sumo_env(), timeout=timeout_s, check=False,
                              cwd=cwd)
    except subprocess.TimeoutExpired:
        raise TrafficgeoError(f"SUMO {what} did not finish within {timeout_s:.0f} s") from None
    except OSError as exc:
        raise TrafficgeoError(f"cannot start SUMO {what} ({cmd[0]}): {exc}") from exc
    if proc.returncode != 0:
        raise TrafficgeoError(f"SUMO {what} failed with exit code {proc.returncode}: "
                              f"{_tail(proc.stderr or proc.stdout)}")
    return proc.stdout


def run_sumo_program(name: str, args: list[str], timeout_s: float, *,
                     cwd: str | os.PathLike[str] | None = None) -> str:
    """Run a SUMO program headless (``name`` as for :func:`sumo_binary`); returns its standard output.

    Raises:
        TrafficgeoError: it failed (exit code and the tail of its error output) or ran over ``timeout_s`` seconds.
    """
    return _run(name, [sumo_binary(name), *args], timeout_s, cwd)


def run_sumo_tool(script: str, args: list[str], timeout_s: float, *,
                  cwd: str | os.PathLike[str] | None = None) -> str:
    """Run a SUMO python tool (``script`` as for :func:`sumo_tool`) with this interpreter; returns its output.

    Raises:
        TrafficgeoError: as :func:`run_sumo_program`.
    """
    return _run(script, [sys.executable, sumo_tool(script), *args], timeout_s, cwd)
