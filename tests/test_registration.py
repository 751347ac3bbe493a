"""Orthophoto registration (issue 21): the draped view, the matching, the judge, the refinement loop and
``trafficgeo refine``, against the truth of a generated scene (tests/conftest.py ``registration_scene``: the frame
is the world's ground texture through the true camera, with vehicles, shadows, blur and noise; the user's
orthophoto is that ground flown at another time; 8 control + 3 check points clicked with 3 px noise)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest
from affine import Affine
from hypothesis import given, settings
from hypothesis import strategies as st

from cli_support import invoke
from trafficgeo.calibration.gcp_read import read_gcps
from trafficgeo.calibration.pipeline import calibrate
from trafficgeo.calibration.validation import build_report
from trafficgeo.camera.calibrated import read_camera_json
from trafficgeo.camera.model import Camera
from trafficgeo.errors import InputError
from trafficgeo.geo.drape import drape_orthophoto
from trafficgeo.geo.mapping import pixels_to_world
from trafficgeo.geo.raster import GeoRaster, read_raster
from trafficgeo.geo.surface import ConstantSurface
from trafficgeo.registration.judge import HeldOutErrors, held_out_errors, worse_p_value
from trafficgeo.registration.matching import MatchSettings, OrthoPyramid, _subpixel, gray, match_orthophoto
from trafficgeo.registration.refine import WORSE_P, RefineOptions, _verdict, refine_camera
from trafficgeo.site.surface import load_surface
from trafficgeo.synth.registration_scene import ground_errors_m

pytestmark = pytest.mark.slow


class Scene:
    """The shared scene's files, loaded."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.truth = read_camera_json(folder / "camera_truth.json")
        self.rough_camera = read_camera_json(folder / "camera.json")
        self.doc = json.loads((folder / "camera.json").read_text(encoding="utf-8"))
        self.gcps = read_gcps(folder / "gcps.csv", crs=self.truth.crs)
        self.perfect = read_gcps(folder / "perfect_gcps.csv", crs=self.truth.crs)
        self.frame = cv2.imread(str(folder / "frame.png"), cv2.IMREAD_COLOR)
        self.ortho = read_raster(folder / "ortho.tif")
        self.surface = load_surface(folder / "dem.tif", self.truth)
        self.points = pd.read_csv(folder / "truth_points.csv")[["x", "y", "z"]].to_numpy()

    def rms_m(self, camera: Camera) -> float:
        """RMS ground error (m) of a camera at the truth points (20-110 m along the road)."""
        e = ground_errors_m(camera, self.truth, self.points)
        return float(np.sqrt(np.mean(e ** 2)))


@pytest.fixture(scope="module")
def scene(registration_scene: Path) -> Scene:
    return Scene(registration_scene)


@pytest.fixture(scope="module")
def refined(scene: Scene):
    rough = calibrate(scene.gcps, scene.truth.image_size)
    return rough, refine_camera(rough.camera, scene.gcps, scene.frame, scene.ortho, scene.surface,
                                model=rough.fit.model, use=rough.inlier)


# ------------------------------------------------------------------------------------------------ the draped view
def _coordinate_ortho(bounds: tuple[float, float, float, float], res: float) -> GeoRaster:
    """A 2-band float orthophoto whose cells hold their own centre's x and y (m)."""
    left, bottom, right, top = bounds
    cols, rows = int((right - left) / res), int((top - bottom) / res)
    x = left + (np.arange(cols) + 0.5) * res
    y = top - (np.arange(rows) + 0.5) * res
    X, Y = np.meshgrid(x, y)
    return GeoRaster(np.stack([X - left, Y - bottom]).astype(np.float32), Affine(res, 0, left, 0, -res, top), None)


