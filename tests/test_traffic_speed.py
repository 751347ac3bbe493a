"""Vehicle and spot speeds are unbiased under position noise: distance along the direction of travel, not the
smoothed path's arc length (which includes the path's sideways wiggle and reads high)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st

from trafficgeo.geo.surface import ConstantSurface
from trafficgeo.site.lines import CountLine
from trafficgeo.synth.noisy_paths import PathNoise, metres_per_px, noisy_road_tracks, road_point
from trafficgeo.traffic.counts import aggregate_counts, find_crossings
from trafficgeo.traffic.smoothing import SmoothedTrack, along_track, smooth_track
from trafficgeo.traffic.trajectories import TrajectoryOptions, world_trajectories

SWAY = PathNoise(sideways_m=0.05, along_m=0.05, sway_m=0.5, sway_hz=1.0)


@pytest.mark.slow
@pytest.mark.parametrize("radius_m", [np.inf, 250.0], ids=["straight", "curved"])
def test_vehicle_and_spot_speeds_unbiased_when_the_path_sways_sideways(radius_m: float) -> None:
    """The ground point sways 0.5 m sideways at 1 Hz (a box edge wandering across the vehicle) and the smoother
    keeps it: the arc length over time (``mean_speed_kmh``) reads ~0.2 km/h high for every vehicle, the distance
    along the direction of travel (``speed_kmh``), the point speeds and the spot speeds at a line do not."""
    speeds = np.sort(np.random.default_rng(3).uniform(60.0, 120.0, 16))[::-1]  # none catches up another
    camera, tracks, truth = noisy_road_tracks(speeds, SWAY, radius_m=radius_m, seed=5)
    world = world_trajectories(camera, ConstantSurface(0.0), tracks,
                               TrajectoryOptions(pixel_sigma=0.1 / metres_per_px()))
    veh = world.vehicles
    assert veh["source_track"].nunique() == speeds.size
    veh = veh[veh["duration_s"] >= 1.0]  # a glimpse of a split-off part has no speed
    true = veh["source_track"].map(truth).to_numpy()
    old = veh["mean_speed_kmh"].to_numpy() - true
    new = veh["speed_kmh"].to_numpy() - true
    assert np.mean(old) > 0.15 and np.all(old > 0.05)  # the arc length reads high (measured +0.23 km/h)
    assert abs(np.mean(new)) < 0.05 and np.max(np.abs(new)) < 0.1, new
    assert np.all(veh["travel_m"] < veh["path_length_m"])
    pts = world.points
    point_err = pts["speed_kmh"].to_numpy() - pts["source_track"].map(truth).to_numpy()
    assert abs(np.nanmean(point_err)) < 0.05
    assert abs(np.nanmedian(veh["median_speed_kmh"].to_numpy() - true)) < 0.1
    # spot speeds at a line across the road 30 m past the camera, and the interval's space-mean speed
    at, d = road_point(np.array([30.0]), radius_m)
    p, normal = at[0], np.array([-d[0, 1], d[0, 0]])
    line = CountLine("c", shapely.LineString([p - 10 * normal, p + 10 * normal]))
    cross = find_crossings(pts, [line])
    assert len(cross) == speeds.size
    source = veh.set_index("track_id")["source_track"]
    spot_err = cross["speed_kmh"].to_numpy() - cross["track_id"].map(source).map(truth).to_numpy()
    assert abs(np.mean(spot_err)) < 0.1 and np.max(np.abs(spot_err)) < 0.5, spot_err
    counts = aggregate_counts(cross, 3600.0, 0.0, float(tracks.time.max()))
    true_space_mean = speeds.size / np.sum(1.0 / speeds)
    assert counts["space_mean_speed_kmh"].iloc[0] == pytest.approx(true_space_mean, abs=0.1)


def _analytic_track(speed: float, radius_m: float, heading_deg: float, wiggle_m: float, wiggle_hz: float,
                    fps: float = 30.0, duration_s: float = 8.0) -> SmoothedTrack:
    """A smoothed track given exactly: constant ``speed`` (m/s) along a road of ``radius_m``, turned to
    ``heading_deg``, plus a sideways wiggle of the path (and the matching sideways velocity)."""
    t = np.arange(0.0, duration_s, 1.0 / fps)
    pos, d = road_point(speed * t, radius_m)
    normal = np.column_stack([-d[:, 1], d[:, 0]])
    w = 2 * np.pi * wiggle_hz
    side, side_v = wiggle_m * np.sin(w * t), wiggle_m * w * np.cos(w * t)
    xy = pos + side[:, None] * normal
    v = speed * d + side_v[:, None] * normal  # the curvature term of the wiggle's velocity is negligible here
    a = np.radians(90.0 - heading_deg)
    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    xy, v = xy @ rot.T, v @ rot.T
    sp = np.hypot(v[:, 0], v[:, 1])
    zeros = np.zeros(t.size)
    return SmoothedTrack(time=t, x=xy[:, 0], y=xy[:, 1], vx=v[:, 0], vy=v[:, 1], position_std=zeros, speed=sp,
                         speed_std=zeros, heading_deg=np.degrees(np.arctan2(v[:, 0], v[:, 1])) % 360, accel=zeros,
                         outlier=np.zeros(t.size, dtype=bool))


@settings(max_examples=40, deadline=None)
@given(speed_kmh=st.floats(60.0, 120.0), radius_m=st.one_of(st.just(np.inf), st.floats(150.0, 2000.0)),
       heading_deg=st.floats(0.0, 360.0), wiggle_m=st.floats(0.1, 0.5), wiggle_hz=st.floats(0.8, 3.0))
def test_distance_along_the_direction_of_travel_ignores_a_sideways_wiggle(
        speed_kmh: float, radius_m: float, heading_deg: float, wiggle_m: float, wiggle_hz: float) -> None:
    """Any heading, straight or curved road: the travel distance over the time gives the true speed within
    0.1 km/h with the path wiggling sideways; the arc length reads high by about (a w)^2 / 4 v."""
    v = speed_kmh / 3.6
    sm = _analytic_track(v, radius_m, heading_deg, wiggle_m, wiggle_hz)
    speed, travel = along_track(sm)
    duration = sm.time[-1] - sm.time[0]
    assert 3.6 * travel / duration == pytest.approx(speed_kmh, abs=0.1)
    assert np.mean(3.6 * speed) == pytest.approx(speed_kmh, abs=0.1)
    arc = np.hypot(np.diff(sm.x), np.diff(sm.y)).sum()
    expected_excess = 3.6 * (wiggle_m * 2 * np.pi * wiggle_hz) ** 2 / (4 * v)
    assert 3.6 * arc / duration - speed_kmh == pytest.approx(expected_excess, rel=0.35, abs=0.03)


def test_noise_around_a_stop_adds_no_distance() -> None:
    """A vehicle at 50 km/h stops for 6 s and drives on; with 0.3 m noise the smoothed path jitters while it
    stands, which the arc length counts as travel. Along the direction of travel the jitter cancels; the point
    speeds at the stop are near 0, not the jitter's magnitude."""
    fps, rng = 10.0, np.random.default_rng(2)
    t = np.arange(0.0, 20.0, 1.0 / fps)
    v = np.interp(t, [0, 4, 7, 13, 16, 20], [50 / 3.6, 50 / 3.6, 0, 0, 50 / 3.6, 50 / 3.6])
    s = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))])
    xy = np.column_stack([s, np.zeros_like(s)]) + rng.normal(0.0, 0.3, (t.size, 2))
    sm = smooth_track(t, xy, 0.3)
    speed, travel = along_track(sm)
    arc = np.hypot(np.diff(sm.x), np.diff(sm.y)).sum()
    assert travel == pytest.approx(s[-1], abs=1.0)  # end-point noise only
    assert arc - s[-1] > 1.0  # the arc length counts the jitter (measured +1.9 m)
    stopped = (t > 8) & (t < 12)
    assert np.mean(3.6 * speed[stopped]) < 0.5 * np.mean(3.6 * sm.speed[stopped])


