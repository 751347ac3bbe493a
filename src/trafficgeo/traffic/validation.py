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

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
import pyproj

from trafficgeo.crs import crs_label
from trafficgeo.errors import InputError
from trafficgeo.io.run_manifest import verify_outputs
from trafficgeo.run.records import SimulationRecord
from trafficgeo.site.lanes import Lanes, lanes_from_polygons
from trafficgeo.site.lines import CountLine
from trafficgeo.traffic.compare import (
    compare_counts,
    compare_speeds_by,
    compare_travel_times,
    count_summary,
    travel_times,
)
from trafficgeo.traffic.counts import aggregate_counts, counted_groups, find_crossings

RUN_HINT = "give the output folder of 'trafficgeo analyze' or 'process' (a run folder)"


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
    """Read an ``analyze``/``process`` output folder (:class:`~trafficgeo.run.folder.RunFolder`)."""
    from trafficgeo.run.folder import RunFolder

    d = Path(folder)
    if not d.is_dir():
        raise InputError(f"{d}: not a folder; {RUN_HINT}")
    for name in ("summary.json", "counts.csv", "crossings.csv"):
        if not (d / name).is_file():
            raise InputError(f"{d}: no {name}; {RUN_HINT}")
    run = RunFolder(d)
    manifest = verify_outputs(d, require=("summary.json", "counts.csv", "crossings.csv"))
    summary = run.summary()
    if summary.interval_s is None:
        raise InputError(f"{d / 'summary.json'}: no options.interval_s; not a summary written by 'trafficgeo "
                         "analyze', run it again")
    crs = pyproj.CRS.from_wkt(summary.crs) if summary.crs else None
    counts = run.table("counts.csv", required=("line", "lane", "direction", "interval_start", "interval_end",
                                                "count"))
    crossings = run.table("crossings.csv", required=("line", "track_id", "lane", "direction", "time"))
    lines, lanes = _layout_layers(d / "trajectories.gpkg") if manifest.has("trajectories.gpkg") else ([], None)
    return ObservedRun(d, crs, summary.period_s, summary.interval_s, counts, crossings, lines, lanes,
                       frozenset(manifest.files))


def _layout_layers(gpkg: Path) -> tuple[list[CountLine], Lanes | None]:
    if not gpkg.is_file():
        return [], None
    from trafficgeo.io.gis import gis_layers, read_gis

    names = set(gis_layers(gpkg))
    lines: list[CountLine] = []
    lanes = None
    if "count_lines" in names:
        g = read_gis(gpkg, layer="count_lines")
        lines = [CountLine(str(n), geom, tuple(s for s in str(ln or "").split(",") if s))
                 for n, geom, ln in zip(g["name"], g.geometry, g.get("lanes", [""] * len(g)), strict=True)]
    if "lanes" in names:
        g = read_gis(gpkg, layer="lanes")
        lanes = lanes_from_polygons(list(g.geometry), [str(v) for v in g["lane"]])
    return lines, lanes


def simulated_points(fcd: str | Path, crs: pyproj.CRS | None, *, net: str | Path | None = None,
                     net_crs: str | None = None, time_offset_s: float = 0.0) -> pd.DataFrame:
    """SUMO FCD as track points in ``crs``: footprint centres (the front bumper moved back by half the typical
    length of the vehicle's type, :data:`trafficgeo.traffic.box_points.VEHICLE_DIMENSIONS`; a car's for unknown
    types), times shifted to observed time."""
    from trafficgeo.crs import metres_per_unit
    from trafficgeo.geo.cuboids import dimensions_for
    from trafficgeo.io.fcd_read import read_fcd

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
    movements: pd.DataFrame | None = None  # at a junction's gates: traffic.movements.compare_movement_counts
    movement_summary: dict | None = None  # its traffic.movements.movement_comparison_summary
    simulated_movements: pd.DataFrame | None = None  # the simulated vehicles' movements (movements.csv's columns)


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
    obs_counts = counted_groups(observed.counts[observed.counts["line"].isin(names)])  # as before zero rows
    table = compare_counts(obs_counts, sim_counts)
    obs_cross = observed.crossings[observed.crossings["line"].isin(names)]
    speeds = compare_speeds_by(obs_cross, sim_cross, by=("line", "lane"))
    tt = None
    if len(names) >= 2:
        tt = compare_travel_times(travel_times(obs_cross, names[0], names[-1]),
                                  travel_times(sim_cross, names[0], names[-1]))
        tt = {"from_line": names[0], "to_line": names[-1], **tt}
    return Comparison(table, count_summary(table), speeds, tt, sim_cross)


