"""Start times from video file names: a strftime-like pattern with ``{camera}`` (default
``{camera}_%Y-%m-%d_%H-%M-%S``) turned into a regular expression, and local clock times turned into UTC.

Local times and daylight saving: a name holds the camera's local clock time in its IANA time zone. A time that
occurs twice (the hour repeated when clocks go back) is read as its **first** occurrence (daylight time, the
earlier instant); a time that does not exist (skipped when clocks go forward) is read with the UTC offset in
force **before** the change (Europe/Berlin ``02:30`` on the last Sunday of March -> ``01:30Z``, i.e. ``03:30``
summer time), as a clock not yet moved forward would mean it. A file started in the repeated hour's second
pass is thus dated an hour early; it then overlaps the file before it and the plan reports it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from datetime import UTC, datetime
from functools import lru_cache
from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

from trafficgeo.errors import InputError

#: the default name of a video file (without its extension): camera id, local date and time of its first frame
DEFAULT_NAME_PATTERN = "{camera}_%Y-%m-%d_%H-%M-%S"

# strftime directives a pattern may hold: (group name, regular expression)
_DIRECTIVES = {"Y": ("year", r"\d{4}"), "y": ("year2", r"\d{2}"), "m": ("month", r"\d{2}"), "d": ("day", r"\d{2}"),
               "H": ("hour", r"\d{2}"), "M": ("minute", r"\d{2}"), "S": ("second", r"\d{2}"),
               "f": ("micro", r"\d{1,6}"), "j": ("yday", r"\d{3}")}
_CAMERA = "\x00camera\x00"  # placeholder of {camera} in a compiled pattern's text


def zone(name: str) -> ZoneInfo:
    """The time zone of IANA name ``name``; an InputError for an unknown one."""
    text = str(name).strip()
    try:
        if not text:
            raise ValueError
        return ZoneInfo(text)
    except (ZoneInfoNotFoundError, ValueError, OSError):
        raise InputError(f"unknown time zone {text!r}: use an IANA name such as Europe/Berlin, America/New_York "
                         "or UTC", parameters=("timezone",)) from None


def local_to_utc(local: datetime, timezone: str) -> datetime:
    """The UTC instant of naive local clock time ``local`` in ``timezone`` (DST rule of the module docstring)."""
    return local.replace(tzinfo=zone(timezone), fold=0).astimezone(UTC)


@dataclass(frozen=True)
class NamePattern:
    """A file name pattern as a regular expression (``{camera}`` still a placeholder: see :meth:`parse`)."""

    pattern: str
    regex_text: str
    has_camera: bool

    def parse(self, stem: str, camera_ids: tuple[str, ...]) -> tuple[str | None, datetime] | None:
        """(camera id, or None when the pattern has no ``{camera}``; naive local time) of a file stem, or None when
        the stem does not match the pattern with one of ``camera_ids``. A matching stem with an impossible date
        (month 13) raises ValueError with the reason."""
        if self.has_camera and not camera_ids:
            return None
        m = _compiled(self.regex_text, tuple(camera_ids) if self.has_camera else ()).fullmatch(stem)
        if m is None:
            return None
        return (m.group("camera") if self.has_camera else None), _datetime_of(m.groupdict())

    def example(self, camera_id: str, when: datetime = datetime(2026, 5, 4, 7, 30, 0)) -> str:
        """A file stem this pattern reads (e.g. ``cam1_2026-05-04_07-30-00``)."""
        return when.strftime(self.pattern.replace("{camera}", camera_id.replace("%", "%%")))


def compile_pattern(pattern: str) -> NamePattern:
    """The pattern as a regular expression over file stems; an InputError naming ``name_pattern`` for an
    unsupported directive or a pattern that does not give a date and an hour."""
    out, seen, i = [], set(), 0
    has_camera = False
    while i < len(pattern):
        if pattern.startswith("{camera}", i):
            if has_camera:
                raise InputError(f"name_pattern {pattern!r}: {{camera}} appears twice; write it once",
                                 parameters=("name_pattern",))
            out.append(_CAMERA)
            has_camera, i = True, i + len("{camera}")
        elif pattern[i] == "%" and i + 1 < len(pattern):
            d = pattern[i + 1]
            if d == "%":
                out.append("%")
            elif d in _DIRECTIVES:
                name, rx = _DIRECTIVES[d]
                if name in seen:
                    raise InputError(f"name_pattern {pattern!r}: %{d} appears twice; write it once",
                                     parameters=("name_pattern",))
                seen.add(name)
                out.append(f"(?P<{name}>{rx})")
            else:
                raise InputError(f"name_pattern {pattern!r}: %{d} is not supported; use %Y %y %m %d %j %H %M %S "
                                 "%f and {camera}", parameters=("name_pattern",))
            i += 2
        else:
            out.append(re.escape(pattern[i]))
            i += 1
    has_date = ({"year", "year2"} & seen) and ({"month", "day"} <= seen or "yday" in seen)
    if not has_date or "hour" not in seen:
        raise InputError(f"name_pattern {pattern!r}: needs a year (%Y), month (%m), day (%d) and hour (%H), e.g. "
                         f"{DEFAULT_NAME_PATTERN!r}", parameters=("name_pattern",))
    return NamePattern(pattern, "".join(out), has_camera)


@lru_cache(maxsize=64)
def _compiled(regex_text: str, camera_ids: tuple[str, ...]) -> re.Pattern[str]:
    ids = "|".join(re.escape(c) for c in sorted(camera_ids, key=len, reverse=True))
    return re.compile(regex_text.replace(_CAMERA, f"(?P<camera>{ids})"))


def _datetime_of(g: dict[str, str | None]) -> datetime:
    """The naive datetime of a match's groups (ValueError for an impossible date)."""
    year = int(g["year"]) if g.get("year") else 2000 + int(g["year2"] or 0)
    hms = (int(g["hour"] or 0), int(g.get("minute") or 0), int(g.get("second") or 0))
    micro = int((g.get("micro") or "0").ljust(6, "0"))
    if g.get("yday"):
        from datetime import timedelta

        yday = int(g["yday"] or 0)
        start = datetime(year, 1, 1)
        t = start + timedelta(days=yday - 1)
        if not 1 <= yday or t.year != year:
            raise ValueError(f"day of year {yday} does not exist in {year}")
        return t.replace(hour=hms[0], minute=hms[1], second=hms[2], microsecond=micro)
    return datetime(year, int(g["month"] or 0), int(g["day"] or 0), *hms, micro)
