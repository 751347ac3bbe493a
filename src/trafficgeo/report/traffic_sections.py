"""The traffic sections of a report as data (:mod:`trafficgeo.report.blocks`): one per ``analyze``/``process`` run,
with its summary, maps and diagrams, the vehicles per class and lane, the counts per line and lane, the video
processing and the ``compare-sumo`` results.

Units: positions in the CRS's units; distances in metres; speeds in km/h; flows in vehicles per hour; times in
seconds.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from trafficgeo.report import figures as F
from trafficgeo.report.blocks import Block, Heading, Part, Section, Table, Text, figure, items, num, table
from trafficgeo.report.context import ReportContext
from trafficgeo.report.inputs import TrafficRun
from trafficgeo.report.movement_section import movement_parts
from trafficgeo.run.records import ProcessRecord, RunSummary
from trafficgeo.traffic.counts import MIN_FLOW_SHARE, flow_rule, period_counts

TABLE_ROWS = 200


def comparison_table(run: TrafficRun, name: str) -> pd.DataFrame | None:
    """Table ``name`` of the run's comparison with a simulation (``compare_counts.csv``, ``compare_speeds.csv``,
    ``simulated_crossings.csv``) read through its :class:`~trafficgeo.run.folder.RunFolder`; None when the
    run has no usable comparison or the comparison has no such table.

    Raises:
        InputError: the file is not a readable table.
    """
    return run.run.comparison_table(name) if run.compare else None


def run_table(run: TrafficRun, name: str) -> pd.DataFrame | None:
    """The run's output table ``name`` (a table of :data:`trafficgeo.run.folder.SCHEMAS`) read through its
    :class:`~trafficgeo.run.folder.RunFolder`, with the schema's dtypes; None when the run has none. No
    column is required: a run written before a column existed still shows what it has.

    Raises:
        InputError: the file is not a readable table.
    """
    folder = run.run
    return folder.table(name, required=()) if folder.has(name) else None


def _layout(folder: Path, crs: Any) -> tuple[list[tuple[str, Any]], list[tuple[str, Any]]]:
    """(name, geometry) of the lanes and of the counting lines a run used, in ``crs``."""
    gpkg = folder / "trajectories.gpkg"
    if not gpkg.is_file():
        return [], []
    from trafficgeo.io.gis import gis_layers, read_gis

    names = set(gis_layers(gpkg))
    lanes, lines = [], []
    if "lanes" in names:
        g = read_gis(gpkg, layer="lanes")
        g = g.to_crs(crs) if crs is not None and g.crs is not None else g
        lanes = [(str(n), geom) for n, geom in zip(g["lane"], g.geometry, strict=True)]
    if "count_lines" in names:
        g = read_gis(gpkg, layer="count_lines")
        g = g.to_crs(crs) if crs is not None and g.crs is not None else g
        lines = [(str(n), geom) for n, geom in zip(g["name"], g.geometry, strict=True)]
    return lanes, lines


def traffic_section(b: ReportContext, run: TrafficRun, k: int) -> Section:
    """The section of the ``k``-th traffic run (1-based); what it cannot show is noted in ``b``."""
    rel = run.folder.relative_to(b.inputs.run_dir) if run.folder != b.inputs.run_dir else Path(".")
    name = "." if str(rel) == "." else str(rel)
    kind = "process" if run.process is not None else "analyze"
    title = f"Traffic: {name}" if len(b.inputs.traffic) > 1 or name != "." else "Traffic"
    points = run_table(run, "trajectories.csv")
    vehicles = run_table(run, "vehicles.csv")
    counts = run_table(run, "counts.csv")
    crossings = run_table(run, "crossings.csv")
    s = run.summary
    b.used.append((f"traffic run ({kind})", str(run.folder)))
    parts: list[Part] = [_run_summary(run, s)]
    lanes, lines = _layout(run.folder, b.crs)
    if points is not None and len(points):
        sp = points["speed_kmh"].to_numpy(float)
        sp = sp[np.isfinite(sp)]
        speed_range = (0.0, max(float(np.percentile(sp, 98)) if sp.size else 1.0, 1.0))
        fx, fy = F.seen_frame(points["x"].to_numpy(float), points["y"].to_numpy(float), lines)
        bg = b.background([fx], [fy], f"trajectories, {name}")
        parts.append((figure(F.trajectories_map(points, b.axes, background=bg, lanes=lanes, lines=lines,
                                                speed_range=speed_range),
                             f"World trajectories (smoothed footprint centres) coloured by speed (km/h), with the "
                             f"lanes and counting lines used. Axes in {b.axes.unit} from the local origin.", b.dpi),))
        parts.append((figure(F.time_space_diagram(points, metres_per_unit=b.m_per_unit, speed_range=speed_range),
                             "Time-space diagram: distance along the road (m, measured on a reference line through "
                             "the middle of all trajectories) against time (s), coloured by speed (km/h), one panel "
                             "per direction of travel.", b.dpi),))
    else:
        b.skip(f"trajectories map and time-space diagram ({name})", "no trajectory points (trajectories.csv missing "
               "or empty)")
    if not lanes:
        b.skip(f"lanes ({name})", "the run has no lanes: pass --lanes to analyze/process for per-lane results")
    if vehicles is not None and "stationary" in vehicles.columns:  # parked vehicles and signs: not in the speeds
        vehicles = vehicles[~vehicles["stationary"].fillna(0).astype(bool)]
    if vehicles is not None and len(vehicles) and _speed_columns(vehicles)[0] in vehicles.columns:
        parts.append((figure(F.speed_histograms(vehicles, column=_speed_columns(vehicles)[0]),
                             "Distribution of the vehicles' speeds (distance travelled along the direction of travel "
                             "over the time seen, km/h) per main lane; dashed: median.", b.dpi),))
        parts.append((Heading("Vehicles"), *_vehicle_tables(vehicles)))
    else:
        b.skip(f"speed histograms and vehicle tables ({name})", "no vehicles (vehicles.csv missing or empty)")
    if counts is not None and len(counts):
        parts.append((figure(F.counts_over_time(counts), "Vehicles counted per interval at each counting line, per "
                             "lane and direction (+1: crossing from left to right looking along the line).", b.dpi),))
    else:
        b.skip(f"counts per lane over time ({name})", "no counts (no counting lines, or nobody crossed them): pass "
               "--lines to analyze/process")
    if crossings is not None and (len(crossings) or lines):
        parts.append((Heading("Counts and speeds per line and lane"),
                      *_crossing_table(crossings, s, dict(lines), counts)))
    if counts is not None and len(counts):
        parts.append(_counts_table(counts))
    parts += movement_parts(b, run, name)
    compare = comparison_table(run, "compare_counts.csv")
    if compare is not None and len(compare) and run.simulation is not None:
        parts.append((Text("The comparison with the SUMO simulation of this run (trafficgeo sumo-validate) is in "
                           "the Simulation section.", "note"),))
    elif compare is not None and len(compare):
        parts.append(_comparison(b, run, compare))
    elif run.compare_problem is not None:
        b.skip(f"observed against simulated ({name})", run.compare_problem)
    if run.process is not None:
        parts.append((Heading("Video processing"), *_process_table(run.process)))
    return Section(f"traffic-{k}", title, tuple(parts))


def _comparison(b: ReportContext, run: TrafficRun, compare: pd.DataFrame) -> Part:
    """The ``compare-sumo`` results of a run: GEH of the counts, the flows figure, and speeds per line and lane."""
    counts = run.compare_summary.counts if run.compare_summary is not None else None
    out: list[Block] = [Heading("Observed vs simulated (compare-sumo)")]
    if counts is not None:
        out.append(Text(f'{counts.rows} counts (line, lane, direction, interval): '
                        f'{num(100.0 * counts.share_geh_below_5, 1)} % with GEH < 5 '
                        f'(the usual acceptance target is 85 %); observed {counts.total_observed} '
                        f'vehicles, simulated {counts.total_simulated}.'))
    out.append(flows_figure(b, compare))
    out.append(compare_counts_table(compare))
    speeds = comparison_table(run, "compare_speeds.csv")
    if speeds is not None and len(speeds):
        out += [Heading("Spot speeds at the lines, observed vs simulated", 4), compare_speeds_table(speeds)]
    return tuple(out)


def flows_figure(b: ReportContext, compare: pd.DataFrame) -> Block:
    """The observed against simulated flows with the GEH band (``compare_counts.csv``)."""
    return figure(F.observed_vs_simulated(compare), "Observed against simulated hourly flows per line, lane, "
                  "direction and interval (veh/h); grey: where the GEH statistic is below 5.", b.dpi)


def compare_counts_table(compare: pd.DataFrame) -> Table:
    """``compare_counts.csv`` (its first :data:`TABLE_ROWS` rows), counts with GEH >= 5 marked as outliers."""
    cols = [("line", "line"), ("lane", "lane"), ("direction", "direction"), ("interval_start", "from s"),
            ("interval_end", "to s"), ("observed", "observed"), ("simulated", "simulated"), ("geh", "GEH")]
    cols = [(c, label) for c, label in cols if c in compare.columns]
    rows, classes = [], []
    for d in compare.head(TABLE_ROWS).to_dict("records"):
        rows.append([d[c] if c in ("line", "lane") else (f"{int(d[c]):+d}" if c == "direction" else
                     (int(d[c]) if c in ("observed", "simulated") else (d[c], 2 if c == "geh" else 1)))
                     for c, _ in cols])
        classes.append("outlier" if float(d.get("geh", 0.0)) >= 5.0 else "")
    return table([label for _, label in cols], rows, row_classes=classes)


def compare_speeds_table(speeds: pd.DataFrame) -> Table:
    """``compare_speeds.csv``: spot speeds per line and lane, observed and simulated, with the KS distance."""
    scols = [("line", "line"), ("lane", "lane"), ("observed_n", "observed n"),
             ("observed_mean_kmh", "observed mean km/h"), ("simulated_n", "simulated n"),
             ("simulated_mean_kmh", "simulated mean km/h"), ("mean_difference_kmh", "difference km/h"),
             ("ks_statistic", "KS distance"), ("ks_pvalue", "KS p")]
    scols = [(c, label) for c, label in scols if c in speeds.columns]
    srows = [[d[c] if c in ("line", "lane") else (int(d[c]) if c.endswith("_n") and np.isfinite(d[c]) else
              (d[c], 2)) for c, _ in scols] for d in speeds.head(TABLE_ROWS).to_dict("records")]
    return table([label for _, label in scols], srows)


def _run_summary(run: TrafficRun, s: RunSummary) -> Part:
    period = s.period_s
    dropped = ", ".join(f"{k} {v}" for k, v in s.dropped_points.items()) or "none"
    classes = ", ".join(f"{k or 'unknown'} {v}" for k, v in s.classes.items()) or "-"
    opts = s.options
    rows = [["folder", str(run.folder), ""],
            ["observed period", f"{num(period[0])} to {num(period[1])}", "s"],
            ["vehicles", s.vehicles, ""], ["classes", classes, ""],
            ["track points / rejected as outliers", f"{s.points} / {s.outlier_points}", ""],
            ["points not used, by reason", dropped, ""],
            ["mean of the vehicles' speeds (speed_kmh: distance travelled over the well-calibrated window / its time)",
             (s.mean_speed_kmh, 1), "km/h"],
            ["lane changes", s.lane_changes, ""]]
    if s.fragments is not None:
        rows.append(["pieces of track joined into the vehicles (a vehicle lost and found again is one)", s.fragments,
                     ""])
    if s.stationary_vehicles:
        rows.append(["vehicles that never moved (parked, signs): listed, counted at no line, not in the speeds",
                     s.stationary_vehicles, ""])
    for key, label, unit in (("interval_s", "counting interval", "s"),
                             ("pixel_sigma", "pixel noise of a track point", "px"),
                             ("max_metres_per_px", "points farther than this many metres per pixel not used", "m")):
        if key in opts:
            rows.append([label, opts[key], unit])
    return table(["quantity", "value", "unit"], rows), items(list(s.warnings), "warn")


def _q(a: np.ndarray, q: float) -> float:
    """The ``q``-th percentile of the finite values of ``a`` (NaN when there are none)."""
    a = a[np.isfinite(a)]
    return float(np.percentile(a, q)) if a.size else float("nan")


def _speed_columns(v: pd.DataFrame) -> tuple[str, str]:
    """The vehicles' speed column and its 1-sigma: ``speed_kmh``, or ``mean_speed_kmh`` in runs written before
    ``speed_kmh`` existed."""
    return ("speed_kmh", "speed_std_kmh") if "speed_kmh" in v.columns else ("mean_speed_kmh", "mean_speed_std_kmh")


def _vehicle_tables(v: pd.DataFrame) -> list[Table]:
    """Speeds, lengths, times seen and paths per class, and speeds and lane changes per main lane."""
    def col(g: pd.DataFrame, c: str) -> np.ndarray:
        return g[c].to_numpy(float) if c in g.columns else np.full(len(g), np.nan)

    speed, speed_std = _speed_columns(v)
    rows = []
    for cls, g in v.groupby(v["class"].replace("", "unknown") if "class" in v.columns else pd.Series(
            ["all"] * len(v), index=v.index), sort=True):
        sp = col(g, speed)
        rows.append([cls, len(g), (_q(sp, 50), 1), (float(np.nanmean(sp)) if np.isfinite(sp).any() else np.nan, 1),
                     (_q(sp, 15), 1), (_q(sp, 85), 1), (_q(col(g, speed_std), 50), 2),
                     (_q(col(g, "length_m"), 50), 2), (_q(col(g, "length_std_m"), 50), 2),
                     (_q(col(g, "duration_s"), 50), 1), (_q(col(g, "path_length_m"), 50), 1)])
    out = [table(["class", "vehicles", "median speed km/h", "mean speed km/h", "15th pct km/h", "85th pct km/h",
                  "median speed 1-sigma km/h", "median length m", "median length 1-sigma m", "median time seen s",
                  "median path m"], rows, caption="per class: each vehicle's speed is its distance travelled over the "
                  "time seen")]
    if "lane" in v.columns:
        rows = []
        for lane, g in v.groupby(v["lane"].replace("", "(none)"), sort=True):
            sp = col(g, speed)
            rows.append([lane, len(g), (_q(sp, 50), 1), (_q(sp, 15), 1), (_q(sp, 85), 1),
                         (_q(col(g, speed_std), 50), 2),
                         int(g["lane_changes"].sum()) if "lane_changes" in g.columns else "-"])
        out.append(table(["main lane", "vehicles", "median speed km/h", "15th pct km/h", "85th pct km/h",
                          "median speed 1-sigma km/h", "lane changes"], rows, caption="per main lane"))
    return out


COMPASS = ("N", "NE", "E", "SE", "S", "SW", "W", "NW")


def crossing_bound(geometry: Any, direction: int) -> str:
    """The compass bound of a crossing of a counting line (e.g. "NE-bound"): direction +1 crosses from left to right
    looking from the line's first point to its last, -1 the other way; "" when the line has no length."""
    coords = np.asarray(geometry.coords, dtype=np.float64)[:, :2]
    dx, dy = coords[-1] - coords[0]
    if not (dx or dy):
        return ""
    ex, ny = (dy, -dx) if direction > 0 else (-dy, dx)  # the line's right (left) normal: where the vehicle goes
    bearing = np.degrees(np.arctan2(ex, ny)) % 360.0
    return f"{COMPASS[int(np.round(bearing / 45.0)) % 8]}-bound"


