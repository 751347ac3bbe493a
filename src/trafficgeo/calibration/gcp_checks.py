"""Sanity checks of a GCP table before calibration (:func:`validate_gcps`): enough control points, spread,
duplicates, collinear or coplanar layouts. See :mod:`trafficgeo.calibration.gcp_table` for the conventions."""

from __future__ import annotations

import numpy as np
import pyproj
from scipy.spatial import ConvexHull, QhullError, cKDTree

from trafficgeo.calibration.gcp_table import (
    GCPTable,
    first_index,
    format_number,
)
from trafficgeo.crs import (
    metres_per_unit,
)
from trafficgeo.errors import InputError
from trafficgeo.groups import group_pairs

# ------------------------------------------------------------------------------------------ validation


def _image_size(image_size: tuple[int, int]) -> tuple[int, int]:
    try:
        w, h = (int(s) for s in image_size)
        ok = w > 0 and h > 0 and all(float(s) == int(s) for s in image_size)
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise InputError(
            f"image_size {image_size!r} is not two positive whole numbers; give the width and height in pixels",
            parameters=("image_size",),
        )
    return w, h


def _unit(crs: pyproj.CRS | None) -> str:
    if crs is None:
        return "units"
    name = crs.axis_info[0].unit_name if crs.axis_info else "units"
    return {"metre": "m", "foot": "ft", "US survey foot": "ftUS"}.get(name, name)


def _clusters(points: np.ndarray, tol: float) -> list[list[int]]:
    """Single-linkage groups of points closer than ``tol`` (connected components of the close pairs), each sorted,
    in order of first row."""
    return group_pairs(len(points), cKDTree(points).query_pairs(tol, output_type="ndarray"))


def _flatness(points: np.ndarray) -> float:
    """Smallest / largest singular value of the centred 2D points (0 = collinear, 1 = isotropic spread)."""
    centred = points - points.mean(axis=0)
    s = np.linalg.svd(centred, compute_uv=False)
    return float(s[-1] / s[0]) if s[0] > 0 else 0.0


def _closest_pair(points: np.ndarray, radius: float) -> tuple[int, int, float] | None:
    pairs = cKDTree(points).query_pairs(radius)
    if not pairs:
        return None
    i, j = min(pairs, key=lambda p: (min(p), max(p)))
    i, j = min(i, j), max(i, j)
    return i, j, float(np.linalg.norm(points[i] - points[j]))


