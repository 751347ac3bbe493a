"""``sumo-demand``: a runnable SUMO scenario from an observed run and a network, and running SUMO on it.

A scenario folder holds (all written atomically, its manifest ``scenario_run.json`` last):

* ``scenario.sumocfg`` - net (the user's, by relative path), ``demand.rou.xml``, ``outputs.add.xml``; opens in
  sumo-gui as it is;
* ``demand.rou.xml`` - observed vehicle types and the sampled vehicles (:mod:`trafficgeo.simulation.demand`);
* ``outputs.add.xml`` - edge data per counting interval (``simulated.edgedata.xml``); FCD goes to ``fcd.xml``;
* ``counts.edgedata.xml`` - the observed counts per edge and interval given to routeSampler;
* ``candidates.rou.xml`` - the candidate routes (randomTrips.py), unless the user gave routes;
* ``mapping.csv`` - line x lane x direction -> SUMO edge/lane; ``observed_lane_counts.csv`` - the counts used;
* for a run with a junction's movements instead of the three above: ``gate_mapping.csv`` - each arm's in- and
  out-edge (:mod:`trafficgeo.simulation.junction`); ``observed_movement_counts.csv`` - the movement counts used;
  the simulation then runs :data:`TAIL_S` past the period so that the last vehicles leave the junction;
* ``scenario.json`` - what :func:`run_scenario` and ``sumo-validate`` need: the run, net, net CRS, interval,
  observed period ``[begin_s, end_s)``, ``time_offset_s`` (SUMO time = observed time + time_offset_s), step, seed.
"""

from __future__ import annotations

import math
import os
import shutil
import tempfile
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from trafficgeo.crs import parse_crs
from trafficgeo.errors import InputError
from trafficgeo.io.json_text import loads_json
from trafficgeo.simulation.demand import (
    SampledDemand,
    VehicleType,
    candidates_for,
    demand_xml,
    edge_counts,
    observed_vehicle_types,
    place_departures,
    sample_routes,
    write_edge_data,
)
from trafficgeo.simulation.junction import (
    map_gates,
    movement_demand,
    movement_routes,
    movement_vehicle_types,
    observed_movement_counts,
    read_run_junction,
    run_has_movements,
)
from trafficgeo.simulation.mapping import map_observations
from trafficgeo.simulation.tools import run_sumo_program
from trafficgeo.traffic.counts import check_interval
from trafficgeo.traffic.validation import ObservedRun, read_observed_run

__all__ = [
    "SCENARIO_MANIFEST",
    "SimulationOutputs",
    "SumoScenario",
    "build_sumo_scenario",
    "mapping_table",
    "read_sumo_scenario",
    "run_fingerprint",
    "run_scenario",
]

SCENARIO_MANIFEST = "scenario_run.json"
FORMAT = "trafficgeo-sumo-scenario/1"
FCD_ATTRIBUTES = "x,y,angle,type,speed,lane"
_SIMULATION_OUTPUTS = ("fcd.xml", "simulated.edgedata.xml")  # what run_scenario writes into the folder
_BUILD_OUTPUTS = ("candidates.rou.xml", "counts.edgedata.xml", "mapping.csv", "observed_lane_counts.csv",
                  "gate_mapping.csv", "observed_movement_counts.csv")  # the one kind of demand or the other's
TAIL_S = 180.0  # s simulated past a movement demand's period: its last vehicles leave the junction, as observed ones


@dataclass(frozen=True)
class SumoScenario:
    """A scenario folder (module docstring) and what it was built from; times in seconds."""

    folder: Path
    run: Path
    net: Path
    net_crs: str | None
    interval_s: float
    begin_s: float  # observed time
    end_s: float
    time_offset_s: float  # SUMO time = observed time + time_offset_s
    step_s: float
    seed: int
    vehicles: int = 0
    vehicle_types: list[dict] = field(default_factory=list)
    build_s: float = 0.0  # wall time of sumo-demand
    warnings: tuple[str, ...] = ()  # observations left out of the demand (see mapping.py)
    run_fingerprint: str = ""  # SHA-256 of the run's crossings.csv and counts.csv (from its manifest)
    junction: dict | None = None  # a movement demand: {"arms": {arm: {"in_edge", "out_edge"}}}; None: counting lines

    @property
    def sumocfg(self) -> Path:
        return self.folder / "scenario.sumocfg"


