"""Lidar point clouds (LAS/LAZ via laspy): ground points, ground elevation lookups and DEMs.

Conventions
-----------
* ``xyz`` is float64 (x east, y north, z up) in the units of the cloud's CRS. Z is assumed to use the same unit as
  x and y (true for the usual state-plane-feet and UTM-metre lidar); every distance given in metres (``cell_m``,
  ``radius_m``, ``resolution_m``, ``tolerance_m``) is converted with :func:`trafficgeo.crs.metres_per_unit`.
* Ground points are ASPRS class 2 when the cloud has any; otherwise a low-percentile filter picks them
  (:func:`ground_mask`).
* KD-trees and triangulations work on coordinates relative to a local origin, so 5e6-sized coordinates keep their
  precision.
* Per-group statistics (cell percentiles, medians, MADs) are computed vectorized: sort by (group, value), then
  index each group's order statistics; quantiles use numpy's default linear interpolation.
"""

from __future__ import annotations

import itertools
import math
import os
from dataclasses import dataclass
from pathlib import Path

import laspy
import numpy as np
import pyproj
from affine import Affine
from numpy.typing import ArrayLike
from scipy.interpolate import LinearNDInterpolator
from scipy.spatial import ConvexHull, Delaunay, QhullError, cKDTree

from trafficgeo.crs import crs_label, is_geographic, metres_per_unit, parse_crs, utm_crs_for
from trafficgeo.errors import InputError
from trafficgeo.geo.raster import GeoRaster

__all__ = [
    "ASPRS_GROUND",
    "MAX_DEM_CELLS",
    "GroundIndex",
    "GroundLookup",
    "PointCloud",
    "cloud_to_dem",
    "ground_mask",
    "read_point_cloud",
    "write_point_cloud",
]

#: ASPRS LAS classification code of ground points.
ASPRS_GROUND = 2
#: Largest DEM :func:`cloud_to_dem` builds (cells); beyond it the resolution is surely a mistake.
MAX_DEM_CELLS = 50_000_000
#: 1.4826 * MAD estimates the standard deviation of normally distributed values.
MAD_TO_SIGMA = 1.4826
#: Fewer ground points than this: cell medians instead of local planes.
_FIT_MIN_POINTS = 32
#: Lower bound of the lidar noise used by the local-plane fit, metres (noise-free or 1 mm-quantized clouds).
_SIGMA_FLOOR_M = 0.0005

try:  # the LAZ decompressor laspy uses; its errors are not laspy's
    from lazrs import LazrsError as _LazrsError
except ImportError:  # pragma: no cover - lazrs is a dependency
    _LazrsError = laspy.errors.LaspyException


