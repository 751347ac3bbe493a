"""The JSON files of a run folder as typed records: one dataclass writes and reads each.

============================  ==========================  ===================================================
``summary.json``              :class:`RunSummary`         ``analyze`` / ``process`` / ``stitch``
                                                          (:func:`trafficgeo.traffic.analyze.summary`)
``process.json``              :class:`ProcessRecord`      ``process`` (:func:`trafficgeo.pipeline.run.run_info`)
``compare_summary.json``      :class:`CompareSummary`     ``compare-sumo`` / ``sumo-validate``
                                                          (:func:`trafficgeo.traffic.validation.write_comparison`)
``compare_simulation.json``   :class:`SimulationRecord`   ``sumo-validate``
                                                          (:func:`trafficgeo.simulation.loop.validate_sumo_scenario`)
============================  ==========================  ===================================================

:class:`~trafficgeo.run.folder.RunFolder` writes them (``write_summary``, ``write_process``,
``write_compare_summary``, ``write_simulation_record``: :meth:`to_dict` through
:func:`trafficgeo.io.atomic.write_json_atomic`) and reads them back (``summary()``, ``process()``,
``compare_summary()``, ``simulation_record()``: ``from_dict``, which names the file and the key in an
:class:`~trafficgeo.errors.InputError` when a file is damaged or foreign). ``to_dict`` gives the document with the
keys in the order of the fields; a number that is not available is NaN in memory and ``null`` in the file (as the
writers have always written it). Keys a file has beyond these are ignored; keys that joined a format later (noted
below) read with their default from a file written before them. Two records are equal when they write the same
JSON. Units as in the names: seconds (``_s``), km/h (``_kmh``), vehicles per hour (``_veh_h``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Any

from trafficgeo.errors import InputError
from trafficgeo.io.atomic import to_json_safe

__all__ = ["SIMULATION_FORMAT", "SIMULATION_RECORD", "CompareSummary", "CountSummary", "LineCount", "ProcessRecord",
           "ProcessSettings", "RunSummary", "SimulationRecord", "TravelTimeSummary", "VideoRead"]

SIMULATION_RECORD = "compare_simulation.json"  # sumo-validate's record of the scenario beside the comparison
SIMULATION_FORMAT = "trafficgeo-sumo-validation/1"

NAN = float("nan")
_REQUIRED = object()


class _Malformed(Exception):
    """A key of the document is missing or has the wrong type (the message names it)."""


class _Obj:
    """One JSON object of a document being read: typed values by key, errors naming ``path`` (``counts.rows``)."""

    def __init__(self, doc: Any, path: str = "") -> None:
        if not isinstance(doc, Mapping):
            raise _Malformed(f"'{path}' is not an object" if path else "the document is not a JSON object")
        self.doc, self.path = doc, path

    def name(self, key: str) -> str:
        return f"{self.path}.{key}" if self.path else key

    def raw(self, key: str, default: Any = _REQUIRED) -> Any:
        if key in self.doc:
            return self.doc[key]
        if default is _REQUIRED:
            raise _Malformed(f"key '{self.name(key)}' is missing")
        return default

    def number(self, key: str, default: Any = _REQUIRED, *, null: float | None = NAN) -> float | None:
        """A number (``null`` for JSON null: NaN, or None where None means "none")."""
        v = self.raw(key, default)
        if v is default and default is not _REQUIRED:
            return v
        return _number(v, self.name(key), null)

    def integer(self, key: str, default: Any = _REQUIRED, *, nullable: bool = False) -> int | None:
        v = self.raw(key, default)
        if (v is default and default is not _REQUIRED) or (v is None and nullable):
            return v
        if isinstance(v, int) and not isinstance(v, bool):
            return v
        raise _Malformed(f"'{self.name(key)}' is not a whole number")

    def text(self, key: str, default: Any = _REQUIRED, *, nullable: bool = False) -> str | None:
        v = self.raw(key, default)
        if (v is default and default is not _REQUIRED) or (v is None and nullable) or isinstance(v, str):
            return v
        raise _Malformed(f"'{self.name(key)}' is not text")

    def flag(self, key: str, default: Any = _REQUIRED, *, nullable: bool = False) -> bool | None:
        v = self.raw(key, default)
        if (v is default and default is not _REQUIRED) or (v is None and nullable) or isinstance(v, bool):
            return v
        raise _Malformed(f"'{self.name(key)}' is not true or false")

    def object(self, key: str, default: Any = _REQUIRED, *, nullable: bool = False) -> dict[str, Any] | None:
        """A JSON object as a plain dict (its values as they are)."""
        v = self.raw(key, default)
        if (v is default and default is not _REQUIRED) or (v is None and nullable):
            return v
        if isinstance(v, Mapping):
            return dict(v)
        raise _Malformed(f"'{self.name(key)}' is not an object")

    def sub(self, key: str, default: Any = _REQUIRED) -> _Obj | None:
        """A nested object to read typed (None for JSON null)."""
        v = self.raw(key, default)
        if v is None or (v is default and default is not _REQUIRED):
            return None
        return _Obj(v, self.name(key))

    def items(self, key: str, default: Any = _REQUIRED) -> list[Any]:
        v = self.raw(key, default)
        if isinstance(v, list | tuple):
            return list(v)
        raise _Malformed(f"'{self.name(key)}' is not a list")

    def counts(self, key: str, default: Any = _REQUIRED) -> dict[str, int]:
        """An object of whole numbers (``{"car": 5}``)."""
        obj = _Obj(self.object(key, default), self.name(key))
        return {str(k): obj.integer(k) for k in obj.doc}


def _number(v: Any, name: str, null: float | None = NAN) -> float | None:
    if v is None:
        return null
    if isinstance(v, int | float) and not isinstance(v, bool):
        return float(v)
    raise _Malformed(f"'{name}' is not a number")


def _read(cls: Any, doc: Any, where: str, file: str, hint: str) -> Any:
    try:
        return cls._from(_Obj(doc))
    except _Malformed as exc:
        raise InputError(f"{where}: not a {file} written by trafficgeo ({exc}); {hint}") from None


class _Record:
    """Base of the records: ``to_dict`` in field order (records and tuples as JSON objects and lists); equal when
    they write the same JSON (NaN, "not available", equals NaN)."""

    def to_dict(self) -> dict[str, Any]:
        return {f.name: _plain(getattr(self, f.name)) for f in fields(self)}

    def __eq__(self, other: object) -> bool:
        if type(other) is not type(self):
            return NotImplemented
        return to_json_safe(self.to_dict()) == to_json_safe(other.to_dict())

    __hash__ = None  # type: ignore[assignment]  (equal by JSON value, which a hash of the fields would not follow)


def _plain(value: Any) -> Any:
    if isinstance(value, _Record):
        return value.to_dict()
    if isinstance(value, tuple | list):
        return [_plain(v) for v in value]
    if isinstance(value, Mapping):
        return {k: _plain(v) for k, v in value.items()}
    return value


# ------------------------------------------------------------------------------------------------ summary.json
@dataclass(frozen=True, eq=False)
class LineCount(_Record):
    """The vehicles that crossed counting line ``line`` in ``lane`` (``""``: none) in ``direction`` (+1 / -1) over
    the whole run (zeros too)."""

    line: str
    lane: str
    direction: int
    count: int

    @classmethod
    def _from(cls, o: _Obj) -> LineCount:
        return cls(o.text("line"), o.text("lane"), o.integer("direction"), o.integer("count"))


@dataclass(frozen=True, eq=False, kw_only=True)
class RunSummary(_Record):
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

    period_s: tuple[float, float]
    vehicles: int
    points: int
    dropped_points: dict[str, int]
    outlier_points: int
    mean_speed_kmh: float | None
    classes: dict[str, int]
    lane_changes: int
    crossings: tuple[LineCount, ...]
    hidden_crossings: int = 0
    options: dict[str, Any]
    warnings: tuple[str, ...] = ()
    crs: str | None = None
    fragments: int | None = None
    stationary_vehicles: int = 0
    junction: dict[str, Any] | None = None

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
        return _read(cls, doc, where, "summary.json", "run 'trafficgeo analyze' or 'process' again to write it")

    @classmethod
    def _from(cls, o: _Obj) -> RunSummary:
        period = o.items("period_s")
        if len(period) != 2:
            raise _Malformed(f"'period_s' has {len(period)} values, expected 2 (first and last time)")
        crossings = tuple(LineCount._from(_Obj(c, f"crossings[{k}]")) for k, c in enumerate(o.items("crossings")))
        warnings = o.items("warnings", [])
        if not all(isinstance(w, str) for w in warnings):
            raise _Malformed("'warnings' is not a list of text")
        return cls(period_s=(_number(period[0], "period_s[0]"), _number(period[1], "period_s[1]")),
                   vehicles=o.integer("vehicles"), points=o.integer("points"),
                   dropped_points=o.counts("dropped_points"), outlier_points=o.integer("outlier_points"),
                   mean_speed_kmh=o.number("mean_speed_kmh", null=None), classes=o.counts("classes"),
                   lane_changes=o.integer("lane_changes"), crossings=crossings,
                   hidden_crossings=o.integer("hidden_crossings", 0), options=o.object("options"),
                   warnings=tuple(warnings), crs=o.text("crs", None, nullable=True),
                   fragments=o.integer("fragments", None, nullable=True),
                   stationary_vehicles=o.integer("stationary_vehicles", 0),
                   junction=o.object("junction", None, nullable=True))


# ------------------------------------------------------------------------------------------------ process.json
@dataclass(frozen=True, eq=False)
class ProcessSettings(_Record):
    """What ``process`` was asked for (``options`` of ``process.json``; :class:`trafficgeo.video.pipeline.
    ProcessOptions`): the detector (a name or a model's path) and its model layout, the time range (s of video;
    ``end_s`` None: to the end), every n-th frame, the tiles and their planning, the runtime and the tile
    schedule. A key a file lacks (written by an older trafficgeo) reads as None."""

    detector: str | None = None
    detector_format: str | None = None
    start_s: float | None = None
    end_s: float | None = None
    every: int | None = None
    tiles: bool | None = None
    tiling: str | None = None
    backend: str | None = None
    tile_schedule: str | None = None

    @classmethod
    def _from(cls, o: _Obj) -> ProcessSettings:
        return cls(o.text("detector", None, nullable=True), o.text("detector_format", None, nullable=True),
                   o.number("start_s", None, null=None), o.number("end_s", None, null=None),
                   o.integer("every", None, nullable=True), o.flag("tiles", None, nullable=True),
                   o.text("tiling", None, nullable=True), o.text("backend", None, nullable=True),
                   o.text("tile_schedule", None, nullable=True))


@dataclass(frozen=True, eq=False)
class VideoRead(_Record):
    """What ``process`` decoded (``read`` of ``process.json``): the time of the first frame and the end of the last
    one (s; None when no frame was read), the frames, and ``complete``: False when the video ended before the asked
    end (e.g. a truncated file)."""

    start_s: float | None
    end_s: float | None
    frames: int
    complete: bool

    @classmethod
    def _from(cls, o: _Obj) -> VideoRead:
        return cls(o.number("start_s", null=None), o.number("end_s", null=None), o.integer("frames"),
                   o.flag("complete"))


@dataclass(frozen=True, eq=False, kw_only=True)
class ProcessRecord(_Record):
    """``process.json``: what a ``process`` run processed and how.

    ``video``, ``camera``: the paths as given (relative ones from the folder ``process`` ran in; ``camera`` ``""``
    for a camera given as an object); ``options`` (:class:`ProcessSettings`); ``detector``: what the detector said
    about itself (its tile plan ``tiling``, ``backend``, cost ``estimate``, ``tile_schedule``, ``schedule``; a JSON
    object, None for a detector that says nothing); ``read`` (:class:`VideoRead`); ``seconds`` of wall clock for
    detection and tracking; ``detections`` and ``track_rows`` written. ``detector``, ``read``, ``seconds``,
    ``detections`` and ``track_rows`` read as None from a file without them.
    """

    video: str
    camera: str = ""
    options: ProcessSettings = field(default_factory=ProcessSettings)
    detector: dict[str, Any] | None = None
    read: VideoRead | None = None
    seconds: float | None = None
    detections: int | None = None
    track_rows: int | None = None

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

    @classmethod
    def _from(cls, o: _Obj) -> ProcessRecord:
        options, read = o.sub("options", None), o.sub("read", None)
        return cls(video=o.text("video"), camera=o.text("camera", ""),
                   options=ProcessSettings._from(options) if options is not None else ProcessSettings(),
                   detector=o.object("detector", None, nullable=True),
                   read=VideoRead._from(read) if read is not None else None,
                   seconds=o.number("seconds", None, null=None),
                   detections=o.integer("detections", None, nullable=True),
                   track_rows=o.integer("track_rows", None, nullable=True))


# ------------------------------------------------------------------------------------------------ compare_summary.json
@dataclass(frozen=True, eq=False)
class CountSummary(_Record):
    """The GEH of the observed against the simulated counts (:func:`trafficgeo.traffic.compare.count_summary`):
    ``rows`` (line x lane x direction x interval), the share of them with GEH < 5, the mean GEH, the vehicles
    observed and simulated, the GEH of the total hourly flows, and ``groups``: one JSON object per line and lane
    (``line``, ``lane``, ``observed``, ``simulated``, ``observed_flow_veh_h``, ``simulated_flow_veh_h``, ``geh``)."""

    rows: int
    share_geh_below_5: float
    mean_geh: float
    total_observed: int
    total_simulated: int
    geh_total: float
    groups: tuple[dict[str, Any], ...] = ()

    @classmethod
    def _from(cls, o: _Obj) -> CountSummary:
        head = (o.integer("rows"), o.number("share_geh_below_5"), o.number("mean_geh"), o.integer("total_observed"),
                o.integer("total_simulated"), o.number("geh_total"))
        groups = (_Obj(g, f"{o.name('groups')}[{k}]").doc for k, g in enumerate(o.items("groups")))
        return cls(*head, tuple(dict(g) for g in groups))


@dataclass(frozen=True, eq=False)
class TravelTimeSummary(_Record):
    """Travel times from the first to the last counting line, observed and simulated
    (:func:`trafficgeo.traffic.compare.compare_travel_times`): vehicles, mean, median and 85th percentile (s), the
    simulated minus observed mean (s), and the two-sample Kolmogorov-Smirnov distance and its p-value."""

    from_line: str
    to_line: str
    observed_n: int
    observed_mean_s: float
    observed_median_s: float
    observed_p85_s: float
    simulated_n: int
    simulated_mean_s: float
    simulated_median_s: float
    simulated_p85_s: float
    mean_difference_s: float
    ks_statistic: float
    ks_pvalue: float

    @classmethod
    def _from(cls, o: _Obj) -> TravelTimeSummary:
        kinds = {f.name: f.type for f in fields(cls)}
        read = {"str": o.text, "int": o.integer, "float": o.number}
        return cls(**{k: read[t](k) for k, t in kinds.items()})


@dataclass(frozen=True, eq=False)
class CompareSummary(_Record):
    """``compare_summary.json``: observed against simulated traffic (``compare-sumo``, ``sumo-validate``): the
    counts' :class:`CountSummary`, the :class:`TravelTimeSummary` (None with fewer than two counting lines) and the
    CRS of the comparison (its label, :func:`trafficgeo.crs.crs_label`)."""

    counts: CountSummary
    travel_times: TravelTimeSummary | None
    crs: str
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

    @classmethod
    def _from(cls, o: _Obj) -> CompareSummary:
        tt = o.sub("travel_times")
        mv = o.sub("movements", None)
        return cls(CountSummary._from(o.sub("counts")), TravelTimeSummary._from(tt) if tt is not None else None,
                   o.text("crs"), CountSummary._from(mv) if mv is not None else None)


# ---------------------------------------------------------------------------------------- compare_simulation.json
_SIMULATION_LATER = ("movements", "movement_share_geh_below_5", "movement_mean_geh")  # keys that joined later


@dataclass(frozen=True, eq=False, kw_only=True)
class SimulationRecord(_Record):
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

    format: str = SIMULATION_FORMAT
    command: str = "sumo-validate"
    scenario: str
    net: str
    net_crs: str | None
    interval_s: float
    begin_s: float
    end_s: float
    time_offset_s: float
    step_s: float
    seed: int
    vehicles: int
    build_s: float
    run_s: float
    counts: int
    share_geh_below_5: float
    mean_geh: float
    target_share: float
    target_met: bool
    max_abs_speed_difference_kmh: float
    travel_time_difference_s: float
    unobserved: tuple[str, ...] = ()
    warnings: tuple[str, ...] = ()
    movements: int = 0  # interval x movement rows compared at a junction's gates (joined 2027-01)
    movement_share_geh_below_5: float = NAN
    movement_mean_geh: float = NAN

    @classmethod
    def from_dict(cls, doc: Any, where: str = SIMULATION_RECORD) -> SimulationRecord:
        """The record of a ``compare_simulation.json`` document; ``where`` (its path) names it in errors.

        Raises:
            InputError: ``doc`` is not a record written by ``sumo-validate`` (another format, a missing key or a
                wrong type).
        """
        return _read(cls, doc, where, SIMULATION_RECORD, "run 'trafficgeo sumo-validate' again to write it")

    @classmethod
    def _from(cls, o: _Obj) -> SimulationRecord:
        if o.raw("format", None) != SIMULATION_FORMAT:
            raise _Malformed(f"'format' is not {SIMULATION_FORMAT}")
        read = {"str": o.text, "int": o.integer, "float": o.number, "bool": o.flag}
        values: dict[str, Any] = {"net_crs": o.text("net_crs", None, nullable=True)}
        for f in fields(cls):
            if f.type in read and f.name not in values:
                later = f.name in _SIMULATION_LATER  # a record written before the key joined reads its default
                values[f.name] = read[f.type](f.name, *((f.default,) if later else ()))
        for key in ("unobserved", "warnings"):
            items = o.items(key, [])
            if not all(isinstance(v, str) for v in items):
                raise _Malformed(f"'{key}' is not a list of text")
            values[key] = tuple(items)
        return cls(**values)