def _check_options(observed: ObservedRun, interval_s: float, begin_s: float | None, end_s: float | None,
                   step_s: float, seed: int) -> tuple[float, float, float]:
    interval = check_interval(interval_s)
    t0, t1 = observed.period
    b = t0 if begin_s is None else float(begin_s)
    e = t1 if end_s is None else float(end_s)
    if not (math.isfinite(b) and math.isfinite(e) and t0 - 1e-9 <= b < e <= t1 + 1e-9):
        raise InputError(f"begin_s {b:g} / end_s {e:g}: need {t0:g} <= begin_s < end_s <= {t1:g} (the observed "
                         "period of the run, s)", parameters=("begin_s", "end_s"))
    if not (math.isfinite(step_s) and 0 < step_s <= 1.0):
        raise InputError(f"step_s {step_s:g}: the SUMO step must be in (0, 1] s, e.g. 0.5", parameters=("step_s",))
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or not 0 <= seed < 2**31:
        raise InputError(f"seed {seed!r}: give an integer in [0, 2^31)", parameters=("seed",))
    return interval, b, e


SUMOCFG_OPTIONS = {  # the options of scenario.sumocfg, by section, as sumo-demand writes them
    "input": ("net-file", "route-files", "additional-files"),
    "time": ("begin", "end", "step-length"),
    "output": ("fcd-output", "fcd-output.attributes", "device.fcd.begin"),
    "random_number": ("seed",),
    "report": ("no-step-log",),
}


def _xml(root: ET.Element) -> str:
    """``root`` as an indented XML document; attribute values escaped by the XML library."""
    ET.indent(root, space="    ")
    return ET.tostring(root, encoding="unicode") + "\n"


def _sumocfg(net_rel: str, end_sumo_s: float, step_s: float, seed: int, fcd_begin_s: float) -> str:
    values = {"net-file": net_rel, "route-files": "demand.rou.xml", "additional-files": "outputs.add.xml",
              "begin": "0", "end": f"{end_sumo_s:.3f}", "step-length": f"{step_s:g}", "fcd-output": "fcd.xml",
              "fcd-output.attributes": FCD_ATTRIBUTES, "device.fcd.begin": f"{fcd_begin_s:.3f}",
              "seed": str(seed), "no-step-log": "true"}
    root = ET.Element("configuration")
    for section, names in SUMOCFG_OPTIONS.items():
        part = ET.SubElement(root, section)
        for name in names:
            ET.SubElement(part, name, value=values[name])
    return _xml(root)


def _outputs_add(file: str, interval_s: float, begin_sumo_s: float, end_sumo_s: float) -> str:
    root = ET.Element("additional")
    ET.SubElement(root, "edgeData", id="simulated", file=file, period=f"{interval_s:g}", begin=f"{begin_sumo_s:.3f}",
                  end=f"{end_sumo_s:.3f}", excludeEmpty="true")
    return _xml(root)


