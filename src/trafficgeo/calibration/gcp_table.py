"""Ground control points (GCPs): the GCP table (:class:`GCPTable`: ids, world and pixel coordinates, roles, pixel
sigmas and the CRS) and its CSV form; read with :func:`~trafficgeo.calibration.gcp_read.read_gcps`, checked with
:func:`~trafficgeo.calibration.gcp_checks.validate_gcps` before calibration.

A GCP pairs a world point with the pixel where it appears in the camera image.

Conventions
-----------
* **World** coordinates (X, Y, Z): a projected CRS with X east, Y north, Z up, in the CRS's own unit (metres
  or feet; see :func:`trafficgeo.crs.metres_per_unit`), float64. ``crs=None`` means local coordinates in an
  unknown CRS. Z is never transformed: it is whatever height the file gives.
* **Pixels** (u, v): (0, 0) is the *centre* of the top-left pixel, u grows to the right and v downwards.
  A pixel lies inside a W x H image when ``-0.5 <= u <= W - 0.5`` and ``-0.5 <= v <= H - 0.5``.
  OpenDroneMap/OpenSfM use the same convention for ``im_x im_y``.
* **Roles**: ``"control"`` points are used in the fit; ``"check"`` points are independent check points that
  are never used in the fit, only to measure its accuracy.
* ``sigma_px``: the standard deviation of a point's pixel position (default 1.0 px), used to weight it.

Input formats (detected from the first non-empty line)
------------------------------------------------------
* **CSV** with a header naming ``id,x,y,z,u,v`` in any order and any case; optional ``role`` and ``sigma_px``
  columns; other columns are ignored. The delimiter may be ``,``, ``;`` or a tab. Blank lines are skipped.
* **OpenDroneMap** ``gcp_list.txt``: the first line is the CRS of the points ("WGS84 UTM 10N", "EPSG:32610",
  a PROJ string, ...), then one observation per line, whitespace separated:
  ``geo_x geo_y geo_z im_x im_y image_name [gcp_name ...]``. Lines starting with ``#`` are comments.
  A GCP list usually covers many images; the rows of one image (``odm_image``) are taken.
  The id is ``gcp_name`` if present, else ``row<line number>``.

Every problem a user can fix raises :class:`~trafficgeo.errors.InputError` with a one-line message naming the
file, line and id, and the fix.
"""

from __future__ import annotations

import csv
import os
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pyproj
from numpy.typing import ArrayLike

from trafficgeo.crs import (
    parse_crs,
)
from trafficgeo.io.atomic import atomic_open

ROLE_CONTROL = "control"
ROLE_CHECK = "check"
ROLES: tuple[str, ...] = (ROLE_CONTROL, ROLE_CHECK)
REQUIRED_COLUMNS: tuple[str, ...] = ("id", "x", "y", "z", "u", "v")
OPTIONAL_COLUMNS: tuple[str, ...] = ("role", "sigma_px")
#: Columns written by :meth:`GCPTable.to_csv`, in order.
CSV_COLUMNS: tuple[str, ...] = REQUIRED_COLUMNS + OPTIONAL_COLUMNS

ODM_COLUMNS = ("geo_x", "geo_y", "geo_z", "im_x", "im_y")
#: Other names people's GCP files give the columns (lower case, spaces and dashes read as underscores), in the
#: order they are tried. World x/y as longitude/latitude names mean a geographic file (EPSG:4326 unless said).
COLUMN_ALIASES: dict[str, tuple[str, ...]] = {
    "id": ("id", "name", "point", "point_id", "gcp", "gcp_id", "gcp_name", "label", "pt", "fid"),
    "u": ("u", "pixel_x", "px", "image_x", "img_x", "im_x", "col", "column", "pixel_u", "x_px", "u_px",
          "sourcex", "source_x"),
    "v": ("v", "pixel_y", "py", "image_y", "img_y", "im_y", "row", "pixel_v", "y_px", "v_px", "sourcey",
          "source_y"),
    "x": ("x", "easting", "east", "e", "mapx", "map_x", "world_x", "geo_x", "x_m"),
    "y": ("y", "northing", "north", "n", "mapy", "map_y", "world_y", "geo_y", "y_m"),
    "z": ("z", "elevation", "elev", "height", "h", "altitude", "alt", "geo_z", "z_m", "elevation_m", "alt_m",
          "height_m", "ellipsoidal_height", "orthometric_height"),
    "lon": ("lon", "lon_deg", "longitude", "long", "lng", "longitude_deg", "gps_lon", "gps_long", "gps_lng",
            "gps_longitude"),
    "lat": ("lat", "lat_deg", "latitude", "latitude_deg", "gps_lat", "gps_latitude"),
    "role": ("role", "type", "use"),
    "sigma_px": ("sigma_px", "sigma", "pixel_sigma", "sigma_pixel"),
    # the image (or camera) a row belongs to, in a file that lists the points of several
    "image": ("image", "image_name", "camera", "camera_id", "camera_name", "cam", "photo", "filename", "img"),
}

