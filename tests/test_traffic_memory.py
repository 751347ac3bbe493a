"""analyze's memory stays bounded per track point: the per-point passes (ground points, covariances, cuboid fits)
run in blocks, so their temporaries do not grow with the number of points."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pandas as pd
import pytest

import trafficgeo.traffic.measurements as measurements
from trafficgeo.camera.model import Camera
from trafficgeo.geo.cuboids import VEHICLE_DIMENSIONS, cuboid_boxes
from trafficgeo.geo.surface import PlaneSurface
from trafficgeo.run.tracks import ImageTracks
from trafficgeo.traffic.trajectories import world_trajectories

pytestmark = pytest.mark.slow  # measures peak memory in a subprocess

E0, N0, Z0 = 500000.0, 4000000.0, 100.0


def _boxed_tracks(vehicles: int, fps: float = 25.0) -> tuple[Camera, PlaneSurface, ImageTracks]:
    """Cars driving north at 15 m/s in two lanes, seen by a camera 8 m up beside the road, as boxes."""
    cam = Camera.from_orientation((1280, 720), 900.0, [E0 + 4.0, N0, Z0 + 8.0], 0.0, 12.0, crs="EPSG:32616")
    surface = PlaneSurface(point=np.array([E0, N0, Z0]), gx=0.0, gy=0.0)
    t = np.arange(0.0, 4.0, 1.0 / fps)
    rows = []
    for k in range(vehicles):
        xyz = np.column_stack([np.full(t.size, E0 - 1.75 * (k % 2)), N0 + 15.0 + 15.0 * t, np.full(t.size, Z0)])
        box = cuboid_boxes(cam, xyz, np.zeros(t.size), *VEHICLE_DIMENSIONS["car"])
        rows.append(pd.DataFrame({"track_id": f"c{k}", "frame": np.arange(t.size), "time": t,
                                  "x1": box[:, 0], "y1": box[:, 1], "x2": box[:, 2], "y2": box[:, 3]}))
    d = pd.concat(rows, ignore_index=True)
    n = len(d)
    box = d[["x1", "y1", "x2", "y2"]].to_numpy() + np.random.default_rng(0).normal(0.0, 1.0, (n, 4))
    tracks = ImageTracks(track_id=d["track_id"].to_numpy(dtype=object), frame=d["frame"].to_numpy(),
                         time=d["time"].to_numpy(), u=0.5 * (box[:, 0] + box[:, 2]), v=box[:, 3], box=box,
                         vclass=np.full(n, "car", dtype=object), score=np.full(n, np.nan))
    return cam, surface, tracks


def test_peak_memory_per_point_does_not_grow_with_the_points(monkeypatch: pytest.MonkeyPatch) -> None:
    """With blocks of 256 points, world_trajectories on 4,000 boxed points peaks (tracemalloc) under 2 kB
    per point; with the cuboid fits of all boxes at once it peaked at ~4.7 kB per point."""
    cam, surface, tracks = _boxed_tracks(40)
    world_trajectories(cam, surface, ImageTracks(*(getattr(tracks, f)[:200] for f in (
        "track_id", "frame", "time", "u", "v", "box", "vclass", "score"))))  # warm-up (compiled code)
    monkeypatch.setattr(measurements, "BLOCK_POINTS", 256)
    tracemalloc.start()
    try:
        world = world_trajectories(cam, surface, tracks)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert len(world.vehicles) == 40 and len(world.points) > 0.9 * len(tracks)
    assert peak / len(tracks) < 2000, peak / len(tracks)  # measured ~1,000 B (all boxes at once: ~4,700 B)