def check_sumocfg(scenario: SumoScenario) -> None:
    """Refuse a ``scenario.sumocfg`` that is not as :func:`build_sumo_scenario` writes it (its manifest can be
    written again by anyone who edits it): only the options of :data:`SUMOCFG_OPTIONS`, the scenario's own route
    and output files, its network, no other outputs and no TraCI port."""
    path = scenario.sumocfg
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError) as exc:
        raise InputError(f"scenario {scenario.folder}: scenario.sumocfg cannot be read ({exc}); run 'trafficgeo "
                         "sumo-demand' again", parameters=("scenario",)) from None
    seen = {(part.tag, opt.tag): opt.attrib for part in root for opt in part}
    allowed = {(section, name) for section, names in SUMOCFG_OPTIONS.items() for name in names}
    fixed = {"route-files": "demand.rou.xml", "additional-files": "outputs.add.xml", "fcd-output": "fcd.xml"}
    why = None
    if root.tag != "configuration" or set(seen) != allowed or any(set(a) != {"value"} for a in seen.values()):
        odd = sorted(f"{s}/{n}" for s, n in set(seen) ^ allowed) or ["an attribute other than value"]
        why = f"it has options sumo-demand does not write or lacks its own ({', '.join(odd[:4])})"
    else:
        values = {name: attrib["value"] for (_s, name), attrib in seen.items()}
        bad = [n for n, v in fixed.items() if values[n] != v]
        if bad:
            why = f"its {', '.join(bad)} {'is' if len(bad) == 1 else 'are'} not the scenario's own"
        elif (scenario.folder / values["net-file"]).resolve() != scenario.net:
            why = f"its net-file {values['net-file']} is not the network of scenario.json"
    if why is not None:
        raise InputError(f"scenario {scenario.folder}: scenario.sumocfg is not as 'trafficgeo sumo-demand' wrote "
                         f"it: {why}; run sumo-demand again", parameters=("scenario",))


def build_sumo_scenario(run: str | os.PathLike[str], net: str | os.PathLike[str], out_dir: str | os.PathLike[str],
                        *, interval_s: float = 900.0, begin_s: float | None = None, end_s: float | None = None,
                        routes: str | os.PathLike[str] | None = None, net_crs: str | None = None,
                        step_s: float = 0.5, seed: int = 0) -> SumoScenario:
    """SUMO demand reproducing the observed counts of ``run`` (a run folder) on ``net`` (a ``.net.xml``), counted
    per ``interval_s`` over ``[begin_s, end_s)`` (observed time, s; default the run's period), on candidate
    ``routes`` (a route file; default randomTrips.py), written as a runnable scenario into ``out_dir`` (module
    docstring). Deterministic for a ``seed``. A run with a junction's movements (analyzed with gates) gets the
    demand of its movements instead (:mod:`trafficgeo.simulation.junction`; its counting lines, if any, are not
    used for the demand, and ``routes`` is refused).

    Raises:
        InputError: bad options, run or network; a line crossing no edge (:class:`MappingError` with its table), a
            gate crossing none (:class:`~trafficgeo.simulation.junction.GateMappingError`).
        TrafficgeoError: a SUMO tool failed.
    """
    from trafficgeo.io.atomic import write_csv_atomic, write_json_atomic, write_text_atomic
    from trafficgeo.io.folder_lock import hold_folder
    from trafficgeo.io.run_manifest import COMPARE_MANIFEST, begin_outputs, check_writable_folder, publish_outputs

    started = time.perf_counter()
    out = Path(out_dir)
    check_writable_folder(out, "out_dir")
    if not Path(net).is_file():
        raise InputError(f"net {net}: SUMO network file not found; give the .net.xml of the network to simulate",
                         parameters=("net",))
    if routes is not None and not Path(routes).is_file():
        raise InputError(f"routes {routes}: route file not found; give a SUMO .rou.xml or leave it out",
                         parameters=("routes",))
    observed = read_observed_run(run)
    interval, b, e = _check_options(observed, interval_s, begin_s, end_s, step_s, seed)
    if net_crs is not None:
        parse_crs(net_crs)
    parent = next(p for p in [out, *out.parents] if p.is_dir())
    work = Path(tempfile.mkdtemp(prefix=".sumo-demand-", dir=parent)).resolve()
    try:
        if run_has_movements(observed.outputs):
            if routes is not None:
                raise InputError(f"routes {routes}: a run with a junction's movements is routed by each movement's "
                                 "shortest path from its in-edge to its out-edge; leave routes out",
                                 parameters=("routes",))
            parts = _junction_parts(observed, Path(net), interval, b, e, net_crs, seed)
        else:
            parts = _line_parts(observed, Path(net), interval, b, e, routes, net_crs, seed, work, step_s)
        offset = parts.demand.time_offset_s
        out.mkdir(parents=True, exist_ok=True)
        with hold_folder(out):  # one run at a time in a folder
            begin_outputs(out, SCENARIO_MANIFEST)
            for stale in (*_SIMULATION_OUTPUTS, *_BUILD_OUTPUTS, COMPARE_MANIFEST):  # of an earlier scenario here
                (out / stale).unlink(missing_ok=True)
            net_rel = os.path.relpath(Path(net).resolve(), out.resolve())
            # two steps past the end: a vehicle crossing a line in the last step is seen on both sides of it
            files = {"scenario.sumocfg": _sumocfg(net_rel, e + offset + max(parts.tail_s, 2.0 * step_s), step_s, seed,
                                                  max(0.0, b + offset - 5.0)),
                     "demand.rou.xml": demand_xml(parts.types, parts.demand),
                     "outputs.add.xml": _outputs_add("simulated.edgedata.xml", interval, b + offset, e + offset)}
            for name, text in files.items():
                write_text_atomic(out / name, text)
            written = [out / n for n in files]
            for name in parts.copies:
                shutil.copyfile(work / name, work / f"{name}.copy")
                os.replace(work / f"{name}.copy", out / name)
                written.append(out / name)
            for name, table in parts.tables.items():
                write_csv_atomic(out / name, table, float_format="%.3f")
                written.append(out / name)
            scenario = SumoScenario(out, Path(run).resolve(), Path(net).resolve(), net_crs, interval, b, e, offset,
                                    step_s, int(seed), len(parts.demand.depart_s), [_type_doc(t) for t in parts.types],
                                    time.perf_counter() - started, parts.warnings,
                                    run_fingerprint(observed.folder), parts.junction)
            doc = _scenario_doc(scenario, net_rel, routes if parts.junction is None else None, parts.observed_total,
                                parts.demand.max_lag_s)
            write_json_atomic(out / "scenario.json", doc)
            written.append(out / "scenario.json")
            publish_outputs(out, written, command="sumo-demand", name=SCENARIO_MANIFEST)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return scenario


