"""A run's outputs as one unit: a manifest written last, checked by every reader.

Each output file is written atomically, but a run writes several of them; a run killed half-way through (or two
runs into one folder) would leave old and new files side by side. So a command that writes a run folder

1. first removes the folder's manifest (:func:`begin_outputs`), then writes its files,
2. last writes the manifest (:func:`publish_outputs`): a format tag, the trafficgeo version, the creation time
   (UTC), the command, and each output file with its size (bytes) and SHA-256.

A reader (:func:`verify_outputs`) refuses a folder whose manifest is missing, or whose listed files are missing or
differ from what the manifest records, with one line saying to run the command again. It reads only files the
manifest lists. Folders written before manifests existed have none and are refused the same way.

Sub-results written into a run folder by a later command (``compare-sumo``) have their own manifest
(``name``), so that they neither invalidate nor hide the run's.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import tempfile
from collections.abc import Iterable
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from trafficgeo.errors import InputError
from trafficgeo.io.atomic import write_json_atomic
from trafficgeo.io.json_text import loads_json

MANIFEST = "run.json"
COMPARE_MANIFEST = "compare_run.json"  # compare-sumo's results in a run folder; invalid once the run is rewritten
FORMAT = "trafficgeo-run/1"


class RunIncompleteError(InputError):
    """A run folder's outputs are incomplete, or not all from the same run (CLI exit code 2)."""


@dataclass(frozen=True)
class RunManifest:
    """A verified manifest: the folder, the command that wrote it and its files (name -> size, sha256)."""

    folder: Path
    command: str
    created: str
    files: dict[str, dict[str, Any]]

    def has(self, name: str) -> bool:
        """True when ``name`` is one of the run's outputs (and was checked)."""
        return name in self.files


def check_writable_folder(folder: str | Path, option: str = "out_dir") -> None:
    """Fail before any work when ``folder`` could not be written: it is a file, a part of its path is a file, or
    a probe file cannot be created in it (or, when it does not exist yet, in the nearest folder above it).
    Nothing is left behind."""
    d = Path(folder)
    if d.exists() and not d.is_dir():
        raise InputError(f"{option} {d}: exists and is not a folder; give a folder for the outputs",
                         parameters=(option,))
    probe_in = d
    while not probe_in.exists():
        if probe_in.parent == probe_in:
            break
        probe_in = probe_in.parent
    if not probe_in.is_dir():
        raise InputError(f"{option} {d}: {probe_in} is a file, so no folder can be made there; give another "
                         "output folder", parameters=(option,))
    try:
        fd, name = tempfile.mkstemp(prefix=".write-probe.", dir=probe_in)
        os.close(fd)
        os.unlink(name)
    except OSError as exc:
        raise InputError(f"{option} {d}: cannot write in {probe_in} ({exc.strerror or exc}); give a folder you can "
                         "write to", parameters=(option,)) from None


def check_writable_file(path: str | Path, option: str = "output") -> None:
    """Fail before any work when the file ``path`` could not be written: it is a folder, or its folder could not
    be made or written in (:func:`check_writable_folder`). ``option`` names the input in messages (a parameter
    name, which the command line turns into its flag)."""
    p = Path(path)
    if p.is_dir():
        raise InputError(f"{option} {p}: is a folder; give the file to write", parameters=(option,))
    if p.parent.exists() and not p.parent.is_dir():
        raise InputError(f"{option} {p}: {p.parent} is a file, so nothing can be written under it; give another "
                         "path", parameters=(option,))
    check_writable_folder(p.parent, option)


def begin_outputs(folder: str | Path, name: str = MANIFEST) -> Path:
    """Create ``folder`` if needed and remove its manifest ``name``, before the first output is written.

    From then on until :func:`publish_outputs`, readers refuse the folder. A new run (``name`` is
    :data:`MANIFEST`) also removes the manifests of results derived from the old one (:data:`COMPARE_MANIFEST`)."""
    d = Path(folder)
    d.mkdir(parents=True, exist_ok=True)
    for n in (name, COMPARE_MANIFEST) if name == MANIFEST else (name,):
        with contextlib.suppress(FileNotFoundError):
            (d / n).unlink()
    return d


def _digest(path: Path) -> tuple[int, str]:
    h = hashlib.sha256()
    size = 0
    with path.open("rb") as fh:
        while chunk := fh.read(1 << 20):
            h.update(chunk)
            size += len(chunk)
    return size, h.hexdigest()


def publish_outputs(folder: str | Path, files: Iterable[str | Path], *, command: str,
                    name: str = MANIFEST) -> Path:
    """Write the manifest ``name`` of ``files`` (paths in ``folder``, or names) last, atomically; returns its
    path."""
    from trafficgeo.version import __version__

    d = Path(folder)
    entries: dict[str, dict[str, Any]] = {}
    for f in files:
        p = d / Path(f).name
        size, sha = _digest(p)
        entries[p.name] = {"size": size, "sha256": sha}
    doc = {"format": FORMAT, "trafficgeo": __version__, "command": command,
           "created": datetime.now(UTC).isoformat(timespec="seconds"), "files": entries}
    path = d / name
    write_json_atomic(path, doc)
    return path


def _refuse(d: Path, why: str) -> RunIncompleteError:
    return RunIncompleteError(f"{d}: outputs incomplete or from different runs ({why}); run the command that "
                              "wrote them again")


def verify_outputs(folder: str | Path, require: Iterable[str] = (), *, name: str = MANIFEST) -> RunManifest:
    """Check ``folder``'s manifest ``name`` against its files; ``require``: names that must be among them.

    Raises:
        RunIncompleteError: no manifest (an interrupted run, or a folder from an older trafficgeo), a damaged one,
            or a listed file missing or changed since the run.
    """
    import json

    d = Path(folder)
    path = d / name
    if not path.is_file():
        raise _refuse(d, f"no {name}: the run that wrote them did not finish, or an older trafficgeo wrote them")
    try:
        doc = loads_json(path.read_text(encoding="utf-8"))
        files = doc["files"]
        ok = doc.get("format") == FORMAT and isinstance(files, dict) and all(
            isinstance(v, dict) and isinstance(v.get("size"), int) and isinstance(v.get("sha256"), str)
            for v in files.values())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, KeyError, TypeError):
        ok = False
    if not ok:
        raise _refuse(d, f"{name} is damaged or not a trafficgeo run manifest")
    for fname, entry in files.items():
        p = d / fname
        if not p.is_file():
            raise _refuse(d, f"{fname} is missing")
        if p.stat().st_size != entry["size"] or _digest(p)[1] != entry["sha256"]:
            raise _refuse(d, f"{fname} changed after the run")
    missing = [r for r in require if r not in files]
    if missing:
        cmd = doc.get("command") or "another command"
        raise InputError(f"{d}: has no {', '.join(missing)} (its outputs are from '{cmd}'); give the output folder "
                         "of a run that writes it")
    return RunManifest(d, str(doc.get("command") or ""), str(doc.get("created") or ""), dict(files))
