"""The JSON files of a run folder as typed records: one dataclass writes and reads each (read through pydantic).

============================  ==========================  ===================================================
``summary.json``              :class:`RunSummary`         ``analyze`` / ``process`` / ``stitch``
                                                          (:func:`trafficgeo.traffic.analyze.summary`)
``process.json``              :class:`ProcessRecord`      ``process`` (:func:`trafficgeo.pipeline.run.run_info`)
``compare_summary.json``      :class:`CompareSummary`     ``compare-sumo`` / ``sumo-validate``
                                                          (:func:`trafficgeo.traffic.validation.write_comparison`)
``compare_simulation.json``   :class:`SimulationRecord`   ``sumo-validate``
                                                          (:func:`trafficgeo.simulation.loop.validate_sumo_scenario`)
============================  ==========================  ===================================================

A run's :class:`~trafficgeo.run.folder.RunWriter` writes them (``summary``, ``process``, ``compare_summary``,
``simulation``: :meth:`to_dict` through
:func:`trafficgeo.io.atomic.write_json_atomic`) and reads them back (``summary()``, ``process()``,
``compare_summary()``, ``simulation_record()``: ``from_dict``, which validates the document against the fields'
types with pydantic (strict JSON types: :data:`Num`, :data:`Int`, :data:`Text`, :data:`Flag`, :data:`Obj`) and
names the file and the key in an :class:`~trafficgeo.errors.InputError` when a file is damaged or foreign).
``to_dict`` gives the document with the keys in the order of the fields; a number that is not available is NaN in
memory and ``null`` in the file (as the writers have always written it). Keys a file has beyond these are ignored;
keys that joined a format later (noted below) read with their default from a file written before them. Two records
are equal when they write the same
JSON. Units as in the names: seconds (``_s``), km/h (``_kmh``), vehicles per hour (``_veh_h``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Annotated, Any

from pydantic import BeforeValidator, Strict

from trafficgeo.errors import InputError
from trafficgeo.io.records import NAN, Flag, Int, MaybeNum, Num, Obj, Record, RecordError, Text, read_record

__all__ = ["SIMULATION_FORMAT", "SIMULATION_RECORD", "CompareSummary", "CountSummary", "LineCount", "ProcessRecord",
           "ProcessSettings", "RunSummary", "SimulationRecord", "TravelTimeSummary", "VideoRead"]

SIMULATION_RECORD = "compare_simulation.json"  # sumo-validate's record of the scenario beside the comparison
SIMULATION_FORMAT = "trafficgeo-sumo-validation/1"

def _empty_for_null(value: Any) -> Any:
    return {} if value is None else value


def _read(cls: Any, doc: Any, where: str, file: str, hint: str) -> Any:
    """``doc`` as the record ``cls`` (:func:`~trafficgeo.io.records.read_record`); InputError naming ``where`` and
    the key otherwise."""
    try:
        return read_record(cls, doc)
    except RecordError as exc:
        raise InputError(f"{where}: not a {file} written by trafficgeo ({exc}); {hint}") from None


# ------------------------------------------------------------------------------------------------ summary.json
@dataclass(frozen=True, eq=False)
class LineCount(Record):
    """The vehicles that crossed counting line ``line`` in ``lane`` (``""``: none) in ``direction`` (+1 / -1) over
    the whole run (zeros too)."""

    line: Text
    lane: Text
    direction: Int
    count: Int



@dataclass(frozen=True, eq=False, kw_only=True)
class RunSummary(Record):
    """``summary.json``: the totals of an analysis, the options used and the CRS.

    ``period_s``: first and last time in the input tracks (s); ``vehicles``, ``points`` (trajectory points kept),
    ``dropped_points`` (input points not used, per reason), ``outlier_points``; ``mean_speed_kmh`` (mean of the
    vehicles' ``speed_kmh``; None when no vehicle has one); ``classes`` (vehicles per class, ``""``: unknown);
    ``lane_changes``; ``crossings`` per line, lane and direction; ``hidden_crossings`` (of vehicles hidden at the
    line); ``options`` (the trajectory options, ``interval_s`` and ``speed_scale_knowledge``, as a JSON object);
    ``warnings``; ``crs`` (WKT, None without a CRS); ``fragments`` (world tracks before they were joined into
    vehicles: :mod:`trafficgeo.traffic.journeys`), ``stationary_vehicles`` (objects that never moved) and, for a run
    with a junction's gates, ``junction`` (:func:`trafficgeo.traffic.analyze.junction_summary`; None otherwise).
    ``hidden_crossings``, ``warnings``, ``crs``, ``fragments`` and ``stationary_vehicles`` joined the format later:
    0, none, None, None and 0 in a file written before them.
    """

    period_s: tuple[Num, Num]
    vehicles: Int
    points: Int
    dropped_points: Annotated[dict[str, Int], Strict()]
    outlier_points: Int
    mean_speed_kmh: MaybeNum
    classes: Annotated[dict[str, Int], Strict()]
    lane_changes: Int
    crossings: tuple[LineCount, ...]
    hidden_crossings: Int = 0
    options: Obj
    warnings: tuple[Text, ...] = ()
    crs: Text | None = None
    fragments: Int | None = None
    stationary_vehicles: Int = 0
    junction: Obj | None = None

    def to_dict(self) -> dict[str, Any]:
        doc = super().to_dict()
        if doc.get("junction") is None:  # a run without gates writes no junction key
            doc.pop("junction", None)
        return doc

    @property
    def interval_s(self) -> float | None:
        """The counting interval (s) of ``options``; None when the options lack it."""
        v = self.options.get("interval_s")
        return float(v) if isinstance(v, int | float) and not isinstance(v, bool) else None

    @classmethod
    def from_dict(cls, doc: Any, where: str = "summary.json") -> RunSummary:
        """The summary of a ``summary.json`` document; ``where`` (its path) names it in errors.

        Raises:
            InputError: ``doc`` is not a summary written by trafficgeo (a missing key or a wrong type).
        """
        hint = "run 'trafficgeo analyze' or 'process' again to write it"
        period = doc.get("period_s") if isinstance(doc, Mapping) else None
        if isinstance(period, list) and len(period) != 2:
            raise InputError(f"{where}: not a summary.json written by trafficgeo ('period_s' has {len(period)} "
                             f"values, expected 2 (first and last time)); {hint}")
        return _read(cls, doc, where, "summary.json", hint)



# ------------------------------------------------------------------------------------------------ process.json
@dataclass(frozen=True, eq=False)
class ProcessSettings(Record):
    """What ``process`` was asked for (``options`` of ``process.json``; :class:`trafficgeo.video.pipeline.
    ProcessOptions`): the detector (a name or a model's path) and its model layout, the time range (s of video;
    ``end_s`` None: to the end), every n-th frame, the tiles and their planning, the runtime, the tile schedule and
    the tracker the run settled on (``tracker``: :class:`trafficgeo.video.track.TrackerOptions` as a JSON object,
    e.g. ``min_iou`` 0.3 at a junction, 0.1 on a road; it joined the format later). A key a file lacks (written by
    an older trafficgeo) reads as None."""

    detector: Text | None = None
    detector_format: Text | None = None
    start_s: MaybeNum = None
    end_s: MaybeNum = None
    every: Int | None = None
    tiles: Flag | None = None
    tiling: Text | None = None
    backend: Text | None = None
    tile_schedule: Text | None = None
    tracker: Obj | None = None



@dataclass(frozen=True, eq=False)
class VideoRead(Record):
    """What ``process`` decoded (``read`` of ``process.json``): the time of the first frame and the end of the last
    one (s; None when no frame was read), the frames, and ``complete``: False when the video ended before the asked
    end (e.g. a truncated file)."""

    start_s: MaybeNum
    end_s: MaybeNum
    frames: Int
    complete: Flag



@dataclass(frozen=True, eq=False, kw_only=True)
class ProcessRecord(Record):
    """``process.json``: what a ``process`` run processed and how.

    ``video``, ``camera``: the paths as given (relative ones from the folder ``process`` ran in; ``camera`` ``""``
    for a camera given as an object); ``options`` (:class:`ProcessSettings`); ``detector``: what the detector said
    about itself (its tile plan ``tiling``, ``backend``, cost ``estimate``, ``tile_schedule``, ``schedule``; a JSON
    object, None for a detector that says nothing); ``read`` (:class:`VideoRead`); ``seconds`` of wall clock for
    detection and tracking; ``detections`` and ``track_rows`` written. ``detector``, ``read``, ``seconds``,
    ``detections`` and ``track_rows`` read as None from a file without them.
    """

    video: Text
    camera: Text = ""
    options: Annotated[ProcessSettings, BeforeValidator(_empty_for_null)] = field(default_factory=ProcessSettings)
    detector: Obj | None = None
    read: VideoRead | None = None
    seconds: MaybeNum = None
    detections: Int | None = None
    track_rows: Int | None = None

    @property
    def tiling(self) -> dict[str, Any] | None:
        """The built-in learned detector's tile plan (``TilePlan.to_dict()``), or None."""
        t = (self.detector or {}).get("tiling")
        return t if isinstance(t, dict) else None

    @classmethod
    def from_dict(cls, doc: Any, where: str = "process.json") -> ProcessRecord:
        """The record of a ``process.json`` document; ``where`` (its path) names it in errors.

        Raises:
            InputError: ``doc`` is not a process.json written by trafficgeo (a missing key or a wrong type).
        """
        return _read(cls, doc, where, "process.json", "run 'trafficgeo process' again to write it")



# ------------------------------------------------------------------------------------------------ compare_summary.json
@dataclass(frozen=True, eq=False)
class CountSummary(Record):
    """The GEH of the observed against the simulated counts (:func:`trafficgeo.traffic.compare.count_summary`):
    ``rows`` (line x lane x direction x interval), the share of them with GEH < 5, the mean GEH, the vehicles
    observed and simulated, the GEH of the total hourly flows, and ``groups``: one JSON object per line and lane
    (``line``, ``lane``, ``observed``, ``simulated``, ``observed_flow_veh_h``, ``simulated_flow_veh_h``, ``geh``)."""

    rows: Int
    share_geh_below_5: Num
    mean_geh: Num
    total_observed: Int
    total_simulated: Int
    geh_total: Num
    groups: tuple[Obj, ...] = ()



@dataclass(frozen=True, eq=False)
class TravelTimeSummary(Record):
    """Travel times from the first to the last counting line, observed and simulated
    (:func:`trafficgeo.traffic.compare.compare_travel_times`): vehicles, mean, median and 85th percentile (s), the
    simulated minus observed mean (s), and the two-sample Kolmogorov-Smirnov distance and its p-value."""

    from_line: Text
    to_line: Text
    observed_n: Int
    observed_mean_s: Num
    observed_median_s: Num
    observed_p85_s: Num
    simulated_n: Int
    simulated_mean_s: Num
    simulated_median_s: Num
    simulated_p85_s: Num
    mean_difference_s: Num
    ks_statistic: Num
    ks_pvalue: Num



@dataclass(frozen=True, eq=False)
class CompareSummary(Record):
    """``compare_summary.json``: observed against simulated traffic (``compare-sumo``, ``sumo-validate``): the
    counts' :class:`CountSummary`, the :class:`TravelTimeSummary` (None with fewer than two counting lines) and the
    CRS of the comparison (its label, :func:`trafficgeo.crs.crs_label`)."""

    counts: CountSummary
    travel_times: TravelTimeSummary | None
    crs: Text
    movements: CountSummary | None = None  # sumo-validate at a junction's gates (joined 2027-01); groups per movement

    def to_dict(self) -> dict[str, Any]:
        doc = super().to_dict()
        if doc.get("movements") is None:  # a comparison without a junction writes no movements key
            doc.pop("movements", None)
        return doc

    @classmethod
    def from_dict(cls, doc: Any, where: str = "compare_summary.json") -> CompareSummary:
        """The summary of a ``compare_summary.json`` document; ``where`` (its path) names it in errors.

        Raises:
            InputError: ``doc`` is not a compare_summary.json written by trafficgeo (a missing key or a wrong type).
        """
        return _read(cls, doc, where, "compare_summary.json", "run 'trafficgeo compare-sumo' again to write it")



# ---------------------------------------------------------------------------------------- compare_simulation.json


@dataclass(frozen=True, eq=False, kw_only=True)
class SimulationRecord(Record):
    """``compare_simulation.json``: the SUMO scenario ``sumo-validate`` simulated and its headline figures, beside
    the comparison tables of the run it was built from.

    The scenario: its ``scenario`` folder and ``net`` (absolute paths), ``net_crs`` (None: the network's own PROJ
    string), the counting ``interval_s`` and the observed period ``begin_s`` to ``end_s`` simulated,
    ``time_offset_s`` (SUMO time minus observed time), ``step_s``, ``seed``, ``vehicles`` in the demand, the
    seconds to build it (``build_s``, NaN when not known) and to run SUMO (``run_s``). The figures: ``counts``
    compared (line x lane x direction x interval), ``share_geh_below_5`` against ``target_share``, ``target_met``,
    ``mean_geh``, ``max_abs_speed_difference_kmh``, ``travel_time_difference_s`` (simulated minus observed mean),
    ``unobserved`` (lines or directions with no observed vehicle, not compared) and the scenario's ``warnings``;
    at a junction's gates the ``movements`` compared (interval x movement), their ``movement_share_geh_below_5``
    and ``movement_mean_geh`` (0 and NaN without a junction).
    """

    format: Text = SIMULATION_FORMAT
    command: Text = "sumo-validate"
    scenario: Text
    net: Text
    net_crs: Text | None = None
    interval_s: Num
    begin_s: Num
    end_s: Num
    time_offset_s: Num
    step_s: Num
    seed: Int
    vehicles: Int
    build_s: Num
    run_s: Num
    counts: Int
    share_geh_below_5: Num
    mean_geh: Num
    target_share: Num
    target_met: Flag
    max_abs_speed_difference_kmh: Num
    travel_time_difference_s: Num
    unobserved: tuple[Text, ...] = ()
    warnings: tuple[Text, ...] = ()
    movements: Int = 0  # interval x movement rows compared at a junction's gates (joined 2027-01)
    movement_share_geh_below_5: Num = NAN
    movement_mean_geh: Num = NAN

    @classmethod
    def from_dict(cls, doc: Any, where: str = SIMULATION_RECORD) -> SimulationRecord:
        """The record of a ``compare_simulation.json`` document; ``where`` (its path) names it in errors.

        Raises:
            InputError: ``doc`` is not a record written by ``sumo-validate`` (another format, a missing key or a
                wrong type).
        """
        hint = "run 'trafficgeo sumo-validate' again to write it"
        if isinstance(doc, Mapping) and doc.get("format") != SIMULATION_FORMAT:
            raise InputError(f"{where}: not a {SIMULATION_RECORD} written by trafficgeo ('format' is not "
                             f"{SIMULATION_FORMAT}); {hint}")
        return _read(cls, doc, where, SIMULATION_RECORD, hint)

