"""Parsing SUMO FCD XML into raw vehicle attribute columns (bytes -> text/float columns, times in s).

SUMO writes every ``<vehicle>`` with the same attributes in the same order, so the values can be cut out of the
bytes with numpy (positions of ``<`` and ``"``) and read by pandas' C CSV parser: :func:`_parse_fcd_fast`. The
file is streamed in pieces of :data:`_PIECE_BYTES` cut before a ``<timestep`` (memory: the pieces' index arrays
plus the columns), and a file in any other layout (comments, mixed attribute sets, ...) is read by expat instead
(:func:`_parse_fcd_expat`, general but about five times slower and three times the memory). Figures, against
sumolib and ElementTree: :mod:`trafficgeo.io.sumo` and ``benchmarks/bench_fcd.py``. See
:func:`trafficgeo.io.fcd_read.read_fcd` for the table built from the columns.
"""

from __future__ import annotations

import csv
import html
import io
import re
import xml.parsers.expat
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import BinaryIO

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike

from trafficgeo.errors import InputError

FCD_HINT = "give a SUMO --fcd-output file (<fcd-export><timestep time=..><vehicle id x y .../>)"
_VEHICLE_ATTRS = ("id", "x", "y", "z", "angle", "type", "speed", "lane")
_STR_ATTRS = ("id", "type", "lane")
_WS = np.frombuffer(b" \t\r\n", np.uint8)
_ROOT = re.compile(rb"\A(?:\xef\xbb\xbf)?(?:\s+|<\?.*?\?>|<!--.*?-->|<!DOCTYPE[^>]*>)*<([\w:.-]+)", re.DOTALL)
_ATTR_NAMES = re.compile(rb'([\w:.-]+)\s*=\s*"')
_PIECE_BYTES = 8 << 20  # bytes per piece the vectorised parser works on


def _root_element(head: bytes, p: Path, hint: str) -> re.Match[bytes]:
    m = _ROOT.match(head)
    if m is None:
        raise InputError(f"{p}: not an XML file; {hint}")
    return m


def _tag_mask(arr: np.ndarray, lt: np.ndarray, tag: bytes) -> np.ndarray:
    """Which ``<`` positions ``lt`` open an element ``tag`` (name followed by whitespace)."""
    idx = np.minimum(lt[:, None] + np.arange(1, len(tag) + 2), arr.size - 1)
    head = arr[idx]
    return np.all(head[:, :-1] == np.frombuffer(tag, np.uint8), axis=1) & np.isin(head[:, -1], _WS)


def _preceded_by(arr: np.ndarray, pos: np.ndarray, text: bytes) -> bool:
    """Whether ``text`` ends right before each position ``pos`` (an attribute's opening quote)."""
    sig = np.frombuffer(text, np.uint8)
    idx = pos[:, None] - sig.size + np.arange(sig.size)
    return bool(pos.size == 0 or (idx.min() >= 0 and np.all(arr[idx] == sig)))


def _spans_table(arr: np.ndarray, starts: list[np.ndarray], ends: list[np.ndarray],
                 names: list[str]) -> pd.DataFrame | None:
    """Attribute values at byte spans [start, end) as a table: the spans are cut out into a CSV (separator 0x01,
    which XML text cannot hold) read by pandas' C parser. None if a value does not parse."""
    delta = np.zeros(arr.size + 1, np.int8)
    for s, e in zip(starts, ends, strict=True):
        delta[s] += 1
        delta[e] -= 1
    keep = np.cumsum(delta[:-1], dtype=np.int8) > 0
    out = arr.copy()
    for k, e in enumerate(ends):
        out[e] = 10 if k == len(ends) - 1 else 1  # field separator, line end after the last field
        keep[e] = True
    dtypes = {n: (str if n in _STR_ATTRS else np.float64) for n in names}
    try:
        table = pd.read_csv(io.BytesIO(out[keep].tobytes()), sep="\x01", header=None, names=names, dtype=dtypes,
                            quoting=csv.QUOTE_NONE, na_filter=False, engine="c", skip_blank_lines=False)
    except (ValueError, pd.errors.ParserError):
        return None
    return table if len(table) == starts[0].size else None