def validate_gcps(table: GCPTable, image_size: tuple[int, int], *, min_control: int = 4) -> list[str]:
    """Check that ``table`` can calibrate a camera with a ``(width, height)`` image; return warnings.

    Raises :class:`~trafficgeo.errors.InputError` for: a pixel outside the image; two rows with the same pixel
    (within 0.5 px) or the same world point (within 1e-3 CRS units in 3D); fewer than ``min_control`` control
    points; degenerate control geometry on the ground (after merging control points closer than
    max(0.5 % of the XY extent, 0.2 m) fewer than min(4, min_control) distinct points remain, the distinct
    points are (nearly) collinear, or, with exactly 4 distinct points, 3 of them are) or in the image
    (collinear pixels). "Nearly collinear" means the smallest singular value of the centred coordinates is
    below 1 % of the largest.

    Returns plain-text warnings for: fewer than 6 control points (little redundancy), control pixels covering
    less than 10 % of the image (convex hull), control points merged as coincident.
    """
    w, h = _image_size(image_size)
    warnings: list[str] = []
    src = table.source
    px = table.pixels
    outside = (px[:, 0] < -0.5) | (px[:, 0] > w - 0.5) | (px[:, 1] < -0.5) | (px[:, 1] > h - 0.5)
    if np.any(outside):
        i = first_index(outside)
        raise InputError(
            f"{table.where(i)}: pixel (u={format_number(px[i, 0])}, v={format_number(px[i, 1])}) is outside the "
            f"{w}x{h} image "
            f"(u from -0.5 to {w - 0.5}, v from -0.5 to {h - 0.5}, (0, 0) = centre of the top-left pixel); "
            "check image_size or the pixel",
            parameters=("image_size",),
        )
    if table.n >= 2:
        dup = _closest_pair(px, 0.5)
        if dup is not None:
            i, j, d = dup
            raise InputError(
                f"{table.where(i)} and {table.row_label(j)} have the same pixel ({d:.2g} px apart); "
                "delete the duplicate row or correct its pixel"
            )
        dup = _closest_pair(table.world, 1e-3)
        if dup is not None:
            i, j, d = dup
            raise InputError(
                f"{table.where(i)} and {table.row_label(j)} have the same world point ({d:.2g} "
                f"{_unit(table.crs)} apart); delete the duplicate row or correct its coordinates"
            )
    ctrl = np.flatnonzero(table.is_control)
    n_ctrl = len(ctrl)
    n_check = table.n - n_ctrl
    if n_ctrl < min_control:
        raise InputError(
            f"{src}: {n_ctrl} control point(s), but calibration needs at least {min_control}; check points "
            f'(role "check", {n_check} here) don\'t count; add control points or change some roles to control'
        )
    if n_ctrl == 0:
        return warnings
    unit = _unit(table.crs)
    xy = table.world[ctrl, :2]
    extent = float(np.hypot(*np.ptp(xy, axis=0)))
    try:
        floor = 0.2 / metres_per_unit(table.crs)
    except InputError:
        floor = 0.2
    tol = max(0.005 * extent, floor)
    groups = _clusters(xy, tol)
    merged = [g for g in groups if len(g) > 1]

    def describe(g: list[int]) -> str:
        span = max(float(np.linalg.norm(xy[a] - xy[b])) for a in g for b in g)
        labels = [table.row_label(ctrl[k]) for k in g]
        names = " and ".join(labels) if len(labels) == 2 else ", ".join(labels)
        return f"{names} ({span:.2g} {unit} apart)"

    needed = min(4, min_control)
    if len(groups) < needed:
        what = "; ".join(describe(g) for g in merged) or "all points"
        raise InputError(
            f"{src}: degenerate control points: {what} coincide on the ground "
            f"(closer than {tol:.2g} {unit}), leaving {len(groups)} distinct ground points; "
            f"at least {needed} well-spread points are needed, "
            "so replace the coincident points with points elsewhere in the scene"
        )
    if merged:
        warnings.append(
            f"{src}: control points {'; '.join(describe(g) for g in merged)} nearly coincide on the ground "
            f"(closer than {tol:.2g} {unit}); they add little to the calibration"
        )
    centres = np.array([xy[g].mean(axis=0) for g in groups])
    if len(groups) >= 3:
        flat = _flatness(centres)
        if flat < 0.01:
            raise InputError(
                f"{src}: degenerate control points: the {len(groups)} distinct ground points lie nearly "
                f"on one line (spread across it {flat:.2%} of the spread along it); "
                "add control points away from that line, e.g. across the road"
            )
        if len(groups) == 4:
            for drop in range(4):
                trio = [k for k in range(4) if k != drop]
                flat = _flatness(centres[trio])
                if flat < 0.01:
                    rows = ", ".join(table.row_label(ctrl[groups[k][0]]) for k in trio)
                    raise InputError(
                        f"{src}: degenerate control points: {rows} lie nearly on one line on the ground "
                        "and only 4 distinct points are given, "
                        "which leaves the ground-to-image mapping undetermined; "
                        "add control points or move one off that line"
                    )
    cpx = px[ctrl]
    if n_ctrl >= 3:
        flat = _flatness(cpx)
        if flat < 0.01:
            raise InputError(
                f"{src}: degenerate control points: their pixels lie nearly on one line in the image "
                f"(spread across it {flat:.2%} of the spread along it); "
                "add control points elsewhere in the image"
            )
        try:
            area = float(ConvexHull(cpx).volume)
        except QhullError:
            area = 0.0
        share = area / (w * h)
        if share < 0.10:
            warnings.append(
                f"{src}: the control points cover only {share:.1%} of the image "
                "(convex hull of their pixels); the calibration may be poor away from them, "
                "so add points near the image edges and corners"
            )
    if n_ctrl < 6:
        warnings.append(
            f"{src}: only {n_ctrl} control points; with fewer than 6 there is little redundancy to detect a "
            "wrong point, so add more if you can"
        )
    return warnings
