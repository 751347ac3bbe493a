"""One run at a time in an output folder: an exclusive lock on ``folder/.lock`` (fcntl, msvcrt on Windows) held by
every command that writes a run folder (``process``, ``analyze``, ``stitch``, the comparison with a simulation,
``sumo-demand``'s scenario). Re-entrant within one process, released when the process ends however it ends."""

from __future__ import annotations

import contextlib
import errno
import os
from collections.abc import Iterator
from pathlib import Path

from trafficgeo.errors import InputError
from trafficgeo.io.atomic import remove_stale_temporaries

LOCK_FILE = ".lock"


_HELD: dict[Path, int] = {}


@contextlib.contextmanager
def hold_folder(folder: str | os.PathLike[str]) -> Iterator[None]:
    """Hold an exclusive lock on an output folder (``folder/.lock``, created with the folder) for the block.

    Another process holding it makes this raise :class:`InputError` at once, naming that process. Re-entrant within
    one process. The lock goes with the process, however it ends (the file stays, unlocked; a folder this created
    and that holds nothing else at the end is removed). Taking it removes the temporary files a writer killed in
    this folder left (:func:`~trafficgeo.io.atomic.remove_stale_temporaries`).
    """
    root = Path(folder)
    ident = root.resolve()
    if ident in _HELD:
        _HELD[ident] += 1
        try:
            yield
        finally:
            _HELD[ident] -= 1
        return
    created = not root.exists()
    root.mkdir(parents=True, exist_ok=True)
    path = root / LOCK_FILE
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    try:
        try:
            _lock(fd)
        except OSError as exc:
            if exc.errno not in (errno.EAGAIN, errno.EACCES, errno.EWOULDBLOCK):
                raise
            os.lseek(fd, 0, os.SEEK_SET)
            holder = os.read(fd, 32).decode("ascii", "replace").strip()
            who = f" (pid {holder})" if holder.isdigit() else ""
            raise InputError(f"out_dir {root}: another trafficgeo run{who} is writing to this folder; wait for it to "
                             "end or give another out_dir", parameters=("out_dir",)) from None
        os.ftruncate(fd, 0)
        os.lseek(fd, 0, os.SEEK_SET)
        os.write(fd, f"{os.getpid()}\n".encode())
        remove_stale_temporaries(root)  # of a writer killed here before: nobody else writes while this is held
        _HELD[ident] = 1
        try:
            yield
        finally:
            del _HELD[ident]
            with contextlib.suppress(OSError):
                os.ftruncate(fd, 0)
                if created and [p.name for p in root.iterdir()] == [LOCK_FILE]:  # a run that wrote nothing
                    path.unlink()
                    root.rmdir()
    finally:
        os.close(fd)  # closing the file releases the lock


def _lock(fd: int) -> None:
    try:
        import fcntl
    except ImportError:  # Windows
        import msvcrt

        msvcrt.locking(fd, msvcrt.LK_NBLCK, 1)
        return
    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