def _crossing_table(c: pd.DataFrame, s: RunSummary, lines: dict[str, Any] | None = None,
                    counts: pd.DataFrame | None = None) -> Part:
    """Per line, lane and direction over the whole observed period: count, flow, time- and space-mean speed and
    mean headway (:func:`trafficgeo.traffic.counts.period_counts`), and the 85th percentile of the spot speeds.
    Directions are named by their compass bound where the line is known; a line, lane or direction nobody crossed
    is listed with 0 (from counts.csv and the run's lines); flows (veh/h) only when the period is long enough to
    extrapolate (:func:`trafficgeo.traffic.counts.flow_rule`, as the terminal and counts.csv)."""
    lines = lines or {}
    start, end = s.period_s
    dur = max(end - start, 1e-9)
    interval_s = float(s.options.get("interval_s", 60.0))
    flows = bool(end - start > 0 and flow_rule(end - start, interval_s))
    stats = period_counts(c if "class" in c.columns else c.assign(**{"class": ""}), start, end) if len(c) else None
    p85 = {key: _q(sp[np.isfinite(sp) & (sp > 0)], 85) for key, sp in (
        (k, g["speed_kmh"].to_numpy(float)) for k, g in c.groupby(["line", "lane", "direction"], sort=True))}
    found = {} if stats is None else {(str(r["line"]), str(r["lane"] or ""), int(r["direction"])): r
                                      for r in stats.to_dict("records")}
    keys = set(found)
    if counts is not None and len(counts) and {"line", "lane", "direction"} <= set(counts.columns):
        keys |= {(str(a), "" if pd.isna(b) else str(b), int(d)) for a, b, d in
                 counts[["line", "lane", "direction"]].itertuples(index=False)}
    for name in lines:
        if not any(k[0] == name for k in keys):
            keys |= {(name, "", 1), (name, "", -1)}

    def named(line: str, direction: int) -> str:
        bound = crossing_bound(lines[line], direction) if line in lines else ""
        return f"{direction:+d} ({bound})" if bound else f"{direction:+d}"

    rows = []
    for key in sorted(keys):
        r = found.get(key)
        line, lane, direction = key
        if r is None:
            rows.append([line, lane or "-", named(line, direction), 0, (0.0, 0) if flows else "-", "-", "-", "-",
                         "-"])
            continue
        rows.append([line, lane or "-", named(line, direction), int(r["count"]),
                     (r["flow_veh_h"], 0) if flows else "-", (r["time_mean_speed_kmh"], 1),
                     (r["space_mean_speed_kmh"], 1), (p85.get((r["line"], r["lane"], r["direction"]), np.nan), 1),
                     (r["mean_headway_s"], 1)])
    caption = (f"all crossings over the observed {dur:.1f} s (spot speeds at the line); direction +1 crosses from "
               "left to right looking along the line, named by where the vehicles head")
    out: list[Block] = [table(["line", "lane", "direction", "vehicles", "flow veh/h", "time-mean speed km/h",
                               "space-mean speed km/h", "85th pct speed km/h", "mean headway s"], rows,
                              caption=caption)]
    if not flows:
        out.append(Text(f"No flows (veh/h): {dur:.1f} s were observed, less than {MIN_FLOW_SHARE:.0%} of the "
                        f"{interval_s:g} s counting interval, too short to extrapolate to an hour.", "note"))
    return tuple(out)


