"""Camera-aware tiling (trafficgeo.video.detectors.tiling): vehicle sizes against pinhole figures, tile plans that bring
every road point to the detector's minimum size (or report it beyond reach), and the tiled detector on a fake base that
only sees vehicles big enough in its own input."""

from __future__ import annotations

import json

import numpy as np
import pytest
import shapely
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from trafficgeo.camera.model import Camera
from trafficgeo.errors import InputError
from trafficgeo.geo.cuboids import cuboid_boxes
from trafficgeo.geo.surface import ConstantSurface
from trafficgeo.site.lanes import Lanes
from trafficgeo.video.detections import Detections, box_iou
from trafficgeo.video.detectors.tile_plan import REFERENCE_CAR_M, TilePlan, box_size_px
from trafficgeo.video.detectors.tiled import TiledDetector, merge_boxes
from trafficgeo.video.detectors.tiling import plan_tiles, vehicle_size_px

W, H = 1920, 1080
INPUT = 416
LANE_W = 3.5
N_LANES = 4


# ---------------------------------------------------------------------------------------------------- scene
def road_lanes(y0: float = 2.0, y1: float = 400.0) -> Lanes:
    """Four 3.5 m lanes along +y (north) between x = 0 and 14 m, from y0 to y1."""
    polys = [shapely.box(k * LANE_W, y0, (k + 1) * LANE_W, y1) for k in range(N_LANES)]
    return Lanes(tuple(f"L{k + 1}" for k in range(N_LANES)), tuple(polys))


def road_camera(height_m: float, tilt_deg: float, focal_px: float) -> Camera:
    """A camera 3 m beyond the right road edge at y = 0, looking along the road (towards its middle at 60 m)."""
    pos = np.array([N_LANES * LANE_W + 3.0, 0.0, height_m])
    heading = float(np.degrees(np.arctan2(0.5 * N_LANES * LANE_W - pos[0], 60.0)) % 360.0)
    return Camera.from_orientation((W, H), focal_px, pos, heading, tilt_deg)


FLAT = ConstantSurface(0.0)


def random_road_points(rng: np.random.Generator, n: int, y1: float = 400.0) -> tuple[np.ndarray, np.ndarray]:
    """Random vehicle footprint centres on the lanes (N, 3) and their lane index, away from the lane ends."""
    lane = rng.integers(0, N_LANES, n)
    x = (lane + rng.uniform(0.25, 0.75, n)) * LANE_W
    y = rng.uniform(5.0, y1 - 3.0, n)
    return np.column_stack([x, y, np.zeros(n)]), lane


def car_boxes(camera: Camera, xyz: np.ndarray) -> np.ndarray:
    """The reference car's image boxes heading north (along the road), from the cuboid module directly."""
    return cuboid_boxes(camera, xyz, np.zeros(len(xyz)), *REFERENCE_CAR_M)


# ---------------------------------------------------------------------------------------------------- sizes
def test_size_is_the_shorter_side_of_the_box_and_matches_pinhole_figures() -> None:
    f = 1500.0
    cam = Camera.from_orientation((W, H), f, [0.0, 0.0, 0.75], 0.0, 0.0)  # level, looking north, at mid-car height
    d = np.array([20.0, 50.0, 120.0])
    centres = np.column_stack([np.zeros(3), d, np.zeros(3)])
    length, width, height = REFERENCE_CAR_M
    # Side-on (heading east): the near side, a length x height rectangle at depth d - width/2, frames the box.
    side = vehicle_size_px(cam, centres, np.full(3, 90.0))
    np.testing.assert_allclose(side, f * height / (d - width / 2), rtol=1e-9)
    # End-on (heading north): the rear face, width x height at depth d - length/2.
    end = vehicle_size_px(cam, centres, np.zeros(3))
    np.testing.assert_allclose(end, f * min(width, height) / (d - length / 2), rtol=1e-9)
    # Unknown heading: the smallest over the headings tried, so no larger than either.
    unknown = vehicle_size_px(cam, centres, np.full(3, np.nan))
    assert np.all(unknown <= np.minimum(side, end) + 1e-9)
    np.testing.assert_allclose(box_size_px([[10, 20, 40, 30]]), [10.0])


