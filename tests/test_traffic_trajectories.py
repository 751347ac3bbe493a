"""World trajectories from image tracks: known vehicles seen through a known camera, with noise and mishaps."""

from __future__ import annotations

import numpy as np
import pytest

from trafficgeo.camera.model import Camera
from trafficgeo.errors import InputError
from trafficgeo.geo.surface import ConstantSurface
from trafficgeo.run.tracks import ImageTracks
from trafficgeo.traffic.trajectories import TrajectoryOptions, ground_covariance, world_trajectories

E0, N0, Z0 = 500000.0, 5000000.0, 100.0


def _camera(crs: str = "EPSG:32633", unit: float = 1.0) -> Camera:
    """8 m up, 5 m east of a road along +y (north), looking north and down 12 degrees."""
    return Camera.from_orientation((1920, 1080), 1700.0, [(E0 + 5.0) / unit, N0 / unit, (Z0 + 8.0) / unit], 0.0,
                                   12.0, crs=crs)


def _tracks_from_world(camera: Camera, tid: np.ndarray, t: np.ndarray, xyz: np.ndarray,
                       noise_px: float = 0.0, seed: int = 0, vclass: str = "car") -> ImageTracks:
    uv = camera.project(xyz) + np.random.default_rng(seed).normal(0, noise_px, (len(t), 2))
    order = np.lexsort((t, tid))
    n = len(t)
    return ImageTracks(track_id=tid[order].astype(object), frame=np.rint(t * 25).astype(int)[order], time=t[order],
                       u=uv[order, 0], v=uv[order, 1], box=np.full((n, 4), np.nan),
                       vclass=np.full(n, vclass, dtype=object), score=np.full(n, np.nan))


def _straight(track: str, x_off: float, y0: float, speed: float, duration: float, fps: float = 25.0):
    t = np.arange(0.0, duration, 1.0 / fps)
    xyz = np.column_stack([np.full(t.size, E0 + x_off), N0 + y0 + speed * t, np.full(t.size, Z0)])
    return np.full(t.size, track, dtype=object), t, xyz


def test_speed_and_path_of_noisy_straight_tracks() -> None:
    cam = _camera()
    parts = [_straight("a", -1.75, 15.0, 50 / 3.6, 4.0), _straight("b", -5.25, 20.0, 80 / 3.6, 3.0)]
    tid, t, xyz = (np.concatenate(p) for p in zip(*parts, strict=True))
    tracks = _tracks_from_world(cam, tid, t, xyz, noise_px=1.0, seed=3)
    world = world_trajectories(cam, ConstantSurface(Z0), tracks, TrajectoryOptions(pixel_sigma=1.0))
    veh = world.vehicles.set_index("track_id")
    assert veh.loc["a", "speed_kmh"] == pytest.approx(50.0, abs=1.0)
    assert veh.loc["b", "speed_kmh"] == pytest.approx(80.0, abs=1.5)
    assert veh.loc["a", "path_length_m"] == pytest.approx(50 / 3.6 * (4.0 - 0.04), abs=1.0)
    pts = world.points
    a = pts[pts["track_id"] == "a"]
    # smoothed positions closer to the truth than the raw ground points
    truth_y = N0 + 15.0 + 50 / 3.6 * a["time"].to_numpy()
    raw = np.abs(a["y_obs"].to_numpy() - truth_y)
    smooth = np.abs(a["y"].to_numpy() - truth_y)
    assert np.median(smooth) < 0.6 * np.median(raw)
    assert np.all(np.abs((a["heading_deg"] + 180.0) % 360.0 - 180.0) < 2.0)  # north, either side of 0
    assert np.all(a["speed_std_kmh"] > 0) and np.all(a["speed_std_kmh"] < 5)
    assert {"lon", "lat", "z"} <= set(pts.columns) and np.allclose(pts["z"], Z0)


