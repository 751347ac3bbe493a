"""gcp-ui web API through FastAPI's TestClient: happy paths, and every kind of bad input gets a 4xx JSON message."""

from __future__ import annotations

import re
import shutil
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest

from trafficgeo.calibration import read_gcps
from trafficgeo.camera.calibrated import read_camera_json
from trafficgeo.ui.server import STATIC_DIR, create_app
from trafficgeo.ui.startup import open_session
from ui_support import CRS, Scene, shared_scene

with warnings.catch_warnings():
    warnings.simplefilter("ignore")  # starlette's deprecation note about httpx
    from fastapi.testclient import TestClient


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Scene:
    return shared_scene(tmp_path_factory)


@pytest.fixture()
def work(tmp_path, scene) -> Path:
    for p in (scene.frame, scene.ortho, scene.dem):
        shutil.copy(p, tmp_path / p.name)
    return tmp_path


@pytest.fixture()
def client(work):
    session, _ = open_session(frame=work / "frame.png", ortho=work / "ortho.tif", dem=work / "dem.tif",
                              gcps=work / "gcps.csv")
    with TestClient(create_app(session)) as c:
        c.session = session
        yield c


def _pair(scene: Scene, i: int, j: int | None = None) -> dict[str, float]:
    j = i if j is None else j
    return {"u": float(scene.truth_pixels[i, 0]), "v": float(scene.truth_pixels[i, 1]),
            "col": float(scene.truth_ortho[j, 0]), "row": float(scene.truth_ortho[j, 1])}


def test_page_and_assets_are_served_locally(client):
    r = client.get("/")
    assert r.status_code == 200 and "text/html" in r.headers["content-type"]
    refs = re.findall(r'(?:src|href)="([^"]+)"', r.text)
    assert refs and not [u for u in refs if re.match(r"(https?:)?//", u)]  # nothing from a CDN
    for ref in refs:
        if ref.startswith("/static/"):
            assert client.get(ref).status_code == 200, ref
    js = client.get("/static/app.js").text
    assert "http://" not in js and "https://" not in js
    lic = client.get("/static/vendor/leaflet/LICENSE")
    assert lic.status_code == 200 and "BSD 2-Clause" in lic.text
    assert (STATIC_DIR / "vendor/leaflet/images/marker-icon.png").is_file()


@pytest.mark.slow
def test_info_and_images(client, scene):
    info = client.get("/api/info").json()
    assert info["frame"]["width"] == 800 and info["frame"]["height"] == 450
    assert info["ortho"]["cols"] == scene.ortho_raster.cols and info["ortho"]["display_factor"] == 1
    assert info["crs"].startswith(CRS) and info["ground"]["kind"] == "dem" and info["min_control"] == 4
    assert info["gcps_name"] == "gcps.csv" and info["autosave"] == "gcps.autosave.csv"
    for url, shape in (("/api/frame.png", (450, 800)), ("/api/ortho.png", scene.ortho_raster.shape)):
        r = client.get(url)
        assert r.headers["content-type"] == "image/png"
        img = cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_UNCHANGED)
        assert img.shape[:2] == shape
    frame = cv2.imread(str(scene.frame))
    sent = cv2.imdecode(np.frombuffer(client.get("/api/frame.png").content, np.uint8), cv2.IMREAD_COLOR)
    assert np.array_equal(frame, sent)  # lossless, full resolution


