"""Observed traffic (an ``analyze`` folder) against a SUMO simulation of it (FCD): the paper's validation mechanism
for traffic simulation models, made concrete.

The simulated vehicles are counted exactly like the observed ones: their FCD trajectories (front bumper, moved
back by half a typical vehicle length of their type to the footprint centre) cross the same counting lines, in
the same lanes, over the same observation period and counting intervals. Then
:mod:`trafficgeo.traffic.compare` gives the GEH of every line/lane/direction/interval count, spot-speed
distributions per line and lane (KS distance) and travel times between the first and the last line.

Simulation time ``t`` is observed time ``t + time_offset_s``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
import pyproj

from trafficgeo.crs import crs_label
from trafficgeo.errors import InputError
from trafficgeo.io.run_manifest import verify_outputs
from trafficgeo.traffic.compare import (
    compare_counts,
    compare_speeds_by,
    compare_travel_times,
    count_summary,
    travel_times,
)
from trafficgeo.traffic.lanes import Lanes, lanes_from_polygons
from trafficgeo.traffic.lines import CountLine, aggregate_counts, find_crossings

RUN_HINT = "give the --out folder of 'trafficgeo analyze'"


@dataclass(frozen=True)
class ObservedRun:
    """What ``analyze`` wrote: counts, crossings, the lines and lanes used, the CRS, period and interval."""

    folder: Path
    crs: pyproj.CRS | None
    period: tuple[float, float]
    interval_s: float
    counts: pd.DataFrame
    crossings: pd.DataFrame
    lines: list[CountLine] = field(default_factory=list)
    lanes: Lanes | None = None
    outputs: frozenset[str] = frozenset()  # the run's output files, checked against its manifest


def read_observed_run(folder: str | Path) -> ObservedRun:
    """Read an ``analyze`` output folder."""
    d = Path(folder)
    if not d.is_dir():
        raise InputError(f"{d}: not a folder; {RUN_HINT}")
    for name in ("summary.json", "counts.csv", "crossings.csv"):
        if not (d / name).is_file():
            raise InputError(f"{d}: no {name}; {RUN_HINT}")
    manifest = verify_outputs(d, require=("summary.json", "counts.csv", "crossings.csv"))
    try:
        summary = json.loads((d / "summary.json").read_text())
        period = (float(summary["period_s"][0]), float(summary["period_s"][1]))
        interval = float(summary["options"]["interval_s"])
    except (json.JSONDecodeError, KeyError, TypeError, ValueError, IndexError):
        raise InputError(f"{d / 'summary.json'}: not a summary written by 'trafficgeo analyze'; run it again") from None
    crs = pyproj.CRS.from_wkt(summary["crs"]) if summary.get("crs") else None
    text = {"line": str, "lane": str, "track_id": str, "class": str}
    counts = pd.read_csv(d / "counts.csv", dtype=text, keep_default_na=False, na_values=[""])
    crossings = pd.read_csv(d / "crossings.csv", dtype=text, keep_default_na=False, na_values=[""])
    for table in (counts, crossings):
        for col in ("lane", "class"):
            if col in table.columns:
                table[col] = table[col].fillna("")
    lines, lanes = _layout_layers(d / "trajectories.gpkg") if manifest.has("trajectories.gpkg") else ([], None)
    return ObservedRun(d, crs, period, interval, counts, crossings, lines, lanes, frozenset(manifest.files))


def _layout_layers(gpkg: Path) -> tuple[list[CountLine], Lanes | None]:
    if not gpkg.is_file():
        return [], None
    import geopandas as gpd
    import pyogrio

    names = set(pyogrio.list_layers(gpkg)[:, 0])
    lines: list[CountLine] = []
    lanes = None
    if "count_lines" in names:
        g = gpd.read_file(gpkg, layer="count_lines")
        lines = [CountLine(str(n), geom, tuple(s for s in str(ln or "").split(",") if s))
                 for n, geom, ln in zip(g["name"], g.geometry, g.get("lanes", [""] * len(g)), strict=True)]
    if "lanes" in names:
        g = gpd.read_file(gpkg, layer="lanes")
        lanes = lanes_from_polygons(list(g.geometry), [str(v) for v in g["lane"]])
    return lines, lanes


def simulated_points(fcd: str | Path, crs: pyproj.CRS | None, *, net: str | Path | None = None,
                     net_crs: str | None = None, time_offset_s: float = 0.0) -> pd.DataFrame:
    """SUMO FCD as track points in ``crs``: footprint centres (the front bumper moved back by half the typical
    length of the vehicle's type, :data:`trafficgeo.traffic.boxes.VEHICLE_DIMENSIONS`; a car's for unknown
    types), times shifted to observed time."""
    from trafficgeo.crs import metres_per_unit
    from trafficgeo.io.sumo import read_fcd
    from trafficgeo.traffic.boxes import dimensions_for

    pts = read_fcd(fcd, net=net, crs=crs, net_crs=net_crs)
    half = 0.5 * dimensions_for(pts["class"].to_numpy())[:, 0] / metres_per_unit(crs)
    h = np.radians(pts["heading_deg"].to_numpy())
    pts["x"] = pts["x"] - half * np.sin(h)
    pts["y"] = pts["y"] - half * np.cos(h)
    pts["time"] = pts["time"] - time_offset_s
    return pts.sort_values(["track_id", "time"], kind="stable").reset_index(drop=True)


@dataclass(frozen=True)
class Comparison:
    """Observed vs simulated: the count table (one row per line, lane, direction, interval), its summary, speeds
    per line and lane, travel times, and the simulated crossings."""

    counts: pd.DataFrame
    count_summary: dict
    speeds: pd.DataFrame
    travel_times: dict | None
    simulated_crossings: pd.DataFrame


def compare_with_simulation(observed: ObservedRun, simulated: pd.DataFrame, *,
                            lines: list[CountLine] | None = None, lanes: Lanes | None = None) -> Comparison:
    """Count the simulated points at the observed run's lines and lanes (or the ones given) and compare."""
    lines = lines if lines is not None else observed.lines
    lanes = lanes if lanes is not None else observed.lanes
    if not lines:
        raise InputError(f"{observed.folder}: the run has no counting lines; give --lines (the lines analyze used)")
    t0, t1 = observed.period
    sim_cross = find_crossings(simulated, lines, lanes)
    sim_cross = sim_cross[(sim_cross["time"] >= t0) & (sim_cross["time"] < t1)].reset_index(drop=True)
    sim_counts = aggregate_counts(sim_cross, observed.interval_s, t0, t1)
    names = [ln.name for ln in lines]
    obs_counts = observed.counts[observed.counts["line"].isin(names)]
    table = compare_counts(obs_counts, sim_counts)
    obs_cross = observed.crossings[observed.crossings["line"].isin(names)]
    speeds = compare_speeds_by(obs_cross, sim_cross, by=("line", "lane"))
    tt = None
    if len(names) >= 2:
        tt = compare_travel_times(travel_times(obs_cross, names[0], names[-1]),
                                  travel_times(sim_cross, names[0], names[-1]))
        tt = {"from_line": names[0], "to_line": names[-1], **tt}
    return Comparison(table, count_summary(table), speeds, tt, sim_cross)


def write_comparison(out_dir: str | Path, comparison: Comparison, crs: pyproj.CRS | None) -> list[Path]:
    """``compare_counts.csv``, ``compare_speeds.csv``, ``simulated_crossings.csv`` and ``compare_summary.json``."""
    from trafficgeo.io.atomic import write_csv_atomic, write_json_atomic
    from trafficgeo.io.run_manifest import COMPARE_MANIFEST, begin_outputs, publish_outputs

    out = begin_outputs(out_dir, COMPARE_MANIFEST)
    written = []
    for name, table in (("compare_counts.csv", comparison.counts), ("compare_speeds.csv", comparison.speeds),
                        ("simulated_crossings.csv", comparison.simulated_crossings)):
        write_csv_atomic(out / name, table, float_format="%.4f")
        written.append(out / name)
    doc = {"counts": comparison.count_summary, "travel_times": comparison.travel_times, "crs": crs_label(crs)}
    write_json_atomic(out / "compare_summary.json", doc)
    written.append(out / "compare_summary.json")
    publish_outputs(out, written, command="compare-sumo", name=COMPARE_MANIFEST)
    return written
