"""The batch manifest: cameras.csv checks, file names to UTC (time zones, DST), windows, camera-day tasks, problems
with files, tasks.csv round trip and the summary."""

from __future__ import annotations

import csv
import itertools
from dataclasses import replace
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trafficgeo.batch.manifest import (
    MAX_WINDOW_S,
    build_tasks,
    plan_batch,
    plan_summary,
    read_cameras,
    read_tasks,
    windows,
    write_tasks,
)
from trafficgeo.batch.model import CameraEntry, VideoFile
from trafficgeo.batch.names import DEFAULT_NAME_PATTERN, compile_pattern, local_to_utc
from trafficgeo.camera.io import write_camera_json
from trafficgeo.camera.model import Camera
from trafficgeo.errors import InputError

HEADER = ["camera_id", "camera", "surface", "timezone", "lanes", "lines", "detector", "options"]


def _camera(path: Path, crs: str | None = "EPSG:2949") -> None:
    write_camera_json(path, Camera.from_orientation((640, 360), 576.0, [245000.0, 5182600.0, 100.0], 30.0, 12.0,
                                                    0.0, crs=crs))


def _video(path: Path, frames: int = 10, fps: int = 10, creation: str | None = None) -> Path:
    """A tiny H.264 video (64x48) of ``frames`` frames at ``fps``."""
    import av

    path.parent.mkdir(parents=True, exist_ok=True)
    with av.open(str(path), mode="w", format="mp4") as c:
        if creation:
            c.metadata["creation_time"] = creation
        s = c.add_stream("libx264", rate=fps)
        s.width, s.height, s.pix_fmt = 64, 48, "yuv420p"
        for k in range(frames):
            img = np.full((48, 64, 3), 10 * k % 256, np.uint8)
            for p in s.encode(av.VideoFrame.from_ndarray(img, format="rgb24")):
                c.mux(p)
        for p in s.encode():
            c.mux(p)
    return path


