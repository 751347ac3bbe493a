"""Real trajectories (NGSIM Peachtree, US survey feet) through a synthetic camera, and the simulated tracker."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from trafficgeo.camera.model import Camera
from trafficgeo.errors import InputError
from trafficgeo.geo.surface import ConstantSurface
from trafficgeo.run.tracks import ImageTracks
from trafficgeo.synth.detections import DetectionNoise, ideal_detections, noisy_tracks
from trafficgeo.traffic.trajectories import TrajectoryOptions, world_trajectories

DATA = Path(__file__).parent / "data" / "ngsim-peachtree-subset" / "peachtree_27s_positions.csv"
FT = 1200.0 / 3937.0  # US survey foot in metres


@pytest.fixture(scope="module")
def ngsim() -> pd.DataFrame:
    df = pd.read_csv(DATA)
    df["track"] = df["Vehicle_ID"].astype(str) + "/" + df["v_length"].map("{:g}".format)
    df["time"] = (df["Global_Time"] - df["Global_Time"].min()) / 1000.0
    return df.sort_values(["track", "time"]).reset_index(drop=True)


def test_ngsim_speeds_recovered_through_a_camera_in_feet(ngsim: pd.DataFrame) -> None:
    """A camera 10 m up beside Peachtree Street (EPSG:2240, feet) sees the real vehicles with 1 px noise; the
    smoothed speeds match NGSIM's v_Vel far better than raw 1 s differences of the same points."""
    x, y = ngsim["Global_X"].to_numpy(), ngsim["Global_Y"].to_numpy()
    c = np.array([np.median(x), np.median(y)])
    *_, vt = np.linalg.svd(np.column_stack([x - c[0], y - c[1]]), full_matrices=False)
    axis = vt[0]
    along = (np.column_stack([x, y]) - c) @ axis
    starts = np.arange(along.min(), along.max(), 10.0 / FT)
    seen = [np.sum((along >= a + 11.0 / FT) & (along <= a + 150.0 / FT)) for a in starts]
    pos = c + axis * starts[int(np.argmax(seen))] - np.array([axis[1], -axis[0]]) * (10.0 / FT)
    heading = float(np.degrees(np.arctan2(axis[0], axis[1])) % 360.0)
    cam = Camera.from_orientation((1920, 1080), 1500.0, [pos[0], pos[1], 10.0 / FT], heading + 5.0, 23.5,
                                  crs="EPSG:2240")
    uv = cam.project(np.column_stack([x, y, np.zeros(x.size)]))
    ok = cam.in_image(np.nan_to_num(uv, nan=-1e9))
    df = ngsim[ok].reset_index(drop=True)
    uv = uv[ok] + np.random.default_rng(4).normal(0.0, 1.0, (int(ok.sum()), 2))
    assert df["track"].nunique() >= 5 and len(df) > 500
    n = len(df)
    frame = np.rint(df["time"].to_numpy() * 10).astype(int)
    tracks = ImageTracks(track_id=df["track"].to_numpy(dtype=object), frame=frame, time=df["time"].to_numpy(),
                         u=uv[:, 0], v=uv[:, 1], box=np.full((n, 4), np.nan), vclass=np.full(n, "", dtype=object),
                         score=np.full(n, np.nan))
    world = world_trajectories(cam, ConstantSurface(0.0), tracks, TrajectoryOptions(pixel_sigma=1.0))
    truth = df.set_index(["track", frame])["v_Vel"] * FT * 3.6
    pts = world.points
    true = np.array([truth[k] for k in zip(pts["source_track"], pts["frame"], strict=True)])
    err = pts["speed_kmh"].to_numpy() - true
    # raw 1 s differences of the same noisy ground points (x_obs, y_obs are in feet)
    raw_err = []
    for _tid, g in pts.groupby("source_track"):
        if len(g) > 10:
            d = np.hypot(np.diff(g["x_obs"].to_numpy()[::10]), np.diff(g["y_obs"].to_numpy()[::10])) * FT
            dt = np.diff(g["time"].to_numpy()[::10])
            mid = truth[[(s, f) for s, f in zip(g["source_track"], g["frame"], strict=True)]].to_numpy()
            raw_err.append(3.6 * d / dt - 0.5 * (mid[::10][1:] + mid[::10][:-1]))
    raw_mae = float(np.mean(np.abs(np.concatenate(raw_err))))
    assert np.isfinite(err).mean() > 0.95  # only glimpses under 1 s carry no speed
    mae = float(np.nanmean(np.abs(err)))
    assert mae < 1.5, mae  # measured 0.9 km/h
    assert mae < 0.6 * raw_mae, (mae, raw_mae)
    assert pts["distance_m"].max() < 200  # metres, although the CRS is in feet


