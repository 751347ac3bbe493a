"""The calibrated camera read once and written once (camera/calibrated.py), and the site loaded once (site/):
real camera JSONs written by earlier versions read back and are written again value for value; what a calibration
knows reaches the site without a file (the GCP plane of ``tg.calibrate(...)``); damaged blocks are named; a site
built from paths equals one built from objects."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import trafficgeo as tg
from trafficgeo.camera.calibrated import CalibratedCamera, CameraGCP
from trafficgeo.camera.io import write_camera_json
from trafficgeo.errors import InputError
from trafficgeo.io.atomic import to_json_safe
from trafficgeo.site.surface import load_surface
from trafficgeo.synth import make_gcp_scene

DATA = Path(__file__).parent / "data"
REAL_CAMERAS = sorted((DATA / "api-reference" / "calibration").glob("*_camera.json")) + sorted(
    (DATA / "camera-json-before").glob("*.json"))


def _same_value(a: object, b: object, where: str = "") -> list[str]:
    """Where two JSON values differ (floats to 1e-12 relative; key order counts)."""
    if isinstance(a, dict):
        if not isinstance(b, dict) or list(a) != list(b):
            return [f"{where}: keys {list(a)} != {list(b) if isinstance(b, dict) else b}"]
        return [d for k in a for d in _same_value(a[k], b[k], f"{where}/{k}")]
    if isinstance(a, list):
        if not isinstance(b, list) or len(a) != len(b):
            return [f"{where}: length"]
        return [d for k, (x, y) in enumerate(zip(a, b, strict=True)) for d in _same_value(x, y, f"{where}[{k}]")]
    if isinstance(a, float) and isinstance(b, int | float) and not isinstance(b, bool):
        return [] if abs(a - b) <= 1e-12 * max(1.0, abs(a)) else [f"{where}: {a} != {b}"]
    return [] if a == b and type(a) is type(b) else [f"{where}: {a!r} != {b!r}"]


@pytest.mark.parametrize("path", REAL_CAMERAS, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_camera_jsons_of_earlier_versions_are_written_again_value_for_value(path: Path, tmp_path: Path) -> None:
    doc = json.loads(path.read_text(encoding="utf-8"))
    camera = CalibratedCamera.read(path)
    assert camera.source == str(path)
    out = tmp_path / "again.json"
    camera.write(out)
    again = json.loads(out.read_text(encoding="utf-8"))
    if doc.get("crs") == "WGS84 UTM 10N":  # a CRS given by name is written as its code (test_camera_crs.py)
        doc["crs"] = "EPSG:32610"
    assert _same_value(doc, again) == []
    if "gcps" in doc:  # what the calibration wrote is typed
        assert [g.id for g in camera.gcps] == [r["id"] for r in doc["gcps"]]
        kept = [(r["x"], r["y"], r["z"]) for r in doc["gcps"] if r["role"] == "control" and r["inlier"]]
        np.testing.assert_array_equal(camera.control_xyz(), np.array(kept).reshape(-1, 3))
        assert camera.stats.n_inliers == doc["stats"]["n_inliers"] == len(kept)
        assert camera.model.free_parameters == tuple(doc["model"]["free_parameters"])
    if "covariance" in doc:
        np.testing.assert_array_equal(camera.covariance.matrix, np.array(doc["covariance"]["matrix"]))
        assert camera.covariance.basis == doc["covariance"]["basis"]


finite = st.floats(-1e7, 1e7, allow_nan=False)
maybe = st.one_of(st.none(), finite)


@settings(max_examples=60, deadline=None)
@given(xyz=st.tuples(finite, finite, finite), uv=st.tuples(finite, finite), proj=st.tuples(maybe, maybe, maybe),
       inlier=st.one_of(st.none(), st.booleans()), role=st.sampled_from(["control", "check"]), ident=st.text())
def test_a_gcp_row_reads_back_as_written(xyz, uv, proj, inlier, role, ident) -> None:
    row = {"id": ident, "role": role, "x": xyz[0], "y": xyz[1], "z": xyz[2], "u": uv[0], "v": uv[1],
           "u_proj": proj[0], "v_proj": proj[1], "error_px": proj[2], "inlier": inlier, "loo_error_px": None}
    gcp = CameraGCP.from_dict(row)
    assert to_json_safe(gcp.to_dict()) == row
    assert gcp.used == (role == "control" and inlier is not False)


def _calibration():
    sc = make_gcp_scene(7, n_control=14)
    return sc, tg.calibrate(sc.gcps, sc.camera.image_size)


def test_the_gcp_plane_of_a_calibration_needs_no_file(tmp_path: Path) -> None:
    """``tg.calibrate(...).calibrated_camera()`` carries the GCPs: the "plane" surface is the same as from the camera
    JSON ``trafficgeo calibrate`` writes, and what it knows survives the file."""
    from trafficgeo.calibration.run import run_calibration

    sc, cal = _calibration()
    in_memory = cal.calibrated_camera()
    path = tmp_path / "camera.json"
    run_calibration(sc.gcps, sc.camera.image_size, camera_path=path)
    from_file = CalibratedCamera.read(path)
    plane_memory, plane_file = load_surface("plane", in_memory), load_surface("plane", path)
    x, y = sc.true_world[:, 0], sc.true_world[:, 1]
    np.testing.assert_allclose(plane_memory.elevation(x, y), plane_file.elevation(x, y), atol=1e-9)
    np.testing.assert_array_equal(from_file.control_xyz(), in_memory.control_xyz())
    # the plane lies on the road where the inlier control points were surveyed (pole tops left out by the fit)
    g = in_memory.control_xyz()
    road_z = sc.road.z(g[:, 0], g[:, 1])
    on_road = np.abs(g[:, 2] - road_z) < 0.5
    assert on_road.sum() >= 8
    off_m = np.abs(plane_memory.elevation(g[on_road, 0], g[on_road, 1]) - road_z[on_road]).max()
    assert off_m < 0.15  # 0.055 m measured
    assert _same_value(json.loads(json.dumps(to_json_safe(in_memory.to_dict()))),
                       json.loads(path.read_text(encoding="utf-8"))) == []
    # a bare Camera knows no GCPs: the plane is refused with what to give instead
    with pytest.raises(InputError, match="CalibratedCamera"):
        load_surface("plane", cal.camera)
    site = tg.Site.load(in_memory, "plane")
    assert site.camera is in_memory and site.lanes is None and site.lines is None
    # a Site is accepted where a site is loaded: as it is, or with parts given in place of its own
    assert tg.Site.load(site) is site
    flat = tg.Site.load(site, 12.5)
    assert flat.camera is in_memory and float(flat.surface.elevation(x[:1], y[:1])[0]) == 12.5
    with pytest.raises(InputError, match="surface: the site needs the road surface"):
        tg.Site.load(in_memory)


@pytest.mark.parametrize(("block", "value", "said"), [
    ("gcps", [{"id": "G1", "x": "north", "y": 1.0, "z": 0.0, "u": 1.0, "v": 2.0}], r"gcps list is damaged \(row 1"),
    ("gcps", {"G1": 1}, "gcps list is damaged"),
    ("gcps", [{"id": "G1", "role": "anchor", "x": 1.0, "y": 1.0, "z": 0.0, "u": 1.0, "v": 2.0}], "anchor"),
    ("covariance", {"parameters": ["rx"], "origin": [0, 0, 0]}, "malformed 'covariance' block"),
    ("refinement", {"accepted": "yes"}, "'refinement' block is damaged"),
    ("stats", {"n_control": "many"}, "'stats' block is damaged"),
])
def test_a_damaged_block_is_named_with_the_file(tmp_path: Path, block: str, value: object, said: str) -> None:
    sc = make_gcp_scene(3, n_control=8)
    path = tmp_path / "camera.json"
    write_camera_json(path, sc.camera, {block: value})
    with pytest.raises(InputError, match=said) as caught:
        CalibratedCamera.read(path)
    assert str(path) in str(caught.value) and "\n" not in str(caught.value)


def test_the_refinement_verdict_is_typed_and_written_back(tmp_path: Path) -> None:
    sc = make_gcp_scene(3, n_control=8)
    block = {"accepted": False, "reason": "the orthophoto may show another place", "matches_kept": 3,
             "before_rmse_m": 0.41, "after_rmse_m": None, "report": "refine.json"}
    path = tmp_path / "camera.json"
    write_camera_json(path, sc.camera, {"refinement": block, "note": {"by": "hand"}})
    camera = CalibratedCamera.read(path)
    assert camera.refinement.accepted is False and camera.refinement.matches_kept == 3
    assert math.isnan(camera.refinement.after_rmse_m) and camera.refinement.report == "refine.json"
    assert camera.extras == {"note": {"by": "hand"}} and camera.gcps is None and camera.covariance is None
    camera.write(tmp_path / "again.json")
    again = json.loads((tmp_path / "again.json").read_text(encoding="utf-8"))
    assert again["refinement"] == block and again["note"] == {"by": "hand"} and "gcps" not in again


def test_a_site_from_paths_equals_one_from_objects(small_world: Path) -> None:
    world = small_world
    by_path = tg.Site.load(world / "camera_truth.json", world / "cloud.laz", world / "lanes.gpkg",
                           world / "count_lines.gpkg")
    camera = CalibratedCamera.read(world / "camera_truth.json")
    by_object = tg.Site.load(camera, by_path.surface, by_path.lanes, list(by_path.lines))
    assert by_object.camera is camera and by_object.surface is by_path.surface and by_object.lanes is by_path.lanes
    assert by_object.lines == by_path.lines and len(by_path.lines) >= 1 and len(by_path.lanes.names) >= 2
    np.testing.assert_array_equal(by_path.camera.camera.K, camera.camera.K)
    # the camera above its surface is checked where the site is loaded: heights read 100 m too high are refused
    with pytest.raises(InputError, match="above the camera"):
        tg.Site.load(camera, float(camera.camera.position[2]) + 100.0)