def _cameras_csv(folder: Path, rows: list[dict[str, str]] | None = None) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    _camera(folder / "cam.json")
    rows = rows if rows is not None else [
        {"camera_id": "A", "camera": "cam.json", "surface": "90", "timezone": "Europe/Berlin",
         "detector": "background"},
        {"camera_id": "B", "camera": "cam.json", "surface": "plane", "timezone": "UTC", "detector": "background",
         "options": '{"every": 2, "interval_s": 300}'}]
    path = folder / "cameras.csv"
    with path.open("w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, HEADER)
        w.writeheader()
        for r in rows:
            w.writerow({k: r.get(k, "") for k in HEADER})
    return path


# ------------------------------------------------------------------------------------------------ names and time
def test_default_pattern_reads_camera_and_local_time_to_utc() -> None:
    pat = compile_pattern(DEFAULT_NAME_PATTERN)
    cid, local = pat.parse("cam_1_2026-05-04_07-30-15", ("cam", "cam_1"))
    assert (cid, local) == ("cam_1", datetime(2026, 5, 4, 7, 30, 15))
    assert local_to_utc(local, "Europe/Berlin") == datetime(2026, 5, 4, 5, 30, 15, tzinfo=UTC)  # CEST = UTC+2
    assert local_to_utc(datetime(2026, 1, 4, 7, 30), "Europe/Berlin") == datetime(2026, 1, 4, 6, 30, tzinfo=UTC)
    assert local_to_utc(datetime(2026, 1, 4, 7, 30), "America/New_York") == datetime(2026, 1, 4, 12, 30, tzinfo=UTC)
    assert pat.parse("other_2026-05-04_07-30-15", ("cam",)) is None
    assert pat.parse("cam_2026-05-04", ("cam",)) is None
    with pytest.raises(ValueError, match="month"):
        pat.parse("cam_2026-13-04_07-30-15", ("cam",))
    assert pat.example("cam") == "cam_2026-05-04_07-30-00"


def test_dst_ambiguous_time_is_the_first_and_a_skipped_time_takes_the_offset_before() -> None:
    # Europe/Berlin 2026: clocks go forward 29 March 02:00 -> 03:00, back 25 October 03:00 -> 02:00.
    assert local_to_utc(datetime(2026, 10, 25, 2, 30), "Europe/Berlin") == datetime(2026, 10, 25, 0, 30, tzinfo=UTC)
    assert local_to_utc(datetime(2026, 3, 29, 2, 30), "Europe/Berlin") == datetime(2026, 3, 29, 1, 30, tzinfo=UTC)
    assert local_to_utc(datetime(2026, 3, 29, 3, 30), "Europe/Berlin") == datetime(2026, 3, 29, 1, 30, tzinfo=UTC)


def test_custom_patterns_and_bad_patterns() -> None:
    pat = compile_pattern("%Y%m%d_%H%M%S.%f_{camera}")
    assert pat.parse("20260504_073015.25_north", ("north",)) == ("north", datetime(2026, 5, 4, 7, 30, 15, 250000))
    assert compile_pattern("rec-%y%j-%H").parse("rec-26124-07", ()) == (None, datetime(2026, 5, 4, 7))
    with pytest.raises(InputError, match="%Q is not supported"):
        compile_pattern("{camera}_%Q")
    with pytest.raises(InputError, match="needs a year"):
        compile_pattern("{camera}_%H-%M")


# ------------------------------------------------------------------------------------------------ windows and tasks
def _vf(cid: str, start: datetime, duration_s: float, name: str = "v", fps: float = 25.0) -> VideoFile:
    return VideoFile(cid, Path(f"/videos/{cid}_{name}.mp4"), start, duration_s, fps, 1, "f")


def _entries(tz: str = "Europe/Berlin") -> dict[str, CameraEntry]:
    return {"A": CameraEntry("A", Path("a.json"), "0", tz)}


def test_a_long_file_is_split_into_windows_of_at_most_an_hour() -> None:
    start = datetime(2026, 5, 4, 6, 0, tzinfo=UTC)
    tasks = build_tasks([_vf("A", start, 9000.0)], _entries())
    detect = [t for t in tasks if t.stage == "detect"]
    assert [(t.video_start_s, t.video_end_s) for t in detect] == [(0.0, 3000.0), (3000.0, 6000.0), (6000.0, 9000.0)]
    assert [t.task_id for t in detect] == ["detect/A/20260504T060000Z", "detect/A/20260504T065000Z",
                                           "detect/A/20260504T074000Z"]
    assert MAX_WINDOW_S == 3600.0
    (track,) = [t for t in tasks if t.stage == "track"]
    assert track.task_id == "track/A/2026-05-04" and track.depends == tuple(t.task_id for t in detect)
    assert (track.start_utc, track.end_utc) == (start, start + timedelta(seconds=9000))


@pytest.mark.slow
@settings(max_examples=200, deadline=None)
@given(st.floats(0.04, 40000.0), st.floats(1.0, 7200.0))
def test_windows_cover_the_file_exactly_without_overlap(duration_s: float, max_window_s: float) -> None:
    w = windows(duration_s, max_window_s)
    assert w[0][0] == 0.0 and w[-1][1] == duration_s
    assert all(a1 == b0 for (_, a1), (b0, _) in itertools.pairwise(w))
    assert all(0 < b - a <= max_window_s * (1 + 1e-9) for a, b in w)
    assert len(w) == 1 or duration_s > (len(w) - 1) * max_window_s * (1 - 1e-9)  # no more windows than needed


def test_a_file_crossing_local_midnight_feeds_both_days() -> None:
    # 23:30 CEST on 4 May to 00:30 CEST on 5 May (21:30Z to 22:30Z)
    v = _vf("A", datetime(2026, 5, 4, 21, 30, tzinfo=UTC), 3600.0)
    tasks = build_tasks([v], _entries())
    d, t4, t5 = tasks
    assert d.task_id == "detect/A/20260504T213000Z" and d.day == "2026-05-04"
    assert (t4.task_id, t5.task_id) == ("track/A/2026-05-04", "track/A/2026-05-05")
    assert t4.depends == t5.depends == (d.task_id,)
    midnight = datetime(2026, 5, 4, 22, 0, tzinfo=UTC)
    assert (t4.start_utc, t4.end_utc) == (v.start_utc, midnight)
    assert (t5.start_utc, t5.end_utc) == (midnight, v.end_utc)
    # in UTC the same file is one day
    assert [t.task_id for t in build_tasks([v], _entries("UTC")) if t.stage == "track"] == ["track/A/2026-05-04"]


def test_task_ids_stay_unique_with_windows_inside_one_second() -> None:
    tasks = build_tasks([_vf("A", datetime(2026, 5, 4, 6, 0, tzinfo=UTC), 1.0)], _entries(), max_window_s=0.4)
    ids = [t.task_id for t in tasks if t.stage == "detect"]
    assert ids == ["detect/A/20260504T060000Z+0", "detect/A/20260504T060000Z+0.333333",
                   "detect/A/20260504T060000Z+0.666667"]


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(0, 86400), st.floats(1.0, 20000.0)), min_size=1, max_size=6),
       st.sampled_from(["UTC", "Europe/Berlin", "America/Los_Angeles", "Asia/Kolkata"]))