@pytest.mark.slow
def test_happy_path_pairs_calibration_files(client, work, scene):
    for i in range(6):
        r = client.post("/api/pairs", json=_pair(scene, i))
        assert r.status_code == 201, r.text
    p = r.json()
    assert p["id"] == "P6"
    np.testing.assert_allclose([p["x"], p["y"]], scene.truth_world[5, :2], atol=1e-6)
    assert abs(p["z"] - scene.truth_world[5, 2]) < 0.005 and p["ground"]["check"] == "ok"
    cal = client.get("/api/calibration").json()
    assert cal["status"] == "ok" and max(q["error_px"] for q in cal["points"]) < 0.5
    r = client.post("/api/pairs", json={**_pair(scene, 8, 9), "id": "wrong"})
    assert r.status_code == 201
    cal = client.get("/api/calibration").json()
    assert cal["outliers"] == ["wrong"]
    r = client.patch("/api/pairs/wrong", json={"col": float(scene.truth_ortho[8, 0]),
                                               "row": float(scene.truth_ortho[8, 1])})
    assert r.status_code == 200
    cal = client.get("/api/calibration").json()
    assert cal["outliers"] == [] and max(q["error_px"] for q in cal["points"]) < 0.5
    assert client.patch("/api/pairs/P2", json={"role": "check", "id": "C1", "sigma_px": 2}).json()["role"] == "check"
    assert client.patch("/api/pairs/P3", json={"z": 95}).json()["z_auto"] is False
    assert client.patch("/api/pairs/P3", json={"z_auto": True}).json()["z_auto"] is True
    assert client.delete("/api/pairs/P4").json()["deleted"] == "P4"
    state = client.get("/api/state").json()
    assert [q["id"] for q in state["pairs"]] == ["P1", "C1", "P3", "P5", "P6", "wrong"]
    assert state["autosave"]["revision"] == state["revision"] and state["autosave"]["error"] is None
    auto = read_gcps(work / "gcps.autosave.csv", crs=CRS)
    assert auto.ids == ("P1", "C1", "P3", "P5", "P6", "wrong") and auto.roles[1] == "check" and auto.sigma_px[1] == 2
    assert client.post("/api/gcps/save", json={}).json() == {"path": "gcps.csv", "n": 6}
    assert client.post("/api/gcps/save", json={"name": "copy.csv"}).json()["n"] == 6
    assert read_gcps(work / "gcps.csv", crs=CRS).ids == auto.ids
    assert client.delete("/api/pairs/P1").status_code == 200
    assert client.post("/api/gcps/load", json={"name": "copy.csv"}).json()["n"] == 6
    assert len(client.get("/api/state").json()["pairs"]) == 6
    r = client.post("/api/camera/save", json={"name": "camera.json"})
    assert r.status_code == 200, r.text
    cam = read_camera_json(work / "camera.json")
    np.testing.assert_allclose(cam.position, scene.camera.position, atol=0.5)


@pytest.mark.slow
def test_calibration_failure_is_a_normal_answer(client, scene):
    for k in range(4):  # collinear on the ground and in the frame
        t = k / 3.0
        uv = scene.truth_pixels[0] * (1 - t) + scene.truth_pixels[1] * t
        cr = scene.truth_ortho[0] * (1 - t) + scene.truth_ortho[1] * t
        assert client.post("/api/pairs", json={"u": uv[0], "v": uv[1], "col": cr[0], "row": cr[1]}).status_code == 201
    r = client.get("/api/calibration")
    assert r.status_code == 200 and r.json()["status"] == "failed" and "degenerate" in r.json()["message"]
    r = client.post("/api/camera/save", json={"name": "camera.json"})
    assert r.status_code == 409 and "no calibrated camera" in r.json()["detail"]


GOOD = {"u": 100.0, "v": 100.0, "col": 100.0, "row": 100.0}

