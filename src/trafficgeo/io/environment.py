"""Environment variables of this process, changed for a block and then put back as they were."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterable, Iterator, Mapping

__all__ = ["environment"]


@contextlib.contextmanager
def environment(values: Mapping[str, str] | None = None, *, keep: Iterable[str] = ()) -> Iterator[None]:
    """Set ``values`` in ``os.environ`` for the block; on leaving it, the variables of ``values`` and ``keep`` are
    back as they were before (unset ones removed again), whatever the block (or an import in it) changed."""
    values = dict(values or {})
    before = {k: os.environ.get(k) for k in {*values, *keep}}
    os.environ.update(values)
    try:
        yield
    finally:
        for k, v in before.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