def test_every_detected_second_is_tracked_once_on_its_local_day(spans, tz) -> None:
    t0 = datetime(2026, 3, 27, tzinfo=UTC)  # spans the spring DST change in Europe and America
    files, at = [], 0.0
    for k, (gap_s, duration_s) in enumerate(spans):  # files one after another, with gaps
        files.append(_vf("A", t0 + timedelta(seconds=at + gap_s), duration_s, name=str(k)))
        at += gap_s + duration_s
    tasks = build_tasks(files, _entries(tz), max_window_s=3600.0)
    detect = {t.task_id: t for t in tasks if t.stage == "detect"}
    track = [t for t in tasks if t.stage == "track"]
    assert len(detect) + len(track) == len(tasks) and len({t.task_id for t in tasks}) == len(tasks)
    from zoneinfo import ZoneInfo

    for t in track:
        for dep in t.depends:
            d = detect[dep]
            assert d.start_utc < t.end_utc and d.end_utc > t.start_utc  # every dependency overlaps the day
        assert t.start_utc.astimezone(ZoneInfo(tz)).date().isoformat() == t.day
        assert (t.end_utc - timedelta(microseconds=1)).astimezone(ZoneInfo(tz)).date().isoformat() == t.day
    for d in detect.values():  # each detect task feeds the track tasks of exactly the days it touches
        days = {t.day for t in track if d.task_id in t.depends}
        first = d.start_utc.astimezone(ZoneInfo(tz)).date()
        last = (d.end_utc - timedelta(microseconds=1)).astimezone(ZoneInfo(tz)).date()
        assert days == {(first + timedelta(days=k)).isoformat() for k in range((last - first).days + 1)}


# ------------------------------------------------------------------------------------------------ cameras.csv
def test_read_cameras_resolves_paths_and_keeps_order(tmp_path) -> None:
    cams = read_cameras(_cameras_csv(tmp_path))
    assert list(cams) == ["A", "B"]
    assert cams["A"].camera == (tmp_path / "cam.json").resolve() and cams["A"].surface == "90"
    assert cams["B"].options == {"every": 2, "interval_s": 300} and cams["B"].detector == "background"
    assert cams["A"].lanes is None and cams["A"].options == {}


_GOOD = {"camera_id": "A", "camera": "cam.json", "surface": "90", "timezone": "Europe/Berlin",
         "detector": "background"}


@pytest.mark.parametrize(("change", "column", "words"), [
    ({"timezone": "Europe/Berlinn"}, "timezone", "IANA name such as Europe/Berlin"),
    ({"camera": "missing.json"}, "camera", "not found"),
    ({"surface": "dem.tif"}, "surface", "not found"),
    ({"camera_id": "a b"}, "camera_id", "letters, digits"),
    ({"options": "{every: 2}"}, "options", "not JSON"),
    ({"options": "[1, 2]"}, "options", "not a JSON object"),
    ({"options": '{"evry": 2}'}, "options", "unknown key 'evry'"),
    ({"options": '{"start_s": 2}'}, "options", "windows set it"),
    ({"options": '{"every": 0}'}, "options", "whole number >= 1"),
    ({"options": '{"interval_s": -5}'}, "options", "interval_s"),
    ({"options": '{"report": "yes"}'}, "options", "report 'yes' must be true or false"),
    ({"detector": "yolo.onnx"}, "detector", "not found"),
    ({"lanes": "lanes.gpkg"}, "lanes", "not found"),
])
def test_a_bad_cameras_row_names_file_line_and_column(tmp_path, change, column, words) -> None:
    path = _cameras_csv(tmp_path, [_GOOD, {**_GOOD, "camera_id": "B", **change}])
    with pytest.raises(InputError) as err:
        read_cameras(path)
    text = str(err.value)
    assert f"{path}, line 3, column {column}:" in text and words in text and "\n" not in text


