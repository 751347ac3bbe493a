"""The multi-camera demo city: files named by the batch pattern, frame-exact cuts, one traffic seen by every
camera, and the plan of a batch over it."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import numpy as np
import pandas as pd
import pytest
from tests.cli_support import invoke

from trafficgeo.batch.manifest import plan_batch, read_cameras
from trafficgeo.batch.names import DEFAULT_NAME_PATTERN
from trafficgeo.errors import InputError
from trafficgeo.synth.city import (
    CITY_NAME_PATTERN,
    CityCamera,
    CityOptions,
    camera_world,
    files_per_camera,
    spread_cameras,
)
from trafficgeo.synth.world import WorldOptions


def test_the_city_names_files_by_the_batch_default_pattern() -> None:
    assert CITY_NAME_PATTERN == DEFAULT_NAME_PATTERN


def test_city_options_are_checked() -> None:
    with pytest.raises(InputError, match=r"file_s 2\.5: must be whole seconds"):
        CityOptions(file_s=2.5)
    with pytest.raises(InputError, match="whole number of frames"):
        CityOptions(file_s=1.0, world=WorldOptions(fps=7.5))
    with pytest.raises(InputError, match="unique"):
        CityOptions(cameras=(CityCamera("a"), CityCamera("a")))
    with pytest.raises(InputError, match="IANA"):
        CityOptions(timezone="Mars/Olympus")
    assert files_per_camera(CityOptions()) == 2
    assert files_per_camera(CityOptions(file_s=7.0)) == 3  # 7 + 7 + 6 s


def test_cameras_spread_along_the_road_and_offsets_turn_them() -> None:
    cams = spread_cameras(3, 200.0)
    assert [c.station for c in cams] == [-60.0, 0.0, 60.0] and [c.camera_id for c in cams] == ["cam1", "cam2",
                                                                                                 "cam3"]
    assert [c.station for c in spread_cameras(2, 100.0)] == [-30.0, 30.0]
    base = WorldOptions()
    plain = camera_world(base, CityCamera("a", station=-60.0))
    assert plain.heading_deg is None and plain.camera_station == -60.0
    turned = camera_world(base, CityCamera("a", station=-60.0, heading_offset_deg=10.0, tilt_offset_deg=-2.0))
    # default view from 12 m right of the axis (2 lanes of 3.5 m + 5 m) to the axis 85 m ahead, 8 m up
    assert turned.heading_deg - 10.0 == pytest.approx(30.0 - np.degrees(np.arctan2(12.0, 85.0)), abs=0.05)
    assert turned.tilt_deg + 2.0 == pytest.approx(np.degrees(np.arctan2(8.0, np.hypot(12.0, 85.0))), abs=0.3)


@pytest.fixture(scope="module")
def city(small_city):
    return small_city, small_city / "cameras.csv"


def _frames(path) -> np.ndarray:
    import av

    with av.open(str(path)) as c:
        # grey, every 4th pixel each way (enough to tell frames apart, small)
        return np.stack([f.to_ndarray(format="gray")[::4, ::4] for f in c.decode(video=0)]).astype(np.int16)


@pytest.mark.slow
def test_city_files_are_named_and_cut_frame_exactly(city) -> None:
    out, csv_path = city
    assert csv_path == out / "cameras.csv"
    names = sorted(p.name for p in (out / "videos").iterdir())
    assert names == ["cam1_2026-05-04_07-30-00.mp4", "cam1_2026-05-04_07-30-10.mp4",
                     "cam2_2026-05-04_07-30-00.mp4", "cam2_2026-05-04_07-30-10.mp4"]
    for cam in ("cam1", "cam2"):
        original = _frames(out / cam / "video.mp4")
        parts = [_frames(out / "videos" / n) for n in names if n.startswith(cam)]
        assert [len(p) for p in parts] == [100, 100] and len(original) == 200
        cut = np.concatenate(parts)
        err = np.abs(cut - original).mean(axis=(1, 2))
        assert err.max() < 3.0  # each frame is its original (re-encoded), in order
        shifted = np.abs(cut[1:] - original[:-1]).mean(axis=(1, 2))
        assert np.median(shifted) > 1.5 * np.median(err)  # ... and not its neighbour


@pytest.mark.slow
def test_files_carry_their_utc_start_as_creation_time(city) -> None:
    from trafficgeo.batch.videos import _creation_time

    out, _ = city
    assert _creation_time(out / "videos" / "cam2_2026-05-04_07-30-10.mp4") == datetime(2026, 5, 4, 5, 30, 10,
                                                                                        tzinfo=UTC)


@pytest.mark.slow
def test_every_camera_sees_the_same_vehicles(city) -> None:
    out, _ = city
    a, b = (pd.read_csv(out / cam / "truth_tracks.csv") for cam in ("cam1", "cam2"))
    key = ["vehicle", "frame"]
    a, b = a.sort_values(key).reset_index(drop=True), b.sort_values(key).reset_index(drop=True)
    assert len(a) > 1000 and a["vehicle"].nunique() > 10
    pd.testing.assert_frame_equal(a[[*key, "x", "y", "z", "speed_kmh"]], b[[*key, "x", "y", "z", "speed_kmh"]])
    # the cameras differ: the same vehicle is elsewhere in their images
    assert np.nanmedian(np.abs(a["u"] - b["u"]) + np.abs(a["v"] - b["v"])) > 50.0


@pytest.mark.slow
def test_plan_of_the_city(city) -> None:
    out, csv_path = city
    cams = read_cameras(csv_path)
    assert list(cams) == ["cam1", "cam2"] and cams["cam1"].detector == "background"
    assert cams["cam2"].surface == str((out / "cam2" / "cloud.laz").resolve())
    assert cams["cam1"].options == {"interval_s": 10}
    plan = plan_batch(csv_path, [str(out / "videos" / "*.mp4")])
    assert plan.problems == () and plan.crs == "EPSG:2949"
    assert [t.task_id for t in plan.tasks] == [
        "detect/cam1/20260504T053000Z", "detect/cam1/20260504T053010Z", "detect/cam2/20260504T053000Z",
        "detect/cam2/20260504T053010Z", "track/cam1/2026-05-04", "track/cam2/2026-05-04"]
    t0 = datetime(2026, 5, 4, 5, 30, tzinfo=UTC)
    for v in plan.videos:
        assert v.duration_s == pytest.approx(10.0) and v.fps == pytest.approx(10.0)
    track = plan.tasks[-1]
    assert (track.start_utc, track.end_utc) == (t0, t0 + timedelta(seconds=20))
    assert track.depends == ("detect/cam2/20260504T053000Z", "detect/cam2/20260504T053010Z")


def test_synth_cameras_flags_are_checked(tmp_path) -> None:
    code, _, err = invoke("synth", "--out", tmp_path / "c", "--cameras", "0")
    assert code == 2 and "--cameras 0 must be at least 1" in err
    code, _, err = invoke("synth", "--out", tmp_path / "c", "--cameras", "2", "--file-s", "2.5")
    assert code == 2 and "--file-s 2.5: must be whole seconds" in err
