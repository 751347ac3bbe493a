"""How much road a vehicle hides behind it at a counting line, and the warning ``analyze`` gives about it."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from trafficgeo.camera.model import Camera
from trafficgeo.geo.surface import ConstantSurface
from trafficgeo.site.lines import CountLine
from trafficgeo.traffic.analyze import MAX_HIDDEN_M, hidden_behind_m, line_warnings
from trafficgeo.traffic.trajectories import TrajectoryOptions

E0, N0, Z0 = 500000.0, 5000000.0, 100.0
US_FOOT = 1200.0 / 3937.0


def _camera(height: float, crs: str = "EPSG:32633", scale: float = 1.0) -> Camera:
    """1080p camera ``height`` m over the road at (E0, N0), looking north (+y) and down 8 degrees; ``scale`` CRS
    units per metre."""
    return Camera.from_orientation((1920, 1080), 1700.0, [E0, N0, (Z0 + height) * scale], 0.0, 8.0, crs=crs)


def _line(name: str, distance: float, scale: float = 1.0) -> CountLine:
    """A line across a two-lane road ``distance`` m north of the camera."""
    y = N0 + distance * scale
    return CountLine(name, shapely.LineString([(E0 - 3.5 * scale, y), (E0 + 3.5 * scale, y)]))


@settings(max_examples=60, deadline=None)
@given(distance=st.floats(5.0, 300.0), height=st.floats(2.0, 40.0), car=st.floats(1.0, 4.5))
def test_hidden_length_is_where_the_sight_line_over_the_roof_meets_the_road(distance: float, height: float,
                                                                           car: float) -> None:
    """The sight line from the camera over the roof edge at ``distance`` reaches the road ``hidden`` m farther."""
    assume(abs(height - car) > 1e-3)
    cam = _camera(height)
    hidden = hidden_behind_m(cam, ConstantSurface(Z0), np.array([[E0, N0 + distance]]), car)[0]
    if height <= car:
        assert hidden == np.inf
        return
    # Walk the sight line: from the camera's height down to the roof at `distance`, on to the road.
    slope = (height - car) / distance
    assert hidden == pytest.approx(height / slope - distance, rel=1e-9)


def test_hidden_length_uses_metres_in_a_feet_crs() -> None:
    """The same scene in US survey feet gives the same metres."""
    metric = hidden_behind_m(_camera(8.0), ConstantSurface(Z0), np.array([[E0, N0 + 120.0]]))[0]
    feet_cam = _camera(8.0, "EPSG:2240", 1.0 / US_FOOT)
    feet = hidden_behind_m(feet_cam, ConstantSurface(Z0 / US_FOOT), np.array([[E0, N0 + 120.0 / US_FOOT]]))[0]
    assert metric == pytest.approx(120.0 * 1.5 / 6.5)
    assert feet == pytest.approx(metric, rel=1e-9)


def test_a_line_far_from_a_low_camera_is_warned_about() -> None:
    """From 8 m up a car hides 9 m at 40 m and 28 m at 120 m: only the far line gets the warning, with figures."""
    cam, road = _camera(8.0), ConstantSurface(Z0)
    words = line_warnings(cam, road, [_line("near", 40.0), _line("far", 120.0)],
                          TrajectoryOptions(max_metres_per_px=10.0))
    assert len(words) == 1, words
    assert words[0].startswith("counting line far: seen from 8.0 m above the road and 120 m away, a car 1.5 m "
                               "high hides 28 m of road behind it")
    assert "count nearer the camera or film from higher up" in words[0]
    # From 25 m up the far line is fine too.
    assert hidden_behind_m(_camera(25.0), road, np.array([[E0, N0 + 120.0]]))[0] < MAX_HIDDEN_M
    assert line_warnings(_camera(25.0), road, [_line("far", 120.0)], TrajectoryOptions(max_metres_per_px=10.0)) == []
