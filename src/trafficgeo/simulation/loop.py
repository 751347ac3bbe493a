"""``sumo-validate`` and the whole loop: run a scenario's SUMO simulation and compare it with the observed run.

The comparison is :func:`trafficgeo.traffic.validation.compare_with_simulation` (GEH per line x lane x direction x
interval, spot speeds per line and lane with the KS distance, travel times between the first and the last line)
and is written by :func:`~trafficgeo.traffic.validation.write_comparison` (``compare_counts.csv``,
``compare_speeds.csv``, ``simulated_crossings.csv``, ``compare_summary.json``: the files the HTML report's
"Observed vs simulated" part reads). The observed counts are re-counted per the scenario's interval over its
period ``[begin_s, end_s)``, the intervals its demand was fitted to; the simulated vehicles are counted at the same
lines, lanes and intervals, SUMO time moved back by the scenario's ``time_offset_s``. A line, or a direction of a
line, where no vehicle at all was observed is not compared (out of the camera's view is not a count of zero); the
validation lists them (``unobserved``).

At a junction (a scenario built from a run's turning movements) the simulated vehicles' FCD trajectories, in the
run's CRS and observed time, go through the same :func:`~trafficgeo.traffic.movements.vehicle_movements` at the
run's gates; both sides are counted per the scenario's interval over its period by the time each vehicle entered
(else was first seen), and compared per interval and movement (origin, destination):
``compare_movements.csv`` (observed, simulated, hourly flows, GEH), ``simulated_movements.csv``, and the headline
(share with GEH < 5, mean GEH) under ``movements`` in ``compare_summary.json`` and in ``compare_simulation.json``.
The simulation runs on past the period (:data:`~trafficgeo.simulation.scenario.TAIL_S`) so that a simulated
vehicle entering near its end is followed until it leaves, as the observed counts hold only vehicles seen leaving.
A run without counting lines has an empty line comparison.

Beside the comparison tables ``sumo-validate`` writes ``compare_simulation.json``
(:class:`~trafficgeo.run.records.SimulationRecord`: the scenario simulated and the headline figures,
written with the comparison in one block: :meth:`~trafficgeo.run.folder.RunFolder.write_comparison`) and lists it
in the comparison's manifest, whose command is then ``sumo-validate``: what tells the HTML report that the
comparison is of a trafficgeo scenario (a plain ``compare-sumo`` writes neither).
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd

from trafficgeo.errors import InputError
from trafficgeo.run.records import SimulationRecord
from trafficgeo.simulation.scenario import (
    SimulationOutputs,
    SumoScenario,
    build_sumo_scenario,
    read_sumo_scenario,
    run_fingerprint,
    run_scenario,
)
from trafficgeo.traffic.compare import GEH_LIMIT, compare_counts, compare_speeds_by, count_summary
from trafficgeo.traffic.counts import aggregate_counts
from trafficgeo.traffic.validation import (
    Comparison,
    ObservedRun,
    compare_with_simulation,
    read_observed_run,
    simulated_points,
    write_comparison,
)

__all__ = ["GEH_TARGET_SHARE", "SumoLoopResult", "SumoValidation",
           "close_sumo_loop", "lane_speed_table", "observed_at_interval", "validate_sumo_scenario"]

GEH_TARGET_SHARE = 0.85  # the usual calibration target: GEH < 5 for at least 85 % of the counts


@dataclass(frozen=True)
class SumoValidation:
    """A scenario's simulation against the observed run: the :class:`Comparison` and its headline figures."""

    scenario: SumoScenario
    comparison: Comparison
    share_geh_below_5: float  # of the line x lane x direction x interval counts
    mean_geh: float
    counts: int  # rows of the count comparison
    target_met: bool  # share_geh_below_5 (and movement_share_geh_below_5 at a junction) >= GEH_TARGET_SHARE
    max_abs_speed_difference_kmh: float  # over lines and lanes with vehicles on both sides (NaN: none)
    travel_time_difference_s: float  # simulated - observed mean, first to last line (NaN: fewer than 2 lines)
    simulation: SimulationOutputs
    written: list[Path]
    unobserved: tuple[str, ...] = ()  # "line L direction +1" where no vehicle was observed: not compared
    movements: pd.DataFrame | None = None  # at a junction: per interval and movement (compare_movements.csv)
    movement_share_geh_below_5: float = float("nan")  # of its rows (interval x movement with a vehicle)
    movement_mean_geh: float = float("nan")


@dataclass(frozen=True)
class SumoLoopResult:
    """:func:`close_sumo_loop`: the scenario built, its validation, and the wall time of each part (s)."""

    scenario: SumoScenario
    validation: SumoValidation
    build_s: float
    run_and_compare_s: float

    @property
    def share_geh_below_5(self) -> float:
        return self.validation.share_geh_below_5