def test_the_draped_view_shows_the_orthophoto_at_each_pixels_ground_point() -> None:
    cam = Camera.from_orientation((320, 180), 300.0, [0.0, 0.0, 10.0], 0.0, 20.0, dist=[-0.05, 0, 0, 0, 0])
    surface = ConstantSurface(0.0)
    ortho = _coordinate_ortho((-40.0, 5.0, 40.0, 60.0), 0.05)
    view = drape_orthophoto(cam, surface, ortho)
    rng = np.random.default_rng(0)
    uv = np.column_stack([rng.integers(0, 320, 400), rng.integers(0, 180, 400)]).astype(float)
    g = pixels_to_world(cam, uv, surface, min_incidence_deg=0.0, with_lonlat=False)
    u, v = uv[:, 0].astype(int), uv[:, 1].astype(int)
    seen = view.visible[v, u]
    inside = (g.xyz[:, 0] > -39.9) & (g.xyz[:, 0] < 39.9) & (g.xyz[:, 1] > 5.1) & (g.xyz[:, 1] < 59.9)
    assert np.array_equal(seen, inside)  # sky above the horizon and ground beyond the orthophoto are not visible
    assert seen.sum() > 100
    np.testing.assert_allclose(view.image[v[seen], u[seen], 0], g.xyz[seen, 0] + 40.0, atol=1e-3)
    np.testing.assert_allclose(view.image[v[seen], u[seen], 1], g.xyz[seen, 1] - 5.0, atol=1e-3)
    coarse = drape_orthophoto(cam, surface, ortho, step_px=4)
    both = coarse.visible & view.visible
    assert both.sum() > 0.9 * view.visible.sum()
    assert np.median(np.abs(coarse.image[both] - view.image[both])) < 0.01  # m, between rays 4 px apart


# ---------------------------------------------------------------------------------------------------- matching
@settings(max_examples=40, deadline=None)
@given(dx=st.floats(-0.49, 0.49), dy=st.floats(-0.49, 0.49), sx=st.floats(1.0, 3.0), sy=st.floats(1.0, 3.0))
def test_the_subpixel_peak_of_a_smooth_score_map_is_found(dx: float, dy: float, sx: float, sy: float) -> None:
    yy, xx = np.mgrid[0:9, 0:9].astype(float)
    scores = np.exp(-0.5 * (((xx - 4 - dx) / sx) ** 2 + ((yy - 4 - dy) / sy) ** 2))
    fx, fy, roundness = _subpixel(scores, 4, 4)
    assert abs(fx - dx) < 0.12 and abs(fy - dy) < 0.12
    assert 0.0 < roundness <= 1.0
    if max(sx, sy) >= 2.0 * min(sx, sy):  # an elongated hill (an edge) is not round
        assert roundness < 0.6
    if max(sx, sy) <= 1.1 * min(sx, sy):
        assert roundness > 0.7


def test_through_the_true_camera_the_matches_land_on_the_true_pixels(scene: Scene) -> None:
    m = match_orthophoto(scene.truth, scene.surface, OrthoPyramid(scene.ortho), gray(scene.frame, bgr=True),
                         MatchSettings(search_px=6.0))
    assert len(m) > 80
    err = np.linalg.norm(scene.truth.project(m.world) - m.pixels, axis=1)
    assert np.median(err) < 0.15  # px, despite the orthophoto's other lighting and blur
    assert np.percentile(err, 75) < 0.5
    np.testing.assert_allclose(m.predicted, scene.truth.project(m.world), atol=1e-6)


# ------------------------------------------------------------------------------------------------------- judge
def test_the_judges_leave_one_out_is_the_calibration_reports(scene: Scene) -> None:
    cal = calibrate(scene.gcps, scene.truth.image_size)
    judged = held_out_errors(cal.camera, scene.gcps, cal.fit.model, use=cal.inlier)
    rows = {r.id: r for r in build_report(cal).gcps}
    for gid, role, px, m in zip(judged.ids, judged.roles, judged.pixel_error_px, judged.ground_error_m,
                                strict=True):
        want_px = rows[gid].loo_error_px if role == "control" else rows[gid].error_px
        want_m = rows[gid].loo_ground_error_m if role == "control" else rows[gid].ground_error_m
        assert px == pytest.approx(want_px, rel=1e-3, abs=1e-3), gid
        assert m == pytest.approx(want_m, rel=1e-3, abs=1e-3), gid