def test_size_from_a_high_level_camera_follows_the_pinhole_figures() -> None:
    # A level camera 8 m up sees a car end-on: the box is f * 1.8 / (d - 2.2) wide (the rear face) and reaches from
    # the rear bottom, f * 8 / (d - 2.2) below the horizon, up to the front of the roof, f * 6.5 / (d + 2.2) below
    # it. Near, the width is the shorter side; far, the roof seen at a grazing angle makes the height shorter.
    f = 1728.0
    cam = Camera.from_orientation((W, H), f, [0.0, 0.0, 8.0], 0.0, 0.0)
    d = np.array([30.0, 80.0, 150.0, 250.0])
    length, width, height = REFERENCE_CAR_M
    size = vehicle_size_px(cam, np.column_stack([np.zeros(4), d, np.zeros(4)]), np.zeros(4))
    box_w = f * width / (d - length / 2)
    box_h = f * (8.0 / (d - length / 2) - (8.0 - height) / (d + length / 2))
    np.testing.assert_allclose(size, np.minimum(box_w, box_h), rtol=1e-9)
    assert box_w[0] < box_h[0] and box_h[-1] < box_w[-1]
    # Far away both are about f * L / d with L = the width or the roof's apparent height.
    np.testing.assert_allclose(size[-1], f * (height + length * 8.0 / d[-1]) / d[-1], rtol=0.03)


# ---------------------------------------------------------------------------------------------------- plans
def check_plan_reaches_road(plan: TilePlan, camera: Camera, xyz: np.ndarray, lane: np.ndarray,
                            max_upscale: float, distance_tol: float = 0.01) -> tuple[int, int]:
    """Every in-view point: the car reaches min_size in the full frame or in a tile holding it whole, or it is
    below min_size even at max zoom and inside its lane's reported beyond-reach distance range (give or take
    ``distance_tol`` of the distance, the spacing of the plan's samples). Returns the number of points reached only
    through a tile and of points beyond reach."""
    boxes = car_boxes(camera, xyz)
    uv = camera.project(xyz)
    view = camera.in_image(np.nan_to_num(uv, nan=-1e9)) & np.all(np.isfinite(boxes), axis=1)
    size = box_size_px(boxes)
    clipped = boxes.copy()
    clipped[:, [0, 2]] = np.clip(clipped[:, [0, 2]], -0.5, W - 0.5)
    clipped[:, [1, 3]] = np.clip(clipped[:, [1, 3]], -0.5, H - 0.5)
    t = plan.tiles.astype(float)
    side = np.maximum(t[:, 2] - t[:, 0], t[:, 3] - t[:, 1])
    holds = ((clipped[:, None, 0] >= t[None, :, 0] - 0.5 - 1e-6) & (clipped[:, None, 1] >= t[None, :, 1] - 0.5 - 1e-6)
             & (clipped[:, None, 2] <= t[None, :, 2] - 0.5 + 1e-6)
             & (clipped[:, None, 3] <= t[None, :, 3] - 0.5 + 1e-6))
    best = np.maximum(size * INPUT / max(W, H), np.max(np.where(holds, size[:, None] * INPUT / side[None, :], 0.0),
                                                         axis=1, initial=0.0))
    tol = 0.98  # the test's points fall between the plan's 1 m grid points
    reached = best >= tol * plan.min_size_px
    beyond = view & ~reached
    # Beyond reach only where the maximum zoom cannot help; and then reported, at the right distance.
    t_min = np.ceil(INPUT / max_upscale)
    assert np.all(size[beyond] * INPUT / t_min < plan.min_size_px / tol), size[beyond]
    dist = np.hypot(xyz[:, 0] - camera.position[0], xyz[:, 1] - camera.position[1])
    for k, region in enumerate(plan.regions):
        mine = beyond & (lane == k)
        if mine.any():
            assert region.beyond_distance_m is not None and region.beyond_m > 0
            lo, hi = region.beyond_distance_m
            slack = 1.0 + distance_tol * dist[mine]
            assert np.all((dist[mine] >= lo - slack) & (dist[mine] <= hi + slack))
    # Tiles: squares inside the frame, between the largest zoom and the frame's height.
    assert np.all(t[:, 2] - t[:, 0] == t[:, 3] - t[:, 1])
    assert np.all((side >= t_min) & (side <= H) & (t[:, 0] >= 0) & (t[:, 1] >= 0) & (t[:, 2] <= W) & (t[:, 3] <= H))
    full_ok = size * INPUT / max(W, H) >= plan.min_size_px
    return int(np.sum(view & reached & ~full_ok)), int(beyond.sum())


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@pytest.mark.slow
@given(height=st.floats(4.0, 15.0), tilt=st.floats(1.0, 20.0), focal=st.floats(0.5, 1.5),
       seed=st.integers(0, 2**31 - 1))