@dataclass(frozen=True)
class _DemandParts:
    """What one kind of demand adds to the scenario folder: the vehicles and their types, files of the work folder
    to copy, tables to write, warnings, the observed vehicles the demand reproduces, the time simulated past the
    period (s) and the junction (None: counting lines)."""

    demand: SampledDemand
    types: list[VehicleType]
    copies: tuple[str, ...]
    tables: dict[str, pd.DataFrame]
    warnings: tuple[str, ...]
    observed_total: dict[str, int]
    tail_s: float = 0.0
    junction: dict | None = None


def _line_parts(observed: ObservedRun, net: Path, interval: float, b: float, e: float, routes, net_crs, seed: int,
                work: Path, step_s: float) -> _DemandParts:
    """The demand of the counting lines (routeSampler on edge counts, :mod:`trafficgeo.simulation.demand`)."""
    mapping = map_observations(observed, net, net_crs=net_crs)
    counts = edge_counts(observed, mapping, interval, b, e)
    if not len(counts.edges) or int(counts.edges["entered"].sum()) == 0:
        raise InputError(f"{observed.folder}: no vehicle counted between {b:g} and {e:g} s; give a run with counts",
                         parameters=("begin_s", "end_s"))
    types = observed_vehicle_types(observed, mapping, b, e)
    write_edge_data(work / "counts.edgedata.xml", counts)
    cand = candidates_for(net.resolve(), Path(routes).resolve() if routes is not None else None, work, counts,
                          seed=seed)
    sampled = sample_routes(cand, counts, work, seed=seed)
    demand = place_departures(sampled, mapping.edge_lengths_m, observed, mapping, counts, seed=seed, step_s=step_s)
    return _DemandParts(demand, types, ("counts.edgedata.xml", *(["candidates.rou.xml"] if routes is None else [])),
                        {"mapping.csv": mapping.table, "observed_lane_counts.csv": counts.lanes}, mapping.warnings,
                        {"observed_vehicles_per_edge": int(counts.edges["entered"].sum())})


