"""The turning movements of a traffic run with a junction's gates, as parts of its traffic section
(:mod:`trafficgeo.report.traffic_sections`): the movement diagram on the orthophoto, the turning-movement table per
approach over the whole run and per interval, the peak hour, how many movements were complete, and travel and
stopped times per movement.

Every number comes from the run folder: ``movements.csv`` (the movements, complete or not), ``turning_movements.csv``
(per interval), ``summary.json``'s ``junction`` (peak hour, interval) and the ``gates`` layer of
``trajectories.gpkg`` (the diagram). Conventions of :mod:`trafficgeo.site.gates`; times in seconds.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

from trafficgeo.report.blocks import Block, Heading, Part, Table, Text, figure, table
from trafficgeo.report.context import ReportContext
from trafficgeo.report.inputs import TrafficRun
from trafficgeo.report.movement_figures import movement_diagram, movement_flows
from trafficgeo.site.gates import MOVEMENTS, Junction
from trafficgeo.traffic.measurements import HEAVY_CLASSES
from trafficgeo.traffic.movements import STOPPED_KMH

TABLE_ROWS = 200
DIAGRAM_CAPTION = "Turning-movement diagram"


def _arms(movements: pd.DataFrame, junction: Junction | None, info: dict[str, Any]) -> list[tuple[str, str]]:
    """(arm, approach bound) in gate order: from the gates, else ``summary.json``, else the arms in the table."""
    if junction is not None:
        return [(a, junction.approach_bound(a)) for a in junction.arms]
    arms = info.get("arms") or {}
    if arms:
        return [(str(a), str((v or {}).get("approach", ""))) for a, v in arms.items()]
    seen = pd.concat([movements["origin"], movements["destination"]]).fillna("").astype(str)
    return [(a, "") for a in sorted(set(seen) - {""})]


def movement_parts(b: ReportContext, run: TrafficRun, name: str) -> list[Part]:
    """The turning-movement parts of a run's traffic section; none for a run without gates (no ``movements.csv``)."""
    folder = run.run
    if not folder.has("movements.csv"):
        return []
    mv = folder.movements()
    info = run.summary.junction or {}
    junction = folder.junction(b.crs)
    arms = _arms(mv, junction, info)
    done = mv[mv["complete"].astype(bool)]
    parts: list[Part] = [(Heading("Turning movements"), Text(completeness_text(mv)))]
    if junction is not None:
        flows = movement_flows(mv)
        xs = [np.asarray(g.geometry.coords)[:, 0] for g in junction.gates]
        ys = [np.asarray(g.geometry.coords)[:, 1] for g in junction.gates]
        bg = b.background(xs, ys, f"movement diagram, {name}")
        parts.append((figure(movement_diagram(junction, flows, b.axes, background=bg),
                             f"{DIAGRAM_CAPTION}: the gate across each arm (arm and the compass bound of the traffic "
                             "entering by it), and an arrow from the origin gate through the junction centre to the "
                             "destination gate for each movement, its width proportional to the number of complete "
                             f"movements over the run (the number on it). Axes in {b.axes.unit} from the local "
                             "origin.", b.dpi),))
    else:
        b.skip(f"movement diagram ({name})", "the run's trajectories.gpkg has no gates layer: run analyze/process "
               "again with --gates")
    parts.append((approach_table(done, arms),))
    per_interval = _interval_table(folder)
    if per_interval is not None:
        parts.append(per_interval)
    parts.append((Text(peak_hour_text(info), "note"),))
    if len(done):
        parts.append((Heading("Travel and stopped time per movement", 4), time_table(done, [a for a, _ in arms])))
    return parts


def completeness_text(mv: pd.DataFrame) -> str:
    """How many movements were complete, how many of those had an end judged from the path, how many incomplete."""
    done = mv[mv["complete"].astype(bool)]
    by_path = int(((done["origin_by"] == "path") | (done["destination_by"] == "path")).sum())
    return (f"{len(mv)} vehicles through the junction: {len(done)} complete movements ({by_path} with an end judged "
            "from the path: first or last seen inside the gates); "
            f"{len(mv) - len(done)} incomplete (origin or destination unknown: listed in movements.csv with "
            "complete=false, not counted).")


