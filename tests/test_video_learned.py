"""The built-in learned detector as `process` runs it (trafficgeo.video.detectors.learned): the shipped NanoDet model,
tiled over the counted road when the camera is calibrated, classes from the ground size, and its tile plan carried into
the run key and process.json."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import shapely

from trafficgeo.camera.model import Camera
from trafficgeo.errors import InputError
from trafficgeo.geo.cuboids import cuboid_boxes
from trafficgeo.geo.surface import ConstantSurface
from trafficgeo.site.lanes import Lanes
from trafficgeo.video.detections import Detections
from trafficgeo.video.detectors.factory import make_detector
from trafficgeo.video.detectors.learned import SizeClasses, detector_plan
from trafficgeo.video.detectors.onnx import OnnxDetector
from trafficgeo.video.detectors.tiled import TiledDetector
from trafficgeo.video.pipeline import ProcessOptions, detect_and_track

FLAT = ConstantSurface(0.0)


def lanes_along_y(n: int = 3, width_m: float = 3.5, y0: float = 3.0, y1: float = 300.0) -> Lanes:
    polys = tuple(shapely.box(k * width_m, y0, (k + 1) * width_m, y1) for k in range(n))
    return Lanes(tuple(f"L{k + 1}" for k in range(n)), polys)


def camera_over_road(size: tuple[int, int] = (1920, 1080), focal_px: float = 1700.0) -> Camera:
    """8 m up beside three lanes along +y, looking along them."""
    return Camera.from_orientation(size, focal_px, [13.0, 0.0, 8.0], 355.0, 4.0)


class Boxes:
    """A fake base detector returning fixed boxes (model classes all "truck", as COCO models often say)."""

    def __init__(self, boxes: np.ndarray) -> None:
        self.boxes = boxes

    def detect(self, image: np.ndarray, time_s: float = 0.0) -> Detections:
        n = len(self.boxes)
        return Detections(self.boxes, np.full(n, 0.9), np.full(n, "truck", dtype=object))


@pytest.mark.slow
def test_the_builtin_detector_is_tiled_over_the_counted_road_and_classes_by_size() -> None:
    cam = camera_over_road()
    det = make_detector("nanodet", camera=cam, surface=FLAT, road=lanes_along_y())
    assert isinstance(det, SizeClasses) and isinstance(det.base, TiledDetector)
    plan = detector_plan(det)
    assert plan is not None and len(plan.tiles) >= 1 and plan.input_size == 416
    # the default: square tiles at the model's 416 px input, over the far road (their tops above the middle); the
    # full frame square too (at 416 x 256 it ran no faster end to end and counted no better: benchmarks/README.md)
    assert plan.tile_input_hw is None and plan.full_input_hw is None
    assert np.all(plan.tiles[:, 1] < cam.height / 2)
    # zoom bands: the shipped model takes any input size, so each tile has its own, zooming beyond the full frame
    bands = detector_plan(make_detector("nanodet", camera=cam, surface=FLAT, road=lanes_along_y(), tiling="bands"))
    assert bands.tile_input_hw is not None and np.all(bands.tile_input_hw % 32 == 0)
    assert bands.full_input_hw == (256, 416)  # 1920 x 1080 at 416 / 1920, rounded up to 32 px
    assert np.all(bands.tile_scales > bands.full_scale * 1.2)
    assert bands.full_input_pixels + bands.added_input_pixels < 0.8 * (plan.full_input_pixels
                                                                       + plan.added_input_pixels)
    with pytest.raises(InputError, match="tiling 'round'"):
        make_detector("nanodet", camera=cam, surface=FLAT, road=lanes_along_y(), tiling="round")
    untiled = make_detector("nanodet", camera=cam, surface=FLAT, road=lanes_along_y(), tiles=False)
    assert isinstance(untiled, SizeClasses) and detector_plan(untiled) is None
    assert isinstance(make_detector("nanodet"), OnnxDetector)  # no camera: the model alone, on the full frame


def test_classes_come_from_the_size_on_the_ground_not_the_model() -> None:
    cam = camera_over_road()
    at = np.array([[5.25, 40.0, 0.0], [8.75, 60.0, 0.0]])
    car = cuboid_boxes(cam, at[:1], np.zeros(1), 4.5, 1.8, 1.5)
    truck = cuboid_boxes(cam, at[1:], np.zeros(1), 12.0, 2.55, 3.8)
    sliver = np.array([[900.0, 600.0, 903.0, 602.0]])  # 3 x 2 px: no vehicle class fits it
    det = SizeClasses(Boxes(np.vstack([car, truck, sliver])), cam, FLAT).detect(np.zeros((1080, 1920, 3), np.uint8))
    assert det.classes.tolist() == ["car", "truck", ""]
    assert len(det) == 3  # kept: whether a box is a vehicle is the detector's call


@pytest.mark.slow
def test_process_records_the_tile_plan_and_keys_the_run_on_it(tmp_path: Path) -> None:
    from video_support import write_two_car_video

    video = write_two_car_video(tmp_path / "v.mp4", 10, 1.0, rows=(60, 120), seed=2)
    cam = Camera.from_orientation((320, 180), 300.0, [13.0, 0.0, 8.0], 355.0, 4.0)
    opts = ProcessOptions(detector="nanodet", checkpoint_s=0.5)
    seen: dict = {}
    told: list[str] = []
    detect_and_track(video, cam, FLAT, tmp_path / "a", opts, lanes=lanes_along_y(), notice=told.append,
                     detector_info=seen.update)
    tiling = seen["tiling"]
    assert tiling["passes_per_frame"] == len(tiling["tiles"]) + 1 >= 2
    assert {r["name"] for r in tiling["regions"]} == {"L1", "L2", "L3"}
    assert any(line.startswith("tiling:") for line in told)
    json.dumps(seen)  # plain data, for process.json
    # The lanes enter the detections through the tiles: a run with other lanes does not reuse the checkpoint.
    from trafficgeo.video.checkpoint import CHECKPOINT_DIR

    out = tmp_path / "b"
    detect_and_track(video, cam, FLAT, out, opts, lanes=lanes_along_y())
    assert (out / CHECKPOINT_DIR).is_dir()  # the caller removes it after analyze
    told = []
    detect_and_track(video, cam, FLAT, out, opts, lanes=lanes_along_y(n=2), notice=told.append)
    assert any("ignoring the checkpoint" in line for line in told), told


def test_a_bus_seen_broadside_is_heavy_and_a_car_seen_broadside_is_not() -> None:
    """At a junction a vehicle crossing the view shows its side: its box's ground width is its length. A bus or a
    truck is then wider on the ground than any van is long (7.5 m) - a size the line-of-sight rule finds
    implausible - and is called a truck; a car or a van crossing the view is not."""
    from trafficgeo.video.detectors.sizes import SizeRules, blob_ground_size, broadside_heavy, classify_sizes

    cam = camera_over_road()
    across = 90.0  # heading (deg) across the camera's view, which looks along +y
    bus = cuboid_boxes(cam, np.array([[0.0, 35.0, 0.0]]), np.array([across]), 12.0, 2.55, 3.2)
    truck = cuboid_boxes(cam, np.array([[0.0, 50.0, 0.0]]), np.array([across]), 9.0, 2.5, 3.5)
    car = cuboid_boxes(cam, np.array([[0.0, 35.0, 0.0]]), np.array([across]), 4.5, 1.8, 1.5)
    van = cuboid_boxes(cam, np.array([[0.0, 35.0, 0.0]]), np.array([across]), 6.0, 2.0, 2.5)
    boxes = np.vstack([bus, truck, car, van])
    sizes = blob_ground_size(cam, FLAT, boxes)
    _cls, _length, plausible = classify_sizes(sizes, SizeRules())
    assert not plausible[:2].any()  # the line-of-sight rule alone cannot place them
    assert broadside_heavy(sizes, SizeRules()).tolist() == [True, True, False, False]
    det = SizeClasses(Boxes(boxes), cam, FLAT).detect(np.zeros((1080, 1920, 3), np.uint8))
    assert det.classes.tolist()[:2] == ["truck", "truck"]
    assert det.classes.tolist()[2] in ("car", "") and det.classes.tolist()[3] in ("car", "van", "")