def _junction_parts(observed: ObservedRun, net: Path, interval: float, b: float, e: float, net_crs,
                    seed: int) -> _DemandParts:
    """The demand of a junction's turning movements (:mod:`trafficgeo.simulation.junction`)."""
    from trafficgeo.run.folder import RunFolder

    if not net.is_file():
        raise InputError(f"net {net}: SUMO network file not found; give the .net.xml of the network to simulate",
                         parameters=("net",))
    junction = read_run_junction(observed.folder, observed.crs)
    gates = map_gates(junction, net, observed.crs, net_crs=net_crs)
    run = RunFolder(observed.folder)
    vehicles = run.vehicles()
    counts = observed_movement_counts(run.movements(), vehicles, junction, interval, b, e)
    if int(counts["count"].sum()) == 0:
        raise InputError(f"{observed.folder}: no complete movement through the junction between {b:g} and {e:g} s; "
                         "give a run with movements (or other begin_s/end_s)", parameters=("begin_s", "end_s"))
    routes, warnings = movement_routes(net, gates, counts)
    demand = movement_demand(counts, routes, gates, seed=seed)
    arms = {str(r.arm): {"in_edge": str(r.in_edge), "out_edge": str(r.out_edge)} for r in gates.table.itertuples()}
    return _DemandParts(demand, movement_vehicle_types(counts, vehicles), (),
                        {"gate_mapping.csv": gates.table, "observed_movement_counts.csv": counts},
                        (*gates.warnings, *warnings), {"observed_movements": int(counts["count"].sum())}, TAIL_S,
                        {"arms": arms})


def _type_doc(t: VehicleType) -> dict:
    return {"class": t.name, "share": t.share, "length_m": t.length_m, "speed_factor": list(t.speed_factor),
            "observed": t.observed}


def _scenario_doc(s: SumoScenario, net_rel: str, routes, observed_total: dict[str, int], max_lag_s: float) -> dict:
    if s.junction is not None:
        route_text = "in-edge to out-edge of each movement (sumolib shortest path)"
    elif routes is not None:
        route_text = str(Path(routes).resolve())
    else:
        route_text = "candidates.rou.xml (randomTrips.py)"
    doc = {"format": FORMAT, "run": str(s.run), "net": net_rel, "net_crs": s.net_crs, "interval_s": s.interval_s,
           "begin_s": s.begin_s, "end_s": s.end_s, "time_offset_s": s.time_offset_s, "step_s": s.step_s,
           "seed": s.seed, "vehicles": s.vehicles, **observed_total, "max_lag_s": max_lag_s, "routes": route_text,
           "vehicle_types": s.vehicle_types, "warnings": list(s.warnings), "run_fingerprint": s.run_fingerprint}
    if s.junction is not None:
        doc["junction"] = s.junction
    return doc


def run_fingerprint(run: str | os.PathLike[str]) -> str:
    """What identifies a run's observations: the SHA-256 of its crossings.csv and counts.csv in its manifest (a copy
    of the folder has the same; a new analysis has another)."""
    from trafficgeo.io.run_manifest import MANIFEST

    try:
        files = loads_json((Path(run) / MANIFEST).read_text(encoding="utf-8"))["files"]
        return f'{files["crossings.csv"]["sha256"]}:{files["counts.csv"]["sha256"]}'
    except (OSError, ValueError, KeyError, TypeError):
        return ""