# ---------------------------------------------------------------------------------------------- the refinement
def test_refinement_from_rough_clicks_beats_them_3x_and_twenty_perfect_gcps(scene: Scene, refined) -> None:
    rough, result = refined
    assert result.accepted, result.reason
    assert result.n_kept >= 100
    perfect = calibrate(scene.perfect, scene.truth.image_size)
    e_rough, e_refined, e_perfect = scene.rms_m(rough.camera), scene.rms_m(result.camera), scene.rms_m(perfect.camera)
    assert e_rough / e_refined >= 3.0, (e_rough, e_refined)
    assert e_refined <= 1.2 * e_perfect, (e_refined, e_perfect)
    assert result.after.rmse_px < result.before.rmse_px
    assert result.passes[-1].search_px == RefineOptions().final_search_px
    assert result.passes[-1].moved_px < RefineOptions().converged_px
    # the kept correspondences really are where the true camera sees their ground points
    kept = result.matches.select(result.kept)
    assert np.median(np.linalg.norm(scene.truth.project(kept.world) - kept.pixels, axis=1)) < 0.2


def test_an_orthophoto_of_another_place_is_refused_and_the_camera_kept(scene: Scene, refined) -> None:
    rough, _ = refined
    elsewhere = read_raster(scene.folder / "ortho_elsewhere.tif")
    result = refine_camera(rough.camera, scene.gcps, scene.frame, elsewhere, scene.surface, model=rough.fit.model,
                           use=rough.inlier)
    assert not result.accepted
    assert result.camera is rough.camera
    assert "orthophoto" in result.reason


def test_a_frame_of_another_size_is_one_line_naming_the_frame(scene: Scene) -> None:
    small = cv2.resize(scene.frame, (480, 270))
    with pytest.raises(InputError, match="frame is 480x270 px but the camera is calibrated for 960x540") as info:
        refine_camera(scene.rough_camera, scene.gcps, small, scene.ortho, scene.surface)
    assert info.value.parameters == ("frame",)


# -------------------------------------------------------------------------------------------------------- CLI
def _args(folder: Path, out: Path, *extra: str) -> list[str]:
    return ["refine", str(folder / "camera.json"), "--ortho", str(folder / "ortho.tif"), "--surface",
            str(folder / "dem.tif"), "-o", str(out), *extra]


def test_refine_command_writes_the_refined_camera_and_its_report(scene: Scene, tmp_path: Path) -> None:
    out = tmp_path / "camera_refined.json"
    code, stdout, stderr = invoke(*_args(scene.folder, out, "--frame", str(scene.folder / "frame.png"), "--report",
                                         str(tmp_path / "refine.json")))
    assert code == 0, stderr
    cam, doc = read_camera_json(out), json.loads(out.read_text(encoding="utf-8"))
    assert doc["refinement"]["accepted"] is True and doc["refinement"]["report"] == "refine.json"
    assert scene.rms_m(cam) < scene.rms_m(scene.rough_camera) / 3
    report = json.loads((tmp_path / "refine.json").read_text())
    assert report["format"] == "trafficgeo-refine/1" and report["accepted"] is True
    assert report["matches_kept"] == sum(row[report["matches"]["columns"].index("kept")]
                                         for row in report["matches"]["rows"])
    assert cv2.imread(str(tmp_path / report["frame"])).shape == scene.frame.shape
    assert "refined: " in stdout and "pass 1: search 60 px" in stdout