def _counts_table(counts: pd.DataFrame) -> Part:
    cols = [("line", "line"), ("lane", "lane"), ("direction", "direction"), ("interval_start", "from s"),
            ("interval_end", "to s"), ("count", "vehicles"), ("flow_veh_h", "flow veh/h"),
            ("time_mean_speed_kmh", "time-mean km/h"), ("space_mean_speed_kmh", "space-mean km/h"),
            ("mean_headway_s", "mean headway s"), ("mean_gap_s", "mean gap s")]
    cols = [(c, label) for c, label in cols if c in counts.columns]
    rows = []
    for d in counts.head(TABLE_ROWS).to_dict("records"):
        rows.append([d[c] if c in ("line", "lane") else (f"{int(d[c]):+d}" if c == "direction" else
                                                         (int(d[c]) if c == "count" else (d[c], 1)))
                     for c, _ in cols])
    out: list[Block] = [Heading("Counts per interval"), table([label for _, label in cols], rows)]
    if len(counts) > TABLE_ROWS:
        out.append(Text(f"first {TABLE_ROWS} of {len(counts)} rows; all are in counts.csv", "note"))
    return tuple(out)


def _process_table(p: ProcessRecord) -> Part:
    def given(value: Any) -> Any:
        return "-" if value is None else value

    opts = p.options
    rows = [["video", p.video, ""], ["detector", given(opts.detector), ""],
            ["start / end", f"{given(opts.start_s)} / {opts.end_s or 'end'}", "s"],
            ["every n-th frame", given(opts.every), ""], ["detections", given(p.detections), ""],
            ["track boxes", given(p.track_rows), ""], ["processing time", (p.seconds, 1), "s"]]
    tiling = p.tiling
    warns: list[str] = []
    if isinstance(tiling, dict):
        tiles = tiling.get("tiles") or []
        rows.append(["detector passes per frame (full frame + tiles over the far road)",
                     tiling.get("passes_per_frame", len(tiles) + 1), ""])
        rows.append(["size a car must reach in the detector's input", tiling.get("min_size_px", "-"), "px"])
        warns = [str(w) for w in tiling.get("warnings") or []]
    return table(["quantity", "value", "unit"], rows), items(warns, "warn")
