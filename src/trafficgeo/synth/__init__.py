"""Synthetic test scenes with known truth (for tests and benchmarks)."""

from trafficgeo.synth.gcp_scene import GCPScene, RoadSurface, make_gcp_scene

__all__ = ["GCPScene", "RoadSurface", "make_gcp_scene"]
