"""No silent misses with counting lines only (issue 29, part 3): without lanes or an ROI the built-in detector's tiles
are planned around the counting lines, and the plan warns per counting line where vehicles crossing it stay below
the detector's reach. Plan-level checks on a generated camera (no video)."""

from __future__ import annotations

import numpy as np
import pytest
import shapely

from trafficgeo.geo.surface import ConstantSurface
from trafficgeo.site.lines import CountLine
from trafficgeo.video.detectors.tile_bands import plan_bands
from trafficgeo.video.detectors.tile_plan import REFERENCE_CAR_M, TilePlan
from trafficgeo.video.detectors.tiling import LINE_BAND_ACROSS_M, line_reach, plan_tiles, vehicle_boxes

W, H = 1280, 720  # the clip
INPUT = 416
FLAT = ConstantSurface(0.0)
ROAD_W = 14.0  # m, four lanes along +y from x = 0


def junction_camera():
    """A camera 35 m above the road's side at y = 0, looking along the road (+y)."""
    from trafficgeo.camera.model import Camera

    return Camera.from_orientation((W, H), 1000.0, np.array([ROAD_W + 5.0, 0.0, 35.0]), 355.0, 20.0)


def across(name: str, y: float) -> CountLine:
    """A counting line across the four lanes at ``y`` m (a metre over each shoulder)."""
    return CountLine(name, shapely.LineString([(-1.0, y), (ROAD_W + 1.0, y)]))


def crossing_boxes(camera, y: float, offsets_m=(-20.0, -10.0, 0.0, 10.0, 20.0)) -> np.ndarray:
    """Image boxes of the reference car heading north at the middle of each lane, at ``y + offset`` m: before, on
    and after the line at ``y``."""
    xs = (np.arange(4) + 0.5) * ROAD_W / 4
    X, Y = np.meshgrid(xs, y + np.asarray(offsets_m))
    xyz = np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])
    return vehicle_boxes(camera, xyz, np.zeros(X.size), REFERENCE_CAR_M)


@pytest.mark.parametrize("planner", [plan_tiles, plan_bands])
def test_a_far_line_is_tiled_from_the_lines_alone(planner) -> None:
    """The far line (130 m) is too small for the full frame alone; planned from the lines, the car crossing it
    reaches the minimum size in the detector input on the line and 10-20 m before and after it."""
    cam = junction_camera()
    lines = [across("near", 70.0), across("far", 130.0)]
    boxes = crossing_boxes(cam, 130.0)
    assert np.isfinite(boxes).all()
    full_only = TilePlan((H, W), INPUT, 24.0, 2.0, np.zeros((0, 4)))
    assert full_only.input_size_px(boxes).max() < 24.0  # the issue: full frame only, the far line is missed
    plan = planner(cam, FLAT, lines, input_size=INPUT, min_size_px=24.0)
    assert plan.source == "lines" and len(plan.tiles) >= 1
    assert plan.input_size_px(boxes).min() >= 24.0 - 1e-6
    assert {r.name for r in plan.regions} == {"near", "far"}
    assert "planned around the counting lines" in plan.summary_lines()[0]
    assert plan.to_dict()["source"] == "lines"


def test_line_band_covers_a_few_metres_along_and_tens_across() -> None:
    """The planned road around a line: its length plus a few metres along it, LINE_BAND_ACROSS_M to each side."""
    cam = junction_camera()
    plan = plan_tiles(cam, FLAT, [across("far", 130.0)], input_size=INPUT)
    xyz = plan.samples.xyz
    assert xyz[:, 0].min() < -1.0 and xyz[:, 0].max() > ROAD_W + 1.0  # beyond the line's ends
    assert xyz[:, 0].min() > -1.0 - 5.0 and xyz[:, 0].max() < ROAD_W + 1.0 + 5.0
    span = xyz[:, 1].max() - xyz[:, 1].min()
    assert span == pytest.approx(2 * LINE_BAND_ACROSS_M, abs=1.0)
    np.testing.assert_allclose(plan.samples.heading_deg, 0.0, atol=1e-9)  # across the east-west line: north


def test_a_line_below_reach_warns_naming_it_and_its_size() -> None:
    cam = junction_camera()
    lines = [across("near", 70.0), across("horizon", 600.0)]
    plan = plan_tiles(cam, FLAT, lines, input_size=INPUT)
    object.__setattr__(plan, "lines", line_reach(plan, cam, FLAT, lines))
    reach = {r.name: r for r in plan.lines}
    assert reach["near"].in_view == reach["horizon"].in_view == 1.0
    assert reach["near"].short == 0.0 and reach["horizon"].short == 1.0
    assert reach["horizon"].input_px[1] < 24.0
    warned = plan.line_warnings()
    assert len(warned) == 1 and warned[0].startswith("counting line horizon:")
    assert f"{reach['horizon'].input_px[0]:.0f}" in warned[0] and "24 px" in warned[0]
    assert warned[0] in plan.warnings() and warned[0] in plan.summary_lines()
    doc = plan.to_dict()
    assert doc["line_warnings"] == warned and [d["name"] for d in doc["lines"]] == ["near", "horizon"]


def test_line_reach_with_a_lanes_plan_warns_where_the_lanes_do_not_reach() -> None:
    """The line warnings do not depend on where the plan came from: lanes that stop at 90 m get no tile at 130 m."""
    from trafficgeo.site.lanes import Lanes

    cam = junction_camera()
    lanes = Lanes(("A",), (shapely.box(0.0, 5.0, ROAD_W, 90.0),))
    plan = plan_tiles(cam, FLAT, lanes, input_size=INPUT)
    lines = [across("near", 70.0), across("far", 130.0)]
    object.__setattr__(plan, "lines", line_reach(plan, cam, FLAT, lines))
    assert [w.split(":")[0] for w in plan.line_warnings()] == ["counting line far"]


def test_the_learned_detector_plans_around_the_lines_and_reports_their_reach() -> None:
    from trafficgeo.video.detectors.learned import detector_plan, make_learned_detector

    cam = junction_camera()
    lines = [across("near", 70.0), across("far", 130.0), across("horizon", 600.0)]
    plan = detector_plan(make_learned_detector(camera=cam, surface=FLAT, lines=lines, threads=1))
    assert plan is not None and plan.source == "lines" and len(plan.tiles)
    assert [r.name for r in plan.lines] == ["near", "far", "horizon"]
    assert [w.split(":")[0] for w in plan.line_warnings()] == ["counting line horizon"]


def test_process_plans_around_the_lines_when_given_only_lines(tmp_path) -> None:
    """The pipeline hands the counting lines to the detector: the plan in process.json is made from them and says
    what it reaches at each line; the notice says where the plan came from."""
    import json

    from trafficgeo.camera.model import Camera
    from trafficgeo.video.pipeline import ProcessOptions, detect_and_track
    from video_support import write_two_car_video

    video = write_two_car_video(tmp_path / "v.mp4", 10, 0.5, rows=(60, 120), seed=2)
    cam = Camera.from_orientation((320, 180), 300.0, [13.0, 0.0, 8.0], 355.0, 4.0)
    seen: dict = {}
    told: list[str] = []
    detect_and_track(video, cam, FLAT, tmp_path / "a", ProcessOptions(detector="nanodet"), notice=told.append,
                     detector_info=seen.update, lines=[across("near", 20.0), across("far", 60.0)])
    tiling = seen["tiling"]
    assert tiling["source"] == "lines" and [d["name"] for d in tiling["lines"]] == ["near", "far"]
    assert "planned around the counting lines" in told[0]
    json.dumps(seen)
