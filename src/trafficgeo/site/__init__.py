"""The site a camera looks at: calibrated camera, road surface, lanes and counting lines, loaded once
(:class:`~trafficgeo.site.site.Site`), with the one surface loader, the layout readers, the check that the camera
is above its surface and the GIS layers of the site."""

from trafficgeo.site.lanes import Lanes, read_lanes
from trafficgeo.site.lines import CountLine, read_count_lines
from trafficgeo.site.site import Site, load_camera, load_lanes, load_lines
from trafficgeo.site.surface import load_surface

__all__ = ["CountLine", "Lanes", "Site", "load_camera", "load_lanes", "load_lines", "load_surface", "read_count_lines",
           "read_lanes"]
