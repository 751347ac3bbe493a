"""Demo world assembly: files, video, truth consistent with the camera and SUMO, determinism (a short, small world)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from trafficgeo.camera.io import read_camera_json
from trafficgeo.synth.world import WorldOptions, build_world

OPTS = WorldOptions(seed=3, duration_s=1.2, fps=10.0, image_size=(480, 270), length_m=200.0, focal_px=430.0,
                    veh_per_hour_per_lane=1200.0, ortho_resolution=0.1, view_half_size=70.0)


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
    for bad in (["--fps", "30"], ["--lanes", "0"], ["--mix", "car=lots"], ["--mix", "plane=1"], ["--length", "-5"]):
        code, _, err = invoke("synth", "--out", tmp_path / "bad", *bad)
        assert code == 2 and err.startswith("trafficgeo: error:") and len(err.strip().splitlines()) == 1, err
        assert not (tmp_path / "bad").exists()
