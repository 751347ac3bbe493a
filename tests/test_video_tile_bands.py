"""Tiles for a detector with a free input size (trafficgeo.video.detectors.tile_bands): every road point's car reaches
the minimum size in a tile holding its truck whole, inputs are multiples of 32 px, the plan costs fewer input pixels
than square tiles, and the tiled detector feeds each tile at its own input size."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from test_video_tiling import (
    FLAT,
    INPUT,
    FakeNet,
    H,
    W,
    car_boxes,
    encode_frame,
    random_road_points,
    road_camera,
    road_lanes,
    spaced_truth,
)
from trafficgeo.errors import InputError
from trafficgeo.geo.cuboids import cuboid_boxes
from trafficgeo.video.detections import Detections, box_iou
from trafficgeo.video.detectors.tile_bands import input_hw_for, plan_bands
from trafficgeo.video.detectors.tile_plan import box_size_px
from trafficgeo.video.detectors.tiled import TiledDetector
from trafficgeo.video.detectors.tiling import LARGE_VEHICLE_M, plan_tiles

pytestmark = pytest.mark.slow  # plans detector tiles over whole 1080p views


def _clip(boxes: np.ndarray) -> np.ndarray:
    out = boxes.copy()
    out[:, [0, 2]] = np.clip(out[:, [0, 2]], -0.5, W - 0.5)
    out[:, [1, 3]] = np.clip(out[:, [1, 3]], -0.5, H - 0.5)
    return out


def _holds(tiles: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """(N, K) whether tile k holds box n whole (computed here, independently of the planner)."""
    t = tiles.astype(float)[None]
    b = boxes[:, None]
    return ((b[..., 0] >= t[..., 0] - 0.5) & (b[..., 1] >= t[..., 1] - 0.5) & (b[..., 2] <= t[..., 2] - 0.5)
            & (b[..., 3] <= t[..., 3] - 0.5))


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(height=st.floats(4.0, 15.0), tilt=st.floats(1.0, 20.0), focal=st.floats(0.5, 1.5),
       seed=st.integers(0, 2 ** 16))
@example(height=4.40625, tilt=19.0, focal=1.2109375, seed=2)
def test_every_reachable_car_gets_the_minimum_size_with_its_truck_whole(height: float, tilt: float, focal: float,
                                                                       seed: int) -> None:
    cam = road_camera(height, tilt, focal * W)
    plan = plan_bands(cam, FLAT, road_lanes(), (H, W), input_size=INPUT, min_size_px=24.0, max_upscale=2.0)
    t = plan.tiles
    hw = plan.tile_input_hw
    # inputs: multiples of 32, tiles in the frame, each tile's zoom read off its own input (letterbox)
    assert hw is not None and hw.shape == (len(t), 2) and np.all(hw % 32 == 0) and np.all(hw >= 32)
    assert np.all((t[:, 0] >= 0) & (t[:, 1] >= 0) & (t[:, 2] <= W) & (t[:, 3] <= H) & (t[:, 2] > t[:, 0]))
    zoom = np.minimum(hw[:, 0] / (t[:, 3] - t[:, 1]), hw[:, 1] / (t[:, 2] - t[:, 0]))
    np.testing.assert_allclose(plan.tile_scales, zoom)
    assert plan.full_input_hw == (256, 416) and plan.full_scale == pytest.approx(INPUT / W)
    xyz, _lane = random_road_points(np.random.default_rng(seed), 3000)
    car = car_boxes(cam, xyz)
    ok = np.all(np.isfinite(car), axis=1) & cam.in_image(np.nan_to_num(cam.project(xyz), nan=-1e9))
    car, xyz = car[ok], xyz[ok]
    size = box_size_px(car)
    truck = _clip(cuboid_boxes(cam, xyz, np.zeros(len(xyz)), *LARGE_VEHICLE_M))
    tol = 0.97  # the test's points fall between the plan's 1 m grid points
    # ... for the full frame as for the tiles: a car the full frame brings to within tol of 24 px is served by it
    # (hypothesis found 5 cars of 110.2-110.7 px at the top edge, 0.3 % short of the full frame's 110.8 px, beside
    # grid points the full frame serves: height 4.4 m, tilt 19 deg, f = 2325 px)
    full_ok = size * plan.full_scale >= tol * 24.0
    reachable = ~full_ok & (size * 2.0 >= 24.0 / tol)
    # The truck standing there lies whole in a tile that brings the car there to 24 px: everywhere but slivers
    # between the plan's 1 m samples, where a truck box can stick out of its band by a pixel (hypothesis found one
    # point in 903 at height 4 m, tilt 4 deg, f = 960 px).
    good = _holds(t, truck[reachable]) & (size[reachable, None] * zoom[None, :] >= tol * 24.0)
    unserved = int((~good.any(axis=1)).sum())
    assert unserved <= 0.005 * max(int(reachable.sum()), 1), f"{unserved} of {int(reachable.sum())} points unserved"
    # The plan's own bookkeeping agrees: road where even 2x zoom leaves the car below 16 px is reported.
    hopeless = size * 2.0 < 16.0 * 0.97
    if hopeless.any():
        assert sum(r.beyond_m for r in plan.regions) > 0


def test_bands_cost_fewer_input_pixels_than_square_tiles_on_a_view_along_the_road() -> None:
    for height, tilt, focal in ((8.0, 4.0, 0.9), (12.0, 8.0, 1.2), (5.0, 2.0, 0.7)):
        cam = road_camera(height, tilt, focal * W)
        bands = plan_bands(cam, FLAT, road_lanes(), input_size=INPUT)
        squares = plan_tiles(cam, FLAT, road_lanes(), input_size=INPUT)
        assert len(squares.tiles) >= 2
        cost = bands.full_input_pixels + bands.added_input_pixels
        assert cost < 0.6 * (squares.full_input_pixels + squares.added_input_pixels)
        # and they reach the same road (per lane, metres reached through the full frame or a tile)
        for a, b in zip(bands.regions, squares.regions, strict=True):
            assert a.beyond_m == pytest.approx(b.beyond_m, abs=0.02 * a.in_view_m + 1.0)
        line = bands.summary_lines()[0]
        assert "Mpx of input" in line and f"runs {len(bands.tiles) + 1} times" in line


def test_input_sizes_and_bad_input() -> None:
    assert input_hw_for((1080, 1920), 416 / 1920) == (256, 416)
    assert input_hw_for((100, 250), 1.0) == (128, 256)
    assert input_hw_for((10, 10), 0.5) == (32, 32)
    cam = road_camera(8.0, 4.0, 0.9 * W)
    with pytest.raises(InputError, match="zoom ratios"):
        plan_bands(cam, FLAT, road_lanes(), ratios=(1.0,))
    with pytest.raises(InputError, match="stride_px"):
        plan_bands(cam, FLAT, road_lanes(), stride_px=0)


class SizedNet(FakeNet):
    """A fake net with a free input size: it sees a truth box when its visible part reaches ``min_px`` in the
    letterboxed ``input_hw`` it is run at; records the (image w, h, input h, w) of each call."""

    def __init__(self, *args: object, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)
        self.sized: list[tuple[int, int, int, int]] = []

    def detect_batch(self, images: list[np.ndarray], input_hw: tuple[int, int] | None = None) -> list[Detections]:
        out = []
        for im in images:
            h, w = im.shape[:2]
            ih, iw = input_hw or (self.input_size, self.input_size)
            self.sized.append((w, h, ih, iw))
            self.input_size = max(h, w) * min(ih / h, iw / w)  # FakeNet sees at input_size / longer side
            out.append(self.detect(im))
        return out


def test_tiled_detector_runs_each_tile_at_its_input_size_and_finds_the_far_cars_once() -> None:
    cam = road_camera(8.0, 4.0, 0.9 * W)
    plan = plan_bands(cam, FLAT, road_lanes(2.0, 300.0), input_size=INPUT, max_upscale=2.0)
    truth, _ = spaced_truth(cam, np.random.default_rng(3))
    net = SizedNet(truth)
    out = TiledDetector(net, plan).detect(encode_frame(), 1.0)
    assert net.sized[0] == (W, H, 256, 416)  # the full frame, at 416 px wide
    assert [s[2:] for s in net.sized[1:]] == [tuple(v) for v in plan.tile_input_hw.tolist()]
    assert [s[:2] for s in net.sized[1:]] == [(int(x1 - x0), int(y1 - y0)) for x0, y0, x1, y1 in plan.tiles]
    reach = plan.input_size_px(truth) >= 24.0
    matched = box_iou(truth[:, None], out.boxes[None, :]) >= 0.9
    assert len(truth) >= 40 and reach.sum() >= 30
    assert np.all(matched[reach].sum(axis=1) == 1), "a reachable vehicle missed or found twice"
    assert np.all(matched.sum(axis=0) == 1), "a detection matching no vehicle (a duplicate or a part)"


def test_a_sized_plan_needs_a_detector_that_takes_input_sizes() -> None:
    cam = road_camera(8.0, 4.0, 0.9 * W)
    plan = plan_bands(cam, FLAT, road_lanes(2.0, 300.0), input_size=INPUT)

    class Plain:
        def detect(self, image: np.ndarray, time_s: float = 0.0) -> Detections:
            return Detections.empty()

    with pytest.raises(InputError, match="input_hw"):
        TiledDetector(Plain(), plan)
