"""Loading helpers of the Python API: each takes a path (as the command line does) or an object already built,
and returns the object, so ``tg.analyze_tracks("camera.json", "cloud.laz", "tracks.csv", lanes="lanes.gpkg")``
and the same call with loaded objects do the same thing.

* :func:`load_camera` - a :class:`~trafficgeo.camera.model.Camera` or a camera JSON (``trafficgeo calibrate``).
* :func:`load_surface` - a :class:`~trafficgeo.geo.mapping.Surface`, a number (constant height, CRS units),
  ``"plane"`` (the GCP plane of the camera JSON), a GeoTIFF DEM or a LAS/LAZ point cloud.
* :func:`load_lanes`, :func:`load_lines` - lanes / counting lines as objects, a GIS file in world coordinates or a
  CSV of lines drawn in the image (``line,u,v``; mapped to the ground through the camera and surface).
* :func:`load_tracks` - :class:`~trafficgeo.traffic.tracks.ImageTracks`, a table, or a tracks CSV / MOT file.

World geometry is in the camera's CRS and its units.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pandas as pd

from trafficgeo.camera.model import Camera
from trafficgeo.errors import InputError
from trafficgeo.geo.mapping import Surface, camera_crs
from trafficgeo.traffic.lanes import Lanes, read_lanes
from trafficgeo.traffic.lines import CountLine, read_count_lines
from trafficgeo.traffic.tracks import ImageTracks, read_tracks, tracks_from_table

__all__ = [
    "load_camera",
    "load_camera_document",
    "load_lanes",
    "load_layout",
    "load_lines",
    "load_surface",
    "load_tracks",
]

PathLike = str | os.PathLike


def check_resolution(resolution_m: float) -> float:
    """``resolution_m`` if it is a usable cell size (m) for gridding a point cloud, else an InputError."""
    if not (resolution_m > 0 and resolution_m < float("inf")):
        raise InputError(f"resolution_m {resolution_m}: must be a positive cell size in metres, e.g. 0.25",
                         parameters=("resolution_m",))
    return float(resolution_m)


def load_camera_document(camera: Camera | PathLike) -> tuple[Camera, dict[str, Any] | None]:
    """The camera and, when read from a camera JSON, the whole document (its GCPs give the ``"plane"`` surface)."""
    if isinstance(camera, Camera):
        return camera, None
    if isinstance(camera, str | os.PathLike):
        from trafficgeo.camera.io import read_camera_document

        return read_camera_document(Path(camera))
    raise InputError(f"camera: {type(camera).__name__} is neither a Camera nor the path of a camera JSON")


def load_camera(camera: Camera | PathLike) -> Camera:
    """A :class:`Camera` as it is, or read from the camera JSON at the path ``camera``."""
    return load_camera_document(camera)[0]


def load_surface(surface: Surface | float | PathLike, camera: Camera | PathLike, *, surface_crs: str | None = None,
                 resolution_m: float = 0.25) -> Surface:
    """The road surface: a :class:`Surface` as it is; else built for ``camera`` (a Camera or its JSON path; the
    JSON is needed for ``"plane"``) from a number (constant height in CRS units), ``"plane"``, a GeoTIFF DEM or a
    LAS/LAZ point cloud (gridded at ``resolution_m`` metres); ``surface_crs`` for a file without a CRS."""
    if hasattr(surface, "elevation") and hasattr(surface, "normal"):
        return surface  # a Surface
    from trafficgeo.geo.load import load_surface as build

    check_resolution(resolution_m)
    cam, doc = load_camera_document(camera)
    if isinstance(surface, bool) or not isinstance(surface, int | float | str | os.PathLike):
        raise InputError(f"surface: {type(surface).__name__} is not a surface, a number, 'plane' or a file path")
    spec = repr(float(surface)) if isinstance(surface, int | float) else os.fspath(surface)
    if spec.strip().lower() == "plane" and doc is None:
        raise InputError("surface 'plane': the GCP plane comes from the camera JSON; give the camera as its path")
    where = str(camera) if doc is not None else "camera"
    return build(spec, cam, doc, surface_crs=surface_crs, resolution_m=resolution_m, where=where)


def load_lanes(lanes: Lanes | PathLike | None, camera: Camera, surface: Surface | None = None) -> Lanes | None:
    """Lanes as they are, or read from a GIS file (polygons or boundary lines) or an image CSV (boundary lines
    drawn in the frame, mapped through ``camera`` onto ``surface``); None stays None."""
    if lanes is None or isinstance(lanes, Lanes):
        return lanes
    if not isinstance(lanes, str | os.PathLike):
        raise InputError(f"lanes: {type(lanes).__name__} is neither Lanes nor the path of a lanes file")
    return read_lanes(Path(lanes), crs=camera_crs(camera), camera=camera, surface=surface)


def load_lines(lines: Sequence[CountLine] | PathLike | None, camera: Camera, surface: Surface | None = None
               ) -> list[CountLine] | None:
    """Counting lines as they are, or read from a GIS file or an image CSV (see :func:`load_lanes`)."""
    if lines is None:
        return None
    if isinstance(lines, str | os.PathLike):
        return read_count_lines(Path(lines), crs=camera_crs(camera), camera=camera, surface=surface)
    out = list(lines)
    if not all(isinstance(ln, CountLine) for ln in out):
        raise InputError("lines: give CountLine objects or the path of a counting lines file")
    return out


def load_layout(camera: Camera, surface: Surface, lanes: Lanes | PathLike | None,
                lines: Sequence[CountLine] | PathLike | None) -> tuple[Lanes | None, list[CountLine] | None]:
    """Lanes and counting lines for ``camera`` over ``surface``, having checked first that the camera is above the
    surface (a surface in feet read as metres would map nothing)."""
    from trafficgeo.traffic.plausibility import check_camera_above_surface

    check_camera_above_surface(camera, surface)
    return load_lanes(lanes, camera, surface), load_lines(lines, camera, surface)


def load_tracks(tracks: ImageTracks | pd.DataFrame | PathLike, *, fps: float | None = None) -> ImageTracks:
    """Image tracks as they are, from a table (``frame, time, track_id`` and boxes ``x1, y1, x2, y2`` or points
    ``u, v``; ``tracks.csv`` of ``process``), or read from a tracks CSV or MOT file (``fps`` when it has no time)."""
    if isinstance(tracks, ImageTracks):
        return tracks
    if isinstance(tracks, pd.DataFrame):
        table = tracks.copy()
        if "class" in table.columns:
            table["class"] = table["class"].fillna("").astype(str)
        return tracks_from_table(table)
    if isinstance(tracks, str | os.PathLike):
        return read_tracks(Path(tracks), fps=fps)
    raise InputError(f"tracks: {type(tracks).__name__} is not ImageTracks, a table or the path of a tracks file")
