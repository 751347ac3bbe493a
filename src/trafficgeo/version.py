"""The version of trafficgeo, defined once (the package metadata and every record that names the version read it
here)."""

__version__ = "0.1.0"