def test_id_switch_splits_the_track_and_single_outliers_do_not() -> None:
    cam = _camera()
    tid_a, t, xyz_a = _straight("a", -1.75, 15.0, 12.0, 4.0)
    _, _, xyz_b = _straight("b", -5.25, 25.0, 12.0, 4.0)
    xyz = xyz_a.copy()
    xyz[50:] = xyz_b[50:]  # from t = 2 s the tracker follows another vehicle, one lane over and 10 m ahead
    xyz[20] += [0.0, 6.0, 0.0]  # and one wild point before that
    tracks = _tracks_from_world(cam, tid_a, t, xyz, noise_px=0.5, seed=1)
    world = world_trajectories(cam, ConstantSurface(Z0), tracks)
    names = list(world.vehicles["track_id"])
    assert names == ["a.1", "a.2"]
    veh = world.vehicles.set_index("track_id")
    assert veh.loc["a.1", "last_time"] < 2.0 <= veh.loc["a.2", "first_time"] + 0.3
    assert veh.loc["a.1", "speed_kmh"] == pytest.approx(43.2, abs=1.5)
    first = world.points[world.points["track_id"] == "a.1"]
    assert bool(first["outlier"].to_numpy()[20])


def test_a_gap_is_bridged_only_by_consistent_motion() -> None:
    """A tracker that lost a vehicle for 0.8 s may give its id to another one for a few frames: the track ends at
    the gap (too few points to be flagged as a switch by the filter, they would join it). The same vehicle found
    again where its motion puts it keeps one track."""
    cam = _camera()
    tid, t, xyz = _straight("a", -1.75, 15.0, 14.0, 4.0)
    keep = (t < 1.2) | ((t >= 2.0) & (t < 2.16))  # 30 points, a 0.8 s gap, then 4 points
    switched = xyz.copy()
    switched[t >= 2.0] += [-3.5, 30.0, 0.0]  # another vehicle, one lane over and 30 m ahead, same speed
    cut = world_trajectories(cam, ConstantSurface(Z0), _tracks_from_world(cam, tid[keep], t[keep], switched[keep],
                                                                          noise_px=0.5, seed=2))
    # nothing of the other vehicle: its 4 points are a fragment of their own (kept for the journeys stage, which
    # joins them to nothing here and drops them as too short: tests/test_journeys.py)
    assert cut.vehicles["last_time"].iloc[0] < 1.2 and cut.vehicles["first_time"].iloc[1] >= 2.0
    assert cut.vehicles["speed_kmh"].iloc[0] == pytest.approx(14.0 * 3.6, abs=1.5)
    same = world_trajectories(cam, ConstantSurface(Z0), _tracks_from_world(cam, tid[keep], t[keep], xyz[keep],
                                                                           noise_px=0.5, seed=2))
    assert list(same.vehicles["track_id"]) == ["a"] and same.vehicles["last_time"].iloc[0] > 2.1
    loose = world_trajectories(cam, ConstantSurface(Z0), _tracks_from_world(cam, tid[keep], t[keep], switched[keep],
                                                                            noise_px=0.5, seed=2),
                               TrajectoryOptions(check_gap_s=5.0))
    assert loose.vehicles["last_time"].max() > 2.1  # without the check the other vehicle's points join the track


def test_a_bad_stretch_is_cut_out_and_the_vehicle_joined_again() -> None:
    """0.4 s of a track on another vehicle (a merged blob) in the middle: the vehicle's own parts on both sides
    are one vehicle again (its whole path and speed); the bad stretch is a part of its own."""
    cam = _camera()
    tid, t, xyz = _straight("a", -1.75, 15.0, 14.0, 4.0)
    bad = (t >= 1.8) & (t < 2.2)
    xyz[bad] += [-3.5, 12.0, 0.0]
    tracks = _tracks_from_world(cam, tid, t, xyz, noise_px=0.5, seed=4)
    world = world_trajectories(cam, ConstantSurface(Z0), tracks)
    veh = world.vehicles.set_index("track_id")
    main = veh[veh["path_length_m"] == veh["path_length_m"].max()].iloc[0]
    assert main["first_time"] < 0.1 and main["last_time"] > 3.9
    assert main["speed_kmh"] == pytest.approx(14.0 * 3.6, abs=1.0)
    pts = world.points[world.points["track_id"] == main.name]
    assert not np.any((pts["time"] >= 1.8) & (pts["time"] < 2.2) & ~pts["outlier"])
    apart = world_trajectories(cam, ConstantSurface(Z0), tracks, TrajectoryOptions(rejoin_gap_s=1e-6))
    assert apart.vehicles["last_time"].min() < 2.0 < apart.vehicles["first_time"].max()  # without: two parts


