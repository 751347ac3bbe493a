"""Comparing what a test computes now with a reference stored in tests/data, on any machine.

A reference written on one machine is compared by value, never by its bytes. numpy, OpenCV and OpenBLAS choose
their SIMD paths by the CPU they run on (numpy's AVX-512 transcendentals, OpenBLAS's SkylakeX or Haswell kernels,
OpenCV's AVX2 warps), so the last bits of a sine, a matrix product or a rendered pixel differ from one CPU to the
next; an iterative fit then stops a few ulps elsewhere, and a rendered video differs in its bytes. Each tolerance
below says what it protects, and `make test` runs the reference tests a second time under another SIMD dispatch
(``OTHER_SIMD`` in the Makefile) so that a comparison that only holds on one CPU fails here too.
"""

from __future__ import annotations

import fnmatch
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import pandas as pd


@dataclass(frozen=True)
class Tol:
    """``|new - old| <= max(abs, rel * |old|)``; NaN equals NaN only."""

    rel: float
    abs: float

    def close(self, new: float, old: float) -> bool:
        if math.isnan(old) or math.isnan(new):
            return math.isnan(old) and math.isnan(new)
        if math.isinf(old) or math.isinf(new):
            return new == old
        return abs(new - old) <= max(self.abs, self.rel * abs(old))


#: Plain floats of a file that is written from the same numbers by arithmetic alone (a camera JSON from its
#: matrices, a table from a deterministic smoother): the last few bits, nothing a user can see.
LAST_BITS = Tol(rel=1e-9, abs=1e-9)

#: The outputs of a calibration (a robust least-squares fit run to convergence). The fit stops within ~1e-8 px of
#: its optimum, and another CPU's BLAS moves that stop by up to 2.6e-6 relative (measured on the stored scenes with
#: OpenBLAS's SkylakeX, Haswell and Nehalem kernels, numpy with and without AVX2/AVX-512). 1e-4 relative (0.1 mm
#: in 1 m, 1e-4 px on a 1 px residual) is 40x that noise and far below anything a calibration can tell.
FIT = Tol(rel=1e-4, abs=1e-6)

#: Entries of a covariance matrix, compared scaled by their standard deviations, |dC_ij| <= tol * sqrt(C_ii C_jj):
#: correlations to 1e-4 and variances to 1e-4 relative. The paper's camera is so ill-determined (position std
#: 6.7 km) that its raw entries move by 2e-5 relative between CPUs; scaled, by 6e-7 (measured as for FIT).
COVARIANCE = 1e-4


#: Traffic outputs from the same input pixels or tracks (trajectories, speeds, counts, times): a Kalman smoother and
#: the ground mapping move by up to 4e-9 under another SIMD dispatch (measured on the small world's process and
#: stitch runs); 1e-6 absolute (a micrometre, a millionth of a km/h or a second) is 250x that and far below any
#: change of the code worth finding. The relative part is tiny on purpose: 1e-6 of a northing of 5e6 m would let a
#: position move by 5 m; 1e-12 of it is 5 micrometres (both dispatches of ``make test`` pass at this tolerance).
TRAFFIC = Tol(rel=1e-12, abs=1e-6)


def _matches(where: str, patterns: Mapping[str, object]) -> object | None:
    for pattern, value in patterns.items():
        if fnmatch.fnmatchcase(where, pattern):
            return value
    return None


def assert_json_close(new: object, old: object, where: str = "", tol: Tol = LAST_BITS,
                      overrides: Mapping[str, Tol] | None = None, covariances: tuple[str, ...] = ()) -> None:
    """``new`` equals ``old`` (parsed JSON): the same keys, list lengths, strings, integers and booleans; floats
    within ``tol`` (or the ``overrides`` tolerance of the first glob pattern matching their dotted path, e.g.
    ``"*.loo_error_px"``); the matrices at paths matching ``covariances`` entry by entry scaled by their standard
    deviations (:data:`COVARIANCE`)."""
    overrides = overrides or {}
    if isinstance(old, dict):
        assert isinstance(new, dict), f"{where}: {type(new).__name__} where the reference has an object"
        assert set(new) == set(old), f"{where}: keys {sorted(new)} != {sorted(old)}"
        for key in old:
            assert_json_close(new[key], old[key], f"{where}.{key}", tol, overrides, covariances)
        return
    if any(fnmatch.fnmatchcase(where, p) for p in covariances):
        assert_covariance_close(np.asarray(new, dtype=float), np.asarray(old, dtype=float), where)
        return
    if isinstance(old, list):
        assert isinstance(new, list) and len(new) == len(old), f"{where}: {new!r} != {old!r}"
        for i, (a, b) in enumerate(zip(new, old, strict=True)):
            assert_json_close(a, b, f"{where}[{i}]", tol, overrides, covariances)
        return
    if isinstance(old, float) and isinstance(new, int | float) and not isinstance(new, bool):
        t = _matches(where, overrides) or tol
        assert t.close(float(new), old), f"{where}: {new!r} != {old!r} (tolerance {t})"
        return
    assert type(new) is type(old) and new == old, f"{where}: {new!r} != {old!r}"


