"""JSON documents from users' folders: parsing that fails like any malformed document, whatever the damage."""

from __future__ import annotations

import json
from typing import Any


def loads_json(text: str) -> Any:
    """``json.loads``, with a document nested deeper than Python's recursion limit (``[[[[...``) raised as the
    :class:`json.JSONDecodeError` of any other malformed document rather than a ``RecursionError``."""
    try:
        return json.loads(text)
    except RecursionError:
        raise json.JSONDecodeError("nested too deeply to be a trafficgeo document", text[:80], 0) from None


__all__ = ["loads_json"]
