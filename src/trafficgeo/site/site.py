"""A site: the calibrated camera, the road surface, the lanes, the counting lines and a junction's gates, loaded
once.

Each input is an object or what a user gives on the command line (a path, a number): ``Site.load("camera.json",
"cloud.laz", lanes="lanes.gpkg", lines="lines.gpkg")`` and the same call with loaded objects build the same site.

* ``camera`` - a :class:`~trafficgeo.camera.calibrated.CalibratedCamera`, a bare
  :class:`~trafficgeo.camera.model.Camera` (knowing nothing of its calibration) or a camera JSON;
* ``surface`` - see :func:`trafficgeo.site.surface.load_surface` (``"plane"`` needs the calibration's GCPs);
* ``lanes``, ``lines``, ``gates`` - objects, a GIS file in world coordinates, or a CSV of lines drawn in the image
  (``line,u,v``; mapped to the ground through the camera and surface). Gates are lines across a junction's arms
  with an ``arm`` attribute (:mod:`trafficgeo.site.gates`).

World geometry is in the camera's CRS and its units.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

from trafficgeo.camera.calibrated import CalibratedCamera, as_camera, load_calibrated_camera
from trafficgeo.camera.model import Camera
from trafficgeo.errors import InputError
from trafficgeo.geo.mapping import Surface, camera_crs
from trafficgeo.site.checks import check_camera_above_surface
from trafficgeo.site.gates import Gate, read_gates
from trafficgeo.site.lanes import Lanes, read_lanes
from trafficgeo.site.lines import CountLine, read_count_lines
from trafficgeo.site.surface import load_surface

PathLike = str | os.PathLike
CameraLike = CalibratedCamera | Camera | PathLike


@dataclass(frozen=True, eq=False)
class Site:
    """What a camera looks at: the calibrated ``camera``, the road ``surface`` (in the camera's CRS), and, when
    given, the ``lanes``, counting ``lines`` and the ``gates`` of a junction's arms."""

    camera: CalibratedCamera
    surface: Surface
    lanes: Lanes | None = None
    lines: tuple[CountLine, ...] | None = None
    gates: tuple[Gate, ...] | None = None
    bare_camera: bool = False  # loaded from a bare Camera: nothing of its calibration was given (see load)

    @classmethod
    def load(cls, camera: CameraLike | Site, surface: Surface | float | PathLike | None = None,
             lanes: Lanes | PathLike | None = None, lines: Sequence[CountLine] | PathLike | None = None, *,
             gates: Sequence[Gate] | PathLike | None = None, surface_crs: str | None = None,
             resolution_m: float = 0.25) -> Site:
        """The site from objects or paths (see the module docstring), having checked that the camera is above the
        surface (a surface in feet read as metres would map nothing). A point cloud is gridded at ``resolution_m``
        m; ``surface_crs`` for a surface file without a CRS. A :class:`Site` given as ``camera`` is the site, with
        whatever else is given (surface, lanes, lines, gates) in place of its own."""
        if isinstance(camera, Site):
            site = camera
            if surface is None and lanes is None and lines is None and gates is None:
                return site
            again = cls.load(site.camera, site.surface if surface is None else surface,
                             site.lanes if lanes is None else lanes, site.lines if lines is None else lines,
                             gates=site.gates if gates is None else gates, surface_crs=surface_crs,
                             resolution_m=resolution_m)
            return replace(again, bare_camera=site.bare_camera)
        if surface is None:
            raise InputError("surface: the site needs the road surface (a number in metres, 'plane', a DEM or a "
                             "point cloud)", parameters=("surface",))
        calibrated = load_calibrated_camera(camera)
        surf = load_surface(surface, calibrated, surface_crs=surface_crs, resolution_m=resolution_m)
        check_camera_above_surface(calibrated.camera, surf)
        found = load_lines(lines, calibrated.camera, surf)
        arms = load_gates(gates, calibrated.camera, surf)
        return cls(calibrated, surf, load_lanes(lanes, calibrated.camera, surf),
                   None if found is None else tuple(found), None if arms is None else tuple(arms),
                   bare_camera=isinstance(camera, Camera))

    @property
    def count_lines(self) -> list[CountLine] | None:
        """The counting lines as a list (None without lines)."""
        return None if self.lines is None else list(self.lines)

    @property
    def tiling_lines(self) -> list[CountLine] | None:
        """The lines the detector's tiles are planned around when there are no lanes: the counting lines, else the
        junction's gates (named ``gate <arm>``), else None."""
        if self.lines:
            return list(self.lines)
        if self.gates:
            return [CountLine(f"gate {g.arm}", g.geometry) for g in self.gates]
        return None


def load_camera(camera: CameraLike) -> CalibratedCamera:
    """The :class:`CalibratedCamera` read from the camera JSON at ``camera`` (the camera and what its calibration
    knows: GCPs, covariance, which place the headline speeds), or as it is; a bare :class:`Camera` is wrapped and
    knows nothing of a calibration. Its ``.camera`` is the projection alone."""
    return load_calibrated_camera(camera)


def load_lanes(lanes: Lanes | PathLike | None, camera: CalibratedCamera | Camera, surface: Surface | None = None
               ) -> Lanes | None:
    """Lanes as they are, or read from a GIS file (polygons or boundary lines) or an image CSV (boundary lines
    drawn in the frame, mapped through ``camera`` onto ``surface``); None stays None."""
    if lanes is None or isinstance(lanes, Lanes):
        return lanes
    camera = as_camera(camera)
    if not isinstance(lanes, str | os.PathLike):
        raise InputError(f"lanes: {type(lanes).__name__} is neither Lanes nor the path of a lanes file",
                         parameters=("lanes",))
    return read_lanes(Path(lanes), crs=camera_crs(camera), camera=camera, surface=surface)


def load_lines(lines: Sequence[CountLine] | PathLike | None, camera: CalibratedCamera | Camera,
               surface: Surface | None = None) -> list[CountLine] | None:
    """Counting lines as they are, or read from a GIS file or an image CSV (see :func:`load_lanes`)."""
    if lines is None:
        return None
    if isinstance(lines, str | os.PathLike):
        camera = as_camera(camera)
        return read_count_lines(Path(lines), crs=camera_crs(camera), camera=camera, surface=surface)
    out = list(lines)
    if not all(isinstance(ln, CountLine) for ln in out):
        raise InputError("lines: give CountLine objects or the path of a counting lines file", parameters=("lines",))
    return out


def load_gates(gates: Sequence[Gate] | PathLike | None, camera: CalibratedCamera | Camera,
               surface: Surface | None = None) -> list[Gate] | None:
    """Junction gates as they are, or read from a GIS file or an image CSV (see :func:`load_lanes`)."""
    if gates is None:
        return None
    if isinstance(gates, str | os.PathLike):
        camera = as_camera(camera)
        return read_gates(Path(gates), crs=camera_crs(camera), camera=camera, surface=surface)
    out = list(gates)
    if not all(isinstance(g, Gate) for g in out):
        raise InputError("gates: give Gate objects or the path of a gates file", parameters=("gates",))
    from trafficgeo.site.gates import Junction

    Junction.from_gates(out)
    return out
