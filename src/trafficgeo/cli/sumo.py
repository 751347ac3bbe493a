"""SUMO commands: sumo-net (a georeferenced SUMO network from the lanes layer), sumo-demand (observed counts -> a
runnable SUMO scenario) and sumo-validate (run it, compare with the observation); thin wrappers over
:mod:`trafficgeo.simulation`."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from trafficgeo.cli.app import app, console
from trafficgeo.errors import InputError

#: library parameter -> this command's argument or flag (``lanes`` is the LANES argument here, not ``--lanes``)
_SUMO_NET_FLAGS = {"lanes": "LANES", "out_path": "--out", "crs": "--crs", "speed_kmh": "--speed-kmh"}


def _print_mapping_problem(exc: Exception) -> None:
    """The table of a MappingError (every line x lane x direction and what it maps to), before the one-line error."""
    from rich.table import Table

    table = getattr(exc, "table", None)
    if table is None or not len(table):
        return
    t = Table(title="counting lines on the SUMO network")
    for col in ("line", "lane", "direction", "SUMO edge", "SUMO lane", "problem"):
        t.add_column(col)
    for r in table.itertuples():
        t.add_row(str(r.line), str(r.lane) or "-", f"{int(r.direction):+d}", str(r.sumo_edge) or "-",
                  str(r.sumo_lane) or "-", str(r.problem) or "ok")
    console.print(t)


def _print_movements(table) -> None:
    """Observed and simulated vehicles per movement (over the intervals) and the worst GEH of its intervals."""
    from rich.table import Table

    t = Table(title="turning movements: observed vs simulated")
    for col in ("from", "to", "movement", "intervals", "observed", "simulated", "max GEH"):
        t.add_column(col, justify="right")
    for (o, d, m), g in table.groupby(["origin", "destination", "movement"], sort=True):
        t.add_row(str(o), str(d), str(m), str(len(g)), str(int(g["observed"].sum())), str(int(g["simulated"].sum())),
                  f"{g['geh'].max():.2f}")
    console.print(t)


@app.command("sumo-demand")
def sumo_demand(
    run: Annotated[Path, typer.Argument(help="output folder of 'trafficgeo analyze' or 'process' (a run folder)")],
    net: Annotated[Path, typer.Option(help="the SUMO network to simulate (.net.xml, georeferenced)")],
    out: Annotated[Path, typer.Option("--out", "-o", help="scenario folder to write")],
    interval: Annotated[float, typer.Option(help="counting interval the demand reproduces (s)")] = 900.0,
    begin: Annotated[float | None, typer.Option(help="start of the observed period to use (s, the run's time)")] = None,
    end: Annotated[float | None, typer.Option(help="end of the observed period to use (s)")] = None,
    routes: Annotated[Path | None, typer.Option(help="candidate routes (.rou.xml); default: randomTrips.py on the "
                                                "network")] = None,
    net_crs: Annotated[str | None, typer.Option(help="CRS of the network's projection when its PROJ string is not "
                                                "enough, e.g. EPSG:2949")] = None,
    seed: Annotated[int, typer.Option(help="random seed (routes, sampling, SUMO)")] = 0,
) -> None:
    """Observed counts -> SUMO demand and a runnable scenario (scenario.sumocfg, opens in sumo-gui).

    A run of 'analyze' or 'process' with --gates (a junction's turning movements) gets a demand of its movements:
    each gate is mapped to its arm's in- and out-edge, and each counted movement (origin -> destination, per
    interval and class) becomes vehicles on the route in-edge -> out-edge that cross the origin gate in their
    interval. Movements take precedence at the junction: the counting lines of such a run are not used for the
    demand (sumo-validate still compares at them). Otherwise routeSampler fits routes to the counts at the
    counting lines."""
    from trafficgeo.simulation.mapping import MappingError
    from trafficgeo.simulation.scenario import build_sumo_scenario

    try:
        sc = build_sumo_scenario(run, net, out, interval_s=interval, begin_s=begin, end_s=end, routes=routes,
                                 net_crs=net_crs, seed=seed)
    except MappingError as exc:
        _print_mapping_problem(exc)
        raise
    for text in sc.warnings:
        console.print(f"[yellow]warning:[/yellow] {text}")
    classes = ", ".join(f"{t['class']} {t['share']:.0%}" for t in sc.vehicle_types)
    console.print(f"{sc.vehicles} vehicles ({classes}) over {sc.begin_s:g}-{sc.end_s:g} s in {sc.interval_s:g} s "
                  f"intervals; SUMO time = observed time + {sc.time_offset_s:g} s; built in {sc.build_s:.1f} s")
    console.print(f"wrote {sc.sumocfg} (sumo-gui -c {sc.sumocfg.name}); check it with: trafficgeo sumo-validate "
                  f"{out} {run}")


@app.command("sumo-validate")
def sumo_validate(
    scenario: Annotated[Path, typer.Argument(help="scenario folder of 'trafficgeo sumo-demand'")],
    run: Annotated[Path, typer.Argument(help="the run folder the scenario was built from")],
    out: Annotated[Path | None, typer.Option("--out", "-o", help="folder for the comparison tables (default: "
                                             "SCENARIO; a run folder shows them in its HTML report)")] = None,
) -> None:
    """Run SUMO headless on the scenario and compare it with the observation: counts (GEH), speeds (KS), travel
    times at the counting lines; at a junction's gates the turning movements per interval (GEH,
    compare_movements.csv)."""
    from trafficgeo.report.traffic import print_comparison
    from trafficgeo.simulation.loop import GEH_TARGET_SHARE, validate_sumo_scenario

    val = validate_sumo_scenario(scenario, run, out_dir=out)
    if val.unobserved:
        console.print(f"not compared (no vehicle observed there): {', '.join(val.unobserved)}")
    target = f"target >= {GEH_TARGET_SHARE:.0%}"
    if val.counts:
        print_comparison(val.comparison, console)
        met = "met" if val.share_geh_below_5 >= GEH_TARGET_SHARE else "NOT met"
        console.print(f"GEH < 5 for {val.share_geh_below_5:.1%} of {val.counts} counts: {target} {met}; SUMO ran "
                      f"{val.simulation.run_s:.1f} s")
    if val.movements is not None:
        _print_movements(val.movements)
        met = "met" if val.movement_share_geh_below_5 >= GEH_TARGET_SHARE else "NOT met"
        console.print(f"GEH < 5 for {val.movement_share_geh_below_5:.1%} of {len(val.movements)} movement counts "
                      f"(origin x destination x interval), mean GEH {val.movement_mean_geh:.2f}: {target} {met}; "
                      f"SUMO ran {val.simulation.run_s:.1f} s")
    console.print(f"wrote {', '.join(p.name for p in val.written)} in {out or scenario}")


@app.command("sumo-net")
def sumo_net(
    lanes: Annotated[Path, typer.Argument(help="lane polygons with a 'bearing' column (direction of travel, deg "
                                          "clockwise from north), e.g. the lanes.gpkg given to analyze")],
    out: Annotated[Path, typer.Option("--out", "-o", help="SUMO network to write (.net.xml)")],
    crs: Annotated[str | None, typer.Option(help="projected CRS (metres) of the network, e.g. the camera's "
                                            "EPSG:32633; default the lanes file's")] = None,
    speed_kmh: Annotated[float, typer.Option("--speed-kmh", help="speed limit of every edge (km/h)")] = 50.0,
) -> None:
    """Lane polygons -> a georeferenced SUMO network (netconvert): one edge per direction of travel, its lanes
    ordered from the right, their mean width; for sumo-demand when there is no network of the area."""
    from trafficgeo.simulation.network import build_sumo_net

    try:
        net = build_sumo_net(lanes, out, crs=crs, speed_kmh=speed_kmh)
    except InputError as exc:
        raise InputError(exc.in_terms_of(_SUMO_NET_FLAGS)) from None
    for e in net.edges:
        console.print(f"edge {e.id}: {len(e.lanes)} lane(s) {', '.join(e.lanes)} (from the right), "
                      f"{e.lane_width_m:.2f} m wide, {e.length_m:.1f} m long, heading {e.bearing_deg:.0f} deg")
    console.print(f"wrote {out} in {net.crs.name} (netOffset {-net.origin[0]:.0f},{-net.origin[1]:.0f}), SUMO "
                  f"{net.sumo_version}; use it with: trafficgeo sumo-demand RUN --net {out} --out SCENARIO")
