"""``trafficgeo report``: one self-contained HTML page of a run folder - figures embedded as PNG, tables, no links.

A run folder may hold any subset of what trafficgeo writes; every section whose inputs exist is included and the
page lists the ones left out, with the reason and the option that would add them. Files are found by name in the
folder, then in its sub-folders (then beside the camera JSON), unless given explicitly:

* calibration: ``camera.json`` (``--camera``) and the validation report ``report.json`` (``--calibration-report``);
  from them the per-GCP residuals, fit statistics, parameter uncertainty, warnings and recommendations, the
  residual vectors on a frame of the video and the GCPs, camera and footprint on the map;
* a frame to draw on: ``--frame``, a ``frame`` key of the camera JSON, ``frame.png``/``.jpg``, or a frame of the
  video named in a process run's ``process.json`` (or ``--video``, or a ``video.mp4`` in the folder);
* ``accuracy.tif`` (``trafficgeo accuracy``), or else the accuracy map computed from the camera JSON's covariance
  on the DEM (``dem.tif``, ``--dem``) or on the GCP plane; ``site.gpkg`` for the footprint;
* an orthophoto (``ortho.tif``, ``--ortho``) behind the plan views, reprojected on the fly when its CRS differs;
* traffic runs: every folder (the run folder or a sub-folder) with the outputs of ``analyze``/``process``
  (``summary.json`` with ``vehicles.csv``/``trajectories.csv``, ``counts.csv``, ``crossings.csv``, ``process.json``).

Units: pixels (px) in the image; positions in the CRS's units (m or ft) relative to a local origin on the plan
views; ground errors and distances in metres; speeds in km/h; times in seconds.
"""

from __future__ import annotations

import base64
import html
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from trafficgeo.errors import InputError
from trafficgeo.io.run_manifest import COMPARE_MANIFEST, MANIFEST, RunIncompleteError, verify_outputs
from trafficgeo.report import figures as F

CALIBRATION_REPORT_FORMAT = "trafficgeo.calibration-report/1"
CAMERA_NAMES = ("camera.json",)
REPORT_NAMES = ("report.json", "calibration_report.json", "calibration.json")
FRAME_NAMES = ("frame.png", "frame.jpg", "frame.jpeg")
FRAME_KEYS = ("frame", "frame_path", "frame_image")
VIDEO_NAMES = ("video.mp4", "video.mov", "video.mkv", "video.avi")
ORTHO_NAMES = ("ortho.tif", "ortho.tiff", "orthophoto.tif", "orthophoto.tiff", "ortho.vrt")
DEM_NAMES = ("dem.tif", "dem.tiff")
ACCURACY_NAMES = ("accuracy.tif",)
SITE_NAMES = ("site.gpkg",)
MAX_BACKGROUND_PX = 1100  # longer side of an orthophoto part behind a plan view (the figures are ~900 px wide)
MAX_FRAME_PX = 1400
COMPUTED_ACCURACY_CELLS = 200 * 200
TABLE_ROWS = 200

CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,Helvetica,Arial,sans-serif;margin:0 auto;max-width:1000px;
padding:0 1.2em 3em;color:#222;line-height:1.4}
h1{margin-bottom:.2em}h2{border-bottom:2px solid #ddd;padding-bottom:.2em;margin-top:2em}h3{margin-top:1.5em}
table{border-collapse:collapse;margin:.6em 0;font-size:.85em}th,td{border:1px solid #ccc;padding:.2em .5em}
th{background:#f2f2f2;text-align:left}td.n{text-align:right;font-variant-numeric:tabular-nums}
tr.outlier td{background:#fde0dd}tr.check td{background:#e0ecf4}
figure{margin:1em 0}figure img{max-width:100%;height:auto;border:1px solid #ddd}
figcaption{font-size:.85em;color:#444}.meta th{width:11em}.warn{color:#a50f15}.note{color:#555;font-size:.9em}
.summary{background:#f7f7f7;border-left:4px solid #2c7fb8;padding:.5em .8em}
ul.left-out li{margin:.2em 0}nav ul{columns:2}
"""


# ------------------------------------------------------------------------------------------------ inputs
@dataclass(frozen=True)
class TrafficRun:
    """An ``analyze``/``process`` output folder: its ``summary.json`` and, for process runs, ``process.json``."""

    folder: Path
    summary: dict[str, Any]
    process: dict[str, Any] | None = None
    compare: bool = False  # compare-sumo results are in the folder and match their manifest
    compare_problem: str | None = None  # why compare-sumo results in the folder are not used


@dataclass(frozen=True)
class ReportInputs:
    """The files a report is built from (None: not given and not found)."""

    run_dir: Path
    camera: Path | None = None
    calibration_report: Path | Mapping[str, Any] | None = None
    frame: Path | None = None
    frame_given: bool = False
    video: Path | None = None
    video_given: bool = False
    video_time_s: float = 0.0
    ortho: Path | None = None
    dem: Path | None = None
    accuracy: Path | None = None
    site: Path | None = None
    traffic: tuple[TrafficRun, ...] = ()

    @property
    def empty(self) -> bool:
        """True when there is nothing to report (no calibration, accuracy map or traffic run)."""
        return (self.camera is None and self.calibration_report is None and self.accuracy is None
                and not self.traffic)


@dataclass(frozen=True)
class ReportPage:
    """A built page: the HTML text, the section titles included, and (section, reason) for those left out."""

    html: str
    sections: tuple[str, ...]
    left_out: tuple[tuple[str, str], ...]


def _subfolders(folder: Path) -> list[Path]:
    try:
        return sorted(p for p in folder.iterdir() if p.is_dir() and not p.name.startswith("."))
    except OSError:
        return []


def _find(dirs: list[Path], names: tuple[str, ...]) -> Path | None:
    for d in dirs:
        for name in names:
            if (d / name).is_file():
                return d / name
    return None


def _given_file(path: str | Path | None, option: str, hint: str) -> Path | None:
    if path is None:
        return None
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{option} {p}: file not found; {hint}")
    return p


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{path}: not readable JSON ({' '.join(str(exc).split())}); write it again with "
                         "trafficgeo") from None


def _resolve(text: Any, bases: list[Path]) -> Path | None:
    """A path named in a JSON file: as given (absolute or from the working folder), else from ``bases`` (a
    ``process`` run stores its paths as typed, relative to the folder it ran in)."""
    if not isinstance(text, str) or not text:
        return None
    p = Path(text)
    if p.is_file():
        return p
    if not p.is_absolute():
        for b in bases:
            if (b / p).is_file():
                return b / p
    return None


def _traffic_runs(dirs: list[Path]) -> tuple[TrafficRun, ...]:
    runs = []
    for d in dirs:
        if (d / MANIFEST).is_file() or ((d / "summary.json").is_file() and (
                (d / "vehicles.csv").is_file() or (d / "trajectories.csv").is_file())):
            manifest = verify_outputs(d)  # refuses a half-written run or a mix of two runs' files
            if not manifest.has("summary.json"):
                continue
            summary = _read_json(d / "summary.json")
            if not isinstance(summary, dict):
                raise InputError(f"{d / 'summary.json'}: not a summary written by 'trafficgeo analyze'")
            process = _read_json(d / "process.json") if manifest.has("process.json") else None
            compare, problem = False, None
            if (d / "compare_counts.csv").is_file():
                try:
                    compare = verify_outputs(d, ("compare_counts.csv",), name=COMPARE_MANIFEST).has(
                        "compare_counts.csv")
                except RunIncompleteError:
                    problem = ("compare-sumo results incomplete or from an earlier run of this folder; run "
                               "'trafficgeo compare-sumo' again")
            runs.append(TrafficRun(d, summary, process if isinstance(process, dict) else None, compare, problem))
    return tuple(runs)


def find_inputs(run_dir: str | Path, *, camera: str | Path | None = None,
                calibration_report: str | Path | Mapping[str, Any] | None = None, frame: str | Path | None = None,
                ortho: str | Path | None = None, dem: str | Path | None = None,
                video: str | Path | None = None) -> ReportInputs:
    """The files of a run folder (see the module docstring); given paths override what is found.

    Raises:
        InputError: ``run_dir`` is not a folder, or a given file does not exist.
    """
    root = Path(run_dir)
    if not root.is_dir():
        raise InputError(f"{root}: not a folder; give the output folder of 'trafficgeo calibrate', 'analyze' or "
                         "'process'")
    dirs = [root, *_subfolders(root)]
    cam = _given_file(camera, "--camera", "give the camera JSON written by 'trafficgeo calibrate'") or \
        _find(dirs, CAMERA_NAMES)
    traffic = _traffic_runs(dirs)
    if cam is None:  # a process run names its camera
        for run in traffic:
            cam = _resolve((run.process or {}).get("camera"), [run.folder, root, run.folder.resolve().parent])
            if cam is not None:
                break
    extra = [cam.parent] if cam is not None and cam.parent.resolve() not in {d.resolve() for d in dirs} else []
    site_dirs = dirs + extra
    if isinstance(calibration_report, Mapping):
        rep: Path | Mapping[str, Any] | None = calibration_report
    else:
        rep = _given_file(calibration_report, "--calibration-report", "give the report JSON of 'trafficgeo "
                          "calibrate --report'")
        if rep is None:
            for d in site_dirs:
                found = _find([d], REPORT_NAMES)
                if found is not None and _is_calibration_report(found):
                    rep = found
                    break
    frame_path = _given_file(frame, "--frame", "give a PNG or JPEG of the video frame the GCPs were clicked on")
    frame_given = frame_path is not None
    if frame_path is None and cam is not None:
        doc = _read_json(cam)
        for key in FRAME_KEYS:
            frame_path = _resolve(doc.get(key) if isinstance(doc, dict) else None, [cam.parent])
            if frame_path is not None:
                break
    frame_path = frame_path or _find(site_dirs, FRAME_NAMES)
    video_path = _given_file(video, "--video", "give the video file")
    video_given = video_path is not None
    time_s = 0.0
    if video_path is None:
        for run in traffic:
            info = run.process or {}
            video_path = _resolve(info.get("video"), [run.folder, root, run.folder.resolve().parent])
            if video_path is not None:
                start = (info.get("options") or {}).get("start_s")
                time_s = float(start) if isinstance(start, int | float) and math.isfinite(start) else 0.0
                break
    video_path = video_path or _find(site_dirs, VIDEO_NAMES)
    ortho_path = _given_file(ortho, "--ortho", "give the orthophoto GeoTIFF") or _find(site_dirs, ORTHO_NAMES)
    dem_path = _given_file(dem, "--dem", "give the DEM GeoTIFF") or _find(site_dirs, DEM_NAMES)
    return ReportInputs(run_dir=root, camera=cam, calibration_report=rep, frame=frame_path, frame_given=frame_given,
                        video=video_path, video_given=video_given, video_time_s=time_s, ortho=ortho_path,
                        dem=dem_path, accuracy=_find(site_dirs, ACCURACY_NAMES), site=_find(site_dirs, SITE_NAMES),
                        traffic=traffic)


def _is_calibration_report(path: Path) -> bool:
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return False
    return isinstance(doc, dict) and doc.get("format") == CALIBRATION_REPORT_FORMAT


# ------------------------------------------------------------------------------------------------ html helpers
def _e(value: Any) -> str:
    return html.escape(str(value), quote=True)


def _num(value: Any, nd: int = 2) -> str:
    try:
        v = float(value)
    except (TypeError, ValueError):
        return "-"
    return "-" if not math.isfinite(v) else f"{v:.{nd}f}"


def _cell(value: Any) -> str:
    if isinstance(value, bool | np.bool_):
        return f"<td>{'yes' if value else 'no'}</td>"
    if isinstance(value, int | np.integer):
        return f'<td class="n">{int(value)}</td>'
    if isinstance(value, float | np.floating):
        return f'<td class="n">{_num(value)}</td>'
    if isinstance(value, tuple) and len(value) == 2 and isinstance(value[1], int):  # (number, decimals)
        return f'<td class="n">{_num(value[0], value[1])}</td>'
    return f"<td>{_e('' if value is None else value)}</td>"


def _table(columns: list[str], rows: list[list[Any]], *, row_classes: list[str] | None = None,
           caption: str | None = None) -> str:
    """An HTML table; every cell escaped; numbers right-aligned (``(value, decimals)`` picks the decimals)."""
    head = "".join(f"<th>{_e(c)}</th>" for c in columns)
    body = []
    for k, row in enumerate(rows):
        cls = f' class="{_e(row_classes[k])}"' if row_classes and row_classes[k] else ""
        body.append(f"<tr{cls}>" + "".join(_cell(v) for v in row) + "</tr>")
    cap = f"<caption>{_e(caption)}</caption>" if caption else ""
    return f"<table>{cap}<thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>"


def _figure(fig: Any, caption: str, dpi: int) -> str:
    png = F.figure_png(fig, dpi=dpi)
    data = base64.b64encode(png).decode("ascii")
    return (f'<figure><img src="data:image/png;base64,{data}" alt="{_e(caption)}">'
            f"<figcaption>{_e(caption)}</figcaption></figure>")


def _list(items: list[str], cls: str = "") -> str:
    if not items:
        return ""
    c = f' class="{cls}"' if cls else ""
    return f"<ul{c}>" + "".join(f"<li>{_e(i)}</li>" for i in items) + "</ul>"


# ------------------------------------------------------------------------------------------------ context
@dataclass
class _Build:
    """What the page's sections share while it is assembled (one per build: no module state)."""

    inputs: ReportInputs
    dpi: int
    crs: Any = None  # pyproj CRS or None
    m_per_unit: float = 1.0
    axes: F.MapAxes = field(default_factory=F.MapAxes)
    sections: list[tuple[str, str, str]] = field(default_factory=list)  # (anchor, title, html)
    left_out: list[tuple[str, str]] = field(default_factory=list)
    used: list[tuple[str, str]] = field(default_factory=list)  # (what, file) for the header
    camera: Any = None
    doc: dict[str, Any] | None = None
    report: dict[str, Any] | None = None
    gcps: pd.DataFrame | None = None
    grid: dict[str, Any] | None = None  # accuracy: values, bounds, source, raster
    footprint: Any = None
    ortho_note: str | None = None

    def skip(self, section: str, reason: str) -> None:
        self.left_out.append((section, reason))

    def background(self, xs: list[np.ndarray], ys: list[np.ndarray], section: str) -> F.Background | None:
        """The orthophoto around the given world coordinates (CRS units), or None (said once in the page)."""
        if self.inputs.ortho is None:
            self.skip("orthophoto behind the maps", "no orthophoto given or found (ortho.tif): pass --ortho with a "
                      "GeoTIFF of the site")
            return None
        x = np.concatenate([np.ravel(a) for a in xs]).astype(float)
        y = np.concatenate([np.ravel(a) for a in ys]).astype(float)
        ok = np.isfinite(x) & np.isfinite(y)
        if not ok.any():
            return None
        cx, cy = (x[ok].min() + x[ok].max()) / 2, (y[ok].min() + y[ok].max()) / 2
        half = 0.75 * max(np.ptp(x[ok]), np.ptp(y[ok]), 10.0 / self.m_per_unit) * 1.2
        bg = read_background(self.inputs.ortho, (cx - half, cy - half, cx + half, cy + half), self.crs)
        if bg is None:
            self.skip(f"orthophoto background ({section})", f"{self.inputs.ortho} does not cover this area")
        return bg


def read_background(path: Path, bounds: tuple[float, float, float, float], crs: Any,
                    max_px: int = MAX_BACKGROUND_PX) -> F.Background | None:
    """The part of an orthophoto within ``bounds`` (left, bottom, right, top; CRS units) as an RGBA image in 0..1,
    decimated to ``max_px`` on its longer side; reprojected to ``crs`` (and north up) when it is not already.
    None when it does not overlap. A file without a CRS is taken to be in ``crs``.

    Raises:
        InputError: the file is not a raster GDAL reads, or has no georeferencing.
    """
    from rasterio.enums import Resampling
    from rasterio.errors import RasterioError, WindowError
    from rasterio.vrt import WarpedVRT
    from rasterio.windows import Window, from_bounds

    from trafficgeo.crs import same_horizontal_crs

    src = _open_raster(path, "--ortho")
    with src:
        try:
            src_crs = _pyproj(src.crs)
            warp = (crs is not None and src_crs is not None and not same_horizontal_crs(src_crs, crs)) or \
                (src.transform.b != 0 or src.transform.d != 0)
            ds = WarpedVRT(src, crs=crs.to_wkt() if (crs is not None and src_crs is not None) else src.crs,
                           resampling=Resampling.bilinear) if warp else src
            try:
                full = Window(0, 0, ds.width, ds.height)
                try:
                    win = from_bounds(*bounds, transform=ds.transform).intersection(full)
                except WindowError:
                    return None
                c0, r0 = math.floor(win.col_off), math.floor(win.row_off)
                win = Window(c0, r0, math.ceil(win.col_off + win.width) - c0, math.ceil(win.row_off + win.height) - r0)
                if win.width < 1 or win.height < 1:
                    return None
                k = max(win.width, win.height) / max_px
                shape = (max(int(win.height / max(k, 1.0)), 1), max(int(win.width / max(k, 1.0)), 1))
                idx = [1, 2, 3] if ds.count >= 3 else [1]  # RGB(A), or grey (+ alpha): the alpha is the mask
                data = ds.read(idx, window=win, out_shape=(len(idx), *shape), resampling=Resampling.average,
                               masked=False)
                mask = ds.read_masks(1, window=win, out_shape=shape, resampling=Resampling.nearest)
                left, bottom, right, top = ds.window_bounds(win)
            finally:
                if ds is not src:
                    ds.close()
        except RasterioError as exc:
            raise InputError(f"--ortho {path}: could not be read ({' '.join(str(exc).split())}); check the "
                             "file") from None
    from trafficgeo.geo.raster import display_rgb

    img = display_rgb(data, mask > 0) / 255.0
    rgba = np.dstack([img, (mask > 0).astype(np.float64)])
    return F.Background(rgba, (float(left), float(bottom), float(right), float(top)))


def _pyproj(rio_crs: Any) -> Any:
    import pyproj

    return pyproj.CRS.from_wkt(rio_crs.to_wkt()) if rio_crs else None


def _open_raster(path: Path, option: str) -> Any:
    """Open a raster with rasterio; InputError (one line) when GDAL cannot read it or it has no georeferencing."""
    import warnings

    import rasterio
    from rasterio.errors import NotGeoreferencedWarning, RasterioError

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            ds = rasterio.open(path)
    except RasterioError as exc:
        reason = " ".join(str(exc).split())[:100]
        raise InputError(f"{option} {path}: not a raster GDAL can read ({reason}); give a GeoTIFF") from None
    if ds.transform.is_identity:
        gcps_only = bool(ds.gcps[0])
        ds.close()
        if gcps_only:
            raise InputError(f"{option} {path}: georeferenced only by ground control points, not a geotransform; "
                             "warp it first (gdalwarp in.tif out.tif)")
        raise InputError(f"{option} {path}: no georeferencing; give a GeoTIFF (or an image with a world file)")
    return ds


def _unit_name(crs: Any, m: float) -> str:
    """Short name of the CRS's horizontal unit: m, ft, US ft, or the name PROJ gives."""
    if crs is None:
        return "m"
    for name, factor in (("m", 1.0), ("ft", 0.3048), ("US ft", 1200.0 / 3937.0)):
        if abs(m - factor) < 1e-12:
            return name
    horizontal = crs.sub_crs_list[0] if crs.is_compound and crs.sub_crs_list else crs
    return str(horizontal.axis_info[0].unit_name)


# ------------------------------------------------------------------------------------------------ loading
def _load(b: _Build) -> None:
    """Camera, calibration report, GCP table, CRS and plan-view axes."""
    from trafficgeo.crs import crs_label, metres_per_unit, parse_crs

    inp = b.inputs
    if inp.camera is not None:
        from trafficgeo.camera.io import read_camera_document

        b.camera, b.doc = read_camera_document(inp.camera)
        b.used.append(("camera", str(inp.camera)))
    rep = inp.calibration_report
    if isinstance(rep, Path):
        doc = _read_json(rep)
        if not (isinstance(doc, dict) and doc.get("format") == CALIBRATION_REPORT_FORMAT):
            raise InputError(f"--calibration-report {rep}: not a calibration report (format "
                             f"{CALIBRATION_REPORT_FORMAT}); give the --report JSON of 'trafficgeo calibrate'")
        b.report = doc
        b.used.append(("calibration report", str(rep)))
    elif isinstance(rep, Mapping):
        b.report = dict(rep)
    crs_text = (b.camera.crs if b.camera is not None else None) or (b.report or {}).get("crs")
    if crs_text:
        b.crs = parse_crs(crs_text)
    else:
        for run in inp.traffic:
            if run.summary.get("crs"):
                import pyproj

                b.crs = pyproj.CRS.from_wkt(run.summary["crs"])
                break
    b.m_per_unit = metres_per_unit(b.crs)
    b.gcps = _gcp_table(b)
    ref = _reference_xy(b)
    origin = (math.floor(ref[0] / 100.0) * 100.0, math.floor(ref[1] / 100.0) * 100.0) if ref else (0.0, 0.0)
    b.axes = F.MapAxes(origin=origin, unit=_unit_name(b.crs, b.m_per_unit),
                       crs_label=crs_label(b.crs) if b.crs is not None else "local coordinates")
    if inp.ortho is not None:
        _open_raster(inp.ortho, "--ortho").close()  # unreadable: fail now, before any work
        b.used.append(("orthophoto", str(inp.ortho)))


def _reference_xy(b: _Build) -> tuple[float, float] | None:
    if b.camera is not None:
        return float(b.camera.position[0]), float(b.camera.position[1])
    if b.report is not None and b.report.get("camera", {}).get("position"):
        p = b.report["camera"]["position"]
        return float(p[0]), float(p[1])
    if b.gcps is not None and len(b.gcps):
        return float(b.gcps["x"].median()), float(b.gcps["y"].median())
    for run in b.inputs.traffic:
        p = run.folder / "crossings.csv"
        if p.is_file():
            c = pd.read_csv(p, usecols=lambda col: col in ("x", "y"))
            if len(c) and {"x", "y"} <= set(c.columns):
                return float(c["x"].median()), float(c["y"].median())
        p = run.folder / "trajectories.csv"
        if p.is_file():
            t = pd.read_csv(p, usecols=["x", "y"], nrows=10_000)
            if len(t):
                return float(t["x"].median()), float(t["y"].median())
    return None


def _gcp_table(b: _Build) -> pd.DataFrame | None:
    """Per-GCP rows from the report (or, lacking it, the camera JSON) with status, du/dv (px) and, with a camera,
    the ground residual vector gdx/gdy (CRS units) and ground error (m)."""
    rows = (b.report or {}).get("gcps") or (b.doc or {}).get("gcps") or []
    rows = [r for r in rows if isinstance(r, dict)]
    if not rows:
        return None
    g = pd.DataFrame(rows)
    for col in ("x", "y", "z", "u", "v", "u_proj", "v_proj", "error_px", "loo_error_px", "ground_error_m",
                "loo_ground_error_m"):
        g[col] = pd.to_numeric(g[col], errors="coerce") if col in g.columns else np.nan
    g["id"] = g["id"].astype(str) if "id" in g.columns else [f"#{k + 1}" for k in range(len(g))]
    g["role"] = g["role"].fillna("control").astype(str) if "role" in g.columns else "control"
    if "status" not in g.columns:
        inl = g["inlier"].fillna(True).astype(bool) if "inlier" in g.columns else True
        g["status"] = np.where(g["role"] == "check", "check", np.where(inl, "inlier", "outlier"))
    if "reason" not in g.columns:
        g["reason"] = ""
    g["reason"] = g["reason"].fillna("").astype(str)
    g["du"] = g["u_proj"] - g["u"]
    g["dv"] = g["v_proj"] - g["v"]
    if b.camera is not None:
        hit = b.camera.intersect_horizontal_plane(g[["u", "v"]].to_numpy(float), g["z"].to_numpy(float))
        g["gdx"] = hit[:, 0] - g["x"].to_numpy(float)
        g["gdy"] = hit[:, 1] - g["y"].to_numpy(float)
        ground = np.hypot(g["gdx"], g["gdy"]) * b.m_per_unit
        g["ground_error_m"] = g["ground_error_m"].fillna(pd.Series(ground, index=g.index))
    return g


# ------------------------------------------------------------------------------------------------ calibration
def _frame_image(b: _Build) -> np.ndarray | None:
    """The frame to draw the GCPs on, RGB (H, W, 3), decimated; None (and a note) when there is none."""
    import cv2

    inp = b.inputs
    size = tuple(b.camera.image_size) if b.camera is not None else tuple((b.report or {}).get("image_size", ()))
    section = "frame behind the GCP residuals"
    img, source = None, None
    if inp.frame is not None:
        img = cv2.imread(str(inp.frame), cv2.IMREAD_COLOR)
        if img is None:
            if inp.frame_given:
                raise InputError(f"--frame {inp.frame}: not an image OpenCV can read; give a PNG or JPEG")
            b.skip(section, f"{inp.frame} is not an image OpenCV can read: pass --frame")
        source = str(inp.frame)
    if img is None and inp.video is not None:
        from trafficgeo.video.reader import read_frame_at

        try:
            picked = read_frame_at(inp.video, inp.video_time_s)
            img, source = picked.image, f"{inp.video} at {picked.time_s:.2f} s"
        except InputError as exc:
            if inp.video_given:
                raise
            b.skip(section, f"the video could not be read ({exc}): pass --frame")
    if img is None:
        if inp.frame is None and inp.video is None:
            b.skip(section, "no frame image found (frame.png, a 'frame' key in the camera JSON, or the video of a "
                   "process run): pass --frame with the frame the GCPs were clicked on")
        return None
    h, w = img.shape[:2]
    if size and len(size) == 2 and abs(w / h - size[0] / size[1]) > 0.01:
        msg = f"{source} is {w}x{h} px but the camera's image is {size[0]}x{size[1]} px"
        if inp.frame_given or inp.video_given:
            raise InputError(f"{msg}; give a frame of this camera's video")
        b.skip(section, f"{msg}: pass --frame")
        return None
    b.used.append(("frame", source or ""))
    k = max(w, h) / MAX_FRAME_PX
    if k > 1:
        img = cv2.resize(img, (round(w / k), round(h / k)), interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(img[:, :, ::-1])


def _accuracy(b: _Build) -> None:
    """The accuracy grid: read from accuracy.tif, or computed from the camera covariance on the DEM or GCP plane."""
    inp = b.inputs
    if inp.accuracy is not None:
        from trafficgeo.geo.raster import read_raster

        r = read_raster(inp.accuracy)
        names = [d or "" for d in r.descriptions]
        band = names.index("radial_m") if "radial_m" in names else 0
        values = r.data[band].astype(np.float64)
        if r.nodata is not None and math.isfinite(r.nodata):
            values[values == r.nodata] = np.nan
        b.grid = {"values": values, "bounds": r.bounds, "raster": r, "band": band,
                  "source": f"{inp.accuracy} (band {names[band] or band + 1})", "transform": r.transform}
        b.used.append(("accuracy map", str(inp.accuracy)))
        return
    if b.camera is None or not (b.doc or {}).get("covariance"):
        why = ("no camera JSON" if b.camera is None else "the camera JSON has no covariance (write it with "
               "'trafficgeo calibrate')")
        if b.camera is not None or b.report is not None:
            b.skip("accuracy map", f"no accuracy.tif and {why}: run 'trafficgeo accuracy CAMERA --surface DEM -o "
                   "accuracy.tif' into the folder")
        return
    from trafficgeo.geo.load import load_surface
    from trafficgeo.geo.mapping import camera_crs
    from trafficgeo.geo.raster import GeoRaster
    from trafficgeo.geo.uncertainty import CameraCovariance, accuracy_grid

    spec = str(inp.dem) if inp.dem is not None else "plane"
    try:
        surf = load_surface(spec, b.camera, b.doc, where=str(inp.camera))
        grid = accuracy_grid(b.camera, surf, CameraCovariance.from_document(b.doc, b.camera), pixel_sigma=1.0,
                             max_distance_m=250.0, max_cells=COMPUTED_ACCURACY_CELLS)
    except InputError as exc:
        if inp.dem is not None:
            raise
        b.skip("accuracy map", f"no accuracy.tif, and none could be computed on the GCP plane ({exc}): pass --dem")
        return
    if inp.dem is not None:
        b.used.append(("DEM", str(inp.dem)))
    r = GeoRaster(grid.bands, grid.transform, camera_crs(b.camera), float("nan"), grid.band_names)
    b.grid = {"values": grid.bands[0].astype(np.float64), "bounds": r.bounds, "raster": r, "band": 0,
              "source": f"computed here from the camera JSON's covariance on "
                        f"{'the DEM ' + inp.dem.name if inp.dem is not None else 'the GCP plane'} (1 px pixel "
                        "noise, within 250 m; run 'trafficgeo accuracy' for a finer map)",
              "transform": grid.transform}


def _footprint(b: _Build) -> None:
    inp = b.inputs
    if inp.site is not None:
        import pyogrio

        from trafficgeo.io.gis import read_gis

        try:
            layers = set(pyogrio.list_layers(inp.site)[:, 0])
        except Exception as exc:  # pyogrio raises several types for unreadable files
            raise InputError(f"{inp.site}: not a GeoPackage GDAL can read ({' '.join(str(exc).split())[:80]})") \
                from None
        if "footprint" in layers:
            g = read_gis(inp.site, layer="footprint")
            if len(g):
                if g.crs is not None and b.crs is not None:
                    g = g.to_crs(b.crs)
                b.footprint = g.geometry.iloc[0]
                b.used.append(("site layers", str(inp.site)))
                return
    if b.grid is not None:
        from trafficgeo.geo.uncertainty import GroundGrid, footprint_polygon

        r = b.grid["raster"]
        res = r.resolution[0]
        visible = np.isfinite(b.grid["values"])
        b.footprint = footprint_polygon(GroundGrid(r.transform, b.crs, visible, r.data, (), res))


def _calibration_section(b: _Build) -> None:
    rep, doc, g = b.report, b.doc or {}, b.gcps
    if rep is None and b.camera is None:
        b.skip("calibration", "no camera.json or calibration report.json found: pass --camera / --calibration-report "
               "(the outputs of 'trafficgeo calibrate')")
        return
    parts: list[str] = []
    if rep is not None and rep.get("summary"):
        parts.append(f'<p class="summary">{_e(rep["summary"])}</p>')
    elif rep is None:
        b.skip("calibration report tables (leave-one-out ground errors, check points, warnings)",
               "no calibration report.json found: pass --calibration-report (calibrate --report)")
    parts.append(_camera_table(b))
    if rep is not None:
        parts.append("<h3>Fit statistics</h3>" + _stats_table(rep, b))
    elif doc.get("stats"):
        s = doc["stats"]
        parts.append("<h3>Fit statistics</h3>" + _table(["quantity", "value", "unit"], [
            ["control points / inliers", f"{s.get('n_control', '-')} / {s.get('n_inliers', '-')}", ""],
            ["mean residual", s.get("mean_px"), "px"], ["RMSE", s.get("rmse_px"), "px"],
            ["leave-one-out RMSE", s.get("loo_rmse_px"), "px"]]))
    unc = (rep or {}).get("uncertainty") or doc.get("uncertainty")
    if unc:
        parts.append("<h3>Parameter uncertainty</h3>" + _uncertainty_table(unc, rep))
    if rep is not None:
        if rep.get("outliers"):
            parts.append("<h3>Outliers</h3>" + _list([f"{o['id']}: {o['reason']}" for o in rep["outliers"]], "warn"))
        if rep.get("warnings"):
            parts.append("<h3>Warnings</h3>" + _list([str(w) for w in rep["warnings"]], "warn"))
        if rep.get("recommendations"):
            parts.append("<h3>Recommendations</h3>" + _list([str(r) for r in rep["recommendations"]]))
    b.sections.append(("calibration", "Calibration", "\n".join(parts)))

    if g is None:
        b.skip("GCP figures and table", "the calibration lists no GCPs")
        return
    size = tuple(b.camera.image_size) if b.camera is not None else tuple(rep["image_size"])  # type: ignore[index]
    figs: list[str] = []
    image = _frame_image(b)
    ok = np.isfinite(g["u"]) & np.isfinite(g["v"])
    figs.append(_figure(F.residuals_on_frame(g[ok], size, image),
                        "GCPs where they were clicked, with their residual vectors (projected survey point minus "
                        "clicked pixel, px) magnified by the factor in the title; red crosses are outliers left "
                        "out of the fit, blue squares check points.", b.dpi))
    cam_xy, heading = None, None
    if b.camera is not None:
        cam_xy, heading = (float(b.camera.position[0]), float(b.camera.position[1])), b.camera.orientation.heading_deg
    elif rep is not None:
        p = rep["camera"]["position"]
        cam_xy, heading = (float(p[0]), float(p[1])), float(rep["camera"]["orientation"]["heading_deg"])
    xs = [g["x"].to_numpy(float)] + ([np.array([cam_xy[0]])] if cam_xy else [])
    ys = [g["y"].to_numpy(float)] + ([np.array([cam_xy[1]])] if cam_xy else [])
    for part in F.geometry_parts(b.footprint):
        fx, fy = np.asarray(part.exterior.coords).T[:2]
        xs.append(fx)
        ys.append(fy)
    if b.footprint is None:
        b.skip("camera footprint on the GCP map", "no site.gpkg and no accuracy map: pass --dem (or run 'trafficgeo "
               "accuracy ... --gis site.gpkg')")
    bg = b.background(xs, ys, "GCP map")
    figs.append(_figure(F.gcps_on_map(g, b.axes, camera_xy=cam_xy, heading_deg=heading, footprint=b.footprint,
                                      background=bg),
                        f"GCPs at their surveyed positions, the camera (triangle, arrow: viewing direction) and the "
                        f"ground it sees (footprint). Arrows: where each clicked pixel's ray meets the point's "
                        f"elevation, minus the survey point (magnified). Axes in {b.axes.unit} from the local "
                        "origin.", b.dpi))
    figs.append(_figure(F.residual_histograms(g),
                        "Fit residuals and leave-one-out errors of the inlier GCPs, in the image (px) and on the "
                        "ground (m). The leave-one-out error (the camera fitted without that point) is the honest "
                        "error to expect for a new point.", b.dpi))
    b.sections.append(("gcps", "GCPs and residuals", "\n".join(figs) + _gcp_residual_table(b)))


def _camera_table(b: _Build) -> str:
    rep, doc = b.report or {}, b.doc or {}
    unc = rep.get("uncertainty") or doc.get("uncertainty") or {}
    ps = unc.get("position_std_m") or [float("nan")] * 3
    os_ = unc.get("orientation_std_deg") or {}
    if b.camera is not None:
        pos, o, f = b.camera.position, b.camera.orientation.to_dict(), b.camera.focal_px
        dist, size = b.camera.dist, b.camera.image_size
    else:
        c = rep["camera"]
        pos, o, f, dist, size = c["position"], c["orientation"], c["focal_px"], c["dist"], rep["image_size"]
    u = b.axes.unit
    rows = [
        ["position X, Y, Z", ", ".join(_num(v, 3) for v in pos), u, ", ".join(_num(v, 2) for v in ps) + " m"],
        ["heading (clockwise from grid north)", (o["heading_deg"], 2), "deg", _num(os_.get("heading"), 3) + " deg"],
        ["tilt (below the horizon)", (o["tilt_deg"], 2), "deg", _num(os_.get("tilt"), 3) + " deg"],
        ["roll", (o["roll_deg"], 2), "deg", _num(os_.get("roll"), 3) + " deg"],
        ["focal length", (f, 1), "px", _num(unc.get("focal_std_px"), 1) + " px"],
        ["k1, k2", f"{_num(dist[0], 4)}, {_num(dist[1], 4)}", "", ""],
        ["image size", f"{size[0]} x {size[1]}", "px", ""],
    ]
    model = rep.get("model") or doc.get("model") or {}
    desc = model.get("description") or ", ".join(model.get("free_parameters") or [])
    if desc:
        rows.append(["free parameters", desc, "", ""])
    reasons = _list([str(r) for r in model.get("reasons") or []], "note")
    return "<h3>Camera</h3>" + _table(["quantity", "value", "unit", "1-sigma"], rows) + reasons


def _stats_table(rep: dict[str, Any], b: _Build) -> str:
    s, c, d = rep.get("stats", {}), rep.get("check", {}), rep.get("distance_ratios", {})
    rows = [
        ["control points / inliers / outliers", f"{s.get('n_control')} / {s.get('n_inliers')} / "
                                                f"{s.get('n_outliers')}", ""],
        ["mean / RMSE / max residual (inliers)",
         f"{_num(s.get('mean_px'))} / {_num(s.get('rmse_px'))} / {_num(s.get('max_px'))}", "px"],
        ["sigma0 (1 = residuals match the stated noise)", (s.get("sigma0"), 2), ""],
        ["redundancy (observations - parameters)", s.get("redundancy"), ""],
        ["leave-one-out RMSE", (s.get("loo_rmse_px"), 2), "px"],
        ["leave-one-out ground error: RMSE / median", f"{_num(s.get('loo_ground_rmse_m'), 3)} / "
                                                      f"{_num(s.get('loo_ground_median_m'), 3)}", "m"],
    ]
    if c.get("n"):
        rows += [["check points (not in the fit)", c["n"], ""],
                 ["check points: RMSE / max", f"{_num(c.get('rmse_px'))} / {_num(c.get('max_px'))}", "px"],
                 ["check points: ground RMSE", (c.get("ground_rmse_m"), 3), "m"]]
    if d.get("n_pairs"):
        rows.append([f"distance ratio error (eq. 15, {d['n_pairs']} pairs): mean / median / max",
                     f"{_num(d.get('mean_pct'))} / {_num(d.get('median_pct'))} / {_num(d.get('max_pct'))}", "%"])
    p = rep.get("pose_consistency", {})
    if p.get("available"):
        sp, ang = p["position_spread_m"], p["angle_spread_deg"]
        rows += [[f"pose spread over {p['n_fits']} leave-one-out fits: X, Y, Z",
                  ", ".join(_num(v, 3) for v in sp), "m"],
                 ["pose spread: heading, tilt, roll", ", ".join(_num(ang[k], 3) for k in ("heading", "tilt", "roll")),
                  "deg"],
                 [f"largest camera shift (without {p.get('most_influential_gcp')})",
                  (p.get("max_position_deviation_m"), 3), "m"]]
    if b.grid is not None and b.gcps is not None and "predicted_m" in b.gcps.columns:
        inl = b.gcps[b.gcps["status"] == "inlier"]
        rows.append(["predicted 1-sigma ground error at the inlier GCPs (accuracy map), median",
                     (float(np.nanmedian(inl["predicted_m"])) if inl["predicted_m"].notna().any() else float("nan"),
                      3), "m"])
    return _table(["quantity", "value", "unit"], rows)


def _uncertainty_table(unc: dict[str, Any], rep: dict[str, Any] | None) -> str:
    params = unc.get("parameters") or {}
    rows = []
    for name, p in params.items():
        v, s = p.get("value"), p.get("std")
        rel = abs(s / v) * 100 if isinstance(v, int | float) and isinstance(s, int | float) and v else float("nan")
        rows.append([name, (v, 6), (s, 6), (rel, 2)])
    out = ""
    if rows:
        out += _table(["parameter", "value", "1-sigma", "1-sigma / |value| (%)"], rows,
                      caption="free parameters (rotation vector rad; translation in CRS units; focal px; distortion "
                              "unitless); from the fit covariance" + (", scaled by sigma0^2"
                                                                      if unc.get("scaled_by_variance_factor") else ""))
    high = unc.get("high_correlations") or []
    if high:
        out += _list([f"parameters {h['a']} and {h['b']} are {abs(h['correlation']):.3f} correlated" for h in high],
                     "warn")
    if not params:
        out += '<p class="note">Only the propagated 1-sigma of position, angles and focal length are stored in the ' \
               "camera JSON (see the camera table); the per-parameter table needs the calibration report.</p>"
    return out


def _gcp_residual_table(b: _Build) -> str:
    g = b.gcps
    assert g is not None
    has_pred = "predicted_m" in g.columns
    cols = ["id", "role", "status", "u", "v", "du", "dv", "|e| px", "LOO px", "ground m", "LOO ground m"]
    cols += ["predicted 1-sigma m"] if has_pred else []
    cols += ["outlier / reason"]
    rows, classes = [], []
    for r in g.to_dict("records"):
        row = [r["id"], r["role"], r["status"], (r["u"], 1), (r["v"], 1), (r["du"], 2), (r["dv"], 2),
               (r["error_px"], 2), (r["loo_error_px"], 2), (r["ground_error_m"], 3), (r["loo_ground_error_m"], 3)]
        if has_pred:
            row.append((r["predicted_m"], 3))
        row.append(("OUTLIER: " if r["status"] == "outlier" else "") + r["reason"])
        rows.append(row)
        classes.append(r["status"] if r["status"] in ("outlier", "check") else "")
    note = ('<p class="note">du, dv: projected minus clicked (px). Ground: horizontal distance (m) from the '
            "surveyed X, Y to where the clicked pixel's ray meets the point's elevation; LOO: with the camera fitted "
            "without the point."
            + (" Predicted 1-sigma: the accuracy map at the point (calibration covariance and 1 px pixel noise), "
               "to compare with the leave-one-out ground error." if has_pred else "") + "</p>")
    return "<h3>Per-GCP residuals</h3>" + _table(cols, rows, row_classes=classes) + note


def _accuracy_section(b: _Build) -> None:
    if b.grid is None:
        return
    values, bounds = b.grid["values"], b.grid["bounds"]
    left, bottom, right, top = bounds
    cam_xy = (float(b.camera.position[0]), float(b.camera.position[1])) if b.camera is not None else None
    gxy = b.gcps[["x", "y"]].to_numpy(float) if b.gcps is not None else None
    xs = [np.array([left, right])] + ([np.array([cam_xy[0]])] if cam_xy else [])
    ys = [np.array([bottom, top])] + ([np.array([cam_xy[1]])] if cam_xy else [])
    bg = b.background(xs, ys, "accuracy map")
    finite = values[np.isfinite(values)]
    text = [f"Source: {b.grid['source']}."]
    if finite.size:
        text.append(f"Over the visible ground the expected 1-sigma horizontal error ranges from {finite.min():.2f} m "
                    f"to {finite.max():.2f} m (median {np.median(finite):.2f} m).")
    if b.gcps is not None and "predicted_m" in b.gcps.columns and b.report is not None:
        s = b.report.get("stats", {})
        inl = b.gcps[b.gcps["status"] == "inlier"]
        if inl["predicted_m"].notna().any():
            text.append(f"At the inlier GCPs it predicts {np.nanmedian(inl['predicted_m']):.3f} m (median); the "
                        f"leave-one-out ground error measured there is {_num(s.get('loo_ground_median_m'), 3)} m "
                        f"(median), RMSE {_num(s.get('loo_ground_rmse_m'), 3)} m.")
        c = b.report.get("check", {})
        if c.get("n"):
            text.append(f"Check points, never used in the fit: ground RMSE {_num(c.get('ground_rmse_m'), 3)} m.")
    fig = F.accuracy_map(values, bounds, b.axes, background=bg, camera_xy=cam_xy, gcps_xy=gxy)
    html_ = "<p>" + _e(" ".join(text)) + "</p>" + _figure(
        fig, "Expected 1-sigma horizontal ground error (m) of a point seen by the camera: calibration uncertainty "
             "and pixel noise carried through the ray-surface intersection; contours in metres.", b.dpi)
    b.sections.append(("accuracy", "Accuracy map", html_))


def _predicted_at_gcps(b: _Build) -> None:
    if b.grid is None or b.gcps is None:
        return
    r = b.grid["raster"]
    b.gcps["predicted_m"] = r.sample_bilinear(b.gcps["x"].to_numpy(float), b.gcps["y"].to_numpy(float),
                                              band=b.grid["band"])


# ------------------------------------------------------------------------------------------------ traffic
def _read_table(path: Path, text_cols: tuple[str, ...] = ("track_id", "class", "lane", "line", "source_track")
                ) -> pd.DataFrame | None:
    if not path.is_file():
        return None
    try:
        t = pd.read_csv(path, dtype={c: str for c in text_cols}, keep_default_na=False, na_values=[""])
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not a table trafficgeo wrote ({' '.join(str(exc).split())[:80]}); run the "
                         "command again") from None
    for c in text_cols:
        if c in t.columns:
            t[c] = t[c].fillna("").astype(str)
    return t


def _layout(folder: Path, crs: Any) -> tuple[list[tuple[str, Any]], list[tuple[str, Any]]]:
    gpkg = folder / "trajectories.gpkg"
    if not gpkg.is_file():
        return [], []
    import pyogrio

    from trafficgeo.io.gis import read_gis

    names = set(pyogrio.list_layers(gpkg)[:, 0])
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


def _traffic_section(b: _Build, run: TrafficRun, k: int) -> None:
    rel = run.folder.relative_to(b.inputs.run_dir) if run.folder != b.inputs.run_dir else Path(".")
    name = "." if str(rel) == "." else str(rel)
    kind = "process" if run.process is not None else "analyze"
    title = f"Traffic: {name}" if len(b.inputs.traffic) > 1 or name != "." else "Traffic"
    points = _read_table(run.folder / "trajectories.csv")
    vehicles = _read_table(run.folder / "vehicles.csv")
    counts = _read_table(run.folder / "counts.csv")
    crossings = _read_table(run.folder / "crossings.csv")
    s = run.summary
    b.used.append((f"traffic run ({kind})", str(run.folder)))
    parts = [_run_summary(run, s)]
    lanes, lines = _layout(run.folder, b.crs)
    speed_range = None
    if points is not None and len(points):
        sp = points["speed_kmh"].to_numpy(float)
        sp = sp[np.isfinite(sp)]
        speed_range = (0.0, max(float(np.percentile(sp, 98)) if sp.size else 1.0, 1.0))
        xs = [points["x"].to_numpy(float)] + [np.asarray(g.coords)[:, 0] for _, g in lines]
        ys = [points["y"].to_numpy(float)] + [np.asarray(g.coords)[:, 1] for _, g in lines]
        bg = b.background(xs, ys, f"trajectories, {name}")
        parts.append(_figure(F.trajectories_map(points, b.axes, background=bg, lanes=lanes, lines=lines,
                                                speed_range=speed_range),
                             f"World trajectories (smoothed footprint centres) coloured by speed (km/h), with the "
                             f"lanes and counting lines used. Axes in {b.axes.unit} from the local origin.", b.dpi))
        parts.append(_figure(F.time_space_diagram(points, metres_per_unit=b.m_per_unit, speed_range=speed_range),
                             "Time-space diagram: distance along the road (m, measured on a reference line through "
                             "the middle of all trajectories) against time (s), coloured by speed (km/h), one panel "
                             "per direction of travel.", b.dpi))
    else:
        b.skip(f"trajectories map and time-space diagram ({name})", "no trajectory points (trajectories.csv missing "
               "or empty)")
    if not lanes:
        b.skip(f"lanes ({name})", "the run has no lanes: pass --lanes to analyze/process for per-lane results")
    if vehicles is not None and len(vehicles) and _speed_columns(vehicles)[0] in vehicles.columns:
        parts.append(_figure(F.speed_histograms(vehicles, column=_speed_columns(vehicles)[0]),
                             "Distribution of the vehicles' speeds (distance travelled along the direction of travel "
                             "over the time seen, km/h) per main lane; dashed: median.", b.dpi))
        parts.append("<h3>Vehicles</h3>" + _vehicle_tables(vehicles))
    else:
        b.skip(f"speed histograms and vehicle tables ({name})", "no vehicles (vehicles.csv missing or empty)")
    if counts is not None and len(counts):
        parts.append(_figure(F.counts_over_time(counts), "Vehicles counted per interval at each counting line, per "
                             "lane and direction (+1: crossing from left to right looking along the line).", b.dpi))
    else:
        b.skip(f"counts per lane over time ({name})", "no counts (no counting lines, or nobody crossed them): pass "
               "--lines to analyze/process")
    if crossings is not None and len(crossings):
        parts.append("<h3>Counts and speeds per line and lane</h3>" + _crossing_table(crossings, s))
    if counts is not None and len(counts):
        parts.append(_counts_table(counts))
    compare = _read_table(run.folder / "compare_counts.csv") if run.compare else None
    if compare is not None and len(compare):
        parts.append(_comparison(b, run, compare))
    elif run.compare_problem is not None:
        b.skip(f"observed against simulated ({name})", run.compare_problem)
    if run.process is not None:
        parts.append("<h3>Video processing</h3>" + _process_table(run.process))
    b.sections.append((f"traffic-{k}", title, "\n".join(parts)))


def _comparison(b: _Build, run: TrafficRun, compare: pd.DataFrame) -> str:
    """The ``compare-sumo`` results of a run: GEH of the counts, the flows figure, and speeds per line and lane."""
    doc = _read_json(run.folder / "compare_summary.json") if (run.folder / "compare_summary.json").is_file() else {}
    counts = doc.get("counts", {}) if isinstance(doc, dict) else {}
    head = ""
    if counts:
        head = (f'<p>{_e(counts.get("rows", len(compare)))} counts (line, lane, direction, interval): '
                f'{_num(100.0 * float(counts.get("share_geh_below_5", float("nan"))), 1)} % with GEH &lt; 5 '
                f'(the usual acceptance target is 85 %); observed {_e(counts.get("total_observed", ""))} vehicles, '
                f'simulated {_e(counts.get("total_simulated", ""))}.</p>')
    fig = _figure(F.observed_vs_simulated(compare), "Observed against simulated hourly flows per line, lane, "
                  "direction and interval (veh/h); grey: where the GEH statistic is below 5.", b.dpi)
    cols = [("line", "line"), ("lane", "lane"), ("direction", "direction"), ("interval_start", "from s"),
            ("interval_end", "to s"), ("observed", "observed"), ("simulated", "simulated"), ("geh", "GEH")]
    cols = [(c, label) for c, label in cols if c in compare.columns]
    rows, classes = [], []
    for d in compare.head(TABLE_ROWS).to_dict("records"):
        rows.append([d[c] if c in ("line", "lane") else (f"{int(d[c]):+d}" if c == "direction" else
                     (int(d[c]) if c in ("observed", "simulated") else (d[c], 2 if c == "geh" else 1)))
                     for c, _ in cols])
        classes.append("outlier" if float(d.get("geh", 0.0)) >= 5.0 else "")
    table = _table([label for _, label in cols], rows, row_classes=classes)
    speeds = _read_table(run.folder / "compare_speeds.csv")
    speed_table = ""
    if speeds is not None and len(speeds):
        scols = [("line", "line"), ("lane", "lane"), ("observed_n", "observed n"),
                 ("observed_mean_kmh", "observed mean km/h"), ("simulated_n", "simulated n"),
                 ("simulated_mean_kmh", "simulated mean km/h"), ("mean_difference_kmh", "difference km/h"),
                 ("ks_statistic", "KS distance"), ("ks_pvalue", "KS p")]
        scols = [(c, label) for c, label in scols if c in speeds.columns]
        srows = [[d[c] if c in ("line", "lane") else (int(d[c]) if c.endswith("_n") and np.isfinite(d[c]) else
                  (d[c], 2)) for c, _ in scols] for d in speeds.head(TABLE_ROWS).to_dict("records")]
        speed_table = "<h4>Spot speeds at the lines, observed vs simulated</h4>" + _table(
            [label for _, label in scols], srows)
    return "<h3>Observed vs simulated (compare-sumo)</h3>" + head + fig + table + speed_table


def _run_summary(run: TrafficRun, s: dict[str, Any]) -> str:
    period = s.get("period_s") or [float("nan"), float("nan")]
    dropped = ", ".join(f"{k} {v}" for k, v in (s.get("dropped_points") or {}).items()) or "none"
    classes = ", ".join(f"{k or 'unknown'} {v}" for k, v in (s.get("classes") or {}).items()) or "-"
    opts = s.get("options") or {}
    rows = [["folder", str(run.folder), ""],
            ["observed period", f"{_num(period[0])} to {_num(period[1])}", "s"],
            ["vehicles", s.get("vehicles"), ""], ["classes", classes, ""],
            ["track points / rejected as outliers", f"{s.get('points')} / {s.get('outlier_points')}", ""],
            ["points not used, by reason", dropped, ""],
            ["mean of the vehicles' speeds (distance travelled / time seen)", (s.get("mean_speed_kmh"), 1),
             "km/h"],
            ["lane changes", s.get("lane_changes"), ""]]
    for key, label, unit in (("interval_s", "counting interval", "s"), ("pixel_sigma", "pixel noise of a track point",
                                                                         "px"),
                             ("max_metres_per_px", "points farther than this many metres per pixel not used", "m")):
        if key in opts:
            rows.append([label, opts[key], unit])
    out = _table(["quantity", "value", "unit"], rows)
    warns = s.get("warnings") or []
    return out + (_list([str(w) for w in warns], "warn") if warns else "")


def _q(a: np.ndarray, q: float) -> float:
    a = a[np.isfinite(a)]
    return float(np.percentile(a, q)) if a.size else float("nan")


def _speed_columns(v: pd.DataFrame) -> tuple[str, str]:
    """The vehicles' speed column and its 1-sigma: ``speed_kmh``, or ``mean_speed_kmh`` in runs written before
    ``speed_kmh`` existed."""
    return ("speed_kmh", "speed_std_kmh") if "speed_kmh" in v.columns else ("mean_speed_kmh", "mean_speed_std_kmh")


def _vehicle_tables(v: pd.DataFrame) -> str:
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
    out = _table(["class", "vehicles", "median speed km/h", "mean speed km/h", "15th pct km/h", "85th pct km/h",
                  "median speed 1-sigma km/h", "median length m", "median length 1-sigma m", "median time seen s",
                  "median path m"], rows, caption="per class: each vehicle's speed is its distance travelled over the "
                  "time seen")
    if "lane" in v.columns:
        rows = []
        for lane, g in v.groupby(v["lane"].replace("", "(none)"), sort=True):
            sp = col(g, speed)
            rows.append([lane, len(g), (_q(sp, 50), 1), (_q(sp, 15), 1), (_q(sp, 85), 1),
                         (_q(col(g, speed_std), 50), 2),
                         int(g["lane_changes"].sum()) if "lane_changes" in g.columns else "-"])
        out += _table(["main lane", "vehicles", "median speed km/h", "15th pct km/h", "85th pct km/h",
                       "median speed 1-sigma km/h", "lane changes"], rows, caption="per main lane")
    return out


def _crossing_table(c: pd.DataFrame, s: dict[str, Any]) -> str:
    period = s.get("period_s") or [0.0, 0.0]
    dur = max(float(period[1]) - float(period[0]), 1e-9)
    rows = []
    for (line, lane, direction), g in c.groupby(["line", "lane", "direction"], sort=True):
        sp = g["speed_kmh"].to_numpy(float)
        ok = sp[np.isfinite(sp) & (sp > 0)]
        t = np.sort(g["time"].to_numpy(float))
        rows.append([line, lane or "-", f"{int(direction):+d}", len(g), (len(g) * 3600.0 / dur, 0),
                     (float(ok.mean()) if ok.size else np.nan, 1),
                     (float(ok.size / np.sum(1.0 / ok)) if ok.size else np.nan, 1), (_q(ok, 85), 1),
                     (float(np.diff(t).mean()) if t.size > 1 else np.nan, 1)])
    return _table(["line", "lane", "direction", "vehicles", "flow veh/h", "time-mean speed km/h",
                   "space-mean speed km/h", "85th pct speed km/h", "mean headway s"], rows,
                  caption=f"all crossings over the observed {dur:.1f} s (spot speeds at the line)")


def _counts_table(counts: pd.DataFrame) -> str:
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
    note = (f'<p class="note">first {TABLE_ROWS} of {len(counts)} rows; all are in counts.csv</p>'
            if len(counts) > TABLE_ROWS else "")
    return "<h3>Counts per interval</h3>" + _table([label for _, label in cols], rows) + note


def _process_table(p: dict[str, Any]) -> str:
    opts = p.get("options") or {}
    rows = [["video", p.get("video", "-"), ""], ["detector", opts.get("detector", "-"), ""],
            ["start / end", f"{opts.get('start_s', '-')} / {opts.get('end_s') or 'end'}", "s"],
            ["every n-th frame", opts.get("every", "-"), ""], ["detections", p.get("detections", "-"), ""],
            ["track boxes", p.get("track_rows", "-"), ""], ["processing time", (p.get("seconds"), 1), "s"]]
    detector = p.get("detector")
    tiling = detector.get("tiling") if isinstance(detector, dict) else None
    warns: list[str] = []
    if isinstance(tiling, dict):
        tiles = tiling.get("tiles") or []
        rows.append(["detector passes per frame (full frame + tiles over the far road)",
                     tiling.get("passes_per_frame", len(tiles) + 1), ""])
        rows.append(["size a car must reach in the detector's input", tiling.get("min_size_px", "-"), "px"])
        warns = [str(w) for w in tiling.get("warnings") or []]
    return _table(["quantity", "value", "unit"], rows) + (_list(warns, "warn") if warns else "")


# ------------------------------------------------------------------------------------------------ page
def _header(b: _Build) -> str:
    from trafficgeo import __version__
    from trafficgeo.crs import crs_label

    unit = b.axes.unit if b.m_per_unit == 1.0 else f"{b.axes.unit} (1 {b.axes.unit} = {b.m_per_unit:.10g} m)"
    crs = (f"{crs_label(b.crs)}; units {unit}; ground errors and distances in m, speeds in km/h"
           if b.crs is not None else "none (local coordinates, taken as metres)")
    rows = [["run folder", str(b.inputs.run_dir.resolve())],
            ["created", datetime.now().astimezone().isoformat(timespec="seconds")],
            ["trafficgeo version", __version__], ["CRS", crs],
            ["plan-view origin", f"easting {b.axes.origin[0]:.0f}, northing {b.axes.origin[1]:.0f} ({b.axes.unit})"]]
    rows += [[f"input: {what}", path] for what, path in b.used]
    body = "".join(f"<tr><th>{_e(k)}</th><td>{_e(v)}</td></tr>" for k, v in rows)
    return f'<h1>trafficgeo report</h1><table class="meta"><tbody>{body}</tbody></table>'



def build_page(run_dir: str | Path, *, camera: str | Path | None = None,
               calibration_report: str | Path | Mapping[str, Any] | None = None, frame: str | Path | None = None,
               ortho: str | Path | None = None, dem: str | Path | None = None, video: str | Path | None = None,
               dpi: int = 100) -> ReportPage:
    """The page with its list of sections and of those left out (see :func:`build_report`)."""
    inputs = find_inputs(run_dir, camera=camera, calibration_report=calibration_report, frame=frame, ortho=ortho,
                         dem=dem, video=video)
    if inputs.empty:
        raise InputError(f"{inputs.run_dir}: nothing to report: no camera.json, calibration report.json, "
                         "accuracy.tif or analyze/process outputs (summary.json with vehicles.csv) in it or its "
                         "sub-folders; give such a folder, or --camera / --calibration-report")
    b = _Build(inputs=inputs, dpi=dpi)
    _load(b)
    _accuracy(b)
    _footprint(b)
    _predicted_at_gcps(b)
    _calibration_section(b)
    _accuracy_section(b)
    if not inputs.traffic:
        b.skip("traffic", "no analyze/process outputs (summary.json with vehicles.csv / trajectories.csv) in the "
               "folder or its sub-folders: run 'trafficgeo analyze' or 'process' with --out in it")
    for k, run in enumerate(inputs.traffic):
        _traffic_section(b, run, k + 1)
    left = list(dict.fromkeys(b.left_out))
    nav = "<nav><ul>" + "".join(f'<li><a href="#{a}">{_e(t)}</a></li>' for a, t, _ in b.sections) + \
        '<li><a href="#left-out">Left out</a></li></ul></nav>'
    body = "\n".join(f'<section id="{a}"><h2>{_e(t)}</h2>\n{h}</section>' for a, t, h in b.sections)
    left_html = ('<section id="left-out"><h2>Left out</h2>'
                 + (_list([f"{s}: {r}" for s, r in left], "left-out") if left else "<p>Nothing: every section "
                    "had its inputs.</p>") + "</section>")
    title = f"trafficgeo report: {inputs.run_dir.resolve().name}"
    page = (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
            f'<meta name="viewport" content="width=device-width, initial-scale=1"><title>{_e(title)}</title>'
            f"<style>{CSS}</style></head><body>\n{_header(b)}\n{nav}\n{body}\n{left_html}\n</body></html>\n")
    return ReportPage(page, tuple(t for _, t, _ in b.sections), tuple(left))


def build_report(run_dir: str | Path, *, camera: str | Path | None = None,
                 calibration_report: str | Path | Mapping[str, Any] | None = None, frame: str | Path | None = None,
                 ortho: str | Path | None = None, dem: str | Path | None = None, video: str | Path | None = None,
                 dpi: int = 100) -> str:
    """One self-contained HTML page (figures as base64 PNG, inline CSS, no links out) of what ``run_dir`` holds.

    ``calibration_report`` may be the report dictionary itself. Files not given are looked for by name (module
    docstring).

    Raises:
        InputError: ``run_dir`` is not a folder, there is nothing to report, or an input cannot be read.
    """
    return build_page(run_dir, camera=camera, calibration_report=calibration_report, frame=frame, ortho=ortho,
                      dem=dem, video=video, dpi=dpi).html


def write_report_html(path: str | Path, run_dir: str | Path, **options: Any) -> ReportPage:
    """Build the page (:func:`build_page`, same options) and write it to ``path`` atomically; nothing is written
    when building fails."""
    from trafficgeo.io.atomic import write_text_atomic

    page = build_page(run_dir, **options)
    write_text_atomic(path, page.html)
    return page
