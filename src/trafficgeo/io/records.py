"""Typed JSON records: the one mechanism the JSON files trafficgeo writes and reads back go through (a run folder's
records, :mod:`trafficgeo.run.records`; the calibration report, :mod:`trafficgeo.calibration.report`).

A record is a frozen stdlib dataclass deriving from :class:`Record`, whose fields carry the strict JSON types below.
:meth:`Record.to_dict` gives the document with the keys in the order of the fields (records as objects, tuples as
lists); :func:`read_record` validates a document against the fields' types with pydantic and builds the record, or
says which key is wrong (:class:`RecordError`, for the caller to name its file). A number that is not available is
NaN in memory and ``null`` in the file. Two records are equal when they write the same JSON (NaN equals NaN).
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from dataclasses import fields
from typing import Annotated, Any

from pydantic import BeforeValidator, Strict, TypeAdapter, ValidationError

from trafficgeo.io.atomic import to_json_safe

__all__ = ["NAN", "Flag", "Int", "MaybeNum", "Num", "Obj", "Record", "RecordError", "Text", "plain", "read_record"]

NAN = float("nan")


def _nan_for_null(value: Any) -> Any:
    return NAN if value is None else value


# Strict JSON types (a whole number is not true, 3.0 or "3"; a number is not text): a number that is not available
# is NaN in memory and null in the file (Num); None means "none" (MaybeNum).
Num = Annotated[float, BeforeValidator(_nan_for_null), Strict()]
Int = Annotated[int, Strict()]
Text = Annotated[str, Strict()]
Flag = Annotated[bool, Strict()]
Obj = Annotated[dict[str, Any], Strict()]
MaybeNum = Annotated[float | None, Strict()]

_WHAT = {"int_type": "a whole number", "float_type": "a number", "string_type": "text", "bool_type": "true or false",
         "dict_type": "an object", "dataclass_type": "an object", "tuple_type": "a list", "list_type": "a list",
         "mapping_type": "an object"}


class RecordError(ValueError):
    """A document is not the record asked for; the message names the key (``crossings[0].count``)."""


class Record:
    """Base of the records: ``to_dict`` in field order; equal when they write the same JSON."""

    def to_dict(self) -> dict[str, Any]:
        """The JSON-ready record (keys = field names, in order)."""
        return {f.name: plain(getattr(self, f.name)) for f in fields(self)}  # type: ignore[arg-type]

    def __eq__(self, other: object) -> bool:
        if type(other) is not type(self):
            return NotImplemented
        return to_json_safe(self.to_dict()) == to_json_safe(other.to_dict())  # type: ignore[attr-defined]

    __hash__ = None  # type: ignore[assignment]  (equal by JSON value, which a hash of the fields would not follow)


def plain(value: Any) -> Any:
    """``value`` as JSON-ready data: anything with a ``to_dict`` (records, orientations) as its dict, tuples and lists
    as lists, mappings as dicts."""
    if hasattr(value, "to_dict"):
        return value.to_dict()
    if isinstance(value, tuple | list):
        return [plain(v) for v in value]
    if isinstance(value, Mapping):
        return {k: plain(v) for k, v in value.items()}
    return value


def _said(exc: ValidationError) -> str:
    """The first problem of a validation, naming the key by its path in the document (``crossings[0].count``)."""
    err = exc.errors(include_url=False)[0]
    key = ""
    for part in err["loc"]:
        key += f"[{part}]" if isinstance(part, int) else f".{part}" if key else str(part)
    if err["type"] == "missing":
        return f"key '{key}' is missing"
    what = _WHAT.get(err["type"])
    return f"'{key}' is not {what}" if what else f"'{key}': {err['msg']}"


@functools.cache
def _adapter(cls: Any) -> TypeAdapter:
    return TypeAdapter(cls)


def read_record(cls: Any, doc: Any) -> Any:
    """``doc`` (a parsed JSON document) as the record ``cls``, validated against its fields' types; keys beyond the
    fields are ignored, fields with defaults may be absent. Raises :class:`RecordError` naming the first wrong key."""
    if not isinstance(doc, Mapping):
        raise RecordError("the document is not a JSON object")
    try:
        return _adapter(cls).validate_python(doc)
    except ValidationError as exc:
        raise RecordError(_said(exc)) from None