def test_direction_of_a_vehicle_that_never_moves() -> None:
    """A parked vehicle (never faster than 1 m/s): its direction is its net displacement, its travel that
    displacement's length; no NaN."""
    t = np.arange(0.0, 5.0, 0.1)
    xy = np.column_stack([0.02 * t, 0.01 * t]) + np.random.default_rng(0).normal(0, 0.05, (t.size, 2))
    speed, travel = along_track(smooth_track(t, xy, 0.05))
    assert np.all(np.isfinite(speed)) and np.isfinite(travel) and abs(travel) < 1.0


def test_vehicles_table_columns() -> None:
    """travel_speed_kmh (the former headline) is travel_m over duration_s; mean_speed_kmh path_length_m over
    duration_s; speed_kmh (the headline, over the middle of the time seen: a camera made by hand) agrees."""
    camera, tracks, _truth = noisy_road_tracks(np.array([72.0]), PathNoise(0.1, 0.1), seed=1)
    veh = world_trajectories(camera, ConstantSurface(0.0), tracks,
                             TrajectoryOptions(pixel_sigma=0.1 / metres_per_px())).vehicles.iloc[0]
    assert veh["travel_speed_kmh"] == pytest.approx(3.6 * veh["travel_m"] / veh["duration_s"])
    assert veh["mean_speed_kmh"] == pytest.approx(3.6 * veh["path_length_m"] / veh["duration_s"])
    assert veh["speed_kmh"] == pytest.approx(72.0, abs=0.1)
    assert 0 < veh["speed_std_kmh"] < 0.5
    assert isinstance(pd.Series(veh).get("point_speed_std_kmh"), float)
    # the window speed_kmh is measured over: the middle half of the time seen (nothing known of the calibration)
    start, end, first, last = (veh[c] for c in ("speed_start_time", "speed_end_time", "first_time", "last_time"))
    assert end - start == pytest.approx(0.5 * veh["duration_s"], abs=0.05)
    assert 0.5 * (start + end) == pytest.approx(0.5 * (first + last), abs=0.05)