def test_every_road_point_reaches_the_minimum_size_or_is_reported(height: float, tilt: float, focal: float,
                                                                  seed: int) -> None:
    cam = road_camera(height, tilt, focal * W)
    plan = plan_tiles(cam, FLAT, road_lanes(), (H, W), input_size=INPUT, min_size_px=24.0, max_upscale=2.0)
    xyz, lane = random_road_points(np.random.default_rng(seed), 3000)
    check_plan_reaches_road(plan, cam, xyz, lane, 2.0)
    assert [r.name for r in plan.regions] == [f"L{k + 1}" for k in range(N_LANES)]
    # The plan's own bookkeeping agrees: its samples below the minimum size are the lanes' beyond-reach metres.
    low = np.isfinite(plan.best_input_px) & (plan.best_input_px < 24.0)
    assert (sum(r.beyond_m for r in plan.regions) > 0) == bool(low.any())
    assert len(plan.summary_lines()) >= 1 + sum(r.beyond_m > 0 for r in plan.regions)


def test_demo_like_camera_needs_tiles_far_away_and_reports_the_end_of_the_road() -> None:
    cam = road_camera(8.0, 4.0, 0.9 * W)
    plan = plan_tiles(cam, FLAT, road_lanes(), input_size=INPUT, max_upscale=1.5)
    xyz, lane = random_road_points(np.random.default_rng(1), 4000)
    via_tiles, beyond = check_plan_reaches_road(plan, cam, xyz, lane, 1.5)
    assert 1 <= len(plan.tiles) <= 8 and via_tiles > 1000 and beyond > 50
    assert plan.added_input_pixels == len(plan.tiles) * INPUT ** 2
    d = json.loads(json.dumps(plan.to_dict()))
    assert d["passes_per_frame"] == len(plan.tiles) + 1 and len(d["warnings"]) == N_LANES
    for r in plan.regions:  # a car ~1.8 m wide reaches 24 px at 1.5x zoom up to f * 1.8 * 1.5 * 416 / 24 / 416 m
        lo, hi = r.beyond_distance_m
        assert 0.8 * 1728 * 1.8 * 1.5 / 24 < lo < hi <= 400.0 + 20.0
    assert any("too far for the detector" in line for line in plan.summary_lines())


def test_no_tiles_when_the_full_frame_suffices() -> None:
    cam = road_camera(8.0, 25.0, 0.9 * W)
    plan = plan_tiles(cam, FLAT, road_lanes(2.0, 25.0), input_size=INPUT)
    assert len(plan.tiles) == 0 and plan.added_frame_pixels == 0
    assert all(r.beyond_m == 0 and r.tiles_m == 0 for r in plan.regions)
    assert plan.summary_lines()[0].startswith("tiling: not needed")


