"""trafficgeo: georeferenced, lane-level traffic data from a fixed camera and common GIS data."""

from trafficgeo.errors import CalibrationError, InputError, TrafficgeoError

__version__ = "0.1.0"

__all__ = ["CalibrationError", "InputError", "TrafficgeoError", "__version__"]
