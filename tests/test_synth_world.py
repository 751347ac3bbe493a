"""Demo world assembly: files, video, truth consistent with the camera and SUMO, determinism (a short, small world)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from trafficgeo.camera.calibrated import read_camera_json
from trafficgeo.synth.world import WorldOptions, build_world

pytestmark = pytest.mark.slow  # builds generated worlds (SUMO, lidar, orthophoto, H.264 video)

OPTS = WorldOptions(seed=3, duration_s=1.2, fps=10.0, image_size=(480, 270), length_m=200.0, focal_px=430.0,
                    veh_per_hour_per_lane=1200.0, ortho_resolution=0.1, view_half_size=70.0,
                    count_stations=(-20.0, 0.0, 30.0))


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    out = tmp_path_factory.mktemp("world")
    summary = build_world(out, OPTS)
    return out, summary


def test_world_writes_every_file_and_a_decodable_h264_video(world):
    out, summary = world
    for name in ("ortho.tif", "cloud.laz", "gcps.csv", "camera_truth.json", "video.mp4", "truth_tracks.csv",
                 "truth_counts.csv", "world.json", "sumo/fcd.xml"):
        assert (out / name).is_file(), name
    import av

    with av.open(str(out / "video.mp4")) as container:
        stream = container.streams.video[0]
        assert stream.codec_context.name == "h264"
        frames = [f.to_ndarray(format="rgb24") for f in container.decode(stream)]
    assert len(frames) == summary["frames"] == 12
    assert frames[0].shape == (270, 480, 3)


def test_vehicles_in_the_video_are_where_the_truth_boxes_say(world):
    out, _ = world
    import av

    with av.open(str(out / "video.mp4")) as container:
        frames = np.stack([f.to_ndarray(format="rgb24") for f in container.decode(video=0)]).astype(np.float32)
    # The empty road through the true camera: the orthophoto draped on the road surface.
    from trafficgeo.geo.raster import read_raster
    from trafficgeo.geo.surface import DEMSurface
    from trafficgeo.synth.gcp_scene import RoadSurface
    from trafficgeo.synth.render import drape_orthophoto

    road = RoadSurface(origin=np.array(OPTS.origin), azimuth_deg=OPTS.azimuth_deg, grade=OPTS.grade,
                       crossfall=OPTS.crossfall, crest_radius=OPTS.crest_radius)
    ortho = read_raster(out / "ortho.tif")
    left, bottom, right, top = ortho.bounds
    res = 0.25
    X, Y = np.meshgrid(np.arange(left + res / 2, right, res), np.arange(top - res / 2, bottom, -res))
    dem = DEMSurface(road.z(X, Y), left, top, res, res)
    background = drape_orthophoto(read_camera_json(out / "camera_truth.json"), dem, ortho)
    tracks = pd.read_csv(out / "truth_tracks.csv")
    checked = 0
    for f in (3, 8):
        diff = np.abs(frames[f] - background).max(axis=2)
        rows = tracks[(tracks["frame"] == f) & (tracks["visible_fraction"] > 0.9)]
        covered = np.zeros(diff.shape, dtype=bool)
        for _, r in rows.iterrows():
            if not np.isfinite(r["x1"]):
                continue
            x1, y1, x2, y2 = (round(r[k]) for k in ("x1", "y1", "x2", "y2"))
            covered[max(y1 - 3, 0):y2 + 4, max(x1 - 3, 0):x2 + 4] = True
            if (x2 - x1) * (y2 - y1) >= 60:
                assert diff[y1:y2 + 1, x1:x2 + 1].mean() > 15, (f, r["vehicle"])
                checked += 1
        # Away from every vehicle (and its shadow, within a margin) the frame is the road plus noise.
        from scipy.ndimage import binary_dilation

        far = ~binary_dilation(covered, iterations=25)
        assert np.median(diff[far]) < 10  # sensor noise, illumination drift, sub-pixel shake
    assert checked >= 3


def test_truth_agrees_with_the_camera_and_gcps_with_their_noise(world):
    out, _ = world
    cam = read_camera_json(out / "camera_truth.json")
    tracks = pd.read_csv(out / "truth_tracks.csv")
    assert len(tracks) > 0 and set(tracks["class"]) <= {"car", "van", "truck", "bus"}
    uv = cam.project(tracks[["x", "y", "z"]].to_numpy())
    inside = cam.in_image(uv)
    assert inside.sum() > 20
    # Ground points are the projections plus the recorded camera shake (at most 3 x 0.3 px).
    np.testing.assert_allclose(tracks[["u", "v"]].to_numpy()[inside], uv[inside], atol=1.0)
    seen = (tracks["visible_fraction"] > 0.5).to_numpy() & inside
    x1, y1, x2, y2 = (tracks.loc[seen, k].to_numpy() for k in ("x1", "y1", "x2", "y2"))
    assert np.all((x1 <= uv[seen, 0] + 1) & (uv[seen, 0] <= x2 + 1) & (y1 - 1 <= uv[seen, 1]) & (uv[seen, 1] <= y2 + 1))
    g = pd.read_csv(out / "gcps.csv")
    res = cam.project(g[["x", "y", "z"]].to_numpy()) - g[["u", "v"]].to_numpy()
    assert np.sqrt(np.mean(res**2)) < 3 * OPTS.pixel_sigma + 1.0
    assert (g["role"] == "check").sum() >= 3


def test_thirty_fps_is_resampled_from_a_finer_simulation(tmp_path):
    opts = WorldOptions(seed=1, duration_s=1.0, fps=30.0, image_size=(320, 180), length_m=150.0,
                        ortho_resolution=0.2, view_half_size=60.0, veh_per_hour_per_lane=1500.0)
    summary = build_world(tmp_path, opts, video=False)
    assert summary["frames"] == 30
    tracks = pd.read_csv(tmp_path / "truth_tracks.csv")
    np.testing.assert_allclose(tracks["time"] * 30, tracks["frame"], atol=0.01)  # times written to 0.1 ms
    assert tracks["frame"].between(0, 29).all()
    # Positions advance by speed / fps between frames (constant-ish speed over 1/30 s).
    for _, g in tracks.groupby("vehicle"):
        if len(g) > 2:
            step = np.hypot(np.diff(g["x"]), np.diff(g["y"]))
            np.testing.assert_allclose(step, g["speed_kmh"].to_numpy()[:-1] / 3.6 / 30, rtol=0.1, atol=0.02)


def test_counts_at_every_line_match_the_tracks(world):
    out, _ = world
    counts = pd.read_csv(out / "truth_counts.csv")
    tracks = pd.read_csv(out / "truth_tracks.csv")
    from trafficgeo.synth.gcp_scene import RoadSurface

    road = RoadSurface(origin=np.array(OPTS.origin), azimuth_deg=OPTS.azimuth_deg)
    s, _ = road.station_offset(tracks["x"].to_numpy(), tracks["y"].to_numpy())
    tracks["s"] = s
    for line, station in ((1, -20.0), (2, 0.0), (3, 30.0)):
        expect = set()
        for vid, g in tracks.groupby("vehicle"):
            g = g.sort_values("time")
            ds = g["s"].to_numpy() - station
            sign = 1.0 if g["direction"].iloc[0] == 1 else -1.0
            if np.any((ds[:-1] * sign < 0) & (ds[1:] * sign >= 0)):
                expect.add(vid)
        got = set(counts.loc[counts["line"] == line, "vehicle"])
        assert got == expect, line
    assert counts["speed_kmh"].between(10, 90).all()


def test_same_seed_gives_the_same_world(world, tmp_path):
    out, _ = world
    build_world(tmp_path, OPTS, video=False)
    for name in ("gcps.csv", "truth_counts.csv", "sumo/fcd.xml", "camera_truth.json"):
        assert (tmp_path / name).read_bytes() == (out / name).read_bytes(), name
    a = pd.read_csv(out / "truth_tracks.csv")
    b = pd.read_csv(tmp_path / "truth_tracks.csv")
    same = [c for c in b.columns if c not in ("u", "v")]  # the video adds the camera shake to u, v
    pd.testing.assert_frame_equal(a[same], b[same])


def test_synth_command_writes_a_world_and_refuses_bad_options(tmp_path):
    from cli_support import invoke

    code, _, err = invoke("synth", "--out", tmp_path / "w", "--duration", "0.4", "--fps", "10", "--image-size",
                            "320x180", "--length", "150", "--outliers", "1", "--grade", "0.02", "--no-video")
    assert code == 0, err
    assert (tmp_path / "w" / "gcps.csv").is_file() and (tmp_path / "w" / "truth_tracks.gpkg").is_file()
    assert (tmp_path / "w" / "count_lines.gpkg").is_file()
    for bad in (["--count-stations", "0,500"], ["--count-stations", "x"], ["--fps", "0"], ["--lanes", "0"],
                ["--mix", "car=lots"], ["--mix", "plane=1"], ["--length", "-5"]):
        code, _, err = invoke("synth", "--out", tmp_path / "bad", *bad)
        assert code == 2 and err.startswith("trafficgeo: error:") and len(err.strip().splitlines()) == 1, err
        assert not (tmp_path / "bad").exists()