def write_comparison(out_dir: str | Path, comparison: Comparison, crs: pyproj.CRS | None, *,
                     simulation: SimulationRecord | None = None) -> list[Path]:
    """``compare_counts.csv``, ``compare_speeds.csv``, ``simulated_crossings.csv`` (at a junction also
    ``compare_movements.csv`` and ``simulated_movements.csv``), ``compare_summary.json`` and ``sumo-validate``'s
    ``simulation`` record into ``out_dir``, under the comparison's manifest
    (:meth:`~trafficgeo.run.folder.RunFolder.write_comparison`); returns the paths written."""
    from trafficgeo.run.folder import RunFolder
    from trafficgeo.run.records import CompareSummary

    doc = {"counts": comparison.count_summary, "travel_times": comparison.travel_times, "crs": crs_label(crs),
           "movements": comparison.movement_summary}
    tables = {"compare_counts.csv": comparison.counts, "compare_speeds.csv": comparison.speeds,
              "simulated_crossings.csv": comparison.simulated_crossings}
    if comparison.movements is not None:
        tables["compare_movements.csv"] = comparison.movements
    if comparison.simulated_movements is not None:
        tables["simulated_movements.csv"] = comparison.simulated_movements
    return RunFolder(out_dir).write_comparison(tables, CompareSummary.from_dict(doc, "the comparison"), simulation)


def compare_with_sumo(run: ObservedRun | str | Path, fcd: str | Path, *, net: str | Path | None = None,
                      net_crs: str | None = None, lines: list[CountLine] | str | Path | None = None,
                      time_offset_s: float = 0.0, out_dir: str | Path | None = None) -> Comparison:
    """Observed vs simulated traffic (``trafficgeo compare-sumo``): the run (a run folder, or an :class:`ObservedRun`)
    against a SUMO FCD output ``fcd`` (network coordinates through ``net``, a ``.net.xml``; ``net_crs`` when its
    PROJ string is not enough), at the run's counting lines or ``lines`` (objects or a GIS file): per-lane counts
    (GEH), spot speeds (KS) and travel times. ``time_offset_s``: simulation time minus observed time (s). With
    ``out_dir``, the comparison tables are written there too (:func:`write_comparison`).

    >>> import trafficgeo as tg
    >>> cmp = tg.compare_with_sumo(out / "run", world / "sumo" / "fcd.xml", net=world / "sumo" / "road.net.xml")
    >>> cmp.count_summary["rows"] > 0, 0.0 <= cmp.count_summary["share_geh_below_5"] <= 1.0
    (True, True)
    """
    import math

    from trafficgeo.site.lines import read_count_lines

    if not math.isfinite(time_offset_s):
        raise InputError(f"time_offset_s {time_offset_s}: give the simulation's time minus the observed time as a "
                         "finite number of seconds, e.g. 0")
    observed = run if isinstance(run, ObservedRun) else read_observed_run(run)
    if isinstance(lines, str | Path):
        lines = read_count_lines(Path(lines), crs=observed.crs)
    sim = simulated_points(fcd, observed.crs, net=net, net_crs=net_crs, time_offset_s=time_offset_s)
    comparison = compare_with_simulation(observed, sim, lines=lines)
    if out_dir is not None:
        write_comparison(out_dir, comparison, observed.crs)
    return comparison


def export_fcd(run: str | Path, output: str | Path, *, net: str | Path | None = None, net_crs: str | None = None,
               geo: bool = False) -> int:
    """Write a run's observed trajectories as SUMO FCD (``trafficgeo export-fcd``): front bumpers, m/s, in the
    run's CRS, or in the coordinates of the SUMO network ``net`` (``net_crs`` when its PROJ string is not enough),
    or lon/lat with ``geo`` (like ``sumo --fcd-output.geo``). Returns the number of points written."""
    from trafficgeo.geo.cuboids import dimensions_for
    from trafficgeo.io.fcd_write import write_fcd
    from trafficgeo.io.run_manifest import check_writable_file
    from trafficgeo.run.folder import RunFolder

    if Path(output).suffix.lower() != ".xml":
        raise InputError(f"output {output}: SUMO FCD is XML; name it .xml (e.g. observed.fcd.xml)")
    check_writable_file(output, "output")
    observed = read_observed_run(run)
    if "trajectories.csv" not in observed.outputs:
        raise InputError(f"{run}: no trajectories.csv; {RUN_HINT}")
    pts = RunFolder(run).table("trajectories.csv", required=("track_id", "time", "x", "y"))
    half = 0.5 * dimensions_for(pts["class"].to_numpy() if "class" in pts else np.full(len(pts), ""))[:, 0]
    if "length_m" in pts.columns:
        half = np.where(np.isfinite(pts["length_m"]), 0.5 * pts["length_m"], half)
    cols = ["track_id", "time", "x", "y", "z", "speed_kmh", "heading_deg", "class", "lane"]
    write_fcd(output, pts[[c for c in cols if c in pts.columns]], crs=observed.crs, net=net, net_crs=net_crs,
              geo=geo, front_offset_m=half)
    return len(pts)