def _parse_fcd_fast(body: bytes, where: str, last: bool = True) -> dict[str, object] | None:
    """Vehicle attributes of a piece of an FCD body (from ``<fcd-export`` or a ``<timestep``; ``last``: up to the
    file's end) laid out as SUMO writes it: every vehicle with the same attributes in the same order, no comments.
    Vectorised over the bytes; None if the layout differs."""
    if (b"<!--" in body or b"<![CDATA[" in body or b"<?" in body
            or (last and not body[-4096:].rstrip().endswith(b"</fcd-export>"))):
        return None
    arr = np.frombuffer(body, np.uint8)
    lt, q = np.flatnonzero(arr == ord("<")), np.flatnonzero(arr == ord('"'))
    if q.size % 2:
        return None
    qo, qc = q[0::2], q[1::2]
    first = np.searchsorted(qo, lt)
    count = np.diff(np.append(first, qo.size))
    veh, ts = _tag_mask(arr, lt, b"vehicle"), _tag_mask(arr, lt, b"timestep")
    if not veh.any():
        return None if b"<vehicle" in body else {"time": np.empty(0)}
    vfirst, k = first[veh], int(count[veh][0])
    names = _ATTR_NAMES.findall(body[lt[veh][0]:qc[vfirst[0] + k - 1] + 1]) if k else []
    tix = np.searchsorted(lt[ts], lt[veh]) - 1
    if (len(names) != k or np.any(count[veh] != k) or tix[0] < 0 or np.any(count[ts] < 1)
            or not _preceded_by(arr, qo[first[ts]], b" time=")
            or not all(_preceded_by(arr, qo[vfirst + j], b" " + n + b"=") for j, n in enumerate(names))):
        return None
    wanted = [j for j, n in enumerate(names) if n.decode() in _VEHICLE_ATTRS]
    if not wanted:
        return None
    table = _spans_table(arr, [qo[vfirst + j] + 1 for j in wanted], [qc[vfirst + j] for j in wanted],
                         [names[j].decode() for j in wanted])
    if table is None:
        return None
    t = first[ts]
    stamps = [body[a + 1:b] for a, b in zip(qo[t].tolist(), qc[t].tolist(), strict=True)]
    cols: dict[str, object] = {c: table[c] if c in _STR_ATTRS else table[c].to_numpy() for c in table.columns}
    cols["time"] = parse_sumo_time(np.asarray(stamps), where)[tix]
    return cols


def _parse_fcd_expat(p: Path) -> dict[str, object]:
    """Vehicle attributes of any well-formed FCD file (slower, general)."""
    rows: list[tuple[str | None, ...]] = []  # (time, *_VEHICLE_ATTRS): only what the table needs is kept
    now: list[str | None] = [None]

    def start(name: str, attrs: dict[str, str]) -> None:
        if name == "vehicle":
            rows.append((now[0], *map(attrs.get, _VEHICLE_ATTRS)))
        elif name == "timestep":
            now[0] = attrs.get("time")

    parser = xml.parsers.expat.ParserCreate()
    parser.StartElementHandler = start
    try:
        with open(p, "rb") as fh:
            parser.ParseFile(fh)
    except xml.parsers.expat.ExpatError as exc:
        raise InputError(f"{p}: broken XML ({exc}; a truncated file from an interrupted run?); {FCD_HINT}") from None
    columns = [list(c) for c in zip(*rows, strict=True)] if rows else [[] for _ in range(len(_VEHICLE_ATTRS) + 1)]
    cols: dict[str, object] = {"time": columns[0]}
    cols.update((k, v) for k, v in zip(_VEHICLE_ATTRS, columns[1:], strict=True) if any(x is not None for x in v))
    return cols


def fcd_columns(p: Path) -> dict[str, object]:
    """Vehicle attribute columns of an FCD file: the vectorised parser piece by piece, else expat."""
    with open(p, "rb") as fh:
        head = fh.read(1 << 20)
        root = _root_element(head, p, FCD_HINT)
        if root.group(1) != b"fcd-export":
            raise InputError(f"{p}: root element is <{root.group(1).decode(errors='replace')}>, not <fcd-export>; "
                             f"{FCD_HINT}")
        cols = _parse_fcd_pieces(_pieces(fh, head[root.start(1) - 1:]), str(p))
    return cols if cols is not None else _parse_fcd_expat(p)


