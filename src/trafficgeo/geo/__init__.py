"""Geospatial layer: rasters, point clouds, surfaces and image <-> world mapping."""