def test_refine_command_refuses_another_place_and_writes_the_original_camera(scene: Scene, tmp_path: Path) -> None:
    folder = tmp_path / "scene"
    shutil.copytree(scene.folder, folder)
    (folder / "ortho_elsewhere.tif").replace(folder / "ortho.tif")
    out = tmp_path / "camera_refined.json"
    code, stdout, stderr = invoke(*_args(folder, out, "--frame", str(folder / "frame.png")))
    assert code == 1, stderr
    said = " ".join(stdout.split())
    assert "refinement refused: " in said and "orthophoto may show another place" in said
    cam, doc = read_camera_json(out), json.loads(out.read_text(encoding="utf-8"))
    np.testing.assert_array_equal(cam.K, scene.rough_camera.K)
    np.testing.assert_array_equal(cam.position, scene.rough_camera.position)
    assert doc["refinement"]["accepted"] is False and "orthophoto" in doc["refinement"]["reason"]
    assert doc["gcps"] == scene.doc["gcps"]


@pytest.mark.parametrize(("change", "message"), [
    ("neither", "give the video (--video) or a still without traffic (--frame), one of them"),
    ("both", "give the video (--video) or a still without traffic (--frame), one of them"),
    ("no-frame-file", "frame image not found"),
    ("small-frame", "480x270 px but the camera is calibrated for 960x540; use a frame of the calibrated video"),
    ("no-gcps", "the camera JSON lists no GCPs of the user's to judge the refinement by; give a GCP file of points "
                "you measured (--gcps)"),
    ("search", "--search = -3.0 must be a positive number"),
])
def test_refine_command_bad_input_is_one_line_and_writes_nothing(scene: Scene, tmp_path: Path, change: str,
                                                                  message: str) -> None:
    folder = scene.folder
    frame = ["--frame", str(folder / "frame.png")]
    extra: list[str] = list(frame)
    camera = folder / "camera.json"
    if change == "neither":
        extra = []
    elif change == "both":
        extra = [*frame, "--video", str(folder / "frame.png")]
    elif change == "no-frame-file":
        extra = ["--frame", str(tmp_path / "missing.png")]
    elif change == "small-frame":
        cv2.imwrite(str(tmp_path / "small.png"), cv2.resize(scene.frame, (480, 270)))
        extra = ["--frame", str(tmp_path / "small.png")]
    elif change == "no-gcps":
        doc = dict(scene.doc)
        doc.pop("gcps")
        camera = tmp_path / "camera.json"
        camera.write_text(json.dumps(doc))
    elif change == "search":
        extra = [*frame, "--search", "-3"]
    out = tmp_path / "out" / "camera_refined.json"
    args = ["refine", str(camera), "--ortho", str(folder / "ortho.tif"), "--surface", str(folder / "dem.tif"),
            "-o", str(out), "--report", str(tmp_path / "out" / "refine.json"), *extra]
    code, _, err = invoke(*args)
    assert code == 2
    err = err.strip()
    assert len(err.splitlines()) == 1 and message in err, err
    assert not out.parent.exists() or not any(out.parent.iterdir())


# ------------------------------------------------------------------------------------- the scene without traffic
def test_the_background_frame_shows_the_road_where_vehicles_drove(small_world: Path) -> None:
    from trafficgeo.synth.render import drape_orthophoto as rendered_background
    from trafficgeo.video.background_frame import background_frame
    from trafficgeo.video.reader import read_frame_at

    camera = read_camera_json(small_world / "camera_truth.json")
    still = background_frame(small_world / "video.mp4", duration_s=8.0)
    assert still.shape == (360, 640, 3) and still.dtype == np.uint8
    empty = rendered_background(camera, load_surface(small_world / "cloud.laz", camera),
                                read_raster(small_world / "ortho.tif"))
    first = read_frame_at(small_world / "video.mp4", 0.0).image
    boxes = pd.read_csv(small_world / "truth_tracks.csv").query("frame == 0").dropna(subset=["x1"])
    assert len(boxes) >= 3
    on_vehicles = np.zeros(still.shape[:2], dtype=bool)
    for b in boxes.itertuples():
        on_vehicles[int(b.y1):int(b.y2) + 1, int(b.x1):int(b.x2) + 1] = True

    def grey_diff(a: np.ndarray) -> np.ndarray:  # against the rendered empty road (RGB float)
        return np.abs(gray(a, bgr=True) - gray(empty, bgr=False))

    assert np.median(grey_diff(first)[on_vehicles]) > 20  # the first frame shows vehicles there
    assert np.median(grey_diff(still)[on_vehicles]) < 8  # the background frame shows the road (video noise, H.264)
    assert np.median(grey_diff(still)[~on_vehicles]) < 6
    with pytest.raises(InputError, match=r"start_s = 9\.0 s is outside") as info:
        background_frame(small_world / "video.mp4", start_s=9.0)
    assert info.value.parameters == ("start_s",)