def _pieces(fh: BinaryIO, first: bytes) -> Iterator[tuple[bytes, bool]]:
    """The FCD body from ``first`` on in pieces of about :data:`_PIECE_BYTES` (longer only to hold a whole timestep),
    each cut right before a ``<timestep`` (so a timestep and its vehicles stay together); True with the last."""
    buf = bytearray(first)
    while True:
        cut = buf.rfind(b"<timestep", 1, _PIECE_BYTES)
        if cut <= 0:  # no timestep starts within a piece's length: cut after the first one, however long
            cut = buf.find(b"<timestep", 1)
        if cut > 0 and len(buf) >= _PIECE_BYTES:
            yield bytes(buf[:cut]), False
            del buf[:cut]
            continue
        more = fh.read(_PIECE_BYTES)
        if not more:
            break
        buf += more
    yield bytes(buf), True


def _parse_fcd_pieces(pieces: Iterable[tuple[bytes, bool]], where: str) -> dict[str, object] | None:
    """:func:`_parse_fcd_fast` over the pieces, joined; None as soon as one piece is not in SUMO's layout or has
    other vehicle attributes than the others."""
    parts: list[dict[str, object]] = []
    for body, last in pieces:
        cols = _parse_fcd_fast(body, where, last)
        if cols is None or (parts and len(cols) > 1 and cols.keys() != parts[0].keys()):
            return None
        if len(cols) > 1:  # a piece without vehicles adds nothing
            parts.append(cols)
    if len(parts) <= 1:
        return parts[0] if parts else {"time": np.empty(0)}
    return {k: pd.concat([c[k] for c in parts], ignore_index=True) if k in _STR_ATTRS else
            np.concatenate([c[k] for c in parts]) for k in parts[0]}


def parse_sumo_time(values: ArrayLike, where: str) -> np.ndarray:
    """Times (s) from SUMO text: seconds, or ``[[d:]h:]m:s`` with --human-readable-time."""
    arr = np.asarray(values)
    try:
        return arr.astype(np.float64)
    except (ValueError, TypeError):
        pass
    uniq, inverse = np.unique(arr.astype(str), return_inverse=True)
    out = np.empty(uniq.size)
    for i, text in enumerate(uniq):
        try:
            parts = [float(v) for v in text.split(":")]
        except ValueError:
            raise InputError(f"{where}: time {str(text)!r} is not seconds nor h:mm:ss; {FCD_HINT}") from None
        scale = (86400.0, 3600.0, 60.0, 1.0)[-len(parts):] if 1 <= len(parts) <= 4 else ()
        if not scale:
            raise InputError(f"{where}: time {str(text)!r} is not seconds nor h:mm:ss; {FCD_HINT}")
        out[i] = sum(a * b for a, b in zip(parts, scale, strict=True))
    return out[inverse]


def float_column(cols: dict[str, object], key: str, n: int, where: str) -> np.ndarray:
    """A numeric attribute as float64 (NaN where absent)."""
    if key not in cols:
        return np.full(n, np.nan)
    values = cols[key]
    if isinstance(values, list):
        values = ["nan" if v is None else v for v in values]
    try:
        return np.asarray(values).astype(np.float64)
    except ValueError:
        bad = next(v for v in np.asarray(values).tolist() if not _is_float(v))
        raise InputError(f"{where}: vehicle attribute {key}={bad!r} is not a number; {FCD_HINT}") from None


def _is_float(v: object) -> bool:
    try:
        float(v)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return False
    return True


def str_column(cols: dict[str, object], key: str, n: int) -> pd.Series:
    """A text attribute as str ("" where absent), XML entities resolved."""
    values = cols.get(key)
    if values is None:
        return pd.Series(np.full(n, ""), dtype=str)
    if isinstance(values, list):
        return pd.Series(["" if v is None else v for v in values], dtype=str)
    series = values if isinstance(values, pd.Series) else pd.Series(values)
    series = series.astype(str).reset_index(drop=True)
    if series.str.contains("&", regex=False).any():  # the fast path leaves entities as they are in the file
        series = series.map(html.unescape).astype(str)
    return series


def require_fcd_columns(cols: dict[str, object], p: Path) -> int:
    n = len(cols["time"])
    for key in ("id", "x", "y", "time"):
        values = cols.get(key)
        if n and (values is None or (isinstance(values, list) and any(v is None for v in values))):
            what = "<timestep> without time" if key == "time" else f"<vehicle> without attribute {key}"
            raise InputError(f"{p}: {what}; {FCD_HINT}")
    return n