@pytest.mark.slow
def test_roi_plan_reaches_the_road_like_the_lanes_plan() -> None:
    cam = road_camera(8.0, 4.0, 0.9 * W)
    lanes = road_lanes(2.0, 250.0)
    # The ROI: the road's image, from a dense grid of ground points projected into the frame.
    gx, gy = np.meshgrid(np.linspace(0.0, N_LANES * LANE_W, 60), np.linspace(2.0, 250.0, 2500))
    uv = cam.project(np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)]))
    uv = np.rint(uv[cam.in_image(np.nan_to_num(uv, nan=-1e9))]).astype(int)
    roi = np.zeros((H, W), dtype=bool)
    roi[uv[:, 1], uv[:, 0]] = True
    roi |= np.roll(roi, 1, axis=0) | np.roll(roi, 1, axis=1)
    plan = plan_tiles(cam, FLAT, roi, input_size=INPUT)
    lanes_plan = plan_tiles(cam, FLAT, lanes, input_size=INPUT)
    assert plan.regions[0].unit == "m2" and plan.regions[0].name == "ROI"
    xyz, lane = random_road_points(np.random.default_rng(2), 2000, 250.0)
    # Far away an 8 px step of the ROI's sample grid spans ~35 m of road: the distances are that coarse there.
    check_plan_reaches_road(plan, cam, xyz, np.full(len(lane), 0), 2.0, distance_tol=0.15)
    # The ROI knows the road's direction from its shape: about as few tiles as with lanes, not one per heading.
    assert len(plan.tiles) <= len(lanes_plan.tiles) + 1


def test_bad_input() -> None:
    cam = road_camera(8.0, 4.0, 0.9 * W)
    with pytest.raises(InputError, match="do not match"):
        plan_tiles(cam, FLAT, road_lanes(), (720, 1280))
    with pytest.raises(InputError, match="not inside"):
        TilePlan((H, W), INPUT, 24.0, 2.0, np.array([[0, 0, W + 10, 100]]))


# ---------------------------------------------------------------------------------------------------- detector
def encode_frame() -> np.ndarray:
    """A BGR frame whose every pixel tells its own (x, y): B = x & 255, G = y & 255, R = (x >> 8) << 4 | y >> 8."""
    y, x = np.mgrid[0:H, 0:W]
    return np.stack([x & 255, y & 255, ((x >> 8) << 4) | (y >> 8)], axis=-1).astype(np.uint8)


class FakeNet:
    """Returns the truth boxes it can see in the image it is given, when their visible part is at least
    ``min_px`` across (shorter side) in its ``input_size`` letterboxed input. Boxes cut by the image's border come
    back clipped to it, scoring higher than whole ones (the worst case for the merge)."""

    def __init__(self, truth: np.ndarray, min_px: float = 24.0, input_size: int = INPUT) -> None:
        self.truth, self.min_px, self.input_size = truth, min_px, input_size
        self.calls: list[tuple[int, int]] = []

    def detect(self, image: np.ndarray, time_s: float = 0.0) -> Detections:
        p = image[0, 0].astype(int)
        x0, y0 = int(p[0]) | ((int(p[2]) >> 4) << 8), int(p[1]) | ((int(p[2]) & 15) << 8)
        h, w = image.shape[:2]
        self.calls.append((w, h))
        b = self.truth - np.array([x0, y0, x0, y0], dtype=float)
        vis = b.copy()
        vis[:, [0, 2]] = np.clip(vis[:, [0, 2]], -0.5, w - 0.5)
        vis[:, [1, 3]] = np.clip(vis[:, [1, 3]], -0.5, h - 0.5)
        seen = box_size_px(vis) * self.input_size / max(h, w) >= self.min_px
        cut = np.any(np.abs(vis - b) > 1e-9, axis=1)
        score = np.where(cut, 0.95, 0.9 - 1e-4 * np.arange(len(b)))
        return Detections(vis[seen], score[seen], np.full(int(seen.sum()), "car", dtype=object))