BAD_REQUESTS = [
    # (method, url, body (dict = JSON, bytes = raw), headers, status, words in the message)
    ("post", "/api/pairs", b'{"u": 1, "v": 2,', None, 422, "not valid JSON"),
    ("post", "/api/pairs", b"[1, 2, 3, 4]", None, 422, "JSON object"),
    ("post", "/api/pairs", b'{"u": NaN, "v": 1, "col": 1, "row": 1}', None, 422, "finite"),
    ("post", "/api/pairs", b'{"u": Infinity, "v": 1, "col": 1, "row": 1}', None, 422, "finite"),
    ("post", "/api/pairs", {**GOOD, "u": "100"}, None, 422, "u: Input should be a valid number"),
    ("post", "/api/pairs", {**GOOD, "v": True}, None, 422, "v:"),
    ("post", "/api/pairs", {**GOOD, "col": [1]}, None, 422, "col:"),
    ("post", "/api/pairs", {**GOOD, "row": None}, None, 422, "row:"),
    ("post", "/api/pairs", {"u": 1, "v": 1, "col": 1}, None, 422, "row: missing"),
    ("post", "/api/pairs", {**GOOD, "colour": "red"}, None, 422, "colour: unknown field"),
    ("post", "/api/pairs", {**GOOD, "role": "boss"}, None, 422, "role:"),
    ("post", "/api/pairs", {**GOOD, "sigma_px": 0}, None, 422, "sigma_px:"),
    ("post", "/api/pairs", {**GOOD, "id": ""}, None, 422, "id:"),
    ("post", "/api/pairs", {**GOOD, "id": "x" * 41}, None, 422, "id:"),
    ("post", "/api/pairs", {**GOOD, "id": "bad\tid"}, None, 400, "printable"),
    ("post", "/api/pairs", {**GOOD, "id": "P1"}, None, 409, "already used"),
    ("post", "/api/pairs", {**GOOD, "u": 800.0}, None, 400, "outside the 800x450 frame"),
    ("post", "/api/pairs", {**GOOD, "v": -0.51}, None, 400, "outside the 800x450 frame"),
    ("post", "/api/pairs", {**GOOD, "col": -1.0}, None, 400, "outside the"),
    ("post", "/api/pairs", {**GOOD, "row": 1e12}, None, 400, "outside the"),
    ("post", "/api/pairs", {**GOOD, "z": 1e7}, None, 400, "out of range"),
    ("post", "/api/pairs", b'{"u": 1, "v": 1, "col": 1, "row": 1}', {"content-type": "text/plain"}, 422,
     "application/json"),
    ("post", "/api/pairs", GOOD, {"origin": "http://evil.example"}, 403, "cross-origin"),
    ("post", "/api/pairs", GOOD, {"origin": "null"}, 403, "opaque"),
    ("post", "/api/pairs", b'{"u": ' + b"1" * 70000 + b"}", None, 413, "larger than"),
    ("patch", "/api/pairs/P1", {}, None, 400, "nothing to change"),
    ("patch", "/api/pairs/P1", {"z": None}, None, 400, "null"),
    ("patch", "/api/pairs/P1", {"z": 90.0, "z_auto": True}, None, 400, "not both"),
    ("patch", "/api/pairs/P1", {"z_auto": False}, None, 400, "give z"),
    ("patch", "/api/pairs/P1", {"z_auto": "yes"}, None, 422, "z_auto:"),
    ("patch", "/api/pairs/P1", {"u": -5.0}, None, 400, "outside"),
    ("patch", "/api/pairs/P1", {"id": "P2"}, None, 409, "already used"),
    ("patch", "/api/pairs/NOPE", {"u": 5.0}, None, 404, 'no pair with id "NOPE"'),
    ("delete", "/api/pairs/NOPE", None, None, 404, "no pair"),
    ("post", "/api/gcps/save", {"name": "../x.csv"}, None, 400, "leaves the working folder"),
    ("post", "/api/gcps/save", {"name": "/tmp/x.csv"}, None, 400, "absolute path"),
    ("post", "/api/gcps/save", {"name": "a/../../x.csv"}, None, 400, "leaves the working folder"),
    ("post", "/api/gcps/save", {"name": "x.exe"}, None, 400, "must end with .csv"),
    ("post", "/api/gcps/save", {"name": 3}, None, 422, "name:"),
    ("post", "/api/gcps/load", {}, None, 422, "name: missing"),
    ("post", "/api/gcps/load", {"name": "missing.csv"}, None, 404, "does not exist"),
    ("post", "/api/gcps/load", {"name": "broken.csv"}, None, 400, "broken.csv line 2"),
    ("post", "/api/gcps/load", {"name": "../../etc/passwd.csv"}, None, 400, "leaves the working folder"),
    ("post", "/api/camera/save", {"name": "camera.csv"}, None, 400, "must end with .json"),
    ("post", "/api/camera/save", {"name": "C:\\cam.json"}, None, 400, "absolute path"),
    ("post", "/api/camera/save", {"name": "camera.json"}, None, 409, "no calibrated camera"),
    ("get", "/api/nothing", None, None, 404, "no such address"),
    ("put", "/api/state", None, None, 405, "not allowed"),
]


