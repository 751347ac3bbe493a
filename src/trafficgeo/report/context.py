"""What the sections of a report share, loaded once per page: the camera and calibration report, the GCP table,
the CRS and plan-view axes, the accuracy grid and the camera footprint; and the images drawn behind the figures
(the orthophoto around a plan view, the video frame behind the GCPs).

Units: positions in the CRS's units (m or ft); ground errors in metres; image positions in pixels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from trafficgeo.calibration.report import CalibrationReport, gcp_row, read_calibration_report
from trafficgeo.camera.calibrated import CalibratedCamera
from trafficgeo.errors import InputError
from trafficgeo.report import figures as F
from trafficgeo.report.inputs import ReportInputs

MAX_BACKGROUND_PX = 1800  # longest side of an orthophoto part behind a plan view; decimated by an integer factor,
#                           so at least 900 px, the width of the figures
MAX_FRAME_PX = 1400
COMPUTED_ACCURACY_CELLS = 200 * 200


@dataclass(frozen=True)
class AccuracyGrid:
    """The accuracy map: 1-sigma horizontal ground error (m) per cell of ``raster`` (band ``band``), NaN where the
    camera does not see the ground; ``source`` says where it comes from."""

    values: np.ndarray
    bounds: tuple[float, float, float, float]
    raster: Any  # trafficgeo.geo.raster.GeoRaster
    band: int
    source: str


@dataclass
class ReportContext:
    """What the page's sections share while it is assembled (one per build: no module state)."""

    inputs: ReportInputs
    dpi: int
    crs: Any = None  # pyproj CRS or None
    m_per_unit: float = 1.0
    axes: F.MapAxes = field(default_factory=F.MapAxes)
    left_out: list[tuple[str, str]] = field(default_factory=list)
    used: list[tuple[str, str]] = field(default_factory=list)  # (what, file) for the header
    camera: Any = None  # the Camera of ``calibrated``
    calibrated: CalibratedCamera | None = None
    report: CalibrationReport | None = None
    gcps: pd.DataFrame | None = None
    grid: AccuracyGrid | None = None
    footprint: Any = None

    def skip(self, section: str, reason: str) -> None:
        """Note a section (or part of one) left out of the page, and why."""
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
    decimated to at most ``max_px`` on its longer side; reprojected to ``crs`` (and north up) when it is not
    already. None when it does not overlap. A file without a CRS is taken to be in ``crs``.

    Raises:
        InputError: the file is not a raster GDAL reads, or has no georeferencing.
    """
    from trafficgeo.geo.raster_display import display_rgb, read_display

    try:
        shown = read_display(path, max_px, bounds=bounds, crs=crs, north_up=True, what="ortho")
    except InputError as exc:
        raise InputError(str(exc), parameters=("ortho",)) from None
    if shown is None:
        return None
    img = display_rgb(shown.data, shown.valid) / 255.0
    rgba = np.dstack([img, shown.valid.astype(np.float64)])
    return F.Background(rgba, shown.bounds)


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
def load_context(inputs: ReportInputs, dpi: int) -> ReportContext:
    """Read what the sections share (camera, calibration report, GCPs, CRS and axes, accuracy grid, footprint).

    Raises:
        InputError: an input cannot be read.
    """
    b = ReportContext(inputs=inputs, dpi=dpi)
    _load(b)
    _accuracy(b)
    _footprint(b)
    _predicted_at_gcps(b)
    return b


def _load(b: ReportContext) -> None:
    """Camera, calibration report, GCP table, CRS and plan-view axes."""
    from trafficgeo.crs import crs_label, metres_per_unit, parse_crs

    inp = b.inputs
    if inp.camera is not None:
        b.calibrated = inp.calibrated if inp.calibrated is not None else CalibratedCamera.read(inp.camera)
        b.camera = b.calibrated.camera
        b.used.append(("camera", str(inp.camera)))
    rep = inp.calibration_report
    if isinstance(rep, Path):
        b.report = read_calibration_report(rep, "calibration_report")
        b.used.append(("calibration report", str(rep)))
    elif isinstance(rep, CalibrationReport):
        b.report = rep
    crs_text = (b.camera.crs if b.camera is not None else None) or (b.report.crs if b.report is not None else None)
    if crs_text:
        b.crs = parse_crs(crs_text)
    else:
        for run in inp.traffic:
            if run.summary.crs:
                import pyproj

                b.crs = pyproj.CRS.from_wkt(run.summary.crs)
                break
    b.m_per_unit = metres_per_unit(b.crs)
    b.gcps = _gcp_table(b)
    ref = _reference_xy(b)
    origin = (math.floor(ref[0] / 100.0) * 100.0, math.floor(ref[1] / 100.0) * 100.0) if ref else (0.0, 0.0)
    b.axes = F.MapAxes(origin=origin, unit=_unit_name(b.crs, b.m_per_unit),
                       crs_label=crs_label(b.crs) if b.crs is not None else "local coordinates")
    if inp.ortho is not None:
        from trafficgeo.geo.raster import open_raster

        try:
            open_raster(inp.ortho, "ortho")[0].close()  # unreadable: fail now, before any work
        except InputError as exc:
            raise InputError(str(exc), parameters=("ortho",)) from None
        b.used.append(("orthophoto", str(inp.ortho)))


def _reference_xy(b: ReportContext) -> tuple[float, float] | None:
    if b.camera is not None:
        return float(b.camera.position[0]), float(b.camera.position[1])
    if b.report is not None:
        p = b.report.camera.position
        return float(p[0]), float(p[1])
    if b.gcps is not None and len(b.gcps):
        return float(b.gcps["x"].median()), float(b.gcps["y"].median())
    for run in b.inputs.traffic:  # read through the run's RunFolder: its schema and manifest checked
        for name in ("crossings.csv", "trajectories.csv"):
            if not run.run.has(name):
                continue
            t = run.run.table(name, required=())
            if len(t) and {"x", "y"} <= set(t.columns):
                x, y = t["x"].to_numpy(float), t["y"].to_numpy(float)
                ok = np.isfinite(x) & np.isfinite(y)
                if ok.any():
                    return float(np.median(x[ok])), float(np.median(y[ok]))
    return None


def _gcp_table(b: ReportContext) -> pd.DataFrame | None:
    """Per-GCP rows (report.json's layout, :func:`~trafficgeo.calibration.report.gcp_row`) from the report (or,
    lacking it, the camera JSON) and, with a camera, the ground residual vector gdx/gdy (CRS units) and the ground
    error (m) where the file has none."""
    rows = b.report.gcps if b.report is not None and b.report.gcps else \
        (b.calibrated.gcps if b.calibrated is not None else None) or ()
    if not rows:
        return None
    g = pd.DataFrame([gcp_row(r) for r in rows])  # one record of a GCP, from either file
    if b.camera is not None:
        hit = b.camera.intersect_horizontal_plane(g[["u", "v"]].to_numpy(float), g["z"].to_numpy(float))
        g["gdx"] = hit[:, 0] - g["x"].to_numpy(float)
        g["gdy"] = hit[:, 1] - g["y"].to_numpy(float)
        ground = np.hypot(g["gdx"], g["gdy"]) * b.m_per_unit
        g["ground_error_m"] = g["ground_error_m"].fillna(pd.Series(ground, index=g.index))
    return g


# ------------------------------------------------------------------------------------------------ frame
def frame_image(b: ReportContext) -> np.ndarray | None:
    """The frame to draw the GCPs on, RGB (H, W, 3), decimated; None (and a note) when there is none."""
    import cv2

    inp = b.inputs
    size = (tuple(b.camera.image_size) if b.camera is not None
            else tuple(b.report.image_size) if b.report is not None else ())
    section = "frame behind the GCP residuals"
    img, source = None, None
    if inp.frame is not None:
        img = cv2.imread(str(inp.frame), cv2.IMREAD_COLOR)
        if img is None:
            if inp.frame_given:
                raise InputError(f"frame {inp.frame}: not an image OpenCV can read; give a PNG or JPEG",
                                 parameters=("frame",))
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


def _accuracy(b: ReportContext) -> None:
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
        b.grid = AccuracyGrid(values, r.bounds, r, band, f"{inp.accuracy} (band {names[band] or band + 1})")
        b.used.append(("accuracy map", str(inp.accuracy)))
        return
    if b.calibrated is None or b.calibrated.covariance is None:
        why = ("no camera JSON" if b.camera is None else "the camera JSON has no covariance (write it with "
               "'trafficgeo calibrate')")
        if b.camera is not None or b.report is not None:
            b.skip("accuracy map", f"no accuracy.tif and {why}: run 'trafficgeo accuracy CAMERA --surface DEM -o "
                   "accuracy.tif' into the folder")
        return
    from trafficgeo.geo.mapping import camera_crs
    from trafficgeo.geo.raster import GeoRaster
    from trafficgeo.geo.uncertainty import accuracy_grid
    from trafficgeo.site.surface import load_surface

    spec = str(inp.dem) if inp.dem is not None else "plane"
    try:
        surf = load_surface(spec, b.calibrated)
        grid = accuracy_grid(b.camera, surf, b.calibrated.covariance, pixel_sigma=1.0,
                             max_distance_m=250.0, max_cells=COMPUTED_ACCURACY_CELLS)
    except InputError as exc:
        if inp.dem is not None:
            raise
        b.skip("accuracy map", f"no accuracy.tif, and none could be computed on the GCP plane ({exc}): pass --dem")
        return
    if inp.dem is not None:
        b.used.append(("DEM", str(inp.dem)))
    r = GeoRaster(grid.bands, grid.transform, camera_crs(b.camera), float("nan"), grid.band_names)
    b.grid = AccuracyGrid(grid.bands[0].astype(np.float64), r.bounds, r, 0,
                          f"computed here from the camera JSON's covariance on "
                          f"{'the DEM ' + inp.dem.name if inp.dem is not None else 'the GCP plane'} (1 px pixel "
                          "noise, within 250 m; run 'trafficgeo accuracy' for a finer map)")


def _footprint(b: ReportContext) -> None:
    inp = b.inputs
    if inp.site is not None:
        from trafficgeo.io.gis import gis_layers, read_gis

        layers = set(gis_layers(inp.site))
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

        r = b.grid.raster
        res = r.resolution[0]
        visible = np.isfinite(b.grid.values)
        b.footprint = footprint_polygon(GroundGrid(r.transform, b.crs, visible, r.data, (), res))


def _predicted_at_gcps(b: ReportContext) -> None:
    if b.grid is None or b.gcps is None:
        return
    r = b.grid.raster
    b.gcps["predicted_m"] = r.sample_bilinear(b.gcps["x"].to_numpy(float), b.gcps["y"].to_numpy(float),
                                              band=b.grid.band)

