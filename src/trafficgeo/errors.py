"""Exceptions a user can act on.

Every error that a user can fix (bad file, bad column, impossible option) is an :class:`InputError` with a
one-line message that says what is wrong, where, and how to fix it. The CLI prints it and exits with code 2.
:class:`CalibrationError` means the data were readable but no trustworthy camera could be found (exit code 1).
"""

from __future__ import annotations


class TrafficgeoError(Exception):
    """Base class of every error trafficgeo raises on purpose."""


class InputError(TrafficgeoError, ValueError):
    """Bad user input: a one-line message naming what, where and how to fix it (CLI exit code 2).

    Library code names the function's parameters (``"start_s 5 / end_s 2: need 0 <= start_s < end_s"``) and lists
    them in ``parameters``; the command line rewrites those names to its flags (``--start``, ``--end``), so each
    layer speaks its own terms. A one-word parameter that could be read as prose (``crs``) is written in backticks
    where it does not open the message (``"check the CRSs (`gcp_crs`, `crs`)"``)."""

    def __init__(self, message: str, *, parameters: tuple[str, ...] = ()) -> None:
        super().__init__(message)
        self.parameters = tuple(parameters)

    def in_terms_of(self, names: dict[str, str]) -> str:
        """The message with each of its ``parameters`` renamed by ``names`` (parameter -> e.g. a CLI flag): a name
        with an underscore (``start_s``) wherever it stands as a word; a plain word (``lanes``) where it opens
        the message or stands in backticks, since elsewhere it may be prose."""
        import re

        text = str(self)
        for p in self.parameters:
            if p not in names:
                continue
            text = text.replace(f"`{p}`", names[p])
            if "_" in p:
                text = re.sub(rf"(?<![\w-]){re.escape(p)}(?!\w)", names[p], text)
            elif re.match(rf"{re.escape(p)}\b", text):
                text = names[p] + text[len(p):]
        return text


class CalibrationError(TrafficgeoError, RuntimeError):
    """Calibration ran but could not converge to a usable camera (CLI exit code 1)."""


class OutputError(TrafficgeoError, RuntimeError):
    """An output could not be written (disk full, read-only or failing disk); the partial file was removed and
    any earlier file of that name is untouched (CLI exit code 1)."""