# ------------------------------------------------------------------------------------------------------ verdict
def _held_out(px: list[float]) -> HeldOutErrors:
    n = len(px)
    return HeldOutErrors(ids=tuple(f"G{k}" for k in range(n)), roles=("control",) * n,
                         ground_error_m=np.asarray(px) * 0.1, pixel_error_px=np.asarray(px, dtype=float))


def test_the_verdict_refuses_a_camera_worse_at_the_clicks_and_says_when_they_cannot_tell() -> None:
    rng = np.random.default_rng(4)
    before = _held_out(list(rng.uniform(2.0, 6.0, 11)))
    better = _held_out(list(before.pixel_error_px * 0.7))
    ok, why = _verdict(before, better, 300, 30, "")
    assert ok and "cannot tell" not in why and f"{before.rmse_px:.2f} px -> {better.rmse_px:.2f} px" in why
    # as noisy clicks do to two cameras both right at them: some points better, some worse, a little worse in all
    same = _held_out(list(before.pixel_error_px + [0.6, -0.4, 0.5, -0.5, 0.4, -0.3, 0.5, -0.4, 0.3, -0.2, 0.2]))
    assert same.rmse_px >= before.rmse_px
    assert worse_p_value(before, same) > WORSE_P
    ok, why = _verdict(before, same, 300, 30, "")
    assert ok and "no worse within the clicks' noise" in why and "cannot tell the two cameras apart" in why
    worse = _held_out(list(before.pixel_error_px * 1.8 + 1.0))
    assert worse_p_value(before, worse) < 0.01
    ok, why = _verdict(before, worse, 300, 30, "")
    assert not ok and "worse beyond their noise" in why
    few = _held_out([3.0, 4.0, 5.0])
    ok, why = _verdict(few, _held_out([3.1, 4.1, 5.1]), 300, 30, "")
    assert not ok and "fewer than 5 points to tell" in why
    ok, why = _verdict(before, better, 12, 30, "")
    assert not ok and "only 12 orthophoto matches" in why


def test_a_registration_that_does_not_settle_says_how_it_moved() -> None:
    """Issue 40: 'not converged' now says how far each pass moved the camera, and whether it was creeping towards a
    camera or swinging between two."""
    from trafficgeo.registration.refine import Pass, _not_converged

    def passes(moved: list[float]) -> list[Pass]:
        return [Pass(search_px=4.0, tried=700, matched=600, kept=590, rmse_px=0.5, moved_px=m) for m in moved]

    creeping = _not_converged(passes([15.9, 0.8, 0.5, 0.4, 0.34]), 0.25)
    assert creeping.startswith("not converged after 5 passes: they moved the camera by 15.90, 0.80, 0.50, 0.40, "
                               "0.34 px (converged below 0.25)") and "more passes may settle it" in creeping
    swinging = _not_converged(passes([12.0, 0.9, 0.3, 0.9, 0.3]), 0.25)
    assert "swung between passes" in swinging and "more passes" not in swinging