def observed_at_interval(observed: ObservedRun, interval_s: float, begin_s: float, end_s: float) -> ObservedRun:
    """The run with its crossings limited to ``[begin_s, end_s)`` and counted per ``interval_s`` (s)."""
    cr = observed.crossings
    cr = cr[(cr["time"] >= begin_s) & (cr["time"] < end_s)].reset_index(drop=True)
    names = [ln.name for ln in observed.lines]
    counts = aggregate_counts(cr[cr["line"].astype(str).isin(names)], interval_s, begin_s, end_s)
    return replace(observed, period=(begin_s, end_s), interval_s=interval_s, counts=counts, crossings=cr)


def _compare_where_observed(obs: ObservedRun, points: pd.DataFrame) -> tuple[Comparison, tuple[str, ...]]:
    """:func:`compare_with_simulation` at the lines, and in the directions of a line, where at least one vehicle was
    observed: a line or a side of it without any is taken as not seen (out of view), not as a count of zero."""
    if not obs.lines:  # a junction's gates only: no line to compare at
        return _no_lines(obs), ()
    cr = obs.crossings
    seen = set(zip(cr["line"].astype(str), cr["direction"].astype(int), strict=True))
    lines = [ln for ln in obs.lines if any(name == ln.name for name, _ in seen)]
    unseen = [f"line {ln.name} (both directions)" for ln in obs.lines if ln not in lines]
    cmp = compare_with_simulation(obs, points, lines=lines or obs.lines)
    keys = list(zip(cmp.counts["line"].astype(str), cmp.counts["direction"].astype(int), strict=True))
    keep = np.array([k in seen for k in keys], dtype=bool)
    unseen += sorted({f"line {line} direction {d:+d}" for (line, d), ok in zip(keys, keep, strict=True) if not ok})
    if keep.all():
        return cmp, tuple(unseen)
    table = cmp.counts[keep].reset_index(drop=True)
    sc = cmp.simulated_crossings
    sim_keep = np.array([k in seen for k in zip(sc["line"].astype(str), sc["direction"].astype(int), strict=True)],
                        dtype=bool)
    return replace(cmp, counts=table, count_summary=count_summary(table),
                   simulated_crossings=sc[sim_keep].reset_index(drop=True)), tuple(unseen)


def _no_lines(obs: ObservedRun) -> Comparison:
    """The (empty) line comparison of a run without counting lines."""
    empty = pd.DataFrame({c: pd.Series(dtype=float) for c in ("line", "lane", "direction", "interval_start",
                                                              "interval_end", "count")})
    cross = pd.DataFrame({c: pd.Series(dtype=float) for c in ("line", "lane", "track_id", "class", "direction",
                                                              "time", "speed_kmh")})
    table = compare_counts(empty, empty)
    return Comparison(table, count_summary(table), compare_speeds_by(cross, cross, by=("line", "lane")), None,
                      obs.crossings.iloc[:0])


def _compare_movements(sc: SumoScenario, observed: ObservedRun, points: pd.DataFrame,
                       comparison: Comparison) -> Comparison:
    """``comparison`` with the movements at the run's gates: the observed ones re-counted per the scenario's
    interval over its period, the simulated ones found and counted alike
    (:func:`~trafficgeo.simulation.junction.simulated_movement_counts`)."""
    from trafficgeo.crs import metres_per_unit
    from trafficgeo.run.folder import RunFolder
    from trafficgeo.simulation.junction import (
        observed_movement_counts,
        read_run_junction,
        simulated_movement_counts,
    )
    from trafficgeo.traffic.movements import compare_movement_counts, movement_comparison_summary

    junction = read_run_junction(observed.folder, observed.crs)
    run = RunFolder(observed.folder)
    obs = observed_movement_counts(run.movements(), run.vehicles(), junction, sc.interval_s, sc.begin_s, sc.end_s)
    moves, sim = simulated_movement_counts(points, junction, sc.interval_s, sc.begin_s, sc.end_s,
                                           metres_per_unit=metres_per_unit(observed.crs))
    table = compare_movement_counts(obs, sim)
    return replace(comparison, movements=table, movement_summary=movement_comparison_summary(table),
                   simulated_movements=moves)


