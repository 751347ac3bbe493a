"""Matplotlib figures of a calibration and a traffic run, one function per figure, for the HTML report.

Every function takes plain data (DataFrames, arrays, shapely geometries) and returns a
:class:`matplotlib.figure.Figure` drawn on its own Agg canvas: no pyplot, no global backend or figure registry,
so nothing needs closing and nothing leaks between calls. Conventions:

* **Image figures** use pixels with (0, 0) the centre of the top-left pixel and v down (the camera module's).
* **Plan views** use the world CRS's projected axes relative to a local origin (:class:`MapAxes`), in the CRS's
  own units (m or ft), so coordinates of 5e6 keep their precision and the tick labels stay short.
* **Speeds** are km/h, distances along the road m, times s (the traffic tables' units).

Artists that carry the data have a ``gid`` (``"residuals"``, ``"trajectories"``, ``"time-space"`` ...), so tests
and callers can find them.
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

STATUS_STYLE = {  # GCP status -> (colour, marker, label)
    "inlier": ("#1a9850", "o", "inlier (control)"),
    "outlier": ("#d73027", "X", "outlier (excluded)"),
    "check": ("#2c7fb8", "s", "check point (not in the fit)"),
}
SPEED_CMAP = "viridis"
ERROR_CMAP = "magma_r"


@dataclass(frozen=True)
class MapAxes:
    """How plan views are labelled: world ``x - origin[0]``, ``y - origin[1]`` in ``unit`` (the CRS's unit)."""

    origin: tuple[float, float] = (0.0, 0.0)
    unit: str = "m"
    crs_label: str = ""

    def local(self, x: Any, y: Any) -> tuple[np.ndarray, np.ndarray]:
        """World x, y (CRS units) -> local plot coordinates (CRS units from the origin)."""
        return (np.asarray(x, dtype=np.float64) - self.origin[0], np.asarray(y, dtype=np.float64) - self.origin[1])

    def label(self, ax: Any) -> None:
        """Axis labels naming the origin, the unit and the CRS; equal scale on both axes."""
        x0, y0 = self.origin
        ax.set_xlabel(f"easting - {x0:.0f} ({self.unit})")
        ax.set_ylabel(f"northing - {y0:.0f} ({self.unit})")
        ax.set_aspect("equal", adjustable="box")
        if self.crs_label:
            ax.text(0.99, 0.01, self.crs_label, transform=ax.transAxes, ha="right", va="bottom", fontsize=7,
                    color="0.2", bbox={"facecolor": "white", "alpha": 0.7, "lw": 0, "pad": 1.5})


@dataclass(frozen=True)
class Background:
    """A map image (an orthophoto's part): ``image`` (rows, cols, 3 or 4) RGB(A) in 0..1 covering ``bounds``
    ``(left, bottom, right, top)`` in CRS units, north up."""

    image: np.ndarray
    bounds: tuple[float, float, float, float]



def frame_axes(ax, w: int, h: int) -> None:
    """Axes in frame pixels (u right, v down; pixel (0, 0) centred on the top-left pixel), equal aspect, labelled."""
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    ax.set_aspect("equal")
    ax.set_xlabel("u (px)")
    ax.set_ylabel("v (px)")

def new_figure(width_in: float, height_in: float, nrows: int = 1, ncols: int = 1,
               **subplot_kw: Any) -> tuple[Any, np.ndarray]:
    """A figure on its own Agg canvas (the backend is chosen here, per figure) and its (nrows, ncols) axes."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(nrows, ncols, squeeze=False, **subplot_kw)
    return fig, axes


def figure_png(fig: Any, dpi: int = 100) -> bytes:
    """The figure as PNG bytes; the figure is cleared afterwards to free its memory."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    fig.clear()
    return buf.getvalue()


def _nice(value: float) -> float:
    """The nearest of 1, 2, 5 x 10^k at or below ``value`` (at least 1)."""
    if not value > 1 or not math.isfinite(value):
        return 1.0
    k = 10 ** math.floor(math.log10(value))
    return float(max(m * k for m in (1, 2, 5) if m * k <= value))


def _status(frame: pd.DataFrame) -> np.ndarray:
    return frame["status"].astype(str).to_numpy() if "status" in frame.columns else np.full(len(frame), "inlier")


def draw_background(ax: Any, background: Background | None, axes: MapAxes) -> None:
    """Draw ``background`` (if any) under a plan view in ``axes``' local coordinates."""
    if background is None:
        return
    left, bottom, right, top = background.bounds
    ax.imshow(background.image, extent=(left - axes.origin[0], right - axes.origin[0], bottom - axes.origin[1],
                                        top - axes.origin[1]), origin="upper", interpolation="bilinear", zorder=0)


def set_extent(ax: Any, x: np.ndarray, y: np.ndarray, margin: float = 0.08) -> None:
    """Limits around the finite ``x, y`` with ``margin`` of the larger extent on every side."""
    ok = np.isfinite(x) & np.isfinite(y)
    if not ok.any():
        return
    x0, x1, y0, y1 = x[ok].min(), x[ok].max(), y[ok].min(), y[ok].max()
    pad = max(x1 - x0, y1 - y0, 1.0) * margin
    ax.set_xlim(x0 - pad, x1 + pad)
    ax.set_ylim(y0 - pad, y1 + pad)


def seen_frame(x: np.ndarray, y: np.ndarray, lines: list[tuple[str, Any]] | None = None, *,
               reach: float = 0.25) -> tuple[np.ndarray, np.ndarray]:
    """The x, y a map of trajectories is framed on: the ground where vehicles were seen (their points' 0.5-99.5
    percentile box, so a few stray far points do not shrink the rest), and the counting lines only as far as they
    reach into it (a line drawn across the whole road, beyond a run's ROI or view, would leave the map half blank);
    ``reach`` is how far beyond the box (a share of its size) the lines still count. Without points: the lines."""
    import shapely

    ok = np.isfinite(x) & np.isfinite(y)
    geoms = [g for _, g in lines or []]
    if not ok.any():
        xs = [np.asarray(g.coords)[:, 0] for g in geoms]
        ys = [np.asarray(g.coords)[:, 1] for g in geoms]
        return (np.concatenate(xs), np.concatenate(ys)) if xs else (np.zeros(0), np.zeros(0))
    x0, x1 = np.percentile(x[ok], [0.5, 99.5])
    y0, y1 = np.percentile(y[ok], [0.5, 99.5])
    pad = reach * max(x1 - x0, y1 - y0, 1.0)
    box = shapely.box(x0 - pad, y0 - pad, x1 + pad, y1 + pad)
    xs, ys = [np.array([x0, x1])], [np.array([y0, y1])]
    for g in geoms:
        part = g.intersection(box)
        if not part.is_empty:
            b = part.bounds
            xs.append(np.array([b[0], b[2]]))
            ys.append(np.array([b[1], b[3]]))
    return np.concatenate(xs), np.concatenate(ys)


def geometry_parts(geom: Any) -> list[Any]:
    """The polygons/lines of a (multi-part) shapely geometry; none for None or an empty one."""
    if geom is None or getattr(geom, "is_empty", True):
        return []
    return list(getattr(geom, "geoms", [geom]))


# ------------------------------------------------------------------------------------------------ calibration
def _status_markers(ax: Any, x: np.ndarray, y: np.ndarray, status: np.ndarray, *, size: float,
                    zorder: int) -> None:
    """GCP markers styled by status (control inlier, outlier, check), each with its count in the legend."""
    for s, (colour, marker, label) in STATUS_STYLE.items():
        sel = status == s
        if sel.any():
            ax.scatter(x[sel], y[sel], s=size, c=colour, marker=marker, edgecolors="white", linewidths=0.6,
                       label=f"{label} ({int(sel.sum())})", zorder=zorder)


def residuals_on_frame(gcps: pd.DataFrame, image_size: tuple[int, int], image: np.ndarray | None = None, *,
                       scale: float | None = None) -> Any:
    """GCPs where they were clicked in the frame, with their residual vectors (projected - clicked, px).

    ``gcps`` needs ``u, v, du, dv`` (px) and optionally ``id`` and ``status`` (inlier / outlier / check). The
    arrows are magnified by ``scale`` (default: a round factor that makes the median inlier arrow about 4 % of the
    frame width); ``image`` (H, W, 3) RGB is drawn behind them, stretched over the frame when its size differs.
    One quiver (gid ``"residuals"``) holds one arrow per GCP.
    """
    w, h = image_size
    fig, axs = new_figure(9.0, 9.0 * h / w + 0.9)
    ax = axs[0, 0]
    if image is not None:
        ax.imshow(image, extent=(-0.5, w - 0.5, h - 0.5, -0.5), interpolation="bilinear")
    else:
        ax.add_patch(rectangle_patch((-0.5, -0.5), w, h))
    u, v = gcps["u"].to_numpy(float), gcps["v"].to_numpy(float)
    du, dv = gcps["du"].to_numpy(float), gcps["dv"].to_numpy(float)
    status = _status(gcps)
    err = np.hypot(du, dv)
    if scale is None:
        ref = err[(status == "inlier") & np.isfinite(err)]
        ref = ref if ref.size else err[np.isfinite(err)]
        scale = _nice(0.04 * w / max(float(np.median(ref)), 1e-3)) if ref.size else 1.0
    colours = [STATUS_STYLE.get(s, STATUS_STYLE["inlier"])[0] for s in status]
    q = ax.quiver(u, v, np.nan_to_num(du) * scale, np.nan_to_num(dv) * scale, color=colours, angles="xy",
                  scale_units="xy", scale=1.0, width=0.003, headwidth=4, zorder=3)
    q.set_gid("residuals")
    _status_markers(ax, u, v, status, size=28, zorder=4)
    if "id" in gcps.columns and len(gcps) <= 80:
        for name, x, y in zip(gcps["id"].astype(str), u, v, strict=True):
            ax.annotate(name, (x, y), xytext=(4, 4), textcoords="offset points", fontsize=6, color="white",
                        bbox={"facecolor": "black", "alpha": 0.45, "lw": 0, "pad": 0.8}, zorder=5)
    frame_axes(ax, w, h)
    ax.set_title(f"GCP residuals in the frame ({w}x{h} px): arrows x{scale:g}, from the clicked pixel towards the "
                 "projected survey point", fontsize=9)
    ax.legend(loc="lower right", fontsize=7, framealpha=0.8)
    return fig


def rectangle_patch(xy: tuple[float, float], w: float, h: float) -> Any:
    from matplotlib.patches import Rectangle

    return Rectangle(xy, w, h, facecolor="0.93", edgecolor="0.4", linewidth=1.0, zorder=0)


def gcps_on_map(gcps: pd.DataFrame, axes: MapAxes, *, camera_xy: tuple[float, float] | None = None,
                heading_deg: float | None = None, footprint: Any = None, background: Background | None = None,
                scale: float | None = None) -> Any:
    """GCPs on the map (surveyed x, y in CRS units) with the camera position, its viewing direction and the
    visible-ground footprint; optional ground residual vectors.

    ``gcps`` needs ``x, y`` and optionally ``id``, ``status`` and ``gdx, gdy`` (CRS units: where the clicked
    pixel's ray meets the point's elevation, minus the surveyed point), drawn magnified by ``scale`` (default: a
    round factor making the median inlier vector 3 % of the plot's size) as a quiver with gid ``"ground-residuals"``.
    """
    fig, axs = new_figure(9.0, 7.5)
    ax = axs[0, 0]
    draw_background(ax, background, axes)
    x, y = axes.local(gcps["x"], gcps["y"])
    status = _status(gcps)
    ex, ey = [x], [y]
    for part in geometry_parts(footprint):
        fx, fy = axes.local(*np.asarray(part.exterior.coords).T[:2])
        ax.fill(fx, fy, facecolor="#ffffbf", alpha=0.25, edgecolor="#fdae61", linewidth=1.5, zorder=1)
        ex.append(fx)
        ey.append(fy)
    if geometry_parts(footprint):
        ax.plot([], [], color="#fdae61", linewidth=1.5, label="visible ground (footprint)")
    if camera_xy is not None:
        cx, cy = axes.local(camera_xy[0], camera_xy[1])
        ax.scatter([cx], [cy], s=120, marker="^", c="black", edgecolors="white", linewidths=1.0, zorder=6,
                   label="camera")
        ex.append(np.atleast_1d(cx))
        ey.append(np.atleast_1d(cy))
        if heading_deg is not None and math.isfinite(heading_deg):
            span = max(np.ptp(np.concatenate(ex)), np.ptp(np.concatenate(ey)), 10.0)
            h = math.radians(heading_deg)
            ax.annotate("", xy=(cx + 0.15 * span * math.sin(h), cy + 0.15 * span * math.cos(h)), xytext=(cx, cy),
                        arrowprops={"arrowstyle": "->", "color": "black", "lw": 1.5}, zorder=6)
    if {"gdx", "gdy"} <= set(gcps.columns):
        gdx, gdy = gcps["gdx"].to_numpy(float), gcps["gdy"].to_numpy(float)
        if scale is None:
            size = np.hypot(gdx, gdy)
            ref = size[(status == "inlier") & np.isfinite(size)]
            span = max(np.ptp(np.concatenate(ex)), np.ptp(np.concatenate(ey)), 1.0)
            scale = _nice(0.03 * span / max(float(np.median(ref)), 1e-6)) if ref.size else 1.0
        q = ax.quiver(x, y, np.nan_to_num(gdx) * scale, np.nan_to_num(gdy) * scale, angles="xy", scale_units="xy",
                      scale=1.0, width=0.003, color=[STATUS_STYLE.get(s, STATUS_STYLE["inlier"])[0] for s in status],
                      zorder=4)
        q.set_gid("ground-residuals")
        ax.plot([], [], color="0.3", label=f"ground residual x{scale:g} (clicked pixel's ray - survey)")
    _status_markers(ax, x, y, status, size=30, zorder=5)
    if "id" in gcps.columns and len(gcps) <= 80:
        for name, px, py in zip(gcps["id"].astype(str), x, y, strict=True):
            ax.annotate(name, (px, py), xytext=(4, 3), textcoords="offset points", fontsize=6, zorder=7)
    set_extent(ax, np.concatenate(ex), np.concatenate(ey))
    axes.label(ax)
    ax.set_title("GCPs, camera and visible ground on the map", fontsize=9)
    ax.legend(loc="upper left", fontsize=7, framealpha=0.8)
    return fig


def residual_histograms(gcps: pd.DataFrame) -> Any:
    """Histograms of the fit residuals and leave-one-out errors of the inlier GCPs: in the image (px) and on the
    ground (m). Check points, never in the fit, are marked below each axis. Bars have gid ``"fit"`` / ``"loo"``."""
    fig, axs = new_figure(9.0, 3.6, 1, 2)
    status = _status(gcps)
    inl = status == "inlier"
    chk = status == "check"
    for ax, (fit_col, loo_col, unit) in zip(axs[0], (("error_px", "loo_error_px", "px"),
                                                     ("ground_error_m", "loo_ground_error_m", "m")), strict=True):
        fit = gcps[fit_col].to_numpy(float)[inl] if fit_col in gcps.columns else np.zeros(0)
        loo = gcps[loo_col].to_numpy(float)[inl] if loo_col in gcps.columns else np.zeros(0)
        fit, loo = fit[np.isfinite(fit)], loo[np.isfinite(loo)]
        both = np.concatenate([fit, loo])
        if not both.size:
            ax.text(0.5, 0.5, f"no {unit} errors in the input", transform=ax.transAxes, ha="center")
            ax.set_axis_off()
            continue
        bins = np.linspace(0.0, max(float(both.max()), 1e-6) * 1.05, 16)
        for values, label, colour, gid in ((fit, "fit residual", "#1a9850", "fit"),
                                           (loo, "leave-one-out", "#7570b3", "loo")):
            if values.size:
                _, _, patches = ax.hist(values, bins=bins, alpha=0.6, color=colour,
                                        label=f"{label} (RMS {np.sqrt(np.mean(values ** 2)):.2f} {unit})")
                for p in patches:
                    p.set_gid(gid)
        chk_col = gcps[fit_col].to_numpy(float)[chk] if fit_col in gcps.columns else np.zeros(0)
        chk_col = chk_col[np.isfinite(chk_col)]
        if chk_col.size:
            ax.plot(chk_col, np.zeros(chk_col.size), "|", color=STATUS_STYLE["check"][0], markersize=14, mew=2,
                    label=f"check points ({chk_col.size})", clip_on=False)
        ax.set_xlabel(f"error ({unit})")
        ax.set_ylabel("GCPs")
        ax.legend(fontsize=7)
        ax.set_title("in the image" if unit == "px" else "on the ground (horizontal)", fontsize=9)
    return fig


def accuracy_map(values: np.ndarray, bounds: tuple[float, float, float, float], axes: MapAxes, *,
                 background: Background | None = None, camera_xy: tuple[float, float] | None = None,
                 gcps_xy: np.ndarray | None = None, label: str = "1-sigma horizontal error (m)") -> Any:
    """A north-up error grid ``values`` (rows, cols; NaN where not seen) covering ``bounds`` (CRS units, left,
    bottom, right, top) with contours, over an optional orthophoto; the image has gid ``"accuracy"``."""
    fig, axs = new_figure(9.0, 7.5)
    ax = axs[0, 0]
    draw_background(ax, background, axes)
    x0, y0 = (float(v) for v in axes.local(bounds[0], bounds[1]))
    x1, y1 = (float(v) for v in axes.local(bounds[2], bounds[3]))
    from matplotlib.colors import LogNorm

    data = np.ma.masked_invalid(np.asarray(values, dtype=np.float64))
    finite = data.compressed()
    finite = finite[finite > 0]
    lo = max(float(np.percentile(finite, 1)), 1e-3) if finite.size else 0.01
    hi = max(float(np.percentile(finite, 99)), lo * 1.01) if finite.size else 1.0
    im = ax.imshow(data, extent=(x0, x1, y0, y1), origin="upper", cmap=ERROR_CMAP, norm=LogNorm(lo, hi, clip=True),
                   alpha=0.75 if background is not None else 1.0, interpolation="nearest", zorder=1)
    im.set_gid("accuracy")
    bar = fig.colorbar(im, ax=ax, label=label + ", log scale", shrink=0.85)
    ticks = [t for t in (0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1, 2, 5, 10, 20, 50, 100) if lo <= t <= hi]
    if ticks:
        bar.set_ticks(ticks, labels=[f"{t:g}" for t in ticks])
        bar.ax.minorticks_off()
    levels = [lv for lv in (0.05, 0.1, 0.25, 0.5, 1.0, 2.0, 5.0, 10.0) if lo < lv < hi]
    if levels:
        rows, cols = data.shape
        xs = x0 + (np.arange(cols) + 0.5) * (x1 - x0) / cols
        ys = y1 - (np.arange(rows) + 0.5) * (y1 - y0) / rows
        cs = ax.contour(xs, ys, smooth_log(np.asarray(values, dtype=np.float64), max(3, round(max(rows, cols) / 50))),
                        levels=levels, colors="black", linewidths=0.6, zorder=2)
        ax.clabel(cs, fmt=lambda v: f"{v:g} m", fontsize=7)
    ex, ey = [np.array([x0, x1])], [np.array([y0, y1])]
    if gcps_xy is not None and len(gcps_xy):
        gx, gy = axes.local(gcps_xy[:, 0], gcps_xy[:, 1])
        ax.scatter(gx, gy, s=14, c="#1a9850", edgecolors="white", linewidths=0.5, zorder=3, label="GCPs")
    if camera_xy is not None:
        cx, cy = axes.local(camera_xy[0], camera_xy[1])
        ax.scatter([cx], [cy], s=100, marker="^", c="black", edgecolors="white", zorder=4, label="camera")
        ex.append(np.atleast_1d(cx))
        ey.append(np.atleast_1d(cy))
    set_extent(ax, np.concatenate(ex), np.concatenate(ey), margin=0.03)
    axes.label(ax)
    if gcps_xy is not None or camera_xy is not None:
        ax.legend(loc="upper left", fontsize=7, framealpha=0.8)
    ax.set_title("Expected ground error of a point seen by the camera", fontsize=9)
    return fig


def smooth_log(values: np.ndarray, size: int) -> np.ndarray:
    """A ``size`` x ``size`` moving geometric mean of positive ``values`` ignoring NaN (NaN where the input is, or
    where under a third of the window has data): contours of a rough error map (a lidar DEM's grass at grazing
    incidence) that can be read."""
    from scipy import ndimage

    ok = np.isfinite(values) & (values > 0)
    logs = np.where(ok, np.log(np.where(ok, values, 1.0)), 0.0)
    num = ndimage.uniform_filter(logs, size, mode="nearest")
    den = ndimage.uniform_filter(ok.astype(np.float64), size, mode="nearest")
    out = np.exp(num / np.maximum(den, 1e-12))
    out[~ok | (den < 1 / 3)] = np.nan
    return out


# ------------------------------------------------------------------------------------------------ traffic
def _speed_norm(speeds: np.ndarray, speed_range: tuple[float, float] | None) -> Any:
    from matplotlib.colors import Normalize

    if speed_range is not None:
        return Normalize(*speed_range)
    s = speeds[np.isfinite(speeds)]
    hi = float(np.percentile(s, 98)) if s.size else 1.0
    return Normalize(0.0, max(hi, 1.0))


def trajectory_segments(points: pd.DataFrame, every: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Segments (M, 2, 2) between consecutive points of each track (sorted by time, x/y as given; only every
    ``every``-th point of a track, and its last, when thinned) and their speeds (M,) km/h (mean of the two ends)."""
    if not len(points):
        return np.zeros((0, 2, 2)), np.zeros(0)
    p = points.sort_values(["track_id", "time"], kind="stable")
    if every > 1:
        k = p.groupby("track_id", sort=False).cumcount().to_numpy()
        last = ~p["track_id"].duplicated(keep="last").to_numpy()
        p = p[(k % every == 0) | last]
    xy = p[["x", "y"]].to_numpy(float)
    sp = p["speed_kmh"].to_numpy(float)
    same = p["track_id"].to_numpy()[1:] == p["track_id"].to_numpy()[:-1]
    seg = np.stack([xy[:-1], xy[1:]], axis=1)[same]
    return seg, 0.5 * (sp[:-1] + sp[1:])[same]


def trajectories_map(points: pd.DataFrame, axes: MapAxes, *, background: Background | None = None,
                     lanes: list[tuple[str, Any]] | None = None, lines: list[tuple[str, Any]] | None = None,
                     speed_range: tuple[float, float] | None = None, max_points: int = 200_000) -> Any:
    """World trajectories (``track_id, time, x, y, speed_kmh``; CRS units, km/h) coloured by speed, with lane
    outlines and counting lines (name, shapely geometry in CRS units). One LineCollection (gid
    ``"trajectories"``) holds a segment between every two consecutive points of a track; tracks are thinned to
    every k-th point when there are more than ``max_points`` (said in the title)."""
    from matplotlib.collections import LineCollection

    fig, axs = new_figure(9.0, 7.5)
    ax = axs[0, 0]
    draw_background(ax, background, axes)
    every = max(1, math.ceil(len(points) / max_points))
    seg, speed = trajectory_segments(points, every)
    seg = seg - np.asarray(axes.origin)[None, None, :]
    norm = _speed_norm(points["speed_kmh"].to_numpy(float) if len(points) else np.zeros(0), speed_range)
    lc = LineCollection(seg, array=speed, cmap=SPEED_CMAP, norm=norm, linewidths=1.4, zorder=3)
    lc.set_gid("trajectories")
    ax.add_collection(lc)
    fig.colorbar(lc, ax=ax, label="speed (km/h)", shrink=0.85)
    for name, geom in lanes or []:
        for part in geometry_parts(geom):
            lx, ly = axes.local(*np.asarray(part.exterior.coords).T[:2])
            ax.plot(lx, ly, color="white", linewidth=0.8, alpha=0.9, zorder=2)
            ax.plot(lx, ly, color="0.3", linewidth=0.4, linestyle="--", zorder=2)
            c = part.representative_point()
            cx, cy = axes.local(c.x, c.y)
            ax.annotate(str(name), (float(cx), float(cy)), fontsize=6, color="0.15", ha="center", zorder=2)
    for name, geom in lines or []:
        lx, ly = axes.local(*np.asarray(geom.coords).T[:2])
        ax.plot(lx, ly, color="#d7191c", linewidth=2.0, zorder=4)
        ax.annotate(f"line {name}", (float(lx[-1]), float(ly[-1])), xytext=(3, 3), textcoords="offset points",
                    fontsize=7, color="#d7191c", zorder=5, annotation_clip=True)
    fx, fy = seen_frame(points["x"].to_numpy(float) if len(points) else np.zeros(0),
                        points["y"].to_numpy(float) if len(points) else np.zeros(0), lines)
    if fx.size:
        lx, ly = axes.local(fx, fy)
        set_extent(ax, np.asarray(lx, float), np.asarray(ly, float))
    axes.label(ax)
    n = points["track_id"].nunique() if len(points) else 0
    ax.set_title(f"{n} trajectories ({len(points)} points{f', every {every}th drawn' if every > 1 else ''}) "
                 "coloured by speed", fontsize=9)
    return fig


def speed_histograms(vehicles: pd.DataFrame, *, column: str = "speed_kmh", group: str = "lane") -> Any:
    """One histogram per lane of the vehicles' speeds (km/h, ``column``), on a common scale; vehicles without a
    lane are grouped as "no lane". Bars have gid ``"speed-<lane>"``."""
    from matplotlib.ticker import MaxNLocator

    v = vehicles[np.isfinite(vehicles[column].to_numpy(float))] if len(vehicles) else vehicles
    names = v[group].fillna("").astype(str) if group in v.columns else pd.Series([""] * len(v), index=v.index)
    lanes = sorted(names.unique())
    n = max(len(lanes), 1)
    fig, axs = new_figure(9.0, 1.2 + 1.5 * n, n, 1, sharex=True)
    speeds = v[column].to_numpy(float)
    bins = np.linspace(max(0.0, float(speeds.min()) - 2) if speeds.size else 0.0,
                       (float(speeds.max()) + 2) if speeds.size else 1.0, 21)
    for ax, lane in zip(axs[:, 0], lanes or [""], strict=False):
        s = speeds[(names == lane).to_numpy()] if speeds.size else speeds
        label = lane or "no lane"
        if s.size:
            _, _, patches = ax.hist(s, bins=bins, color="#3182bd", alpha=0.85)
            for p in patches:
                p.set_gid(f"speed-{lane}")
            ax.axvline(float(np.median(s)), color="black", linewidth=1.0, linestyle="--")
        ax.set_ylabel("vehicles")
        ax.yaxis.set_major_locator(MaxNLocator(integer=True))
        ax.set_title(f"lane {label}: {s.size} vehicles, median {np.median(s) if s.size else float('nan'):.1f} km/h",
                     fontsize=8, loc="left")
    axs[-1, 0].set_xlabel("vehicle mean speed over its observed path (km/h)")
    return fig


def counts_over_time(counts: pd.DataFrame) -> Any:
    """Vehicles per counting interval, one panel per counting line and one bar series per lane and direction
    (``counts.csv``: ``line, lane, direction, interval_start, interval_end, count``; s). Bars have gid
    ``"count-<line>-<lane>-<direction>"``."""
    from matplotlib.ticker import MaxNLocator

    lines = sorted(counts["line"].astype(str).unique())
    n = max(len(lines), 1)
    fig, axs = new_figure(9.0, 1.0 + 2.2 * n, n, 1, sharex=True)
    for ax, line in zip(axs[:, 0], lines, strict=False):
        c = counts[counts["line"].astype(str) == line]
        keys = c[["lane", "direction"]].drop_duplicates().sort_values(["direction", "lane"]).itertuples(index=False)
        keys = list(keys)
        for k, (lane, direction) in enumerate(keys):
            g = c[(c["lane"] == lane) & (c["direction"] == direction)].sort_values("interval_start")
            start, end = g["interval_start"].to_numpy(float), g["interval_end"].to_numpy(float)
            width = (end - start) / (len(keys) + 1)
            bars = ax.bar(start + width * (k + 0.5), g["count"].to_numpy(float), width=width, align="edge",
                          label=f"lane {lane or '-'}, dir {int(direction):+d}")
            for p in bars:
                p.set_gid(f"count-{line}-{lane}-{int(direction)}")
        ax.set_ylabel("vehicles")
        ax.yaxis.set_major_locator(MaxNLocator(integer=True))
        ax.set_title(f"counting line {line}", fontsize=8, loc="left")
        ax.legend(fontsize=6, ncol=min(len(keys), 4) or 1, loc="upper right")
    intervals = counts["interval_end"] - counts["interval_start"]
    step = float(intervals.max()) if len(intervals) else float("nan")
    axs[-1, 0].set_xlabel(f"time (s); intervals of up to {step:g} s")
    return fig


def geh_limits(observed: np.ndarray, geh: float = 5.0) -> tuple[np.ndarray, np.ndarray]:
    """The simulated hourly flows (low, high) at which the GEH statistic ``sqrt(2 (M - C)^2 / (M + C))`` reaches
    ``geh`` for observed flows ``observed`` (veh/h): ``C = M + d`` with ``2 d^2 - g^2 d - 2 g^2 M = 0``."""
    m = np.asarray(observed, dtype=np.float64)
    g2 = geh * geh
    root = np.sqrt(g2 * g2 + 16.0 * g2 * m)
    return np.maximum(m + (g2 - root) / 4.0, 0.0), m + (g2 + root) / 4.0


def observed_vs_simulated(compare: pd.DataFrame) -> Any:
    """Observed against simulated hourly flows (``compare_counts.csv`` of ``compare-sumo``: one point per line,
    lane, direction and interval), with the 1:1 line and the band where GEH < 5. Points have gid ``"geh-ok"`` or
    ``"geh-high"``."""
    fig, axs = new_figure(5.5, 5.0)
    ax = axs[0, 0]
    obs = compare["observed_flow_veh_h"].to_numpy(float)
    sim = compare["simulated_flow_veh_h"].to_numpy(float)
    ok = compare["geh"].to_numpy(float) < 5.0
    top = max(float(np.nanmax(np.concatenate([obs, sim, [1.0]]))) * 1.1, 1.0)
    grid = np.linspace(0.0, top, 200)
    lo, hi = geh_limits(grid)
    ax.fill_between(grid, lo, np.minimum(hi, top), color="0.9", label="GEH < 5", zorder=1)
    ax.plot([0, top], [0, top], color="0.4", lw=0.8, zorder=2)
    for sel, colour, gid, label in ((ok, "tab:green", "geh-ok", "GEH < 5"), (~ok, "tab:red", "geh-high", "GEH >= 5")):
        if sel.any():
            pts = ax.scatter(obs[sel], sim[sel], s=18, c=colour, label=f"{label} ({int(sel.sum())})", zorder=3)
            pts.set_gid(gid)
    ax.set_xlim(-0.02 * top, top)
    ax.set_ylim(-0.02 * top, top)
    ax.set_aspect("equal")
    ax.set_xlabel("observed flow (veh/h)")
    ax.set_ylabel("simulated flow (veh/h)")
    ax.legend(fontsize=7, loc="upper left")
    return fig


def road_stations(x: np.ndarray, y: np.ndarray, *, degree: int = 3) -> tuple[np.ndarray, Any]:
    """Distance of each point along the road (CRS units) and the reference line it is measured on.

    The line follows the points' main direction (their first principal axis) with a smooth polynomial of
    ``degree`` for the cross-road offset, fitted to all points, so it follows a curved road and lies between the
    two directions of a two-way road. It is drawn densely (no corners a point could snap to) and extended
    straight at both ends, so no point is clamped to an end. Distances increase along the principal axis,
    oriented towards the north-east half-plane (so reruns agree), from the first point's station.
    """
    import shapely

    xy = np.column_stack([x, y]).astype(np.float64)
    ok = np.all(np.isfinite(xy), axis=1)
    out = np.full(len(xy), np.nan)
    if ok.sum() < 2:
        return out, None
    c = np.median(xy[ok], axis=0)
    d = xy[ok] - c
    _, _, vt = np.linalg.svd(d - d.mean(axis=0), full_matrices=False)
    axis = vt[0] if (vt[0][0] + vt[0][1]) >= 0 else -vt[0]
    normal = np.array([-axis[1], axis[0]])
    s, n = d @ axis, d @ normal
    lo, hi = float(s.min()), float(s.max())
    span = max(hi - lo, 1e-6)
    deg = min(degree, max(int(ok.sum()) // 10, 0))
    coef = np.polynomial.polynomial.polyfit((s - lo) / span, n, deg) if deg > 0 else np.array([float(np.median(n))])
    t = np.linspace(0.0, 1.0, 400)
    st = lo + t * span
    off = np.polynomial.polynomial.polyval(t, coef)
    pts = c + st[:, None] * axis + off[:, None] * normal
    ends = [pts[0] - (pts[1] - pts[0]) / np.linalg.norm(pts[1] - pts[0]) * span,
            pts[-1] + (pts[-1] - pts[-2]) / np.linalg.norm(pts[-1] - pts[-2]) * span]
    line = shapely.LineString(np.vstack([ends[0], pts, ends[1]]))
    out[ok] = shapely.line_locate_point(line, shapely.points(xy[ok])) - span
    return out, line


def time_space_diagram(points: pd.DataFrame, *, metres_per_unit: float = 1.0,
                       speed_range: tuple[float, float] | None = None, max_points: int = 200_000) -> Any:
    """Distance along the road (m, :func:`road_stations`) against time (s), coloured by speed (km/h), one panel
    per direction of travel (whether a track's distance grows or shrinks). ``points``: ``track_id, time, x, y,
    speed_kmh`` (CRS units, converted with ``metres_per_unit``). Each panel's scatter has gid ``"time-space"``;
    more than ``max_points`` points are thinned evenly (said in the title)."""
    p = points[np.isfinite(points["x"].to_numpy(float)) & np.isfinite(points["y"].to_numpy(float))
               & np.isfinite(points["time"].to_numpy(float))] if len(points) else points
    dist, line = road_stations(p["x"].to_numpy(float), p["y"].to_numpy(float)) if len(p) else (np.zeros(0), None)
    bearing = float("nan")
    if line is not None:
        (ax0, ay0), (ax1, ay1) = line.coords[1], line.coords[-2]
        bearing = math.degrees(math.atan2(ax1 - ax0, ay1 - ay0)) % 360.0
    dist = dist * metres_per_unit
    p = p.assign(_d=dist)
    sign = {}
    for tid, g in p.groupby("track_id", sort=False):
        g = g.sort_values("time")
        sign[tid] = 1 if g["_d"].iloc[-1] >= g["_d"].iloc[0] else -1
    p = p.assign(_dir=p["track_id"].map(sign) if len(p) else [])
    thin = max(1, math.ceil(len(p) / max_points))
    norm = _speed_norm(p["speed_kmh"].to_numpy(float) if len(p) else np.zeros(0), speed_range)
    fig, axs = new_figure(9.0, 6.6, 2, 1, sharex=True)
    sc = None
    for ax, direction in zip(axs[:, 0], (1, -1), strict=True):
        g = p[p["_dir"] == direction].iloc[::thin]
        sc = ax.scatter(g["time"].to_numpy(float), g["_d"].to_numpy(float), c=g["speed_kmh"].to_numpy(float),
                        cmap=SPEED_CMAP, norm=norm, s=3, linewidths=0, rasterized=True)
        sc.set_gid("time-space")
        ax.set_ylabel("distance along the road (m)")
        towards = (bearing if direction > 0 else bearing + 180.0) % 360.0
        word = "increasing" if direction > 0 else "decreasing"
        ax.set_title(f"travelling towards {towards:.0f} deg from grid north ({word} distance): "
                     f"{g['track_id'].nunique()} vehicles, {len(g)} points"
                     + (f" (every {thin}th)" if thin > 1 else ""), fontsize=8, loc="left")
    axs[-1, 0].set_xlabel("time (s)")
    if sc is not None:
        fig.colorbar(sc, ax=axs[:, 0].tolist(), label="speed (km/h)", shrink=0.9)
    return fig
