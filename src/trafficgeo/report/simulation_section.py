"""The Simulation section of a report (:mod:`trafficgeo.report.blocks`): a run's comparison with the SUMO scenario
trafficgeo built from it (``sumo-validate``, recorded in ``compare_simulation.json``).

It shows what was simulated, the headline (share of the line x lane x direction x interval counts with GEH < 5
against the 85 % target, mean GEH), the observed against simulated flows with the GEH band, the spot speeds at
the lines observed and simulated side by side (KS distance), the travel times between the first and the last
line and the count table. A plain ``compare-sumo`` comparison stays in the traffic section.

Units: flows in vehicles per hour; speeds in km/h; times in seconds (observed time unless said).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from trafficgeo.report import simulation_figures as SF
from trafficgeo.report.blocks import Block, Heading, Part, Section, Text, figure, num, table
from trafficgeo.report.context import ReportContext
from trafficgeo.report.inputs import TrafficRun
from trafficgeo.report.traffic_sections import (
    TABLE_ROWS,
    compare_counts_table,
    compare_speeds_table,
    comparison_table,
    flows_figure,
    run_table,
)
from trafficgeo.run.records import SimulationRecord, TravelTimeSummary

GEH_LIMIT = 5.0


def _finite_or(value: float, default: float) -> float:
    return value if np.isfinite(value) else default


def headline(record: SimulationRecord, compare: pd.DataFrame) -> dict[str, Any]:
    """Share of the counts with GEH < 5, mean GEH, number of counts, target share and whether it is met: from
    ``sumo-validate``'s record, or from ``compare_counts.csv`` for what the record lacks (NaN)."""
    geh = compare["geh"].to_numpy(float) if "geh" in compare.columns else np.full(len(compare), np.nan)
    share = _finite_or(record.share_geh_below_5, float((geh < GEH_LIMIT).mean()) if geh.size else float("nan"))
    mean = _finite_or(record.mean_geh, float(np.nanmean(geh)) if np.isfinite(geh).any() else float("nan"))
    target = _finite_or(record.target_share, 0.85)
    return {"share_geh_below_5": share, "mean_geh": mean, "counts": record.counts or len(compare),
            "target_share": target, "target_met": bool(np.isfinite(share) and share >= target)}


def _what_was_simulated(rec: SimulationRecord) -> Block:
    def seconds(value: float) -> Any:
        return (value, 1) if np.isfinite(value) else "not known"

    rows = [["scenario folder (sumo-gui scenario.sumocfg)", rec.scenario, ""],
            ["network", rec.net, ""],
            ["network CRS", rec.net_crs or "the network's own", ""],
            ["observed period simulated", f"{num(rec.begin_s, 1)} to {num(rec.end_s, 1)}", "s"],
            ["counting interval", (rec.interval_s, 0), "s"],
            ["SUMO time minus observed time", (rec.time_offset_s, 1), "s"],
            ["simulation step", (rec.step_s, 2), "s"],
            ["vehicles in the demand", rec.vehicles, ""], ["seed", rec.seed, ""],
            ["time to build the scenario (sumo-demand)", seconds(rec.build_s), "s"],
            ["time to run SUMO", seconds(rec.run_s), "s"]]
    return table(["quantity", "value", "unit"], rows, caption="the SUMO scenario built from this run's counts")


def _travel_times(tt: TravelTimeSummary) -> Part:
    rows = [["observed", tt.observed_n, (tt.observed_mean_s, 1), (tt.observed_median_s, 1), (tt.observed_p85_s, 1)],
            ["simulated", tt.simulated_n, (tt.simulated_mean_s, 1), (tt.simulated_median_s, 1),
             (tt.simulated_p85_s, 1)]]
    text = (f"Simulated minus observed mean: {num(tt.mean_difference_s, 1)} s; KS distance of the two "
            f"distributions {num(tt.ks_statistic, 2)} (p {num(tt.ks_pvalue, 3)}).")
    return (Heading(f"Travel times from line {tt.from_line} to line {tt.to_line}", 4),
            table(["", "vehicles", "mean s", "median s", "85th pct s"], rows), Text(text))