def assert_covariance_close(new: np.ndarray, old: np.ndarray, where: str, tol: float = COVARIANCE) -> None:
    """Covariance matrices equal to ``tol`` of ``sqrt(C_ii C_jj)`` per entry (see :data:`COVARIANCE`)."""
    assert new.shape == old.shape, f"{where}: shape {new.shape} != {old.shape}"
    std = np.sqrt(np.abs(np.diag(old)))
    scale = np.outer(std, std)
    worst = np.max(np.abs(new - old) / np.where(scale > 0, scale, 1.0)) if old.size else 0.0
    assert worst <= tol, f"{where}: differs by {worst:.2g} of sqrt(C_ii C_jj) (tolerance {tol:g})"


_NUMBER = re.compile(r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?")


def assert_text_close(new: str, old: str, where: str = "text") -> None:
    """Two printed reports are the same text with the same numbers as printed: every character outside the numbers
    equal, integers equal, and each real number within one unit of its last printed digit (a value on a rounding
    boundary may print either way on another CPU), and printed with as many decimals."""
    new_lines, old_lines = new.splitlines(), old.splitlines()
    assert len(new_lines) == len(old_lines), f"{where}: {len(new_lines)} lines != {len(old_lines)}"
    for k, (a, b) in enumerate(zip(new_lines, old_lines, strict=True)):
        assert _NUMBER.sub("#", a) == _NUMBER.sub("#", b), f"{where} line {k + 1}: {a!r} != {b!r}"
        for x, y in zip(_NUMBER.findall(a), _NUMBER.findall(b), strict=True):
            if x != y:
                assert _is_real(y) and _decimals(x) == _decimals(y), f"{where} line {k + 1}: {x} != {y} in {a!r}"
                assert abs(float(x) - float(y)) <= _last_digit(y) * 1.000001, \
                    f"{where} line {k + 1}: {x} != {y} in {a!r}"


def _is_real(number: str) -> bool:
    """A number printed with a decimal point or an exponent; integers (counts, ids) must be equal."""
    return "." in number or "e" in number.lower()


def _decimals(number: str) -> int:
    mantissa = number.lower().split("e")[0]
    return len(mantissa.split(".")[1]) if "." in mantissa else 0


def _last_digit(number: str) -> float:
    """The value of one unit in the last printed digit of ``number`` (e.g. 0.001 for "0.094", 1e-5 for "1.2e-4")."""
    exponent = int(number.lower().split("e")[1]) if "e" in number.lower() else 0
    return 10.0 ** (exponent - _decimals(number))


def assert_csv_close(new_path: object, old_path: object, name: str, tol: Tol = LAST_BITS, *,
                     sort_by: tuple[str, ...] = ()) -> None:
    """Two CSV files hold the same table: the same header and rows, text and integer cells equal, and each real within
    ``tol`` or one unit in the last digit the reference printed, whichever is larger (a value rounded to 4 decimals
    on a rounding boundary may print either way on another CPU). ``sort_by``: numeric columns that identify a row,
    for a table whose row order beyond them means nothing (rows compared in their order)."""
    new, old = (pd.read_csv(p, dtype=str, keep_default_na=False) for p in (new_path, old_path))
    if sort_by:
        new, old = (t.iloc[np.lexsort([pd.to_numeric(t[c]).to_numpy() for c in reversed(sort_by)])]
                    .reset_index(drop=True) for t in (new, old))
    assert list(new.columns) == list(old.columns), f"{name}: columns {list(new.columns)} != {list(old.columns)}"
    assert len(new) == len(old), f"{name}: {len(new)} rows != {len(old)}"
    for col in old.columns:
        for i, (x, y) in enumerate(zip(new[col], old[col], strict=True)):
            if x == y:
                continue
            where = f"{name}: column {col!r} row {i}"
            assert _NUMBER.fullmatch(x) and _NUMBER.fullmatch(y) and _is_real(y), f"{where}: {x!r} != {y!r}"
            bound = max(tol.abs, tol.rel * abs(float(y)), _last_digit(y) * 1.000001)
            assert abs(float(x) - float(y)) <= bound, f"{where}: {x} != {y} (tolerance {bound:.3g})"