def test_duplicate_camera_id_names_both_lines(tmp_path) -> None:
    path = _cameras_csv(tmp_path, [_GOOD, {**_GOOD, "surface": "plane"}])
    with pytest.raises(InputError, match=r"line 3, column camera_id: duplicate camera_id 'A' \(also on line 2\)"):
        read_cameras(path)


def test_missing_column_and_empty_file(tmp_path) -> None:
    path = tmp_path / "cameras.csv"
    path.write_text("camera_id,camera,surface\nA,cam.json,90\n", encoding="utf-8")
    with pytest.raises(InputError, match=r"line 1: missing column.*timezone"):
        read_cameras(path)
    path.write_text(",".join(HEADER) + "\n", encoding="utf-8")
    with pytest.raises(InputError, match="no cameras"):
        read_cameras(path)


def test_a_camera_without_crs_cannot_join_the_dataset(tmp_path) -> None:
    path = _cameras_csv(tmp_path)
    _camera(tmp_path / "cam.json", crs=None)
    with pytest.raises(InputError, match="has no CRS"):
        plan_batch(path, [str(tmp_path / "*.mp4")])


# ------------------------------------------------------------------------------------------------ files and plan
@pytest.fixture
def folder(tmp_path) -> Path:
    _cameras_csv(tmp_path)
    v = tmp_path / "videos"
    _video(v / "A_2026-05-04_07-30-00.mp4")  # 1 s
    _video(v / "A_2026-05-04_07-30-05.mp4")  # 4 s gap
    _video(v / "A_2026-05-04_07-30-05_copy.mp4")  # no match; no creation_time
    _video(v / "A_2026-05-04_07-30-05.5.mp4", frames=5)  # matches nothing either (".5" suffix)
    _video(v / "A_2026-05-04_07-30-06.mp4", frames=30)  # overlaps nothing: 07:30:06..09
    _video(v / "A_2026-05-04_07-30-08.mp4")  # overlaps the one before
    (v / "B_2026-05-04_07-30-00.mp4").write_bytes(b"not a video at all")
    _video(tmp_path / "byB" / "B" / "clip.mp4", creation="2026-05-04T09:00:00.000000Z")
    return tmp_path


def test_plan_finds_dates_and_reports_problem_files(folder) -> None:
    plan = plan_batch(folder / "cameras.csv", [str(folder / "videos" / "*.mp4"), str(folder / "byB" / "{camera}/*"),
                                               str(folder / "none" / "*.mp4")], crs="EPSG:32617")
    assert plan.crs == "EPSG:32617"
    names = [(v.camera_id, v.path.name, v.start_utc, round(v.duration_s, 3)) for v in plan.videos]
    assert names == [("A", "A_2026-05-04_07-30-00.mp4", datetime(2026, 5, 4, 5, 30, tzinfo=UTC), 1.0),
                     ("A", "A_2026-05-04_07-30-05.mp4", datetime(2026, 5, 4, 5, 30, 5, tzinfo=UTC), 1.0),
                     ("A", "A_2026-05-04_07-30-06.mp4", datetime(2026, 5, 4, 5, 30, 6, tzinfo=UTC), 3.0),
                     ("B", "clip.mp4", datetime(2026, 5, 4, 9, 0, tzinfo=UTC), 1.0)]
    assert all(len(v.fingerprint) == 64 and v.fps == 10.0 for v in plan.videos)
    problems = "\n".join(plan.problems)
    assert len(plan.problems) == 5, problems
    assert "A_2026-05-04_07-30-05_copy.mp4: no start time" in problems and "rename it like A_2026" in problems
    assert "B_2026-05-04_07-30-00.mp4: unreadable: not a readable video (" in problems
    assert "A_2026-05-04_07-30-08.mp4: overlaps A_2026-05-04_07-30-06.mp4" in problems
    assert "none/*.mp4: no video file matches" in problems
    ids = [t.task_id for t in plan.tasks]
    assert ids == ["detect/A/20260504T053000Z", "detect/A/20260504T053005Z", "detect/A/20260504T053006Z",
                   "detect/B/20260504T090000Z", "track/A/2026-05-04", "track/B/2026-05-04"]
    lines = plan_summary(plan)
    assert lines[0].startswith("2 camera(s), 4 video file(s), 0.00 h (0:00:06) of video; 6 tasks (4 detect, 2 track)")
    assert any("camera A (Europe/Berlin): 3 file(s)" in ln and "2026-05-04 07:30:00 CEST (2026-05-04T05:30:00Z)" in ln
               for ln in lines)
    assert any(ln.strip().startswith("gap of 0:00:04 from 2026-05-04 07:30:01 CEST") for ln in lines)
    assert sum("gap of" in ln for ln in lines) == 1  # 07:30:06 follows 07:30:05 + 1 s exactly
    assert "5 problem(s):" in lines