def _observed_crossings(run: TrafficRun, rec: SimulationRecord, lines: set[str]) -> pd.DataFrame:
    """The run's crossings the comparison used: at the compared lines, within the simulated period."""
    cr = run_table(run, "crossings.csv")
    if cr is None or not len(cr):
        return pd.DataFrame(columns=["line", "lane", "speed_kmh"])
    t = pd.to_numeric(cr["time"], errors="coerce")
    keep = cr["line"].isin(lines) & (t >= _finite_or(rec.begin_s, -np.inf)) & (t < _finite_or(rec.end_s, np.inf))
    return cr[keep.to_numpy()]


def simulation_section(b: ReportContext, run: TrafficRun, k: int, compare: pd.DataFrame) -> Section:
    """The Simulation section of the ``k``-th traffic run (1-based), whose comparison ``compare``
    (``compare_counts.csv``) ``sumo-validate`` wrote; what it cannot show is noted in ``b``."""
    rec = run.simulation
    if rec is None:
        raise ValueError(f"{run.folder}: its comparison is not one sumo-validate wrote (no compare_simulation.json)")
    rel = run.folder.relative_to(b.inputs.run_dir) if run.folder != b.inputs.run_dir else Path(".")
    name = str(rel)
    title = f"Simulation: {name}" if len(b.inputs.traffic) > 1 or name != "." else "Simulation"
    b.used.append(("SUMO scenario (sumo-validate)", rec.scenario))
    h = headline(rec, compare)
    verdict = "met" if h["target_met"] else "NOT met"
    lead = (f'{num(100.0 * h["share_geh_below_5"], 1)} % of the {h["counts"]} counts (line, lane, direction, '
            f'interval) have GEH < 5, against the target of {num(100.0 * h["target_share"], 0)} %: {verdict}. '
            f'Mean GEH {num(h["mean_geh"], 2)}; observed {int(compare["observed"].sum())} vehicles, simulated '
            f'{int(compare["simulated"].sum())}.')
    parts: list[Part] = [(Text(lead, "summary"), _what_was_simulated(rec))]
    notes = [f"not compared (no vehicle observed there): {u}" for u in rec.unobserved]
    notes += list(rec.warnings)
    if notes:
        parts.append(tuple(Text(n, "note") for n in notes))
    parts.append((flows_figure(b, compare),))
    speeds = comparison_table(run, "compare_speeds.csv")
    sim_cross = comparison_table(run, "simulated_crossings.csv")
    lines = set(compare["line"].astype(str))
    fig = None
    if sim_cross is not None and len(sim_cross):
        fig = SF.observed_vs_simulated_speeds(_observed_crossings(run, rec, lines), sim_cross)
    if fig is not None:
        parts.append((figure(fig, "Spot speeds at the counting lines (km/h), observed (blue) and simulated (orange) "
                             "side by side, per line and lane with vehicles on both sides, on the same bins; KS: the "
                             "two-sample Kolmogorov-Smirnov distance (0: the same distribution).", b.dpi),))
    else:
        b.skip(f"simulated speed histograms ({name})", "no line and lane with observed and simulated crossings "
               "(simulated_crossings.csv empty or missing): run 'trafficgeo sumo-validate' again")
    if speeds is not None and len(speeds):
        parts.append((Heading("Spot speeds at the lines, observed vs simulated", 4), compare_speeds_table(speeds)))
    tt = run.compare_summary.travel_times if run.compare_summary is not None else None
    if tt is not None and (tt.observed_n > 0 or tt.simulated_n > 0):
        parts.append(_travel_times(tt))
    elif tt is not None:
        b.skip(f"travel times between lines ({name})", f"no vehicle, observed or simulated, crossed line "
               f"{tt.from_line} and then line {tt.to_line}: simulate a longer period")
    else:
        b.skip(f"travel times between lines ({name})", "the comparison has fewer than two counting lines")
    blocks: list[Block] = [Heading("Counts, observed vs simulated", 4), compare_counts_table(compare)]
    if len(compare) > TABLE_ROWS:
        blocks.append(Text(f"first {TABLE_ROWS} of {len(compare)} rows; all are in compare_counts.csv", "note"))
    parts.append(tuple(blocks))
    return Section(f"simulation-{k}", title, tuple(parts))
