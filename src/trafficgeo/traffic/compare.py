"""Observed versus simulated traffic: counts (GEH statistic), spot speeds and travel times.

Pure functions on the tables trafficgeo produces for both sides (from video and from a simulation):

* a **crossings** table: one row per vehicle and counting line, columns ``line`` (str), ``track_id`` (str),
  ``class`` (str), ``lane`` (str, "" unknown), ``direction`` (+1/-1), ``time`` (s), ``speed_kmh``, ``x``, ``y``;
* a **counts** table: one row per ``line, lane, direction, interval_start, interval_end`` (s) with ``count``
  (vehicles); other columns are ignored.

The GEH statistic compares hourly flows M (observed/modelled reference) and C (counted/compared):
``GEH = sqrt(2 (M - C)^2 / (M + C))``. The usual calibration target (UK DMRB, FHWA) is GEH < 5 for at least 85 %
of the counts. Counts are turned into hourly flows with the interval length: ``flow = count * 3600 / (end -
start)``. Distributions are compared with the two-sample Kolmogorov-Smirnov test (``scipy.stats.ks_2samp``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike
from scipy import stats

from trafficgeo.errors import InputError

__all__ = [
    "COUNT_KEYS",
    "compare_counts",
    "compare_speeds",
    "compare_speeds_by",
    "compare_travel_times",
    "count_summary",
    "geh",
    "travel_times",
]

COUNT_KEYS = ["line", "lane", "direction", "interval_start", "interval_end"]
GEH_LIMIT = 5.0
_CROSSING_HINT = "give a crossings table with columns line, track_id, class, lane, direction, time, speed_kmh"
_COUNT_HINT = "give a counts table with columns line, lane, direction, interval_start, interval_end, count"


# ---------------------------------------------------------------------------------------------------- GEH
def geh(m: ArrayLike, c: ArrayLike) -> np.ndarray | float:
    """GEH statistic of hourly flows ``m`` and ``c`` (veh/h, >= 0), element-wise; 0 where both are 0.

    Returns a float for scalar inputs, else an array of the broadcast shape (NaN where an input is NaN).

    Raises:
        InputError: a negative flow.
    """
    ma, ca = np.asarray(m, dtype=np.float64), np.asarray(c, dtype=np.float64)
    if np.any(ma < 0) or np.any(ca < 0):
        raise InputError("GEH needs hourly flows >= 0 (veh/h); got a negative flow")
    total = ma + ca
    with np.errstate(divide="ignore", invalid="ignore"):
        value = np.sqrt(2.0) * np.abs(ma - ca) / np.sqrt(total)  # = sqrt(2 (M - C)^2 / (M + C)), no underflow
    value = np.where(total == 0, 0.0, value)
    return float(value) if value.ndim == 0 else value


# ---------------------------------------------------------------------------------------------------- counts
def _require(table: pd.DataFrame, columns: Sequence[str], what: str, hint: str) -> None:
    if not isinstance(table, pd.DataFrame):
        raise InputError(f"{what} must be a pandas DataFrame, got {type(table).__name__}; {hint}")
    missing = [c for c in columns if c not in table.columns]
    if missing:
        raise InputError(f"{what} lacks column(s) {', '.join(missing)} (has: "
                         f"{', '.join(map(str, table.columns)) or 'none'}); {hint}")


def _count_frame(table: pd.DataFrame, what: str) -> pd.DataFrame:
    """The key columns (normalised types) and ``count`` of a counts table; one row per key."""
    _require(table, [*COUNT_KEYS, "count"], what, _COUNT_HINT)
    out = pd.DataFrame({
        "line": table["line"].astype(str), "lane": table["lane"].fillna("").astype(str),
        "direction": pd.to_numeric(table["direction"], errors="coerce"),
        "interval_start": pd.to_numeric(table["interval_start"], errors="coerce"),
        "interval_end": pd.to_numeric(table["interval_end"], errors="coerce"),
        "count": pd.to_numeric(table["count"], errors="coerce"),
    })
    bad = out[["direction", "interval_start", "interval_end", "count"]].isna().any(axis=1)
    if bad.any():
        row = int(np.flatnonzero(bad.to_numpy())[0])
        raise InputError(f"{what} row {row}: direction, interval_start, interval_end and count must be numbers; "
                         f"{_COUNT_HINT}")
    if (out["count"] < 0).any() or (out["interval_end"] <= out["interval_start"]).any():
        raise InputError(f"{what}: counts must be >= 0 and intervals must end after they start (s); {_COUNT_HINT}")
    out["direction"] = out["direction"].astype(np.int64)
    dup = out.duplicated(COUNT_KEYS)
    if dup.any():
        key = out.loc[dup, COUNT_KEYS].iloc[0].tolist()
        raise InputError(f"{what}: two rows for line, lane, direction, interval {key}; give one row per key")
    return out


def compare_counts(observed_counts: pd.DataFrame, simulated_counts: pd.DataFrame) -> pd.DataFrame:
    """Observed and simulated counts side by side, per line, lane, direction and interval, with their GEH.

    An outer join on :data:`COUNT_KEYS`: a key missing on one side counts 0 vehicles there. Columns: the keys,
    ``observed``, ``simulated`` (vehicles), ``observed_flow_veh_h``, ``simulated_flow_veh_h`` (count * 3600 /
    interval length), ``geh`` (observed as M, simulated as C; symmetric anyway) and ``geh_ok`` (GEH < 5).
    """
    obs = _count_frame(observed_counts, "observed counts")
    sim = _count_frame(simulated_counts, "simulated counts")
    table = obs.merge(sim, on=COUNT_KEYS, how="outer", suffixes=("_obs", "_sim"))
    table["observed"] = table.pop("count_obs").fillna(0).astype(np.int64)
    table["simulated"] = table.pop("count_sim").fillna(0).astype(np.int64)
    hours = (table["interval_end"] - table["interval_start"]) / 3600.0
    table["observed_flow_veh_h"] = table["observed"] / hours
    table["simulated_flow_veh_h"] = table["simulated"] / hours
    table["geh"] = geh(table["observed_flow_veh_h"].to_numpy(), table["simulated_flow_veh_h"].to_numpy())
    table["geh_ok"] = table["geh"] < GEH_LIMIT
    return table.sort_values(COUNT_KEYS, kind="stable").reset_index(drop=True)


def _totals(table: pd.DataFrame) -> dict[str, float | int]:
    """Total counts of a :func:`compare_counts` table, their hourly flows over its intervals and their GEH."""
    intervals = table[["interval_start", "interval_end"]].drop_duplicates()
    hours = float((intervals["interval_end"] - intervals["interval_start"]).sum()) / 3600.0
    o, s = int(table["observed"].sum()), int(table["simulated"].sum())
    fo, fs = (o / hours, s / hours) if hours > 0 else (np.nan, np.nan)
    return {"observed": o, "simulated": s, "observed_flow_veh_h": fo, "simulated_flow_veh_h": fs,
            "geh": float(geh(fo, fs)) if hours > 0 else np.nan}


def count_summary(table: pd.DataFrame, by: Sequence[str] = ("line", "lane")) -> dict:
    """Summary of a :func:`compare_counts` table.

    Keys: ``rows``; ``share_geh_below_5`` (fraction of rows with GEH < 5; the usual target is >= 0.85);
    ``mean_geh``; ``total_observed``, ``total_simulated`` (vehicles); ``geh_total`` (GEH of the total hourly
    flows over the distinct intervals); ``groups``: one dict per ``by`` group (default line and lane; add
    "direction" to split directions) with its ``observed``, ``simulated``, hourly flows and ``geh`` of the totals.
    """
    _require(table, [*COUNT_KEYS, "observed", "simulated", "geh"], "count comparison table",
             "give the output of compare_counts")
    n = len(table)
    total = _totals(table) if n else {"observed": 0, "simulated": 0, "geh": np.nan}
    groups = [{**dict(zip(by, key if isinstance(key, tuple) else (key,), strict=True)), **_totals(g)}
              for key, g in table.groupby(list(by), sort=True)] if n else []
    return {
        "rows": n,
        "share_geh_below_5": float((table["geh"] < GEH_LIMIT).mean()) if n else np.nan,
        "mean_geh": float(table["geh"].mean()) if n else np.nan,
        "total_observed": total["observed"],
        "total_simulated": total["simulated"],
        "geh_total": total["geh"],
        "groups": groups,
    }


# ---------------------------------------------------------------------------------------------------- speeds
def _sample(values: ArrayLike) -> np.ndarray:
    """Finite values of a 1-D sample as float64."""
    a = np.asarray(values, dtype=np.float64).ravel()
    return a[np.isfinite(a)]


def _describe(a: np.ndarray, prefix: str, unit: str) -> dict[str, float | int]:
    """n, mean, std (ddof 1) and the 15th/50th/85th percentiles of a sample (NaN when too small)."""
    empty = a.size == 0
    p15, p50, p85 = (np.nan,) * 3 if empty else np.percentile(a, [15, 50, 85])
    return {f"{prefix}_n": int(a.size),
            f"{prefix}_mean{unit}": np.nan if empty else float(a.mean()),
            f"{prefix}_std{unit}": float(a.std(ddof=1)) if a.size > 1 else np.nan,
            f"{prefix}_p15{unit}": float(p15), f"{prefix}_p50{unit}": float(p50), f"{prefix}_p85{unit}": float(p85)}


def _ks(a: np.ndarray, b: np.ndarray) -> dict[str, float]:
    if a.size == 0 or b.size == 0:
        return {"ks_statistic": np.nan, "ks_pvalue": np.nan}
    res = stats.ks_2samp(a, b)
    return {"ks_statistic": float(res.statistic), "ks_pvalue": float(res.pvalue)}


def compare_speeds(observed_kmh: ArrayLike, simulated_kmh: ArrayLike) -> dict[str, float | int]:
    """Compare two samples of spot speeds (km/h; NaN and inf are dropped).

    Keys: ``observed_n``, ``observed_mean_kmh``, ``observed_std_kmh``, ``observed_p15_kmh``, ``observed_p50_kmh``,
    ``observed_p85_kmh``, the same for ``simulated_``, ``mean_difference_kmh`` (simulated - observed) and the
    two-sample Kolmogorov-Smirnov ``ks_statistic`` (0: identical distributions) and ``ks_pvalue``.
    """
    o, s = _sample(observed_kmh), _sample(simulated_kmh)
    out = {**_describe(o, "observed", "_kmh"), **_describe(s, "simulated", "_kmh")}
    out["mean_difference_kmh"] = out["simulated_mean_kmh"] - out["observed_mean_kmh"]
    return {**out, **_ks(o, s)}


def compare_speeds_by(crossings_obs: pd.DataFrame, crossings_sim: pd.DataFrame,
                      by: Sequence[str] = ("line", "lane")) -> pd.DataFrame:
    """:func:`compare_speeds` per group of two crossings tables (default per line and lane; groups present on
    either side), one row per group: the ``by`` columns then the statistics."""
    by = list(by)
    for what, t in (("observed crossings", crossings_obs), ("simulated crossings", crossings_sim)):
        _require(t, [*by, "speed_kmh"], what, _CROSSING_HINT)
    obs, sim = _groups(crossings_obs, by), _groups(crossings_sim, by)
    rows = []
    for key in sorted(set(obs) | set(sim)):
        empty = np.empty(0)
        rows.append({**dict(zip(by, key, strict=True)), **compare_speeds(obs.get(key, empty), sim.get(key, empty))})
    columns = [*by, *compare_speeds([], []).keys()]
    return pd.DataFrame(rows, columns=columns)


def _groups(table: pd.DataFrame, by: list[str]) -> dict[tuple, np.ndarray]:
    """Speeds (km/h) of each ``by`` group; text keys with missing values become ""."""
    keys = table[by].copy()
    for c in by:
        if not pd.api.types.is_numeric_dtype(keys[c]):
            keys[c] = keys[c].fillna("").astype(str)
    speed = pd.to_numeric(table["speed_kmh"], errors="coerce").to_numpy(np.float64)
    return {k if isinstance(k, tuple) else (k,): speed[idx]
            for k, idx in keys.groupby(by, sort=True).indices.items()}


# ---------------------------------------------------------------------------------------------------- travel times
def travel_times(crossings: pd.DataFrame, from_line: str, to_line: str) -> pd.DataFrame:
    """Travel times between two counting lines: one row per vehicle that crosses ``from_line`` and later
    ``to_line`` (its first crossing of each; vehicles crossing only one line, or the other way round, are left
    out). Columns ``track_id, class, t_from, t_to`` (s) and ``travel_time_s``, sorted by ``t_from``."""
    _require(crossings, ["line", "track_id", "time"], "crossings", _CROSSING_HINT)
    t = pd.DataFrame({"line": crossings["line"].astype(str), "track_id": crossings["track_id"].astype(str),
                      "class": crossings["class"].fillna("").astype(str) if "class" in crossings else "",
                      "time": pd.to_numeric(crossings["time"], errors="coerce")})
    t = t[np.isfinite(t["time"])].sort_values("time", kind="stable")
    first = t[t["line"] == str(from_line)].drop_duplicates("track_id")
    later = t[t["line"] == str(to_line)].merge(first[["track_id", "time"]], on="track_id", suffixes=("", "_from"))
    later = later[later["time"] > later["time_from"]].drop_duplicates("track_id")
    out = first.rename(columns={"time": "t_from"}).merge(
        later[["track_id", "time"]].rename(columns={"time": "t_to"}), on="track_id")
    out["travel_time_s"] = out["t_to"] - out["t_from"]
    columns = ["track_id", "class", "t_from", "t_to", "travel_time_s"]
    return out[columns].sort_values("t_from", kind="stable").reset_index(drop=True)


def _travel_sample(values: pd.DataFrame | ArrayLike) -> np.ndarray:
    if isinstance(values, pd.DataFrame):
        _require(values, ["travel_time_s"], "travel times", "give the output of travel_times or an array of s")
        values = values["travel_time_s"].to_numpy()
    return _sample(values)


def compare_travel_times(obs: pd.DataFrame | ArrayLike, sim: pd.DataFrame | ArrayLike) -> dict[str, float | int]:
    """Compare observed and simulated travel times (tables from :func:`travel_times`, or arrays of seconds).

    Keys: ``observed_n``, ``observed_mean_s``, ``observed_median_s``, ``observed_p85_s``, the same for
    ``simulated_``, ``mean_difference_s`` (simulated - observed), ``ks_statistic`` and ``ks_pvalue``.
    """
    o, s = _travel_sample(obs), _travel_sample(sim)
    out: dict[str, float | int] = {}
    for prefix, a in (("observed", o), ("simulated", s)):
        d = _describe(a, prefix, "_s")
        out.update({f"{prefix}_n": d[f"{prefix}_n"], f"{prefix}_mean_s": d[f"{prefix}_mean_s"],
                    f"{prefix}_median_s": d[f"{prefix}_p50_s"], f"{prefix}_p85_s": d[f"{prefix}_p85_s"]})
    out["mean_difference_s"] = out["simulated_mean_s"] - out["observed_mean_s"]
    return {**out, **_ks(o, s)}