@pytest.fixture(scope="module")
def shared(tmp_path_factory, scene):
    """One client with two pairs for all the bad requests (none of them may change anything)."""
    work = tmp_path_factory.mktemp("work")
    (work / "broken.csv").write_text("id,x,y,z,u,v\nA,1,2,three,4,5\n")
    session, _ = open_session(frame=scene.frame, ortho=scene.ortho, dem=scene.dem, gcps=work / "gcps.csv")
    with TestClient(create_app(session)) as c:
        for i in range(2):
            assert c.post("/api/pairs", json=_pair(scene, i)).status_code == 201
        yield c, work


@pytest.mark.parametrize("method, url, body, headers, status, words", BAD_REQUESTS,
                         ids=[f"{i:02d}-{r[0]}-{r[5][:24]}" for i, r in enumerate(BAD_REQUESTS)])
def test_bad_input_gets_a_4xx_json_message_and_changes_nothing(shared, method, url, body, headers, status, words):
    client, work = shared
    before = client.get("/api/state").json()
    assert len(before["pairs"]) == 2
    kwargs: dict = {"headers": headers or {}}
    if isinstance(body, bytes):
        kwargs["content"] = body
        kwargs["headers"] = {"content-type": "application/json", **kwargs["headers"]}
    elif body is not None:
        kwargs["json"] = body
    r = client.request(method.upper(), url, **kwargs)
    assert r.status_code == status, r.text
    assert r.headers["content-type"] == "application/json"
    detail = r.json()["detail"]
    assert isinstance(detail, str) and words in detail and "\n" not in detail
    assert client.get("/api/state").json() == before
    assert not list(work.parent.glob("x.*")) and not (Path("/tmp") / "x.csv").exists()


def test_host_header_is_checked_when_asked(work):
    session, _ = open_session(frame=work / "frame.png", ortho=work / "ortho.tif", gcps=work / "g.csv")
    with TestClient(create_app(session, allowed_hosts=["127.0.0.1", "localhost"]),
                    base_url="http://127.0.0.1:8765") as c:
        assert c.get("/api/info").status_code == 200
        r = c.get("/api/info", headers={"host": "attacker.example:8765"})
        assert r.status_code == 400 and "not served here" in r.json()["detail"]


def test_unexpected_errors_are_json_500_and_the_server_keeps_going(client, scene, monkeypatch):
    def boom(*a, **k):
        raise RuntimeError("simulated bug")

    monkeypatch.setattr(client.session, "state", boom)
    with TestClient(client.app, raise_server_exceptions=False) as c:
        r = c.get("/api/state")
        assert r.status_code == 500 and "internal error" in r.json()["detail"]
        assert c.post("/api/pairs", json=_pair(scene, 0)).status_code == 201


def test_a_peers_gcp_file_is_read_and_kept_as_it_is(work, scene):
    """A GCP file with other column names (issue 42: easting/northing/elevation, col/row, no id) opens with a note
    of how its columns were read; Save writes trafficgeo's layout beside it and leaves the user's file unchanged."""
    rows = ["Easting,Northing,Elevation,Col,Row"]
    for i in range(8):
        x, y, z = (float(c) for c in scene.truth_world[i])
        u, v = (float(c) for c in scene.truth_pixels[i])
        rows.append(f"{x!r}, {y!r}, {z!r}, {u!r}, {v!r}")
    theirs = work / "theirs.csv"
    theirs.write_text("\n".join(rows) + "\n", encoding="utf-8")
    before = theirs.read_bytes()
    session, note = open_session(frame=work / "frame.png", ortho=work / "ortho.tif", dem=work / "dem.tif",
                                 gcps=theirs)
    assert "columns read as Col -> u, Row -> v, Easting -> x, Northing -> y, Elevation -> z" in note
    assert "theirs_trafficgeo.csv" in note
    with TestClient(create_app(session)) as c:
        assert len(c.get("/api/state").json()["pairs"]) == 8
        assert c.get("/api/calibration").json()["status"] == "ok"
        assert c.post("/api/gcps/save", json={}).json() == {"path": "theirs_trafficgeo.csv", "n": 8}
    assert theirs.read_bytes() == before
    saved = read_gcps(work / "theirs_trafficgeo.csv", crs=CRS)
    np.testing.assert_allclose(saved.world, scene.truth_world[:8])
    assert saved.columns_note == ""


