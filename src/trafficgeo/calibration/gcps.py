"""Ground control points (GCPs): reading, writing and sanity checks before calibration.

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

from trafficgeo.calibration.gcp_checks import validate_gcps
from trafficgeo.calibration.gcp_read import read_gcps
from trafficgeo.calibration.gcp_table import (
    CSV_COLUMNS,
    OPTIONAL_COLUMNS,
    REQUIRED_COLUMNS,
    ROLE_CHECK,
    ROLE_CONTROL,
    ROLES,
    GCPTable,
)

__all__ = [
    "CSV_COLUMNS",
    "OPTIONAL_COLUMNS",
    "REQUIRED_COLUMNS",
    "ROLES",
    "ROLE_CHECK",
    "ROLE_CONTROL",
    "GCPTable",
    "read_gcps",
    "validate_gcps",
]
