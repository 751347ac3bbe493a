"""``Camera.crs`` is a ``pyproj.CRS`` parsed once; camera JSON writes it as ``AUTH:CODE`` (else WKT) and reads back
the same CRS; camera JSON written before reads back to equal cameras."""

from __future__ import annotations

import copy
import json
import pickle
from pathlib import Path

import numpy as np
import pyproj
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from reference_values import LAST_BITS, assert_json_close
from trafficgeo.camera.calibrated import read_camera_json
from trafficgeo.camera.io import write_camera_json
from trafficgeo.camera.model import Camera, crs_to_text
from trafficgeo.crs import metres_per_unit, parse_crs
from trafficgeo.errors import InputError
from trafficgeo.geo.mapping import camera_crs
from trafficgeo.video.checkpoint import content_hash

BEFORE = Path(__file__).parent / "data" / "camera-json-before"
LOCAL_TM = "+proj=tmerc +lat_0=45 +lon_0=-73.2 +k=1 +x_0=100000 +y_0=0 +ellps=GRS80 +units=m +no_defs +type=crs"
WKT_NO_AUTHORITY = pyproj.CRS(LOCAL_TM).to_wkt()
GIVEN_BEFORE = {  # what each file was written from (tests/data/camera-json-before/SOURCE.txt)
    "epsg2949": ("EPSG:2949", [300000.0, 5040000.0, 30.0]),
    "epsg2994_feet": ("EPSG:2994", [4300000.0, 600000.0, 250.0]),
    "odm_utm10n": ("WGS84 UTM 10N", [786800.0, 3810000.0, 20.0]),
    "wkt_no_authority": (WKT_NO_AUTHORITY, [100050.0, 30.0, 12.0]),
    "local": (None, [5.0, -20.0, 9.0]),
}


def _camera(crs: object, position: object = (300000.0, 5040000.0, 30.0)) -> Camera:
    return Camera.from_orientation((1920, 1080), 1400.0, position, 35.0, 15.0, 0.5,
                                   dist=[-0.1, 0.02, 0.001, -0.0005, 0.0], crs=crs)


def assert_same_camera(a: Camera, b: Camera, rotation_atol: float = 0.0) -> None:
    """Equal cameras; ``rotation_atol`` > 0 where one was made on another machine (R from sines and cosines,
    whose last bits depend on the CPU's SIMD paths)."""
    assert a.image_size == b.image_size
    for name in ("K", "dist", "position"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    np.testing.assert_allclose(a.R, b.R, rtol=0.0, atol=rotation_atol, err_msg="R")
    assert (a.crs is None) == (b.crs is None)
    if a.crs is not None:
        assert a.crs == b.crs and a.crs.to_wkt() == b.crs.to_wkt()


# ------------------------------------------------------------------ the attribute
@pytest.mark.parametrize("given_crs", ["EPSG:2949", pyproj.CRS.from_epsg(2949), 2949, "  'EPSG:2949' "])
def test_every_constructor_holds_a_parsed_crs(given_crs: object) -> None:
    want = pyproj.CRS.from_epsg(2949)
    cams = [_camera(given_crs),
            Camera((640, 480), [[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]], crs=given_crs),
            Camera.from_rvec_tvec((640, 480), np.diag([500.0, 500.0, 1.0]), np.zeros(5), [0.1, 0.2, 0.3],
                                  [1.0, 2.0, 30.0], origin=(300000.0, 5040000.0, 0.0), crs=given_crs),
            _camera(None).replace(crs=given_crs)]
    for cam in cams:
        assert isinstance(cam.crs, pyproj.CRS) and cam.crs == want
        assert camera_crs(cam) is cam.crs  # no parsing at use
        assert cam.crs_text == "EPSG:2949" or cam.crs_text == given_crs


def test_no_crs_and_the_old_empty_text_mean_local_coordinates() -> None:
    for given_crs in (None, ""):
        cam = _camera(given_crs)
        assert cam.crs is None and camera_crs(cam) is None and metres_per_unit(cam.crs) == 1.0
        assert cam.crs_text is None


def test_an_unknown_crs_is_refused_when_the_camera_is_made(tmp_path: Path) -> None:
    with pytest.raises(InputError, match=r'^"EPSG:99999" is not a coordinate reference system') as info:
        _camera("EPSG:99999")
    assert "\n" not in str(info.value)
    doc = json.loads((BEFORE / "epsg2949.json").read_text())
    doc["crs"] = "EPSG:99999"
    path = tmp_path / "camera.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(InputError, match=r"camera\.json: 'crs': \"EPSG:99999\" is not a coordinate") as info:
        read_camera_json(path)
    assert "\n" not in str(info.value)


def test_the_camera_stays_frozen_and_replace_keeps_the_crs() -> None:
    cam = _camera("WGS84 UTM 10N")
    with pytest.raises(AttributeError):
        cam.crs = "EPSG:4326"  # type: ignore[misc]
    moved = cam.replace(position=cam.position + 1.0)
    assert moved.crs == pyproj.CRS.from_epsg(32610) and moved.crs_text == "EPSG:32610"
    assert content_hash(moved.replace(position=cam.position)) == content_hash(cam)


@pytest.mark.slow
@pytest.mark.parametrize("given_crs", ["EPSG:2994", WKT_NO_AUTHORITY, None, pyproj.CRS(LOCAL_TM)])
def test_pickle_and_copies_keep_the_crs_and_the_run_key(given_crs: object) -> None:
    cam = _camera(given_crs)
    for other in (pickle.loads(pickle.dumps(cam)), copy.copy(cam), copy.deepcopy(cam)):
        assert_same_camera(other, cam)
        assert other.crs_text == cam.crs_text and content_hash(other) == content_hash(cam)