# Beside longitude/latitude columns these name the pixel (the I-24 camera GCPs: "Camera X, Camera Y").
PIXEL_BESIDE_LONLAT: tuple[tuple[str, str], ...] = (("x", "y"), ("camera_x", "camera_y"), ("image_x", "image_y"))

COLUMN_HINTS = {
    "x": "give world coordinates as numbers",
    "y": "give world coordinates as numbers",
    "z": "give world coordinates as numbers (use 0 for flat ground)",
    "u": "give pixel coordinates as numbers",
    "v": "give pixel coordinates as numbers",
    "sigma_px": "give the pixel standard deviation as a positive number, or leave it empty for 1.0",
}


def quote_text(text: str, limit: int = 40) -> str:
    """Quote user text for a one-line message (control characters escaped, long text shortened)."""
    text = str(text)
    if len(text) > limit:
        text = text[: limit - 3] + "..."
    return f'"{text}"' if text.isprintable() else repr(text)


def format_number(value: float) -> str:
    return f"{value:.10g}"


@dataclass(frozen=True, eq=False)
class GCPTable:
    """An immutable table of N ground control points.

    Attributes:
        ids: unique point ids.
        world: (N, 3) float64 X east, Y north, Z up in the units of ``crs`` (see module docstring).
        pixels: (N, 2) float64 (u, v), (0, 0) = centre of the top-left pixel, u right, v down.
        roles: ``"control"`` (used in the fit) or ``"check"`` (independent check point, never fitted).
        sigma_px: (N,) float64 standard deviation of each pixel position [px], > 0.
        crs: working projected CRS of ``world``; ``None`` = unknown local coordinates.
        source: where the table came from (file name), for messages.
        lines: 1-based line number of each row in ``source`` (0 when the row has no line, e.g. built in code).
        columns_note: how a file's columns were understood when they were not ``id,x,y,z,u,v`` by name (e.g.
            "pixel_x -> u, lat_deg -> y (EPSG:4326)"), "" otherwise: say it to the user.
        from_lonlat: the file gave longitude/latitude (points picked on a web map, usually: metres, not the
            centimetres of a survey).

    Arrays are copied to read-only float64 arrays. Equality is identity (``eq=False``) because the fields are
    arrays; compare fields explicitly. Building a table with inconsistent shapes, non-finite values, unknown
    roles or non-positive sigma raises :class:`ValueError` (a programming error, not a user error: files go
    through :func:`read_gcps`, which reports such problems as :class:`~trafficgeo.errors.InputError`).
    """

    ids: tuple[str, ...]
    world: np.ndarray
    pixels: np.ndarray
    roles: tuple[str, ...]
    sigma_px: np.ndarray
    crs: pyproj.CRS | None
    source: str
    lines: tuple[int, ...]
    columns_note: str = ""
    from_lonlat: bool = False

    def __post_init__(self) -> None:
        ids = tuple(str(i) for i in self.ids)
        n = len(ids)
        world = np.array(self.world, dtype=np.float64, copy=True)
        pixels = np.array(self.pixels, dtype=np.float64, copy=True)
        sigma = np.array(self.sigma_px, dtype=np.float64, copy=True).reshape(-1)
        if n == 0:
            world, pixels = world.reshape(0, 3), pixels.reshape(0, 2)
        if world.ndim != 2 or world.shape[1] != 3 or pixels.ndim != 2 or pixels.shape[1] != 2:
            raise ValueError(
                f"GCPTable world must be (N, 3) and pixels (N, 2), got {world.shape}, {pixels.shape}"
            )
        roles = tuple(str(r) for r in self.roles)
        lines = tuple(int(i) for i in self.lines)
        sizes = {
            "ids": n,
            "world": world.shape[0],
            "pixels": pixels.shape[0],
            "roles": len(roles),
            "sigma_px": sigma.shape[0],
            "lines": len(lines),
        }
        if len(set(sizes.values())) != 1:
            raise ValueError(f"GCPTable fields have different lengths: {sizes}")
        if not (np.all(np.isfinite(world)) and np.all(np.isfinite(pixels)) and np.all(np.isfinite(sigma))):
            raise ValueError("GCPTable world, pixels and sigma_px must be finite")
        if np.any(sigma <= 0):
            raise ValueError("GCPTable sigma_px must be > 0")
        bad_roles = sorted(set(roles) - set(ROLES))
        if bad_roles:
            raise ValueError(f"GCPTable roles must be one of {ROLES}, got {bad_roles}")
        for arr in (world, pixels, sigma):
            arr.setflags(write=False)
        object.__setattr__(self, "ids", ids)
        object.__setattr__(self, "world", world)
        object.__setattr__(self, "pixels", pixels)
        object.__setattr__(self, "sigma_px", sigma)
        object.__setattr__(self, "roles", roles)
        object.__setattr__(self, "lines", lines)
        object.__setattr__(self, "source", str(self.source))

    @classmethod
    def from_arrays(
        cls,
        ids: Sequence[str],
        world: ArrayLike,
        pixels: ArrayLike,
        *,
        roles: Sequence[str] | None = None,
        sigma_px: ArrayLike | None = None,
        crs: pyproj.CRS | str | None = None,
        source: str = "<memory>",
        lines: Sequence[int] | None = None,
    ) -> GCPTable:
        """Build a table in code: roles default to all ``"control"``, sigma_px to 1.0, lines to 0."""
        n = len(ids)
        return cls(
            ids=tuple(ids),
            world=np.asarray(world, dtype=np.float64),
            pixels=np.asarray(pixels, dtype=np.float64),
            roles=tuple(roles) if roles is not None else (ROLE_CONTROL,) * n,
            sigma_px=np.asarray(sigma_px, dtype=np.float64) if sigma_px is not None else np.ones(n),
            crs=parse_crs(crs),
            source=source,
            lines=tuple(lines) if lines is not None else (0,) * n,
        )

    @property
    def n(self) -> int:
        """Number of points (control and check)."""
        return len(self.ids)

    @property
    def is_control(self) -> np.ndarray:
        """(N,) bool: rows used in the fit."""
        return np.array([r == ROLE_CONTROL for r in self.roles], dtype=bool)

    @property
    def is_check(self) -> np.ndarray:
        """(N,) bool: independent check points (never used in the fit)."""
        return np.array([r == ROLE_CHECK for r in self.roles], dtype=bool)

    def subset(self, mask_or_indices: ArrayLike) -> GCPTable:
        """A new table with the rows selected by a boolean mask of length N or by integer indices."""
        sel = np.asarray(mask_or_indices)
        if sel.dtype == bool:
            if sel.shape != (self.n,):
                raise ValueError(f"boolean mask has shape {sel.shape}, expected ({self.n},)")
            idx = np.flatnonzero(sel)
        elif sel.size == 0:
            idx = np.zeros(0, dtype=np.intp)
        elif np.issubdtype(sel.dtype, np.integer):
            idx = sel.reshape(-1).astype(np.intp)
        else:
            raise ValueError(f"subset needs a boolean mask or integer indices, got dtype {sel.dtype}")
        return GCPTable(
            ids=tuple(self.ids[i] for i in idx),
            world=self.world[idx],
            pixels=self.pixels[idx],
            roles=tuple(self.roles[i] for i in idx),
            sigma_px=self.sigma_px[idx],
            crs=self.crs,
            source=self.source,
            lines=tuple(self.lines[i] for i in idx),
        )

    def row_label(self, i: int) -> str:
        """Row ``i`` without the file name, e.g. ``line 5 (id "P4")`` (``row 5`` when it has no line)."""
        line = self.lines[i]
        place = f"line {line}" if line > 0 else f"row {i + 1}"
        return f"{place} (id {quote_text(self.ids[i])})"

    def where(self, i: int) -> str:
        """Row ``i`` for messages, e.g. ``gcps.csv line 5 (id "P4")``."""
        return f"{self.source} {self.row_label(i)}"

    def to_csv(self, path: str | os.PathLike[str]) -> None:
        """Write ``id,x,y,z,u,v,role,sigma_px`` with full float precision (``repr``), atomically.

        The file is written to a temporary file in the same folder and then moved over ``path``, so readers
        never see a half-written file. The CRS is not stored: pass it again to :func:`read_gcps`
        (``gcp_crs`` or ``crs``). ``read_gcps(path, crs=table.crs)`` gives back the same values exactly.
        """
        with atomic_open(path, "w", encoding="utf-8", newline="") as fh:
            writer = csv.writer(fh, lineterminator="\n")
            writer.writerow(CSV_COLUMNS)
            for i in range(self.n):
                x, y, z = (repr(float(c)) for c in self.world[i])
                u, v = (repr(float(c)) for c in self.pixels[i])
                writer.writerow([self.ids[i], x, y, z, u, v, self.roles[i], repr(float(self.sigma_px[i]))])

def first_index(mask: np.ndarray) -> int:
    return int(np.flatnonzero(mask)[0])
