"""A synthetic orthophoto of a straight road: asphalt, lane markings and verges, georeferenced, with known geometry.

Layout across the road (offset ``o`` from the axis, right of the driving direction positive, metres): lanes of
``lane_width`` on each side of the axis (``lanes_right`` on the right, ``lanes_left`` on the left, 0 for a one-way
road whose lanes all lie right of the axis), a paved shoulder of ``shoulder`` beyond each edge line, then grass.
Markings follow common North American practice:

* centre line (two-way roads): solid yellow, 0.10 m, on the axis;
* lane lines: white dashes 3 m long every 9 m (3 m dash, 6 m gap), 0.10 m wide, centred on the lane boundary;
* edge lines: solid white, 0.15 m, at the outer lane boundaries.

:func:`dash_corners` returns the world corners of every dash: the lane-marking corners a user would click as GCPs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from affine import Affine

from trafficgeo.geo.raster import GeoRaster
from trafficgeo.synth.gcp_scene import RoadSurface

ASPHALT = np.array([78.0, 80.0, 84.0])
SHOULDER = np.array([96.0, 94.0, 90.0])
GRASS = np.array([72.0, 112.0, 58.0])
WHITE = np.array([232.0, 232.0, 228.0])
YELLOW = np.array([226.0, 186.0, 40.0])


@dataclass(frozen=True)
class RoadMarkings:
    """Cross-section and markings of a straight road (metres).

    ``lanes_right``/``lanes_left``: lanes right/left of the axis (``lanes_left = 0``: one-way, no centre line);
    ``dash``/``period``: dash length and dash-to-dash distance of the lane lines, with a dash starting at station
    ``dash_phase``.
    """

    lanes_right: int = 2
    lanes_left: int = 2
    lane_width: float = 3.5
    shoulder: float = 1.0
    line_width: float = 0.10
    edge_width: float = 0.15
    dash: float = 3.0
    period: float = 9.0
    dash_phase: float = 0.0

    def __post_init__(self) -> None:
        if self.lanes_right < 1 or self.lanes_left < 0:
            raise ValueError("a road needs at least one lane right of its axis (lanes_left may be 0)")
        for name in ("lane_width", "dash", "period"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive")
        if self.dash >= self.period:
            raise ValueError("the dash must be shorter than the dash period")

    @property
    def right_edge(self) -> float:
        return self.lanes_right * self.lane_width

    @property
    def left_edge(self) -> float:
        return -self.lanes_left * self.lane_width

    def lane_lines(self) -> np.ndarray:
        """Offsets of the dashed lane lines (between lanes of the same direction)."""
        right = [k * self.lane_width for k in range(1, self.lanes_right)]
        left = [-k * self.lane_width for k in range(1, self.lanes_left)]
        return np.array(sorted(left + right), dtype=np.float64)

    def in_dash(self, station: np.ndarray) -> np.ndarray:
        """Whether stations fall on a dash of the lane lines."""
        return np.mod(station - self.dash_phase, self.period) < self.dash


def texture(rng: np.random.Generator, shape: tuple[int, int], scale: float) -> np.ndarray:
    """Fine grain plus a blotchy low-frequency component (values around 0, std ~ scale)."""
    from scipy.ndimage import gaussian_filter

    grain = rng.normal(0.0, 1.0, shape)
    blotch = gaussian_filter(rng.normal(0.0, 1.0, shape), 12.0)
    blotch /= max(float(blotch.std()), 1e-9)
    return scale * (0.6 * grain + 0.4 * blotch)


def render_orthophoto(road: RoadSurface, markings: RoadMarkings, bounds: tuple[float, float, float, float], *,
                      resolution: float = 0.05, seed: int = 0, crs: str | None = "EPSG:2949") -> GeoRaster:
    """RGB orthophoto (3, rows, cols) uint8 of ``bounds`` (left, bottom, right, top, CRS units = metres) at
    ``resolution`` metres per pixel, north up. Deterministic for a seed."""
    left, bottom, right, top = bounds
    cols = int(np.ceil((right - left) / resolution))
    rows = int(np.ceil((top - bottom) / resolution))
    if rows * cols > 80_000_000:
        raise ValueError(f"an orthophoto of {cols}x{rows} pixels is too large; use a coarser resolution")
    rng = np.random.default_rng(seed)
    x = left + (np.arange(cols) + 0.5) * resolution
    y = top - (np.arange(rows) + 0.5) * resolution
    X, Y = np.meshgrid(x, y)
    s, o = road.station_offset(X, Y)
    img = np.empty((rows, cols, 3))
    paved = (o >= markings.left_edge - markings.shoulder) & (o <= markings.right_edge + markings.shoulder)
    carriageway = (o >= markings.left_edge) & (o <= markings.right_edge)
    img[:] = GRASS
    img[paved] = SHOULDER
    img[carriageway] = ASPHALT
    tex = texture(rng, (rows, cols), 1.0)
    img += tex[..., None] * np.where(carriageway | paved, 6.0, 14.0)[..., None]
    # Markings (anti-aliased by pixel coverage across the line).
    half_px = 0.5 * resolution

    def paint(mask_along: np.ndarray, centre: float, width: float, colour: np.ndarray) -> None:
        near = np.nonzero(np.abs(o - centre) < 0.5 * width + half_px)  # only the pixels the line can touch
        cover = np.clip((0.5 * width + half_px - np.abs(o[near] - centre)) / resolution, 0.0, 1.0) * mask_along[near]
        img[near] = img[near] * (1 - cover[:, None]) + colour * cover[:, None]

    everywhere = np.ones_like(s)
    if markings.lanes_left > 0:
        paint(everywhere, 0.0, markings.line_width, YELLOW)
    m = np.mod(s - markings.dash_phase, markings.period)
    inside = m < markings.dash
    # Signed distance along the line to the nearest dash end (positive inside a dash).
    along = np.where(inside, np.minimum(m, markings.dash - m), -np.minimum(m - markings.dash, markings.period - m))
    dash_cover = np.clip(along / resolution + 0.5, 0.0, 1.0)
    for line in markings.lane_lines():
        paint(dash_cover, float(line), markings.line_width, WHITE)
    for edge, sign in ((markings.right_edge, 1.0), (markings.left_edge, -1.0)):
        paint(everywhere, edge - sign * 0.5 * markings.edge_width, markings.edge_width, WHITE)
    # Worn paint and sensor grain on everything.
    img += rng.normal(0.0, 2.0, img.shape)
    data = np.clip(np.rint(img), 0, 255).astype(np.uint8).transpose(2, 0, 1)
    from trafficgeo.crs import parse_crs

    return GeoRaster(data=data, transform=Affine(resolution, 0.0, left, 0.0, -resolution, top),
                     crs=parse_crs(crs) if crs else None, descriptions=("red", "green", "blue"))


def dash_corners(road: RoadSurface, markings: RoadMarkings, station_range: tuple[float, float]) -> np.ndarray:
    """World corners (N, 3) of the lane-line dashes whose whole length lies in ``station_range``.

    Corners are ordered per dash: start-left, start-right, end-right, end-left (left/right of the line, in the
    direction of increasing station). Z is the road surface.
    """
    s0, s1 = station_range
    k0 = int(np.ceil((s0 - markings.dash_phase) / markings.period))
    k1 = int(np.floor((s1 - markings.dash - markings.dash_phase) / markings.period))
    starts = markings.dash_phase + markings.period * np.arange(k0, k1 + 1)
    pts = []
    hw = 0.5 * markings.line_width
    for line in markings.lane_lines():
        for a in starts:
            b = a + markings.dash
            pts += [(a, line - hw), (a, line + hw), (b, line + hw), (b, line - hw)]
    if not pts:
        return np.zeros((0, 3))
    st = np.array(pts)
    return road.points(st[:, 0], st[:, 1])