def test_a_file_named_for_another_camera_than_its_glob_is_a_problem(folder) -> None:
    _video(folder / "byB" / "B" / "A_2026-05-04_10-00-00.mp4")
    plan = plan_batch(folder / "cameras.csv", [str(folder / "byB" / "{camera}" / "*.mp4")])
    assert [v.path.name for v in plan.videos] == ["clip.mp4"]
    (line,) = plan.problems
    assert "A_2026-05-04_10-00-00.mp4: named for camera A but found by the glob of camera B" in line


def test_a_file_with_creation_time_but_no_camera_is_a_problem(folder) -> None:
    plan = plan_batch(folder / "cameras.csv", [str(folder / "byB" / "*" / "*.mp4")])
    assert plan.videos == () and plan.tasks == ()
    (line,) = plan.problems
    assert "clip.mp4: cannot tell which camera: name it like A_2026-05-04_07-30-00.mp4" in line
    with pytest.raises(InputError, match="no tasks"):
        write_tasks(folder / "tasks.csv", plan)


def test_tasks_csv_round_trip_and_edited_values(folder) -> None:
    plan = plan_batch(folder / "cameras.csv", [str(folder / "videos" / "*.mp4"), str(folder / "byB/{camera}/*")],
                      max_window_s=1.5)
    out = folder / "plans" / "tasks.csv"
    assert write_tasks(out, plan) == out
    back = read_tasks(out)
    assert back.tasks == plan.tasks and len(plan.tasks) == 7  # the 3 s file in two windows
    assert back.cameras == plan.cameras and back.crs == plan.crs and back.cameras_csv == plan.cameras_csv
    assert back.videos == plan.videos
    rows = list(csv.DictReader(out.open(encoding="utf-8")))
    assert rows[0]["cameras"] == "../cameras.csv" and rows[0]["video"] == "../videos/A_2026-05-04_07-30-00.mp4"
    for col, value, words in [("start_utc", "yesterday", "not a UTC time"), ("stage", "detekt", "not a stage"),
                              ("video_end_s", "-1", "time >= 0"), ("depends", "detect/A/x", "not a detect task"),
                              ("camera_id", "Z", "not a camera"), ("crs", "EPSG:99999999", "column crs")]:
        edited = [dict(r) for r in rows]
        target = edited[-1] if col == "depends" else edited[0]
        target[col] = value
        if col == "crs":
            for r in edited:
                r[col] = value
        with out.open("w", newline="", encoding="utf-8") as fh:
            w = csv.DictWriter(fh, list(rows[0]))
            w.writeheader()
            w.writerows(edited)
        line = len(edited) + 1 if col == "depends" else 2
        with pytest.raises(InputError) as err:
            read_tasks(out)
        assert f"line {line}, column {col}:" in str(err.value) and words in str(err.value), str(err.value)


def test_task_builder_refuses_overlapping_files() -> None:
    t = datetime(2026, 5, 4, 6, 0, tzinfo=UTC)
    with pytest.raises(ValueError, match="overlap"):
        build_tasks([_vf("A", t, 10.0, "a"), _vf("A", t + timedelta(seconds=5), 10.0, "b")], _entries())


def test_overlap_keeps_the_first_file() -> None:
    from trafficgeo.batch.videos import _without_overlaps

    t = datetime(2026, 5, 4, 6, 0, tzinfo=UTC)
    a, b, c = _vf("A", t, 10.0, "a"), _vf("A", t + timedelta(seconds=9.9), 5.0, "b"), \
        _vf("A", t + timedelta(seconds=9.99), 5.0, "c", fps=10.0)
    problems: list[str] = []
    assert _without_overlaps([b, a], ["A"], problems) == [a] and "A_b.mp4: overlaps A_a.mp4" in problems[0]
    assert _without_overlaps([a, c], ["A"], []) == [a, c]  # within half a frame (10 fps): not an overlap
    assert replace(a, duration_s=1.0).end_utc == t + timedelta(seconds=1)