@pytest.fixture(scope="module")
def truth_boxes() -> pd.DataFrame:
    """Two vehicles driving past each other in the image, with visibility."""
    rows = []
    for f in range(50):
        rows.append({"frame": f, "time": f / 25, "vehicle": "a", "class": "car", "x1": 100 + 10 * f, "y1": 500,
                     "x2": 200 + 10 * f, "y2": 560, "visible_fraction": 1.0})
        rows.append({"frame": f, "time": f / 25, "vehicle": "b", "class": "truck", "x1": 700 - 10 * f, "y1": 480,
                     "x2": 850 - 10 * f, "y2": 570, "visible_fraction": 1.0 if f < 40 else 0.2})
    return pd.DataFrame(rows)


def test_noisy_tracks_swap_misses_occlusion_and_truth(truth_boxes: pd.DataFrame) -> None:
    noise = DetectionNoise(jitter_px=1.0, jitter_rel=0.0, miss_rate=0.0, fragment_rate=0.0, swap_rate=1.0)
    out = noisy_tracks(truth_boxes, (1920, 1080), noise, seed=0)
    assert set(out.columns) >= {"frame", "track_id", "class", "x1", "y1", "x2", "y2", "vehicle"}
    assert len(out[out["vehicle"] == "b"]) == 40  # hidden for its last 10 frames
    # the boxes overlap from about frame 20: from then on each track follows the other vehicle
    late = out[out["frame"] >= 35]
    assert (late["track_id"] != late["vehicle"]).all()
    early = out[out["frame"] <= 15]
    assert (early["track_id"] == early["vehicle"]).all()
    assert not out.duplicated(["track_id", "frame"]).any()
    jitter = out.merge(truth_boxes, on=["frame", "vehicle"], suffixes=("", "_t"))
    d = (jitter["x1"] - jitter["x1_t"]).to_numpy()
    assert 0.7 < d.std() < 1.3 and abs(d.mean()) < 0.3


def test_noisy_tracks_fragments_and_misses(truth_boxes: pd.DataFrame) -> None:
    noise = DetectionNoise(miss_rate=0.3, fragment_rate=1.0, swap_rate=0.0)
    out = noisy_tracks(truth_boxes, (1920, 1080), noise, seed=3)
    assert out["track_id"].nunique() == 4  # each vehicle continues under a new id
    assert 0.55 < len(out) / 90 < 0.85
    with pytest.raises(InputError, match="miss_rate"):
        DetectionNoise(miss_rate=1.5)
    with pytest.raises(InputError, match="columns"):
        noisy_tracks(truth_boxes.drop(columns="visible_fraction"), (1920, 1080))


def test_ideal_detections_are_the_visible_true_boxes_frame_by_frame(truth_boxes: pd.DataFrame) -> None:
    frames = list(ideal_detections(truth_boxes, (1920, 1080), min_visible=0.5))
    assert [f for f, _, _ in frames] == list(range(50))
    assert np.allclose([t for _, t, _ in frames], np.arange(50) / 25)
    assert [len(d) for _, _, d in frames] == [2] * 40 + [1] * 10  # b is hidden for its last 10 frames
    _, _, d = frames[3]
    assert np.allclose(d.boxes, [[130, 500, 230, 560], [670, 480, 820, 570]])
    assert list(d.classes) == ["car", "truck"] and np.all(d.scores == 1.0)
    # clipped to the image; a box left under 4 px wide there is not seen
    edge = truth_boxes.assign(x1=truth_boxes["x1"] - 300, x2=truth_boxes["x2"] - 300)
    first = next(ideal_detections(edge, (1920, 1080), min_visible=0.0))[2]
    assert np.allclose(first.boxes[:, [0, 2]], [[400, 550]])  # a (-200..-100) is off the image
    late = list(ideal_detections(truth_boxes.assign(x1=truth_boxes["x1"] + 1700, x2=truth_boxes["x2"] + 1700),
                                 (1920, 1080)))[2][2]
    assert len(late) == 1 and np.allclose(late.boxes[0, [0, 2]], [1820, 1919])  # b is off to the right
    with pytest.raises(InputError, match="min_visible"):
        next(ideal_detections(truth_boxes, (1920, 1080), min_visible=1.5))