def test_crs_to_text_prefers_the_authority_code_and_keeps_wkt_without_one() -> None:
    assert crs_to_text(None) is None
    assert crs_to_text(pyproj.CRS.from_epsg(2994)) == "EPSG:2994"
    assert crs_to_text(pyproj.CRS(WKT_NO_AUTHORITY)) == WKT_NO_AUTHORITY  # its own text
    from_proj = pyproj.CRS(LOCAL_TM)
    assert pyproj.CRS(crs_to_text(from_proj)) == from_proj


# ------------------------------------------------------------------ camera JSON
@pytest.mark.parametrize("given_crs, written", [
    ("EPSG:2949", "EPSG:2949"),
    (WKT_NO_AUTHORITY, WKT_NO_AUTHORITY),
    ("EPSG:2994", "EPSG:2994"),  # international feet
    (None, None),
    (pyproj.CRS.from_epsg(2994), "EPSG:2994"),
    (pyproj.CRS(WKT_NO_AUTHORITY), WKT_NO_AUTHORITY),
])
def test_camera_json_round_trip_keeps_the_crs(tmp_path: Path, given_crs: object, written: str | None) -> None:
    cam = _camera(given_crs)
    path = tmp_path / "camera.json"
    write_camera_json(path, cam)
    back, doc = read_camera_json(path), json.loads(path.read_text(encoding="utf-8"))
    assert doc["crs"] == written
    assert_same_camera(back, cam)
    if cam.crs is not None:
        assert metres_per_unit(back.crs) == metres_per_unit(cam.crs)
        assert back.crs.to_authority() == cam.crs.to_authority()


def test_feet_crs_round_trip_keeps_the_unit(tmp_path: Path) -> None:
    cam = _camera("EPSG:2994", position=[4300000.0, 600000.0, 250.0])
    write_camera_json(tmp_path / "c.json", cam)
    back = read_camera_json(tmp_path / "c.json")
    assert metres_per_unit(back.crs) == 0.3048 and back.crs.to_epsg() == 2994


@pytest.mark.reference
@pytest.mark.parametrize("name", sorted(GIVEN_BEFORE))
def test_camera_json_written_before_reads_back_equal(tmp_path: Path, name: str) -> None:
    # The files were written on another machine: the rotation made here from the same angles, and the angles
    # written back from it, agree to the last bits (1e-12 in R; reference_values.LAST_BITS in the JSON), not bytes.
    given_crs, position = GIVEN_BEFORE[name]
    cam = read_camera_json(BEFORE / f"{name}.json")
    assert_same_camera(cam, _camera(given_crs, position), rotation_atol=1e-12)
    assert cam.crs is None if given_crs is None else cam.crs == pyproj.CRS.from_user_input(
        "EPSG:32610" if given_crs == "WGS84 UTM 10N" else given_crs)
    # written again it is the same file, value for value (the CRS as AUTH:CODE where the text was another form)
    write_camera_json(tmp_path / "again.json", cam, {"stats": {"rmse_px": 0.8}})
    again = json.loads((tmp_path / "again.json").read_text())
    before = json.loads((BEFORE / f"{name}.json").read_text())
    crs_again, crs_before = again.pop("crs"), before.pop("crs")
    assert_json_close(again, before, f"{name}.json", LAST_BITS)
    assert (crs_again is None) == (crs_before is None)
    if crs_again is not None:
        assert parse_crs(crs_again) == parse_crs(crs_before)
    assert_same_camera(read_camera_json(tmp_path / "again.json"), cam)


_CRS_TEXTS = ["EPSG:2949", "EPSG:2994", "EPSG:32616", "WGS84 UTM 17S", LOCAL_TM, WKT_NO_AUTHORITY, None]


@pytest.mark.slow
@settings(max_examples=40, deadline=None)
@given(crs_index=st.integers(0, len(_CRS_TEXTS) - 1), as_object=st.booleans(),
       focal=st.floats(300.0, 5000.0), heading=st.floats(-180.0, 180.0), tilt=st.floats(-80.0, 89.0),
       roll=st.floats(-20.0, 20.0), k1=st.floats(-0.4, 0.4), x=st.floats(-1e6, 1e6), y=st.floats(-1e7, 1e7),
       z=st.floats(-100.0, 3000.0))
def test_any_camera_reads_back_equal_from_its_json(tmp_path_factory: pytest.TempPathFactory, crs_index: int,
                                                   as_object: bool, focal: float, heading: float, tilt: float,
                                                   roll: float, k1: float, x: float, y: float, z: float) -> None:
    text = _CRS_TEXTS[crs_index]
    given_crs = parse_crs(text) if as_object else text
    cam = Camera.from_orientation((1280, 720), focal, [x, y, z], heading, tilt, roll, dist=[k1, 0, 0, 0, 0],
                                  crs=given_crs)
    path = tmp_path_factory.mktemp("cam") / "camera.json"
    write_camera_json(path, cam)
    back, doc = read_camera_json(path), json.loads(path.read_text(encoding="utf-8"))
    assert_same_camera(back, cam)
    assert content_hash(back) == content_hash(cam)
    if given_crs is None:
        assert doc["crs"] is None
    else:
        assert parse_crs(doc["crs"]) == cam.crs