def peak_hour_text(info: dict[str, Any]) -> str:
    """The peak hour of ``summary.json``'s junction, or why there is none."""
    peak = info.get("peak_hour")
    interval = info.get("interval_s")
    every = f"{float(interval):g} s " if interval is not None else ""
    if not peak:
        return (f"No peak hour: less than an hour of whole {every}intervals was observed (the counts per interval "
                "are in movement_counts.csv and turning_movements.csv).")
    return (f"Peak hour {float(peak['start_s']):.0f}-{float(peak['end_s']):.0f} s: {int(peak['volume'])} vehicles, "
            f"peak-hour factor (PHF) {float(peak['phf']):.2f}, heavy vehicles {float(peak['heavy_pct']):.1f} %.")


def approach_counts(done: pd.DataFrame, arm: str) -> tuple[list[int], int, int]:
    """Of the complete movements entering by ``arm``: the count per movement (:data:`MOVEMENTS` order), the total
    and how many were heavy vehicles (:data:`HEAVY_CLASSES`)."""
    sel = done[done["origin"].astype(str) == arm]
    return ([int((sel["movement"] == m).sum()) for m in MOVEMENTS], len(sel),
            int(sel["class"].isin(HEAVY_CLASSES).sum()))


def approach_table(done: pd.DataFrame, arms: list[tuple[str, str]]) -> Table:
    """Rows = approaches (arm and bound), columns left/through/right/U, total and heavy % over the whole run."""
    rows = []
    for arm, bound in arms:
        n, total, heavy = approach_counts(done, arm)
        rows.append([bound or "-", arm, *n, total, (100.0 * heavy / total if total else float("nan"), 1)])
    n_all = [int((done["movement"] == m).sum()) for m in MOVEMENTS]
    heavy_all = int(done["class"].isin(HEAVY_CLASSES).sum())
    rows.append(["all", "", *n_all, len(done), (100.0 * heavy_all / len(done) if len(done) else float("nan"), 1)])
    return table(["approach", "from arm", *MOVEMENTS, "total", "heavy %"], rows,
                 caption="complete movements over the whole run, by the arm the vehicles entered by; heavy: "
                         f"{', '.join(HEAVY_CLASSES)}")


def _interval_table(folder: Any) -> Part | None:
    """``turning_movements.csv`` when it has more than one interval."""
    if not folder.has("turning_movements.csv"):
        return None
    tm = folder.turning_movements()
    if len(tm) < 2:
        return None
    cols = list(tm.columns)
    labels = ["from s" if c == "interval_start" else "to s" if c == "interval_end" else
              "heavy %" if c == "heavy_pct" else c.replace("_", " ") for c in cols]
    rows = [[(r[c], 0) if c in ("interval_start", "interval_end") else (r[c], 1) if c == "heavy_pct" else int(r[c])
             for c in cols] for r in tm.head(TABLE_ROWS).to_dict("records")]
    out: list[Block] = [Heading("Turning movements per interval", 4),
                        table(labels, rows, caption="turning_movements.csv: complete movements per interval (by the "
                              "time the vehicle entered), per approach arm and movement")]
    if len(tm) > TABLE_ROWS:
        out.append(Text(f"first {TABLE_ROWS} of {len(tm)} intervals; all are in turning_movements.csv", "note"))
    return tuple(out)


def time_table(done: pd.DataFrame, arms: list[str]) -> Table:
    """Per origin -> destination movement: vehicles, and the median travel time (gate to gate) and stopped time
    with how many vehicles each is of."""
    order = {a: k for k, a in enumerate(arms)}
    rows = []
    groups = done.groupby([done["origin"].astype(str), done["destination"].astype(str)], sort=False)
    for (o, d), g in sorted(groups, key=lambda kv: (order.get(kv[0][0], 99), order.get(kv[0][1], 99), kv[0])):
        tt = g["travel_time_s"].to_numpy(float)
        st = g["stopped_s"].to_numpy(float)
        tt, st = tt[np.isfinite(tt)], st[np.isfinite(st)]
        rows.append([o, d, str(g["movement"].iloc[0]), len(g), (float(np.median(tt)) if tt.size else np.nan, 1),
                     int(tt.size), (float(np.median(st)) if st.size else np.nan, 1), int(st.size)])
    return table(["from arm", "to arm", "movement", "vehicles", "median travel time s", "travel time n",
                  "median stopped s", "stopped n"], rows,
                 caption="complete movements; travel time from the entry gate to the exit gate (only for vehicles "
                         "seen crossing both), stopped: time below "
                         f"{STOPPED_KMH:g} km/h between entering (else first seen) and leaving (else last seen)")