def test_points_off_the_road_are_dropped_with_a_reason() -> None:
    cam = _camera()
    tid, t, xyz = _straight("a", -1.75, 15.0, 10.0, 2.0)
    tracks = _tracks_from_world(cam, tid, t, xyz)
    v = tracks.v.copy()
    v[:3] = 10.0  # above the horizon (the camera looks down 12 degrees)
    tracks = ImageTracks(tracks.track_id, tracks.frame, tracks.time, tracks.u, v, tracks.box, tracks.vclass,
                         tracks.score)
    short = _tracks_from_world(cam, np.array(["s", "s"], dtype=object), np.array([0.0, 0.04]), xyz[:2])
    both = ImageTracks(*(np.concatenate([getattr(tracks, f), getattr(short, f)]) for f in
                         ("track_id", "frame", "time", "u", "v", "box", "vclass", "score")))
    # fragments this short are kept by default for the journeys stage to join (tests/test_journeys.py)
    world = world_trajectories(cam, ConstantSurface(Z0), both, TrajectoryOptions(min_fragment_points=5))
    assert world.dropped == {"above_horizon": 3, "short_track": 2}
    assert list(world.vehicles["track_id"]) == ["a"]


def test_feet_crs_gives_the_same_metric_answer() -> None:
    ft = 1200.0 / 3937.0  # US survey foot in metres
    cam_m = _camera("EPSG:32633")
    cam_ft = _camera("EPSG:2240", unit=ft)  # Georgia West, US survey feet (only the unit matters here)
    tid, t, xyz = _straight("a", -1.75, 15.0, 60 / 3.6, 3.0)
    tr_m = _tracks_from_world(cam_m, tid, t, xyz, noise_px=1.0, seed=5)
    tr_ft = _tracks_from_world(cam_ft, tid, t, xyz / ft, noise_px=1.0, seed=5)
    np.testing.assert_allclose(tr_m.u, tr_ft.u, atol=1e-6)
    w_m = world_trajectories(cam_m, ConstantSurface(Z0), tr_m)
    w_ft = world_trajectories(cam_ft, ConstantSurface(Z0 / ft), tr_ft)
    np.testing.assert_allclose(w_ft.points["speed_kmh"], w_m.points["speed_kmh"], rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(w_ft.points["x"] * ft, w_m.points["x"], atol=1e-6)
    np.testing.assert_allclose(w_ft.points["distance_m"], w_m.points["distance_m"], rtol=1e-9)
    assert w_ft.vehicles["speed_kmh"].iloc[0] == pytest.approx(60.0, abs=1.0)


def test_ground_covariance_grows_with_range_and_along_the_ray() -> None:
    cam = _camera()
    uv = cam.project(np.array([[E0 - 1.75, N0 + 20.0, Z0], [E0 - 1.75, N0 + 80.0, Z0]]))
    from trafficgeo.geo.mapping import pixels_to_world

    g = pixels_to_world(cam, uv, ConstantSurface(Z0))
    cov = ground_covariance(cam, ConstantSurface(Z0), uv, g.xyz, 1.0, 1.0)
    near, far = np.linalg.eigvalsh(cov[0]), np.linalg.eigvalsh(cov[1])
    assert far[1] > 10 * near[1]  # range^2 / sin(incidence)
    assert cov[1][1, 1] > 20 * cov[1][0, 0]  # looking north: mostly along y
    # 1 px at 80 m, 8 m up, f = 1700: about 80 / 1700 / (8.8 / 80) m along the road
    assert np.sqrt(cov[1][1, 1]) == pytest.approx(80 / 1700 / np.sin(np.arctan2(8, 80)), rel=0.15)


def test_options_checked() -> None:
    with pytest.raises(InputError, match="pixel_sigma"):
        TrajectoryOptions(pixel_sigma=0.0)
    with pytest.raises(InputError, match="min_points"):
        TrajectoryOptions(min_points=1)


def test_a_wrong_first_point_does_not_capture_the_filter() -> None:
    """Given parts (as in the second pass), a first point 1 m ahead makes the filter believe in 90 km/h and
    reject everything after it; the run of rejections splits it off and the rest is smoothed right."""
    from trafficgeo.traffic.trajectories import _smooth_segments

    t = np.arange(0.0, 2.0, 0.04)
    xy = np.column_stack([np.zeros(t.size), 12.5 * t])  # 45 km/h
    xy[1, 1] += 1.0  # 1 m jump between the first two points: 25 m/s more
    cov = np.broadcast_to(0.05**2 * np.eye(2), (t.size, 2, 2)).copy()
    parts = _smooth_segments(t, xy, cov, TrajectoryOptions(), segments=[np.arange(t.size)])
    # the points split off are a fragment of their own (kept for the journeys stage)
    assert len(parts) <= 2 and all(p[0].max() < 5 for p in parts[:-1])
    idx, sm = parts[-1]
    assert idx[0] >= 1 and np.median(sm.speed) == pytest.approx(12.5, abs=0.2)


def test_box_noise_that_grows_with_the_box_is_not_taken_for_outliers() -> None:
    """A car drives from 60 m to 16 m towards the camera; its boxes grow from 45 to 137 px tall and scatter by 7 %
    of their height, as a detector's do. A fixed pixel noise takes the near points for outliers; noise in
    proportion to the box (``box_sigma_share``) keeps them, and the speed stays right."""
    cam = _camera()
    t = np.arange(0.0, 4.4, 0.08)
    xyz = np.column_stack([np.full(t.size, E0 - 1.75), N0 + 60.0 - 10.0 * t, np.full(t.size, Z0)])
    range_m = np.linalg.norm(xyz - cam.position, axis=1)
    h, w = 1700.0 * 1.6 / range_m, 1700.0 * 1.9 / range_m
    n = t.size
    for seed in range(4):
        uv = cam.project(xyz) + np.random.default_rng(seed).normal(0.0, 1.0, (n, 2)) * (0.07 * h)[:, None]
        box = np.column_stack([uv[:, 0] - w / 2, uv[:, 1] - h, uv[:, 0] + w / 2, uv[:, 1]])
        tracks = ImageTracks(track_id=np.full(n, "a", dtype=object), frame=np.rint(t * 25).astype(int), time=t,
                             u=uv[:, 0], v=uv[:, 1], box=box, vclass=np.full(n, "car", dtype=object),
                             score=np.full(n, 0.5))
        fixed, grows = (world_trajectories(cam, ConstantSurface(Z0), tracks,
                                           TrajectoryOptions(box_correction=False, box_sigma_share=share))
                        for share in (0.0, 0.07))
        assert int(fixed.points["outlier"].sum()) >= 5
        assert len(grows.vehicles) == 1 and int(grows.points["outlier"].sum()) <= 1
        assert grows.vehicles["speed_kmh"].iloc[0] == pytest.approx(36.0, abs=1.5)


def test_point_noise_from_the_box_height() -> None:
    from trafficgeo.traffic.trajectories import point_sigma_px

    box = np.array([[0.0, 100.0, 50.0, 140.0], [0.0, 0.0, 10.0, 300.0], [np.nan] * 4])
    got = point_sigma_px(box, TrajectoryOptions(pixel_sigma=3.0, box_sigma_share=0.1))
    np.testing.assert_allclose(got, [5.0, np.hypot(3.0, 30.0), 3.0])
    np.testing.assert_allclose(point_sigma_px(box, TrajectoryOptions(pixel_sigma=2.0)), 2.0)
    assert TrajectoryOptions().box_sigma_share == 0.0 < TrajectoryOptions.at_junction().box_sigma_share
    with pytest.raises(InputError, match=r"box_sigma_share=-0.1 is out of range; it must be 0 \(off\) or more"):
        TrajectoryOptions(box_sigma_share=-0.1)
    # one sigma per point: each point's covariance is its own sigma's
    cam = _camera()
    xyz = np.array([[E0 - 1.75, N0 + 20.0, Z0], [E0 - 1.75, N0 + 40.0, Z0]])
    uv = cam.project(xyz)
    each = ground_covariance(cam, ConstantSurface(Z0), uv, xyz, np.array([1.0, 4.0]), 1.0)
    for k, s in enumerate((1.0, 4.0)):
        np.testing.assert_allclose(each[k], ground_covariance(cam, ConstantSurface(Z0), uv[k:k + 1], xyz[k:k + 1],
                                                              s, 1.0)[0], rtol=1e-9)