def validate_sumo_scenario(scenario: SumoScenario | str | os.PathLike[str],
                           run: ObservedRun | str | os.PathLike[str], *,
                           out_dir: str | os.PathLike[str] | None = None) -> SumoValidation:
    """Run SUMO on ``scenario`` (a folder of ``sumo-demand``) and compare it with ``run`` (a run folder); the
    comparison tables go to ``out_dir`` (default the scenario folder)."""
    from trafficgeo.io.run_manifest import check_writable_folder

    sc = scenario if isinstance(scenario, SumoScenario) else read_sumo_scenario(scenario)
    out = Path(out_dir) if out_dir is not None else sc.folder
    check_writable_folder(out, "out_dir")
    observed = run if isinstance(run, ObservedRun) else read_observed_run(run)
    if sc.run_fingerprint and run_fingerprint(observed.folder) != sc.run_fingerprint:
        raise InputError(f"run {observed.folder}: not the observations scenario {sc.folder} was built from ({sc.run}); "
                         "give that run, or build the scenario again with 'trafficgeo sumo-demand'",
                         parameters=("run",))
    sim = run_scenario(sc)
    obs = observed_at_interval(observed, sc.interval_s, sc.begin_s, sc.end_s)
    points = simulated_points(sim.fcd, observed.crs, net=sc.net, net_crs=sc.net_crs, time_offset_s=sc.time_offset_s)
    comparison, unobserved = _compare_where_observed(obs, points)
    if sc.junction is not None:
        comparison = _compare_movements(sc, observed, points, comparison)
    table = comparison.counts
    share = float((table["geh"] < GEH_LIMIT).mean()) if len(table) else float("nan")
    speeds = comparison.speeds
    both = speeds[(speeds["observed_n"] > 0) & (speeds["simulated_n"] > 0)]
    tt = comparison.travel_times or {}
    ms = comparison.movement_summary or {}
    shares = [v for v in (share, ms.get("share_geh_below_5", np.nan)) if np.isfinite(v)]
    val = SumoValidation(sc, comparison, share, float(table["geh"].mean()) if len(table) else float("nan"), len(table),
                         bool(shares) and all(v >= GEH_TARGET_SHARE for v in shares),
                         float(np.abs(both["mean_difference_kmh"]).max())
                         if len(both) else float("nan"), float(tt.get("mean_difference_s", np.nan)), sim, [],
                         unobserved, comparison.movements, float(ms.get("share_geh_below_5", np.nan)),
                         float(ms.get("mean_geh", np.nan)))
    written = write_comparison(out, comparison, observed.crs, simulation=_simulation_record(val))
    return replace(val, written=written)


def _simulation_record(val: SumoValidation) -> SimulationRecord:
    """``compare_simulation.json``'s record of ``val``: the scenario simulated and the headline figures."""
    sc = val.scenario
    return SimulationRecord(
        scenario=str(sc.folder.resolve()), net=str(sc.net), net_crs=sc.net_crs, interval_s=sc.interval_s,
        begin_s=sc.begin_s, end_s=sc.end_s, time_offset_s=sc.time_offset_s, step_s=sc.step_s, seed=sc.seed,
        vehicles=sc.vehicles, build_s=sc.build_s if sc.build_s > 0 else float("nan"),  # 0: read from its folder
        run_s=val.simulation.run_s, counts=val.counts, share_geh_below_5=val.share_geh_below_5,
        mean_geh=val.mean_geh, target_share=GEH_TARGET_SHARE, target_met=val.target_met,
        max_abs_speed_difference_kmh=val.max_abs_speed_difference_kmh,
        travel_time_difference_s=val.travel_time_difference_s, unobserved=tuple(val.unobserved),
        warnings=tuple(sc.warnings), movements=len(val.movements) if val.movements is not None else 0,
        movement_share_geh_below_5=val.movement_share_geh_below_5, movement_mean_geh=val.movement_mean_geh)


def close_sumo_loop(run: str | os.PathLike[str], net: str | os.PathLike[str], out_dir: str | os.PathLike[str], *,
                    interval_s: float = 900.0, begin_s: float | None = None, end_s: float | None = None,
                    routes: str | os.PathLike[str] | None = None, net_crs: str | None = None, seed: int = 0,
                    comparison_dir: str | os.PathLike[str] | None = None) -> SumoLoopResult:
    """Observed counts of ``run`` -> SUMO demand on ``net`` -> simulation -> comparison, all in ``out_dir``
    (:func:`~trafficgeo.simulation.scenario.build_sumo_scenario` then :func:`validate_sumo_scenario`); the
    comparison tables in ``comparison_dir`` instead when given (the run folder: its HTML report shows them).

    >>> loop = close_sumo_loop("run", "road.net.xml", "scenario", interval_s=60)   # doctest: +SKIP
    >>> loop.share_geh_below_5 >= 0.85                                          # doctest: +SKIP
    True
    """
    t = time.perf_counter()
    sc = build_sumo_scenario(run, net, out_dir, interval_s=interval_s, begin_s=begin_s, end_s=end_s, routes=routes,
                             net_crs=net_crs, seed=seed)
    built = time.perf_counter()
    val = validate_sumo_scenario(sc, run, out_dir=comparison_dir)
    return SumoLoopResult(sc, val, built - t, time.perf_counter() - built)


def lane_speed_table(validation: SumoValidation) -> pd.DataFrame:
    """Per line and lane: observed and simulated vehicles, mean speeds (km/h), their difference and the KS
    distance."""
    s = validation.comparison.speeds
    return s[["line", "lane", "observed_n", "simulated_n", "observed_mean_kmh", "simulated_mean_kmh",
              "mean_difference_kmh", "ks_statistic"]].copy()