class FakeBatchNet(FakeNet):
    def __init__(self, *args: object, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)
        self.batches: list[int] = []

    def detect_batch(self, images: list[np.ndarray]) -> list[Detections]:
        self.batches.append(len(images))
        return [self.detect(im) for im in images]


def spaced_truth(camera: Camera, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Cars along the lanes whose image boxes do not touch the frame edge and overlap little (IoU < 0.3 and less
    than half of the smaller box covered: two vehicles to any merge): (boxes, xyz)."""
    xyz, _ = random_road_points(rng, 1500, 300.0)
    boxes = car_boxes(camera, xyz)
    ok = np.all(np.isfinite(boxes), axis=1) & (boxes[:, 0] > 3) & (boxes[:, 1] > 3) & (boxes[:, 2] < W - 4) \
        & (boxes[:, 3] < H - 4)
    keep: list[int] = []
    for i in np.flatnonzero(ok):
        if keep:
            k = boxes[keep]
            iw = np.clip(np.minimum(k[:, 2], boxes[i, 2]) - np.maximum(k[:, 0], boxes[i, 0]), 0, None)
            ih = np.clip(np.minimum(k[:, 3], boxes[i, 3]) - np.maximum(k[:, 1], boxes[i, 1]), 0, None)
            inter = iw * ih
            area = (k[:, 2] - k[:, 0]) * (k[:, 3] - k[:, 1])
            mine = (boxes[i, 2] - boxes[i, 0]) * (boxes[i, 3] - boxes[i, 1])
            if np.any(inter >= 0.5 * np.minimum(area, mine)) or np.any(inter >= 0.3 * (area + mine - inter)):
                continue
        keep.append(int(i))
    return boxes[keep], xyz[keep]


@pytest.mark.slow
@pytest.mark.parametrize("net_class", [FakeNet, FakeBatchNet])
def test_tiled_detector_recovers_the_far_vehicles_once_and_whole(net_class: type) -> None:
    cam = road_camera(8.0, 4.0, 0.9 * W)
    plan = plan_tiles(cam, FLAT, road_lanes(2.0, 300.0), input_size=INPUT, max_upscale=2.0)
    truth, _ = spaced_truth(cam, np.random.default_rng(3))
    frame = encode_frame()
    net = net_class(truth)
    alone = net.detect(frame, 1.0)
    out = TiledDetector(net, plan).detect(frame, 1.0)
    reach = plan.input_size_px(truth) >= 24.0
    iou = box_iou(truth[:, None], out.boxes[None, :])  # (truth, detections)
    matched = iou >= 0.9
    missed_alone = len(truth) - int(np.sum(box_iou(truth[:, None], alone.boxes[None, :]).max(axis=1) >= 0.9))
    assert len(truth) >= 40 and reach.sum() >= 30 and missed_alone >= 10
    assert np.all(matched[reach].sum(axis=1) == 1), "a reachable vehicle missed or found twice"
    assert np.all(matched.sum(axis=0) == 1), "a detection matching no vehicle (a duplicate or a part)"
    assert len(out) == int(matched.any(axis=1).sum())
    np.testing.assert_allclose(out.boxes[np.argmax(matched[reach], axis=1)], truth[reach], atol=1e-9)
    assert net.calls[0] == (W, H) and len(net.calls) == 2 + len(plan.tiles)
    if net_class is FakeBatchNet:
        sizes = {(int(x1 - x0), int(y1 - y0)) for x0, y0, x1, y1 in plan.tiles}
        assert sum(net.batches) == len(plan.tiles) and len(net.batches) == len(sizes)  # one batch per tile size
    # Some reachable vehicles straddle a tile edge somewhere, so the cut parts were there to drop.
    t = plan.tiles.astype(float)
    straddle = ((truth[:, None, 0] < t[None, :, 2] - 0.5) & (truth[:, None, 2] > t[None, :, 2] - 0.5)
                & (truth[:, None, 1] < t[None, :, 3] - 0.5) & (truth[:, None, 3] > t[None, :, 1] - 0.5))
    assert straddle[reach].any()


def test_a_vehicle_cut_by_a_tile_edge_comes_out_whole_and_frame_edges_do_not_cut() -> None:
    # Two 300 px tiles overlapping by 50 px: a 20 px car is 8.3 px in the full frame (1000 px wide) and 27.7 px in
    # a tile. Car a crosses the first tile's right edge, car b lies in the overlap (in both tiles), car c touches
    # the frame's left edge (a tile edge that is the frame edge).
    w, h = 1000, 600
    plan = TilePlan((h, w), INPUT, 24.0, 2.0, np.array([[0, 0, 300, 300], [250, 0, 550, 300]]))
    truth = np.array([[275.0, 100.0, 305.0, 120.0], [262.0, 200.0, 282.0, 220.0], [-0.5, 50.0, 19.5, 70.0]])
    y, x = np.mgrid[0:h, 0:w]
    frame = np.stack([x & 255, y & 255, ((x >> 8) << 4) | (y >> 8)], axis=-1).astype(np.uint8)
    net = FakeNet(truth)
    out = TiledDetector(net, plan).detect(frame, 0.0)
    assert len(out) == 3
    np.testing.assert_allclose(out.boxes[np.argsort(out.boxes[:, 1])], truth[[2, 0, 1]], atol=1e-9)
    # Without dropping the cut part, the part (score 0.95) would win over the whole car: check the fake did cut it.
    part = net.detect(frame[0:300, 0:300])
    assert np.any(np.isclose(part.boxes[:, 2], 299.5) & (part.scores == 0.95))


def test_merge_keeps_a_car_behind_a_truck_within_one_source_but_drops_a_tile_part() -> None:
    truck = [100.0, 100.0, 300.0, 200.0]
    car = [120.0, 120.0, 180.0, 190.0]  # 100 % inside the truck's box, IoU 0.21
    boxes = np.array([truck, car])
    scores = np.array([0.9, 0.8])
    assert merge_boxes(boxes, scores, np.array([0, 0])).tolist() == [0, 1]
    assert merge_boxes(boxes, scores, np.array([0, 1])).tolist() == [0]
    # IoU >= 0.5 suppresses within one source too, best score first.
    twins = np.array([truck, [105.0, 100.0, 300.0, 200.0]])
    assert merge_boxes(twins, np.array([0.5, 0.7]), np.array([0, 0])).tolist() == [1]
    assert merge_boxes(np.zeros((0, 4)), np.zeros(0), np.zeros(0)).size == 0


def test_tiled_detector_checks_frames_and_base_roi() -> None:
    plan = TilePlan((H, W), INPUT, 24.0, 2.0, np.array([[0, 0, 400, 400]]))
    net = FakeNet(np.zeros((0, 4)))
    with pytest.raises(InputError, match="planned for"):
        TiledDetector(net, plan).detect(np.zeros((720, 1280, 3), np.uint8), 0.0)
    net.roi = np.ones((H, W), bool)
    with pytest.raises(ValueError, match="ROI"):
        TiledDetector(net, plan)


def test_tiled_detector_roi_keeps_boxes_standing_in_it() -> None:
    # Two 30 px cars found in the 400 px tile only; the ROI is the left half: the car standing right of it goes.
    plan = TilePlan((H, W), INPUT, 24.0, 2.0, np.array([[0, 0, 400, 400]]))
    truth = np.array([[100.0, 100.0, 130.0, 130.0], [300.0, 100.0, 330.0, 130.0]])
    roi = np.zeros((H, W), bool)
    roi[:, :200] = True
    out = TiledDetector(FakeNet(truth), plan, roi=roi).detect(encode_frame(), 0.0)
    np.testing.assert_allclose(out.boxes, truth[:1])