def read_sumo_scenario(folder: str | os.PathLike[str]) -> SumoScenario:
    """A scenario folder written by :func:`build_sumo_scenario` (checked against its manifest)."""
    from trafficgeo.io.run_manifest import verify_outputs

    d = Path(folder)
    if not (d / "scenario.json").is_file():
        raise InputError(f"scenario {d}: no scenario.json; give the folder written by 'trafficgeo sumo-demand'",
                         parameters=("scenario",))
    verify_outputs(d, require=("scenario.json", "scenario.sumocfg", "demand.rou.xml"), name=SCENARIO_MANIFEST)
    try:
        doc = loads_json((d / "scenario.json").read_text(encoding="utf-8"))
        if doc.get("format") != FORMAT:
            raise KeyError("format")
        return SumoScenario(d, Path(doc["run"]), (d / doc["net"]).resolve(), doc["net_crs"],
                            float(doc["interval_s"]), float(doc["begin_s"]), float(doc["end_s"]),
                            float(doc["time_offset_s"]), float(doc["step_s"]), int(doc["seed"]), int(doc["vehicles"]),
                            list(doc["vehicle_types"]), warnings=tuple(doc.get("warnings", ())),
                            run_fingerprint=str(doc.get("run_fingerprint", "")),
                            junction=_junction_doc(doc.get("junction")))
    except (KeyError, TypeError, ValueError):
        raise InputError(f"scenario {d}: scenario.json is not one written by 'trafficgeo sumo-demand'; run it again",
                         parameters=("scenario",)) from None


def _junction_doc(doc) -> dict | None:
    """The ``junction`` of a scenario.json (None: a demand of counting lines); KeyError when malformed."""
    if doc is None:
        return None
    arms = doc["arms"]
    if not isinstance(arms, dict) or not all(isinstance(a, dict) and {"in_edge", "out_edge"} <= set(a)
                                             for a in arms.values()):
        raise KeyError("junction")
    return {"arms": {str(k): {"in_edge": str(v["in_edge"]), "out_edge": str(v["out_edge"])} for k, v in arms.items()}}


@dataclass(frozen=True)
class SimulationOutputs:
    """What a SUMO run of a scenario wrote (into the scenario folder) and how long it took (s)."""

    fcd: Path
    edge_data: Path
    run_s: float


def run_scenario(scenario: SumoScenario) -> SimulationOutputs:
    """Run SUMO headless on the scenario; ``fcd.xml`` and ``simulated.edgedata.xml`` land in its folder only when
    SUMO succeeded."""
    from trafficgeo.io.atomic import write_text_atomic

    if not scenario.net.is_file():
        raise InputError(f"scenario {scenario.folder}: its network {scenario.net} is gone; give it back or run "
                         "'trafficgeo sumo-demand' again", parameters=("scenario",))
    check_sumocfg(scenario)
    started = time.perf_counter()
    work = Path(tempfile.mkdtemp(prefix=".sumo-run-", dir=scenario.folder)).resolve()
    try:
        b, e = scenario.begin_s + scenario.time_offset_s, scenario.end_s + scenario.time_offset_s
        write_text_atomic(work / "outputs.add.xml",
                          _outputs_add(str(work / "simulated.edgedata.xml"), scenario.interval_s, b, e))
        steps = e / scenario.step_s
        run_sumo_program("sumo", ["-c", str(scenario.sumocfg.resolve()), "--fcd-output", str(work / "fcd.xml"),
                                  "--additional-files", str(work / "outputs.add.xml")],
                         120.0 + 0.05 * steps, cwd=scenario.folder)
        for name in _SIMULATION_OUTPUTS:
            os.replace(work / name, scenario.folder / name)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return SimulationOutputs(scenario.folder / "fcd.xml", scenario.folder / "simulated.edgedata.xml",
                             time.perf_counter() - started)


def mapping_table(scenario: SumoScenario) -> pd.DataFrame:
    """The scenario's ``mapping.csv``."""
    return pd.read_csv(scenario.folder / "mapping.csv", dtype={"line": str, "lane": str}, keep_default_na=False)

