"""Vehicle ground points from image bounding boxes, corrected for the vehicle's 3-D extent.

A detector gives a vehicle's axis-aligned image box ``(x1, y1, x2, y2)`` in pixels (OpenCV pixel-centre convention:
pixel (0, 0) is the centre of the top-left pixel). The naive ground point, the box's bottom centre
``((x1 + x2) / 2, y2)`` mapped to the road, is where the vehicle's *nearest bottom corner or edge* meets the road,
not its footprint centre: it lies up to half the vehicle's length or width (1-2 m) towards the camera.

With a calibrated camera, a road surface and the vehicle's heading (from its track), :func:`box_ground_points`
models the vehicle as a level cuboid of typical size (:data:`VEHICLE_DIMENSIONS`) and solves for the footprint
centre whose projected cuboid matches the observed box's horizontal centre and bottom edge, the two box quantities
least sensitive to the size being a bit wrong. :func:`estimate_length_refit` (centres and headings fitted with the
size) and :func:`estimate_length` (centres and headings known) recover one vehicle's length from many frames.

Conventions (those of :mod:`trafficgeo.synth.render`, whose boxes :func:`cuboid_corners` builds):

* World coordinates in the camera's CRS and its units (x east, y north, z up). Vehicle dimensions given in metres
  are converted to CRS units with :func:`trafficgeo.crs.metres_per_unit` (US-foot CRSs exist).
* ``heading_deg``: direction of travel, degrees clockwise from grid north.
* A cuboid's ``centre`` is the centre of its footprint on the road; the cuboid is level (its bottom at the height of
  the centre, even on a grade), ``length`` along the heading, ``width`` across it, ``height`` up.
* Corners are ordered front-left, front-right, rear-right, rear-left, bottom (0-3) then top (4-7).
"""

from __future__ import annotations

from trafficgeo.traffic.box_length import (
    HEADING_PRIOR_DEG,
    MOTION_SIGMA_M,
    TURN_SIGMA_DEG,
    estimate_length,
    estimate_length_refit,
)
from trafficgeo.traffic.box_points import (
    CLIPPED_BOTTOM,
    CLIPPED_SIDES,
    FALLBACK_STATUSES,
    NO_BOX,
    NO_DIMENSIONS,
    NO_HEADING,
    NOT_CONVERGED,
    BoxGroundPoints,
    box_ground_points,
)
from trafficgeo.traffic.cuboids import (
    CLASS_ALIASES,
    DEFAULT_CLASS,
    VEHICLE_DIMENSIONS,
    cuboid_boxes,
    cuboid_corners,
    dimensions_for,
    free_edges,
)

__all__ = [
    "CLASS_ALIASES",
    "CLIPPED_BOTTOM",
    "CLIPPED_SIDES",
    "DEFAULT_CLASS",
    "FALLBACK_STATUSES",
    "HEADING_PRIOR_DEG",
    "MOTION_SIGMA_M",
    "NOT_CONVERGED",
    "NO_BOX",
    "NO_DIMENSIONS",
    "NO_HEADING",
    "TURN_SIGMA_DEG",
    "VEHICLE_DIMENSIONS",
    "BoxGroundPoints",
    "box_ground_points",
    "cuboid_boxes",
    "cuboid_corners",
    "dimensions_for",
    "estimate_length",
    "estimate_length_refit",
    "free_edges",
]
