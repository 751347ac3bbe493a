"""Readable terminal tables of traffic results: an ``analyze`` run and a ``compare-sumo`` comparison (rich)."""

from __future__ import annotations

from rich.console import Console
from rich.table import Table

from trafficgeo.traffic.analyze import TrafficResult
from trafficgeo.traffic.counts import MIN_FLOW_SHARE, flow_rule
from trafficgeo.traffic.outputs import summary
from trafficgeo.traffic.validation import Comparison


def _kmh(value: float) -> str:
    return "-" if value != value else f"{value:.1f}"


def print_analysis(analysis: TrafficResult, console: Console) -> None:
    """Totals and per-line counts of an ``analyze`` run."""
    s = summary(analysis)
    t0, t1 = s.period_s
    dropped = ", ".join(f"{k} {v}" for k, v in s.dropped_points.items()) or "none"
    speed = f"{s.mean_speed_kmh:.1f} km/h" if s.mean_speed_kmh is not None else "-"
    classes = ", ".join(f"{k or 'unknown'} {v}" for k, v in s.classes.items())
    console.print(f"{s.vehicles} vehicles ({classes}) in {t1 - t0:.1f} s; {s.points} track points, "
                  f"{s.outlier_points} rejected as outliers; not used: {dropped}")
    console.print(f"mean vehicle speed (speed_kmh: distance travelled over the well-calibrated window / its time): "
                  f"{speed}; lane changes: {s.lane_changes}")
    if s.fragments is not None and s.fragments > s.vehicles:
        console.print(f"{s.fragments} pieces of track joined into {s.vehicles} vehicles (a vehicle lost for a moment "
                      "and found again is one vehicle: 'fragments' and 'tracker_ids' in vehicles.csv)")
    if s.stationary_vehicles:
        console.print(f"{s.stationary_vehicles} of the vehicles never moved (parked vehicles, signs): listed with "
                      "'stationary' in vehicles.csv, with their near-zero speeds, counted at no line and left out of "
                      "the mean speed")
    for text in analysis.warnings:
        console.print(f"[yellow]warning:[/yellow] {text}")
    if s.crossings:
        table = Table(title="crossings per counting line")
        for col in ("line", "lane", "direction", "vehicles", "flow veh/h", "mean speed km/h"):
            table.add_column(col, justify="right")
        dur = t1 - t0
        interval_s = float(analysis.options.get("interval_s", 60.0))  # type: ignore[arg-type]
        flows = bool(dur > 0 and flow_rule(dur, interval_s))
        cr = analysis.crossings
        for row in s.crossings:
            sel = cr[(cr["line"].astype(str) == row.line) & (cr["lane"].fillna("").astype(str) == row.lane)
                     & (cr["direction"] == row.direction)] if len(cr) else cr
            table.add_row(row.line, row.lane or "-", f"{row.direction:+d}", str(row.count),
                          f"{row.count * 3600.0 / dur:.0f}" if flows else "-",
                          _kmh(sel["speed_kmh"].mean() if len(sel) else float("nan")))
        console.print(table)
        if not flows:
            console.print(f"no flows (veh/h): {dur:.1f} s of video were observed, less than "
                          f"{MIN_FLOW_SHARE:.0%} of the {interval_s:g} s counting interval, too short to extrapolate "
                          "to an hour (counts.csv leaves flow_veh_h empty where an interval was observed for less "
                          f"than {MIN_FLOW_SHARE:.0%} of its length; observed_s says how long)")
        if s.hidden_crossings:
            console.print(f"{s.hidden_crossings} of these crossings are of vehicles hidden behind a nearer one at "
                          "the line, carried on from where they vanished ('hidden' in crossings.csv; --coast-hidden)")
    if s.junction is not None:
        print_movements(analysis, s.junction, console)


def print_movements(analysis: TrafficResult, junction: dict, console: Console) -> None:
    """The turning movements of a run with gates: per approach, left/through/right/U over the whole run, the
    incomplete movements and the peak hour."""
    from trafficgeo.site.gates import MOVEMENTS

    j, mv = analysis.junction, analysis.movements
    if j is None or mv is None:
        return
    done = mv[mv["complete"].astype(bool)]
    table = Table(title="turning movements (vehicles entering by each arm)")
    for col in ("approach", "from arm", *MOVEMENTS, "total", "heavy %"):
        table.add_column(col, justify="right")
    for arm in j.arms:
        sel = done[done["origin"] == arm]
        n = [int((sel["movement"] == m).sum()) for m in MOVEMENTS]
        heavy = f"{100.0 * sel['class'].isin(('truck', 'bus')).mean():.0f}" if len(sel) else "-"
        table.add_row(j.approach_bound(arm), arm, *map(str, n), str(len(sel)), heavy)
    console.print(table)
    by_path = junction["by_path"]
    console.print(f"{junction['complete']} complete movements ({by_path} with an end judged from the path: first or "
                  f"last seen inside the gates); {junction['incomplete']} incomplete (origin or destination unknown: "
                  "listed in movements.csv with complete=false, not counted)")
    peak = junction.get("peak_hour")
    interval = junction["interval_s"]
    if peak is None:
        console.print(f"no peak hour: less than an hour of whole {interval:g} s intervals was observed "
                      "(movement_counts.csv and turning_movements.csv hold the counts per interval)")
    else:
        console.print(f"peak hour {peak['start_s']:.0f}-{peak['end_s']:.0f} s: {peak['volume']} vehicles, "
                      f"PHF {peak['phf']:.2f}, heavy vehicles {peak['heavy_pct']:.1f} %")


def print_comparison(comparison: Comparison, console: Console) -> None:
    """GEH per line and lane, speeds and travel times of a ``compare-sumo`` run."""

    s = comparison.count_summary
    console.print(f"{s['rows']} counts (line x lane x direction x interval): {s['share_geh_below_5']:.0%} with GEH < 5 "
                  f"(target >= 85 %), mean GEH {s['mean_geh']:.2f}; vehicles observed {s['total_observed']}, "
                  f"simulated {s['total_simulated']}")
    table = Table(title="per line and lane")
    for col in ("line", "lane", "observed", "simulated", "GEH", "speed obs km/h", "speed sim km/h", "KS"):
        table.add_column(col, justify="right")
    speeds = comparison.speeds.set_index(["line", "lane"]) if len(comparison.speeds) else None
    for g in s["groups"]:
        key = (g["line"], g["lane"])
        sp = speeds.loc[key] if speeds is not None and key in speeds.index else None
        fmt = (lambda v: "-" if v is None or v != v else f"{v:.1f}")  # noqa: E731
        table.add_row(str(g["line"]), str(g["lane"]) or "-", str(g["observed"]), str(g["simulated"]),
                      f"{g['geh']:.2f}", fmt(sp["observed_mean_kmh"] if sp is not None else None),
                      fmt(sp["simulated_mean_kmh"] if sp is not None else None),
                      "-" if sp is None or sp["ks_statistic"] != sp["ks_statistic"] else f"{sp['ks_statistic']:.2f}")
    console.print(table)
    tt = comparison.travel_times
    if tt:
        console.print(f"travel time {tt['from_line']} -> {tt['to_line']}: observed median "
                      f"{tt.get('observed_median_s', float('nan')):.1f} s (n {tt.get('observed_n', 0)}), simulated "
                      f"{tt.get('simulated_median_s', float('nan')):.1f} s (n {tt.get('simulated_n', 0)}), KS "
                      f"{tt.get('ks_statistic', float('nan')):.2f}")