def test_a_qgis_points_file_opens_with_heights_from_the_ground(work, scene):
    """A QGIS Georeferencer .points file (map CRS on its first line, image rows negated, pixel corners, no heights):
    gcp-ui opens it with the heights taken from the DEM, as for pairs clicked in the page, and saves beside it."""
    rows = [f"#CRS: {CRS}", "mapX,mapY,sourceX,sourceY,enable,dX,dY,residual"]
    for i in range(8):
        x, y = (float(c) for c in scene.truth_world[i, :2])
        u, v = (float(c) for c in scene.truth_pixels[i])
        rows.append(f"{x!r},{y!r},{u + 0.5!r},{-(v + 0.5)!r},1,0,0,0")
    rows.append(f"{x!r},{y!r},5,-5,0,0,0,0")  # disabled in QGIS: left out
    theirs = work / "frame.points"
    theirs.write_text("\n".join(rows) + "\n", encoding="utf-8")
    before = theirs.read_bytes()
    session, note = open_session(frame=work / "frame.png", ortho=work / "ortho.tif", dem=work / "dem.tif",
                                 gcps=theirs)
    assert "QGIS Georeferencer points" in note and "1 disabled point(s) left out" in note
    assert "frame_trafficgeo.csv" in note
    with TestClient(create_app(session)) as c:
        assert len(c.get("/api/state").json()["pairs"]) == 8
        assert c.post("/api/gcps/save", json={}).json() == {"path": "frame_trafficgeo.csv", "n": 8}
    assert theirs.read_bytes() == before
    saved = read_gcps(work / "frame_trafficgeo.csv", crs=CRS)
    np.testing.assert_allclose(saved.pixels, scene.truth_pixels[:8], atol=1e-9)
    np.testing.assert_allclose(saved.world[:, :2], scene.truth_world[:8, :2], atol=1e-9)
    ground = session.ground.sample(saved.world[:, 0], saved.world[:, 1], np.full(8, np.nan))
    np.testing.assert_allclose(saved.world[:, 2], [g.z for g in ground], atol=1e-9)


def test_lon_lat_gcps_open_with_gcp_crs_and_are_saved_beside(work, scene):
    """Issue 42: gcp-ui refused lon/lat GCPs and pointed to a --gcp-crs it did not have. With gcp_crs EPSG:4326 the
    file opens (projected to the orthophoto's CRS), the note asks for the survey accuracy of map-picked points, and
    Save leaves the user's lon/lat file as it is."""
    from pyproj import Transformer

    lon, lat = Transformer.from_crs(CRS, "EPSG:4326", always_xy=True).transform(scene.truth_world[:8, 0],
                                                                              scene.truth_world[:8, 1])
    rows = ["id,x,y,z,u,v"] + [f"P{i},{lon[i]:.10f},{lat[i]:.10f},{float(scene.truth_world[i, 2]):.4f},"
                               f"{float(scene.truth_pixels[i, 0]):.4f},{float(scene.truth_pixels[i, 1]):.4f}"
                               for i in range(8)]
    theirs = work / "lonlat.csv"
    theirs.write_text("\n".join(rows) + "\n", encoding="utf-8")
    before = theirs.read_bytes()
    with pytest.raises(Exception, match="gcp_crs EPSG:4326"):
        open_session(frame=work / "frame.png", ortho=work / "ortho.tif", dem=work / "dem.tif", gcps=theirs)
    session, note = open_session(frame=work / "frame.png", ortho=work / "ortho.tif", dem=work / "dem.tif",
                                 gcps=theirs, gcp_crs="EPSG:4326")
    assert "lonlat_trafficgeo.csv" in note and "survey_sigma" in note
    with TestClient(create_app(session)) as c:
        assert c.post("/api/gcps/save", json={}).json() == {"path": "lonlat_trafficgeo.csv", "n": 8}
    assert theirs.read_bytes() == before
    saved = read_gcps(work / "lonlat_trafficgeo.csv", crs=CRS)
    np.testing.assert_allclose(saved.world[:, :2], scene.truth_world[:8, :2], atol=1e-4)
