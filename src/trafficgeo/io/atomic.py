"""Atomic file output: a reader never sees a half-written file.

Write to a temporary file in the destination folder, flush it to disk, then ``os.replace`` it over the target
(atomic on POSIX and Windows). On any error the temporary file is removed and the target is untouched. A process
killed while writing leaves its temporary file behind: :func:`remove_stale_temporaries` clears a folder of them.
"""

from __future__ import annotations

import contextlib
import errno
import json
import math
import os
import re
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

import numpy as np

from trafficgeo.errors import OutputError

# Temporary files are named ".<target name>.<8 random characters from mkstemp>.tmp<target suffix>".
_TEMP_NAME = re.compile(r"\.(?P<target>.+)\.[a-z0-9_]{8}\.tmp(?P<suffix>\.[^.]*)?")


def _temp_prefix_suffix(target: Path) -> tuple[str, str]:
    return f".{target.name}.", f".tmp{target.suffix}"


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (same suffix); on success move it over ``path``.

    For libraries that want a file name rather than a file object (OpenCV FileStorage, GDAL, ...).
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    prefix, suffix = _temp_prefix_suffix(target)
    fd, tmp_name = tempfile.mkstemp(prefix=prefix, suffix=suffix, dir=target.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)  # mkstemp creates 0600; give the file the permissions a plain open() would
    try:
        yield tmp
        os.replace(tmp, target)
    except BaseException as exc:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        if isinstance(exc, OSError) and exc.errno in WRITE_ERRNOS:
            raise write_failed(target, exc.strerror or str(exc)) from exc
        raise


WRITE_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EIO, errno.EFBIG}  # the disk refused the data


def write_failed(target: Path, why: str) -> OutputError:
    """The one-line error for an output the disk would not take (the partial file is already removed)."""
    text = " ".join(str(why).split())
    if len(text) > 160:  # GDAL quotes whole SQL scripts; the cause is at the end ("... database or disk is full")
        text = "..." + text[-120:]
    return OutputError(f"could not write {target}: {text}; nothing of it was kept - free space (or fix the disk) "
                       "and run the command again")


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike[str], mode: str = "w", encoding: str | None = "utf-8",
                newline: str | None = None) -> Iterator[IO]:
    """Open a temporary file for writing; it replaces ``path`` only when the block ends without error."""
    if "b" in mode:
        encoding = None
    with atomic_path(path) as tmp, open(tmp, mode, encoding=encoding, newline=newline) as fh:
        yield fh
        fh.flush()
        os.fsync(fh.fileno())


def write_text_atomic(path: str | os.PathLike[str], text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    with atomic_open(path, "w") as fh:
        fh.write(text)


def write_csv_atomic(path: str | os.PathLike[str], table: Any, *, float_format: str | None = None) -> None:
    """Write the pandas DataFrame ``table`` as CSV (no index; missing values as empty fields) to ``path``
    atomically."""
    with atomic_path(path) as tmp:
        table.to_csv(tmp, index=False, na_rep="", float_format=float_format)


def to_json_safe(obj: Any) -> Any:
    """Replace non-finite floats by None so the JSON stays standard (NaN is not JSON)."""
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {k: to_json_safe(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [to_json_safe(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_json_safe(obj.tolist())
    if isinstance(obj, np.floating):
        return to_json_safe(float(obj))
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj


def write_json_atomic(path: str | os.PathLike[str], doc: Any) -> None:
    """Write ``doc`` as indented standard JSON (NaN and infinities become null; numpy scalars and arrays become
    numbers and lists) to ``path`` atomically."""
    write_text_atomic(path, json.dumps(to_json_safe(doc), indent=2, allow_nan=False) + "\n")


SQLITE_SIDE_FILES = ("-journal", "-wal", "-shm")  # what SQLite (a GeoPackage) keeps beside a file it writes


def is_temporary_name(name: str) -> bool:
    """Whether a file name is one :func:`atomic_path` gives its temporary files, or the SQLite journal of one (a
    GeoPackage being written when its writer was killed)."""
    for side in SQLITE_SIDE_FILES:
        if name.endswith(side) and _is_atomic_name(name[: -len(side)]):
            return True
    return _is_atomic_name(name)


def _is_atomic_name(name: str) -> bool:
    m = _TEMP_NAME.fullmatch(name)
    return m is not None and Path(m["target"]).suffix == (m["suffix"] or "")


def remove_stale_temporaries(folder: str | os.PathLike[str]) -> list[Path]:
    """Delete the temporary files that writers killed mid-write left in ``folder`` (not its sub-folders); returns
    them. Only names of :func:`atomic_path`'s pattern are touched. Call it only while no other process writes
    into ``folder`` (e.g. under a lock on it)."""
    removed = []
    root = Path(folder)
    if not root.is_dir():
        return removed
    for path in sorted(root.iterdir()):
        if is_temporary_name(path.name) and path.is_file() and not path.is_symlink():
            with contextlib.suppress(FileNotFoundError):
                path.unlink()
                removed.append(path)
    return removed
