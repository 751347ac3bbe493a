"""Ctrl-C around a Dask run: ignored while worker processes start (they inherit it, so a Ctrl-C in the terminal
reaches the client only), and held back while the runner builds Dask objects (:class:`DeferredInterrupt`)."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from typing import Any

__all__ = ["DeferredInterrupt", "sigint_ignored"]


@contextlib.contextmanager
def sigint_ignored() -> Iterator[None]:
    """Ignore SIGINT in this process for the block (main thread only; POSIX). Worker processes spawned meanwhile
    inherit "ignored", so a Ctrl-C in the terminal reaches this process only (which cancels and closes the cluster)
    instead of also killing each worker with a traceback. A Ctrl-C during the block (the cluster's start) is lost."""
    import signal
    import threading

    if os.name != "posix" or threading.current_thread() is not threading.main_thread():
        yield
        return
    old = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)


class DeferredInterrupt:
    """A SIGINT handler that raises KeyboardInterrupt only while the runner waits, never inside :meth:`held` (Dask
    calls that build futures: an interrupt half-way through one leaves a future whose ``__del__`` prints a
    traceback). A Ctrl-C arriving inside raises when the block ends. Main thread on POSIX only; a no-op elsewhere."""

    def __init__(self) -> None:
        self.holding = False
        self.pending = False

    def __call__(self, signum: int, frame: Any) -> None:
        if self.holding:
            self.pending = True
            return
        raise KeyboardInterrupt

    @contextlib.contextmanager
    def installed(self) -> Iterator[None]:
        import signal
        import threading

        if os.name != "posix" or threading.current_thread() is not threading.main_thread():
            yield
            return
        old = signal.signal(signal.SIGINT, self)
        try:
            yield
        finally:
            signal.signal(signal.SIGINT, old)

    @contextlib.contextmanager
    def held(self) -> Iterator[None]:
        self.holding = True
        try:
            yield
        finally:
            self.holding = False
        if self.pending:
            self.pending = False
            raise KeyboardInterrupt
