"""What a run's analysis writes: the GIS layers (:func:`gis_layers`), the summary record (:func:`summary`,
:func:`junction_summary`), the names of the output files (:data:`OUTPUT_FILES`), and :func:`write_traffic`, which
writes them all through the run's writer (:meth:`trafficgeo.run.folder.RunFolder.writing`)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
import pyproj
import shapely

from trafficgeo.run.records import LineCount, RunSummary
from trafficgeo.traffic.movements import MOVEMENT_INTERVAL_S

if TYPE_CHECKING:
    from pathlib import Path

    from trafficgeo.camera.calibrated import CalibratedCamera
    from trafficgeo.camera.model import Camera
    from trafficgeo.run.folder import RunWriter
    from trafficgeo.traffic.analyze import TrafficResult

OUTPUT_FILES = ("vehicles.csv", "counts.csv", "crossings.csv", "trajectories.csv", "trajectories.parquet",
                "trajectories.gpkg", "movements.csv", "movement_counts.csv", "turning_movements.csv", "summary.json")


def write_traffic(run: RunWriter, result: TrafficResult, camera: Camera | CalibratedCamera) -> list[Path]:
    """Write ``result`` through ``run`` (``with RunFolder(out).writing(...) as run``): vehicles, crossings, counts,
    trajectories (CSV, and GIS layers where the camera has a CRS), a junction's movements and turning-movement
    table, summary.json; outputs of an earlier run that this one does not have are removed (e.g. no GeoPackage
    without a CRS). Returns the paths written."""
    from trafficgeo.camera.calibrated import as_camera
    from trafficgeo.geo.mapping import camera_crs

    crs = camera_crs(as_camera(camera))
    written = [run.table(name, table) for name, table in (("vehicles.csv", result.vehicles),
                                                           ("counts.csv", result.counts),
                                                           ("crossings.csv", result.crossings))]
    written.append(run.points("trajectories.csv", result.points, crs))
    if result.movements is not None:
        written += [run.table(name, table) for name, table in (("movements.csv", result.movements),
                                                                ("movement_counts.csv", result.movement_counts),
                                                                ("turning_movements.csv", result.turning))]
    if crs is not None and len(result.points):
        layers = gis_layers(result, crs)
        written += [run.layers("trajectories.gpkg", layers, crs), run.layers("trajectories.parquet", layers[:1], crs)]
    written.append(run.summary(summary(result, crs)))
    run.remove(OUTPUT_FILES)
    return written


def _paths_layer(points: pd.DataFrame, vehicles: pd.DataFrame):
    from trafficgeo.io.gis import Layer

    geoms = []
    groups = dict(tuple(points.groupby("track_id", sort=False))) if len(points) else {}
    for tid in vehicles["track_id"]:
        g = groups.get(tid)
        xy = g[["x", "y"]].to_numpy() if g is not None else np.zeros((0, 2))
        geoms.append(shapely.LineString(xy) if len(xy) >= 2 else shapely.from_wkt("LINESTRING EMPTY"))
    return Layer("paths", geoms, {c: vehicles[c].to_numpy() for c in vehicles.columns})


def gis_layers(analysis: TrafficResult, crs: pyproj.CRS) -> list:
    """The GeoPackage layers: points, paths, and the lanes and counting lines used."""
    from trafficgeo.io.gis import Layer, points_layer

    pts = analysis.points
    attrs = {c: pts[c].to_numpy() for c in pts.columns if c not in ("x", "y", "z", "lon", "lat")}
    layers = [points_layer("points", pts["x"].to_numpy(), pts["y"].to_numpy(), pts["z"].to_numpy(), attrs, crs),
              _paths_layer(pts, analysis.vehicles)]
    if analysis.lanes is not None:
        layers.append(Layer("lanes", list(analysis.lanes.polygons), {"lane": list(analysis.lanes.names)}))
    if analysis.lines:
        layers.append(Layer("count_lines", [ln.geometry for ln in analysis.lines],
                            {"name": [ln.name for ln in analysis.lines],
                             "lanes": [",".join(ln.lanes) for ln in analysis.lines]}))
    if analysis.junction is not None:
        j = analysis.junction
        layers.append(Layer("gates", [g.geometry for g in j.gates],
                            {"arm": j.arms, "bearing_deg": [j.bearings_deg[a] for a in j.arms],
                             "approach": [j.approach_bound(a) for a in j.arms]}))
    return layers


def summary(analysis: TrafficResult, crs: pyproj.CRS | None = None) -> RunSummary:
    """Totals for the terminal and ``summary.json`` (its record; ``crs``: the camera's, written as WKT)."""
    veh = analysis.vehicles
    traffic = veh[~veh["stationary"].astype(bool)] if "stationary" in veh.columns else veh
    c = analysis.counts
    # every line x lane x direction of the counts table, zeros too (a line nobody crossed is listed)
    per_line = (c.assign(line=c["line"].astype(str), lane=c["lane"].fillna("").astype(str))
                .groupby(["line", "lane", "direction"], sort=True)["count"].sum() if len(c) else [])
    return RunSummary(
        period_s=(float(analysis.period[0]), float(analysis.period[1])),
        vehicles=len(veh),
        points=len(analysis.points),
        dropped_points=analysis.dropped,
        outlier_points=int(analysis.points["outlier"].sum()) if len(analysis.points) else 0,
        mean_speed_kmh=float(traffic["speed_kmh"].mean()) if traffic["speed_kmh"].notna().any() else None,
        classes={str(k): int(v) for k, v in veh["class"].value_counts().items()} if len(veh) else {},
        lane_changes=int(veh["lane_changes"].sum()) if len(veh) else 0,
        crossings=tuple(LineCount(str(k[0]), str(k[1]), int(k[2]), int(v))
                        for k, v in (per_line.items() if len(per_line) else [])),
        hidden_crossings=int(analysis.crossings["hidden"].sum()) if "hidden" in analysis.crossings else 0,
        options=analysis.options,
        warnings=tuple(analysis.warnings),
        crs=crs.to_wkt() if crs is not None else None,
        fragments=int(veh["fragments"].sum()) if "fragments" in veh.columns else None,
        stationary_vehicles=int(veh["stationary"].sum()) if "stationary" in veh.columns else 0,
        junction=junction_summary(analysis),
    )


def junction_summary(analysis: TrafficResult) -> dict[str, object] | None:
    """The junction part of ``summary.json``: the arms (bearing, approach bound), the vehicles through it, the
    complete movements (and how many had an end assigned by their path), the incomplete ones, and the peak hour
    (None when less than an hour of whole intervals was observed)."""
    from trafficgeo.traffic.measurements import HEAVY_CLASSES
    from trafficgeo.traffic.movements import peak_hour

    j, mv = analysis.junction, analysis.movements
    if j is None or mv is None:
        return None
    done = mv[mv["complete"].astype(bool)]
    interval = float(analysis.options.get("movement_interval_s", MOVEMENT_INTERVAL_S))
    peak = peak_hour(analysis.turning, interval) if analysis.turning is not None else None
    return {
        "arms": {a: {"bearing_deg": round(j.bearings_deg[a], 3), "approach": j.approach_bound(a)} for a in j.arms},
        "centre": [float(j.centre[0]), float(j.centre[1])],
        "vehicles": len(mv),
        "complete": len(done),
        "by_path": int(((done["origin_by"] == "path") | (done["destination_by"] == "path")).sum()),
        "incomplete": int(len(mv) - len(done)),
        "movements": {k: int(v) for k, v in done["movement"].value_counts().sort_index().items()},
        "heavy_pct": float(100.0 * done["class"].isin(HEAVY_CLASSES).mean()) if len(done) else None,
        "interval_s": interval,
        "peak_hour": None if peak is None else {"start_s": peak.start, "end_s": peak.end, "volume": peak.volume,
                                                "phf": round(peak.phf, 4), "heavy_pct": round(peak.heavy_pct, 3)},
    }


__all__ = ["OUTPUT_FILES", "gis_layers", "junction_summary", "summary"]