def _readonly(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


def _unit_name(crs: pyproj.CRS | None) -> str:
    """Name of the linear unit of ``crs`` ("metre", "foot", "US survey foot"); "metre" for None."""
    if crs is None or not crs.axis_info:
        return "metre"
    return crs.axis_info[0].unit_name or "metre"


def _metres_text(value_m: float, crs: pyproj.CRS | None) -> str:
    """``"1.0 m"`` or ``"1.0 m (3.281 foot)"`` for messages."""
    mpu = metres_per_unit(crs)
    return f"{value_m:g} m" if mpu == 1.0 else f"{value_m:g} m ({value_m / mpu:.4g} {_unit_name(crs)})"


def _group_quantile(keys: np.ndarray, values: np.ndarray, q: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-group quantile ``q`` (0..1, linear interpolation like ``np.quantile``) of ``values`` grouped by ``keys``.

    Returns:
        (unique keys sorted ascending, quantile of each group, number of values in each group).
    """
    order = np.lexsort((values, keys))
    k = keys[order]
    v = values[order]
    uniq, start, counts = np.unique(k, return_index=True, return_counts=True)
    pos = start + (counts - 1) * q
    lo = np.floor(pos).astype(np.intp)
    hi = np.minimum(lo + 1, start + counts - 1)
    frac = pos - lo
    return uniq, v[lo] + (v[hi] - v[lo]) * frac, counts


class _Footprint:
    """Convex hull of 2-D points (local coordinates) with a vectorized inside test; the bbox when degenerate."""

    def __init__(self, xy: np.ndarray) -> None:
        self.lo = xy.min(axis=0)
        self.hi = xy.max(axis=0)
        self.tri: Delaunay | None = None
        try:
            hull = ConvexHull(xy)
            self.tri = Delaunay(xy[hull.vertices])
        except (QhullError, ValueError):
            self.tri = None

    def contains(self, xy: np.ndarray) -> np.ndarray:
        """True where the points lie inside (or on the edge of) the footprint; False for non-finite points."""
        finite = np.all(np.isfinite(xy), axis=1)
        span = float(np.max(self.hi - self.lo)) if xy.size else 0.0
        tol = 1e-9 * max(span, 1.0)
        inside = finite & np.all((xy >= self.lo - tol) & (xy <= self.hi + tol), axis=1)
        if self.tri is not None and inside.any():
            idx = np.flatnonzero(inside)
            inside[idx] = self.tri.find_simplex(xy[idx], tol=tol) >= 0
        return inside


# ---------------------------------------------------------------------- point cloud
@dataclass(frozen=True, eq=False)
class PointCloud:
    """A lidar point cloud.

    Attributes:
        xyz: (N, 3) float64 x east, y north, z up in CRS units.
        classification: (N,) uint8 ASPRS classes (2 = ground).
        rgb: (N, 3) uint16 colours as stored in the file (8-bit values are common despite the 16-bit field), or None.
        crs: the CRS, or None (unknown local coordinates, assumed metres).
        path: the file it was read from, for messages.

    Arrays are stored read-only (copies when the input needed converting). Equality is identity.
    """

    xyz: np.ndarray
    classification: np.ndarray
    rgb: np.ndarray | None
    crs: pyproj.CRS | None
    path: str | None = None

    def __post_init__(self) -> None:
        xyz = np.array(self.xyz, dtype=np.float64, copy=True)
        n = xyz.shape[0] if xyz.ndim == 2 else -1
        if xyz.ndim != 2 or xyz.shape[1] != 3:
            raise ValueError(f"PointCloud xyz must be (N, 3), got {xyz.shape}")
        cls = np.array(self.classification, dtype=np.uint8, copy=True).reshape(-1)
        if cls.shape != (n,):
            raise ValueError(f"PointCloud classification must be ({n},), got {cls.shape}")
        rgb = None
        if self.rgb is not None:
            rgb = np.array(self.rgb, dtype=np.uint16, copy=True)
            if rgb.shape != (n, 3):
                raise ValueError(f"PointCloud rgb must be ({n}, 3), got {rgb.shape}")
            rgb = _readonly(rgb)
        object.__setattr__(self, "xyz", _readonly(xyz))
        object.__setattr__(self, "classification", _readonly(cls))
        object.__setattr__(self, "rgb", rgb)
        object.__setattr__(self, "crs", parse_crs(self.crs))
        object.__setattr__(self, "path", None if self.path is None else str(self.path))

    def __len__(self) -> int:
        return int(self.xyz.shape[0])

    @property
    def label(self) -> str:
        """The file path, or a placeholder for clouds built in memory (for messages)."""
        return self.path or "<in-memory point cloud>"


def _geographic_error(path: str, crs: pyproj.CRS, xyz: np.ndarray) -> InputError:
    try:
        code = ":".join(utm_crs_for(float(np.mean(xyz[:, 0])), float(np.mean(xyz[:, 1]))).to_authority())
    except InputError:
        code = "EPSG:xxxx"
    return InputError(
        f"point cloud {path} is in the geographic CRS {crs_label(crs)} (degrees); reproject it to a projected CRS, "
        f"e.g. pdal translate {path} out.laz reprojection --filters.reprojection.out_srs={code}"
    )


def read_point_cloud(path: str | os.PathLike[str], crs: str | pyproj.CRS | None = None) -> PointCloud:
    """Read a LAS or LAZ file (laspy, lazrs backend for LAZ): scaled xyz, classification and RGB when present.

    Args:
        path: the LAS/LAZ file.
        crs: overrides (or supplies) the CRS; otherwise the header's CRS VLRs (WKT or GeoTIFF keys) are used,
            and None when it has none.

    Raises:
        InputError: missing file, not LAS/LAZ, no points, or a geographic (lon/lat) CRS.
    """
    p = Path(path)
    if not p.exists():
        raise InputError(f"point cloud {p} does not exist; check the path")
    if p.is_dir():
        raise InputError(f"point cloud {p} is a folder, not a file; give the path of a .las or .laz file")
    try:
        las = laspy.read(p)
    except (laspy.errors.LaspyException, _LazrsError, ValueError, EOFError, OSError) as exc:  # lazrs: a cut LAZ
        reason = " ".join(str(exc).split())[:100]
        raise InputError(
            f"point cloud {p} is not a LAS/LAZ file laspy can read ({reason}); give a .las or .laz file"
        ) from None
    if len(las.points) == 0:
        raise InputError(f"point cloud {p} has no points; give a LAS/LAZ file with points")
    if crs is not None:
        out_crs = parse_crs(crs)
    else:
        try:
            out_crs = las.header.parse_crs()
        except Exception as exc:  # laspy raises assorted errors on malformed CRS VLRs
            raise InputError(
                f"point cloud {p}: the CRS in its header cannot be parsed ({exc}); give the CRS explicitly"
            ) from None
    xyz = np.column_stack((np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)))
    names = set(las.point_format.dimension_names)
    rgb = None
    if {"red", "green", "blue"} <= names:
        rgb = np.column_stack((np.asarray(las.red), np.asarray(las.green), np.asarray(las.blue)))
    if is_geographic(out_crs):
        raise _geographic_error(str(p), out_crs, xyz)
    return PointCloud(xyz, np.asarray(las.classification), rgb, out_crs, str(p))


def write_point_cloud(path: str | os.PathLike[str], cloud: PointCloud, scale: float = 0.001) -> None:
    """Write a LAS (or LAZ, by suffix) 1.4 file atomically: xyz at ``scale`` CRS units, classification, RGB if any,
    and the CRS as a WKT VLR."""
    p = Path(path)
    if p.suffix.lower() not in (".las", ".laz"):
        raise InputError(f"{p}: a point cloud must be written as .las or .laz")
    from trafficgeo.io.atomic import atomic_path

    header = laspy.LasHeader(point_format=7 if cloud.rgb is not None else 6, version="1.4")
    header.offsets = np.floor(cloud.xyz.min(axis=0))
    header.scales = np.array([scale, scale, scale])
    if cloud.crs is not None:
        header.add_crs(cloud.crs)
    las = laspy.LasData(header)
    las.x, las.y, las.z = cloud.xyz[:, 0], cloud.xyz[:, 1], cloud.xyz[:, 2]
    las.classification = cloud.classification
    if cloud.rgb is not None:
        las.red, las.green, las.blue = cloud.rgb[:, 0], cloud.rgb[:, 1], cloud.rgb[:, 2]
    with atomic_path(p) as tmp:
        las.write(tmp, do_compress=p.suffix.lower() == ".laz")


# ---------------------------------------------------------------------- ground selection
def ground_mask(
    cloud: PointCloud, cell_m: float = 2.0, percentile: float = 10.0, tolerance_m: float = 0.3
) -> np.ndarray:
    """Boolean (N,) mask of the ground points of ``cloud``.

    If any point is classified ASPRS 2 (ground), exactly those. Otherwise a low-percentile filter: the xy plane is
    cut into square cells of ``cell_m`` metres, and a point is ground when its z lies within ``tolerance_m`` metres
    of the ``percentile``-th percentile of z in its cell (so trees, roofs and vehicles above the ground are dropped,
    as are isolated low outliers).
    """
    if np.any(cloud.classification == ASPRS_GROUND):
        return cloud.classification == ASPRS_GROUND
    if not (cell_m > 0 and tolerance_m >= 0 and 0.0 <= percentile <= 100.0):
        raise ValueError(f"ground_mask needs cell_m > 0, tolerance_m >= 0, 0 <= percentile <= 100; got "
                         f"{cell_m}, {tolerance_m}, {percentile}")
    mpu = metres_per_unit(cloud.crs)
    cell = cell_m / mpu
    xy = cloud.xyz[:, :2]
    ij = np.floor((xy - xy.min(axis=0)) / cell).astype(np.int64)
    keys = ij[:, 1] * (int(ij[:, 0].max()) + 1) + ij[:, 0]
    z = cloud.xyz[:, 2]
    uniq, level, _ = _group_quantile(keys, z, percentile / 100.0)
    cell_level = level[np.searchsorted(uniq, keys)]
    return np.abs(z - cell_level) <= tolerance_m / mpu


# ---------------------------------------------------------------------- ground elevation lookups
@dataclass(frozen=True, eq=False)
class GroundLookup:
    """Result of :meth:`GroundIndex.lookup` for N query points (all arrays (N,)).

    Attributes:
        z: median z of the ground points within the radius (CRS units), NaN when there are none.
        spread: robust spread of those z, 1.4826 * MAD (CRS units; ~ standard deviation); NaN with < 3 points.
        count: number of ground points within the radius (int64).
        inside: True where (x, y) lies inside the convex hull of the ground points' xy (their bbox when the hull
            is degenerate, e.g. collinear points).
    """

    z: np.ndarray
    spread: np.ndarray
    count: np.ndarray
    inside: np.ndarray


class GroundIndex:
    """Ground z lookups: a KD-tree on the ground points' xy (relative to their mean) and their footprint."""

    def __init__(self, ground_xyz: ArrayLike, crs: str | pyproj.CRS | None, source: str | None = None) -> None:
        """Args:
            ground_xyz: (N, 3) ground points, CRS units.
            crs: their CRS (None = local metres); radii given in metres are converted with it.
            source: file the points came from, named in error messages.
        """
        xyz = np.array(ground_xyz, dtype=np.float64, copy=True)
        if xyz.ndim != 2 or xyz.shape[1] != 3:
            raise ValueError(f"ground_xyz must be (N, 3), got {xyz.shape}")
        self.source = source or "<in-memory point cloud>"
        if xyz.shape[0] == 0:
            raise InputError(f"point cloud {self.source} has no ground points; give a cloud with ground (class 2)")
        self.crs = parse_crs(crs)
        self.metres_per_unit = metres_per_unit(self.crs)
        self.xyz = _readonly(xyz)
        self.origin = xyz[:, :2].mean(axis=0)
        local = xyz[:, :2] - self.origin
        self._tree = cKDTree(local)
        self._footprint = _Footprint(local)

    @classmethod
    def from_cloud(cls, cloud: PointCloud, **ground_kw: float) -> GroundIndex:
        """Index the ground points of ``cloud`` (:func:`ground_mask` with ``ground_kw``)."""
        mask = ground_mask(cloud, **ground_kw)
        if not mask.any():
            raise InputError(
                f"point cloud {cloud.label} has no ground points (no class 2 and the percentile filter kept none); "
                "classify ground first (e.g. pdal filters.smrf)"
            )
        return cls(cloud.xyz[mask], cloud.crs, cloud.path)

    def __len__(self) -> int:
        return int(self.xyz.shape[0])

    def _local(self, x: ArrayLike, y: ArrayLike) -> np.ndarray:
        xa, ya = np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
        return np.column_stack((xa.ravel() - self.origin[0], ya.ravel() - self.origin[1]))

    def lookup(self, x: ArrayLike, y: ArrayLike, radius_m: float = 1.0) -> GroundLookup:
        """Median ground z, its spread and neighbour count within ``radius_m`` METRES of each (x, y) (CRS units).

        Non-finite queries get count 0, z NaN and inside False.
        """
        if not (radius_m > 0 and math.isfinite(radius_m)):
            raise InputError(f"the ground search radius must be a positive number of metres, got {radius_m}")
        q = self._local(x, y)
        n = q.shape[0]
        inside = self._footprint.contains(q)
        finite = np.all(np.isfinite(q), axis=1)
        z = np.full(n, np.nan)
        spread = np.full(n, np.nan)
        count = np.zeros(n, dtype=np.int64)
        if finite.any():
            qi = np.flatnonzero(finite)
            hits = self._tree.query_ball_point(q[qi], radius_m / self.metres_per_unit, return_sorted=False)
            lens = np.fromiter((len(h) for h in hits), dtype=np.int64, count=len(hits))
            count[qi] = lens
            if lens.sum() > 0:
                nbr = np.fromiter(itertools.chain.from_iterable(hits), dtype=np.intp, count=int(lens.sum()))
                group = np.repeat(qi, lens)
                nz = self.xyz[nbr, 2]
                uniq, med, _ = _group_quantile(group, nz, 0.5)
                z[uniq] = med
                dev = np.abs(nz - z[group])
                uniq_d, mad, cnt = _group_quantile(group, dev, 0.5)
                ok = cnt >= 3
                spread[uniq_d[ok]] = MAD_TO_SIGMA * mad[ok]
        return GroundLookup(z=z, spread=spread, count=count, inside=inside)

    def z_at(self, x: ArrayLike, y: ArrayLike, radius_m: float = 1.0) -> np.ndarray:
        """Strict ground z (CRS units) at each (x, y): the median of the ground points within ``radius_m`` metres.

        Raises:
            InputError: naming the first point (0-based index and coordinates) that lies outside the cloud's ground
                footprint or has no ground point within the radius.
        """
        res = self.lookup(x, y, radius_m)
        bad = ~res.inside | (res.count == 0)
        if bad.any():
            i = int(np.argmax(bad))
            xa, ya = (a.ravel() for a in np.broadcast_arrays(np.asarray(x, np.float64), np.asarray(y, np.float64)))
            where = f"point {i} at ({xa[i]:.3f}, {ya[i]:.3f})"
            if not res.inside[i]:
                raise InputError(
                    f"{where} lies outside the point cloud {self.source}; give points inside the cloud's ground "
                    "footprint or use a cloud that covers them"
                )
            raise InputError(
                f"{where}: no ground points within {_metres_text(radius_m, self.crs)} in the point cloud "
                f"{self.source}; increase radius_m", parameters=("radius_m",)
            )
        return res.z


# ---------------------------------------------------------------------- DEM from a cloud
def cloud_to_dem(
    cloud: PointCloud,
    resolution_m: float,
    bounds: tuple[float, float, float, float] | None = None,
    ground: ArrayLike | None = None,
) -> GeoRaster:
    """Ground DEM of ``cloud``: at each cell centre, a local plane through the ground points with an adaptive radius.

    The value at a cell centre is that of the least-squares plane through the ground points within a radius chosen
    for that centre (:mod:`trafficgeo.geo._groundfit`): from about 6 points (at the cloud's typical spacing) up to
    about 96, growing by sqrt(2) while the larger plane agrees with the smaller ones (and the TIN of the points)
    within 2 standard errors (from the cloud's own noise, estimated robustly). Smooth road is averaged over many
    points; kerbs and ditches keep a small radius. The grid samples a surface, so cells finer than the point
    spacing are fine (and cells are not biased towards where their points happen to lie, as cell means and
    medians are on a sloped or crowned road). Cells holding points that get no plane (fewer than 32 ground points
    in all, or at the footprint's edge) get the median z of their points.

    Args:
        cloud: the point cloud.
        resolution_m: cell size in METRES (converted to CRS units, e.g. 1.0 -> 3.2808 ft cells in EPSG:2994).
        bounds: (left, bottom, right, top) in CRS units to cover; default the ground points' extent. The grid edges
            are snapped outward to multiples of the cell size; ground points outside it are ignored.
        ground: (N,) bool mask of the ground points; default :func:`ground_mask`.

    Returns:
        A north-up :class:`GeoRaster` ``(1, rows, cols)`` float64 with the cloud's CRS, nodata NaN and description
        ``"ground elevation (<unit>)"``. Cell centres inside the convex hull of the ground points get the local
        plane's value (clamped to the z range of the points it was fitted to); centres in data holes (no 6 points
        around them) are interpolated linearly (Delaunay TIN over the fitted centres; within half a cell of the hull
        edge a cell may stay NaN); every other cell is NaN.

    Raises:
        InputError: no ground points (in the bounds), or a grid of more than :data:`MAX_DEM_CELLS` cells.
    """
    if not (resolution_m > 0 and math.isfinite(resolution_m)):
        raise InputError(f"the DEM resolution must be a positive number of metres, got {resolution_m}")
    res = resolution_m / metres_per_unit(cloud.crs)
    if ground is None:
        mask = ground_mask(cloud)
    else:
        mask = np.asarray(ground, dtype=bool).reshape(-1)
        if mask.shape != (len(cloud),):
            raise ValueError(f"ground mask must be ({len(cloud)},), got {mask.shape}")
    pts = cloud.xyz[mask]
    if bounds is not None:
        left, bottom, right, top = (float(v) for v in bounds)
        if not (left < right and bottom < top):
            raise InputError(f"DEM bounds {bounds} are not (left, bottom, right, top) with left < right, bottom < top")
        keep = (pts[:, 0] >= left) & (pts[:, 0] <= right) & (pts[:, 1] >= bottom) & (pts[:, 1] <= top)
        pts = pts[keep]
    if pts.shape[0] == 0:
        where = "" if bounds is None else f" inside the bounds {tuple(bounds)}"
        raise InputError(
            f"point cloud {cloud.label} has no ground points{where}; classify ground (class 2) or check the bounds"
        )
    if bounds is None:
        left, bottom = pts[:, 0].min(), pts[:, 1].min()
        right, top = pts[:, 0].max(), pts[:, 1].max()
    # Edges on multiples of the cell size. Given bounds are snapped outward; the points' own extent gets a far
    # (right/top) edge strictly beyond the last point.
    i0, j0 = math.floor(left / res), math.floor(bottom / res)
    if bounds is None:
        i_end, j_end = math.floor(right / res) + 1, math.floor(top / res) + 1
    else:
        i_end, j_end = max(math.ceil(right / res), i0 + 1), max(math.ceil(top / res), j0 + 1)
    cols, rows = i_end - i0, j_end - j0
    if rows * cols > MAX_DEM_CELLS:
        raise InputError(
            f"a {_metres_text(resolution_m, cloud.crs)} DEM of {cloud.label} would have {rows} x {cols} cells "
            f"(more than {MAX_DEM_CELLS}); use a coarser resolution or smaller bounds"
        )
    x0, y_top = i0 * res, j_end * res
    transform = Affine(res, 0.0, x0, 0.0, -res, y_top)
    # Work in pixel units (col, row of cell centres) for the footprint and the TIN, in local CRS units for the fit.
    local_pts = np.column_stack(((pts[:, 0] - x0) / res, (y_top - pts[:, 1]) / res))
    footprint = _Footprint(local_pts)
    all_cells = np.arange(rows * cols)
    centres = np.column_stack((all_cells % cols + 0.5, all_cells // cols + 0.5)).astype(np.float64)
    in_hull = footprint.contains(centres)
    col = np.clip(np.floor(local_pts[:, 0]).astype(np.int64), 0, cols - 1)
    row = np.clip(np.floor(local_pts[:, 1]).astype(np.int64), 0, rows - 1)
    cells, med, _ = _group_quantile(row * cols + col, pts[:, 2], 0.5)
    grid = np.full(rows * cols, np.nan)
    if pts.shape[0] >= _FIT_MIN_POINTS:
        from trafficgeo.geo._groundfit import adaptive_ground

        use = in_hull.copy()
        use[cells] = True
        node = all_cells[use]
        origin = pts[:, :2].mean(axis=0)
        rel = np.column_stack((pts[:, 0] - origin[0], pts[:, 1] - origin[1], pts[:, 2]))
        qx = x0 + (node % cols + 0.5) * res - origin[0]
        qy = y_top - (node // cols + 0.5) * res - origin[1]
        grid[node], _, _ = adaptive_ground(rel, qx, qy, sigma_floor=_SIGMA_FLOOR_M / metres_per_unit(cloud.crs))
    # Cells holding points that got no plane (too few points, or at the footprint's edge): their median z.
    unset = np.isnan(grid[cells])
    grid[cells[unset]] = med[unset]
    filled = np.flatnonzero(np.isfinite(grid))
    empty = np.flatnonzero(np.isnan(grid) & in_hull)
    if empty.size and filled.size >= 3:
        try:
            tin = LinearNDInterpolator(centres[filled], grid[filled])
            grid[empty] = tin(centres[empty])
        except QhullError:  # filled cells collinear: nothing to interpolate across
            pass
    return GeoRaster(
        grid.reshape(1, rows, cols),
        transform,
        cloud.crs,
        nodata=math.nan,
        descriptions=(f"ground elevation ({_unit_name(cloud.crs)})",),
        path=cloud.path,
    )
