"""gcp-ui session (no HTTP): pairs, ground heights, live calibration, overlays, autosave, files, input checks."""

from __future__ import annotations

import math
import os
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from trafficgeo.calibration import read_gcps
from trafficgeo.camera.calibrated import read_camera_json
from trafficgeo.errors import InputError
from trafficgeo.geo.mapping import pixels_to_world
from trafficgeo.geo.raster import write_geotiff
from trafficgeo.ui.inputs import MAX_DISPLAY_PX, load_ground, load_ortho
from trafficgeo.ui.session import ConflictError, NotFoundError, Session, SessionError
from trafficgeo.ui.startup import open_session
from ui_support import CRS, Scene, shared_scene

GRADE_SLOPE_DEG = math.degrees(math.atan(math.hypot(0.02, 0.02)))


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Scene:
    return shared_scene(tmp_path_factory)


@pytest.fixture()
def work(tmp_path, scene) -> Path:
    """A fresh working folder holding copies of the scene's files."""
    for p in (scene.frame, scene.ortho, scene.dem, scene.cloud):
        shutil.copy(p, tmp_path / p.name)
    return tmp_path


def _session(work: Path, ground: str | None = "dem", **kw) -> Session:
    extra = {} if ground is None else {ground: work / f"{ground}.{'tif' if ground == 'dem' else 'laz'}"}
    session, _ = open_session(frame=work / "frame.png", ortho=work / "ortho.tif", gcps=work / "gcps.csv", **extra,
                              **kw)
    return session


def _add_truth(session: Session, scene: Scene, idx) -> None:
    for i in idx:
        session.add_pair(*scene.truth_pixels[i], *scene.truth_ortho[i])


def test_pairs_take_x_y_from_the_orthophoto_transform_and_z_from_the_dem(work, scene):
    s = _session(work)
    p = s.add_pair(*scene.truth_pixels[0], *scene.truth_ortho[0])
    assert p["id"] == "P1" and p["z_auto"]
    np.testing.assert_allclose([p["x"], p["y"]], scene.truth_world[0, :2], atol=1e-6)  # float64 all the way
    assert p["z"] == pytest.approx(scene.dem_surface.elevation(p["x"], p["y"]), abs=1e-9)
    assert p["z"] == pytest.approx(scene.truth_world[0, 2], abs=0.005)
    g = p["ground"]
    assert g["check"] == "ok" and g["points"] == -1
    assert 0 < g["spread_m"] < 0.03  # a 2 % crossfall within 0.5 m
    assert g["slope_deg"] == pytest.approx(GRADE_SLOPE_DEG, abs=0.05)
    np.testing.assert_allclose([p["col"], p["row"]], scene.truth_ortho[0], atol=1e-6)


@pytest.mark.slow
def test_cloud_gives_z_from_the_lidar_ground_points_with_their_spread(work, scene):
    s = _session(work, "cloud")
    p = s.add_pair(*scene.truth_pixels[1], *scene.truth_ortho[1])
    g = p["ground"]
    assert g["points"] >= 3
    assert 0.0 < g["spread_m"] < 0.06  # lidar noise of 2 cm
    assert p["z"] == pytest.approx(scene.truth_world[1, 2], abs=0.04)
    assert s.info()["ground"]["kind"] == "cloud"
    _add_truth(s, scene, [0, 2, 3, 4, 5])
    cal = s.calibration()  # the footprint is drawn on a ground DEM made from the cloud
    assert cal["status"] == "ok" and cal["footprint"] and cal["grid"]["frame"] and cal["overlay_error"] is None


@pytest.mark.slow
def test_live_calibration_gives_small_residuals_and_flags_a_wrong_pair(work, scene):
    s = _session(work)
    assert s.calibration()["status"] == "waiting"
    _add_truth(s, scene, range(3))
    cal = s.calibration()
    assert cal["status"] == "waiting" and "1 more control pair" in cal["message"]
    _add_truth(s, scene, range(3, 7))
    cal = s.calibration()
    assert cal["status"] == "ok" and cal["revision"] == s.revision
    errors = [p["error_px"] for p in cal["points"]]
    assert len(errors) == 7 and max(errors) < 0.5
    assert all(p["status"] == "inlier" and math.isfinite(p["loo_error_px"]) for p in cal["points"])
    np.testing.assert_allclose(cal["camera"]["position"], scene.camera.position, atol=0.5)
    # a wrong pair: the frame pixel of one feature with the orthophoto position of another
    s.add_pair(*scene.truth_pixels[8], *scene.truth_ortho[9])
    cal = s.calibration()
    by_id = {p["id"]: p for p in cal["points"]}
    assert cal["outliers"] == ["P8"]
    assert by_id["P8"]["status"] == "outlier" and by_id["P8"]["error_px"] > 20
    assert "wrong click" in by_id["P8"]["reason"]
    assert max(by_id[f"P{i}"]["error_px"] for i in range(1, 8)) < 0.5
    assert s.calibration() is cal  # cached for the revision


@pytest.mark.slow
def test_footprint_and_grid_follow_the_camera(work, scene):
    s = _session(work)
    _add_truth(s, scene, range(8))
    cal = s.calibration()
    assert cal["footprint"], cal.get("overlay_error")
    outer = np.asarray(cal["footprint"][0][0])
    assert outer.shape[1] == 2 and outer.shape[0] >= 4
    # The camera looks along the road: the footprint holds the true ground points of the GCPs.
    from shapely.geometry import Point, Polygon

    poly = Polygon(outer)
    assert all(poly.buffer(1.0).contains(Point(*c)) for c in scene.truth_ortho[:8])
    grid = cal["grid"]
    assert grid["spacing"] in (5.0, 10.0, 20.0) and grid["frame"] and grid["ortho"]
    w, h = s.frame.size
    s.save_camera("cam.json")
    cam = read_camera_json(work / "cam.json")  # the calibrated camera the grid is drawn through
    checked = 0
    for line in grid["frame"]:
        axis, value = line["label"].split(" = ")[0], float(line["label"].split(" = ")[1].split()[0])
        uv = np.asarray(line["points"])
        assert np.all((uv[:, 0] >= -0.5) & (uv[:, 0] <= w - 0.5) & (uv[:, 1] >= -0.5) & (uv[:, 1] <= h - 0.5))
        # Through the camera, each drawn pixel sees the ground on the labelled grid line.
        g = pixels_to_world(cam, uv, scene.dem_surface, with_lonlat=False, min_incidence_deg=0.0).xyz
        ok = np.all(np.isfinite(g), axis=1)
        on = g[ok].copy()
        on[:, 0 if axis == "x" else 1] = value
        on[:, 2] = scene.dem_surface.elevation(on[:, 0], on[:, 1])
        back = cam.project(on)
        good = np.all(np.isfinite(back), axis=1)
        if good.any():  # rays near the far edge may leave the DEM
            assert np.max(np.linalg.norm(back[good] - uv[ok][good], axis=1)) < 0.05
            checked += 1
    assert checked >= 0.8 * len(grid["frame"]) and checked >= 6
    for line in grid["ortho"]:
        axis, value = line["label"].split(" = ")[0], float(line["label"].split(" = ")[1].split()[0])
        cr = np.asarray(line["points"])
        x, y = s.ortho.pixel_to_map(cr[:, 0], cr[:, 1])
        np.testing.assert_allclose(x if axis == "x" else y, value, atol=1e-3)


@pytest.mark.slow
def test_edit_rename_role_typed_z_and_delete(work, scene):
    s = _session(work)
    _add_truth(s, scene, range(6))
    p = s.update_pair("P2", new_id="lane-A", role="check")
    assert p["id"] == "lane-A" and p["role"] == "check"
    with pytest.raises(ConflictError):
        s.update_pair("P3", new_id="lane-A")
    with pytest.raises(NotFoundError):
        s.update_pair("P2", role="check")
    with pytest.raises(SessionError, match="printable"):
        s.update_pair("P3", new_id=" P3")
    z_ground = s.pairs[2].z
    p = s.update_pair("P3", z=z_ground + 0.5)
    assert not p["z_auto"] and p["z"] == z_ground + 0.5
    assert p["ground"]["dz_m"] == pytest.approx(0.5, abs=1e-9) and p["ground"]["check"] == "disagrees"
    p = s.update_pair("P3", z_auto=True)
    assert p["z_auto"] and p["z"] == pytest.approx(z_ground, abs=1e-12)
    # moving on the orthophoto re-reads z; moving in the frame keeps it
    old = s.pairs[3]
    p = s.update_pair("P4", col=scene.truth_ortho[7, 0], row=scene.truth_ortho[7, 1])
    assert p["z"] == pytest.approx(scene.dem_surface.elevation(p["x"], p["y"]), abs=1e-9) and p["z"] != old.z
    p = s.update_pair("P4", u=old.u + 2.0)
    assert p["u"] == old.u + 2.0 and p["v"] == old.v
    cal = s.calibration()
    assert cal["n_check"] == 1 and {q["id"]: q["status"] for q in cal["points"]}["lane-A"] == "check"
    s.delete_pair("lane-A")
    assert [q.id for q in s.pairs] == ["P1", "P3", "P4", "P5", "P6"]
    with pytest.raises(NotFoundError):
        s.delete_pair("lane-A")
    assert s.add_pair(*scene.truth_pixels[9], *scene.truth_ortho[9])["id"] == "P7"  # P2 is not reused


@pytest.mark.parametrize("kwargs, match", [
    ({"u": -0.6}, "outside the 800x450 frame"),
    ({"v": 449.6}, "outside the 800x450 frame"),
    ({"u": math.nan}, "finite"),
    ({"col": -1e-3}, "outside the"),
    ({"row": 1e9}, "outside the"),
    ({"z": 2e5}, "out of range"),
    ({"sigma_px": 0.0}, "sigma_px"),
    ({"role": "ctrl"}, "unknown"),
    ({"pair_id": "a\nb"}, "printable"),
    ({"pair_id": "x" * 41}, "printable"),
])
def test_bad_pair_values_are_refused_and_change_nothing(work, scene, kwargs, match):
    s = _session(work)
    args = {"u": 10.0, "v": 10.0, "col": 10.0, "row": 10.0}
    args.update({k: kwargs[k] for k in ("u", "v", "col", "row") if k in kwargs})
    extra = {k: v for k, v in kwargs.items() if k not in args}
    rev = s.revision
    with pytest.raises(SessionError, match=match):
        s.add_pair(args["u"], args["v"], args["col"], args["row"], **extra)
    assert s.revision == rev and s.pairs == []
    assert s.add_pair(-0.5, 449.5, 0.0, float(s.ortho.rows))["id"] == "P1"  # the edges themselves are fine


@pytest.mark.slow
def test_autosave_after_every_change_and_resume(work, scene):
    s = _session(work)
    autosave = work / "gcps.autosave.csv"
    assert s.autosave_path == autosave and not autosave.exists()
    _add_truth(s, scene, range(5))
    s.update_pair("P2", role="check")
    s.update_pair("P3", z=91.25)
    s.delete_pair("P5")
    t = read_gcps(autosave, crs=CRS)
    assert t.ids == ("P1", "P2", "P3", "P4") and t.roles == ("control", "check", "control", "control")
    for i, p in enumerate(s.pairs):  # exact: the CSV holds repr floats
        assert tuple(t.world[i]) == (p.x, p.y, p.z) and tuple(t.pixels[i]) == (p.u, p.v)
    assert s.state()["autosave"]["revision"] == s.revision
    # A new session (after a crash) continues from the autosave; z that equal the ground follow it again.
    s2, note = open_session(frame=work / "frame.png", ortho=work / "ortho.tif", dem=work / "dem.tif",
                            gcps=work / "gcps.csv")
    assert "gcps.autosave.csv" in note and [p.id for p in s2.pairs] == ["P1", "P2", "P3", "P4"]
    assert [p.z_auto for p in s2.pairs] == [True, True, False, True]
    assert s2.state()["autosave"]["revision"] is None  # opening a session writes nothing
    # Saving writes the --gcps file; an autosave with the same content (even if newer) holds nothing new.
    assert s2.save_csv()["path"] == "gcps.csv"
    os.utime(autosave, (2e9, 2e9))
    s3, note = open_session(frame=work / "frame.png", ortho=work / "ortho.tif", dem=work / "dem.tif",
                            gcps=work / "gcps.csv")
    assert note.endswith("/gcps.csv") and len(s3.pairs) == 4
    s3.delete_pair("P4")  # an unsaved change: the next session continues from the autosave
    os.utime(autosave, (2e9 + 1, 2e9 + 1))
    s4, note = open_session(frame=work / "frame.png", ortho=work / "ortho.tif", dem=work / "dem.tif",
                            gcps=work / "gcps.csv")
    assert "unsaved changes" in note and [p.id for p in s4.pairs] == ["P1", "P2", "P3"]


def test_autosave_failure_is_reported_not_raised(work, scene):
    s = _session(work)
    s.autosave_path = work / "missing-folder" / "file" / "x.csv"
    (work / "missing-folder").write_text("a file, not a folder")
    s.add_pair(*scene.truth_pixels[0], *scene.truth_ortho[0])
    err = s.state()["autosave"]["error"]
    assert err and "autosave" in err and "failed" in err
    assert len(s.pairs) == 1


@pytest.mark.parametrize("name, match", [
    ("../x.csv", "leaves the working folder"),
    ("sub/../../x.csv", "leaves the working folder"),
    ("..\\x.csv", "leaves the working folder"),
    ("/tmp/x.csv", "absolute path"),
    ("C:\\x.csv", "absolute path"),
    ("~/x.csv", "absolute path"),
    ("", "empty"),
    ("x.txt", "must end with .csv"),
    ("nodir/x.csv", "does not exist"),
    ("escape/x.csv", "leads out of the working folder"),
])
def test_file_names_cannot_leave_the_working_folder(work, scene, tmp_path_factory, name, match):
    outside = tmp_path_factory.mktemp("outside")
    (work / "escape").symlink_to(outside, target_is_directory=True)
    s = _session(work)
    with pytest.raises(SessionError, match=match):
        s.save_csv(name)
    assert not list(outside.iterdir())


@pytest.mark.slow
def test_save_and_load_csv_and_save_camera(work, scene):
    s = _session(work)
    _add_truth(s, scene, range(7))
    (work / "sub").mkdir()
    assert s.save_csv("sub/picked.csv") == {"path": "sub/picked.csv", "n": 7}
    s2 = _session(work)
    assert s2.load_csv("sub/picked.csv")["n"] == 7
    assert [(p.id, p.u, p.v, p.x, p.y, p.z) for p in s2.pairs] == [(p.id, p.u, p.v, p.x, p.y, p.z) for p in s.pairs]
    with pytest.raises(NotFoundError):
        s2.load_csv("nothing.csv")
    (work / "bad.csv").write_text("id,x,y,z,u,v\nA,1,2,3,4\n")
    with pytest.raises(InputError, match=r"bad\.csv line 2"):
        s2.load_csv("bad.csv")
    (work / "offframe.csv").write_text("id,x,y,z,u,v\nA,245000,5182600,90,900,10\n")
    with pytest.raises(InputError, match="outside the 800x450 frame"):
        s2.load_csv("offframe.csv")
    assert len(s2.pairs) == 7  # a refused load changes nothing
    out = s2.save_camera("cam.json")
    assert out["path"] == "cam.json"
    cam = read_camera_json(work / "cam.json")
    np.testing.assert_allclose(cam.position, scene.camera.position, atol=0.5)
    assert cam.crs == CRS


def test_calibration_failure_is_an_answer(work, scene):
    s = _session(work)
    # four pairs along one line of the frame and the ground: degenerate
    for k in range(4):
        t = k / 3.0
        uv = scene.truth_pixels[0] * (1 - t) + scene.truth_pixels[1] * t
        cr = scene.truth_ortho[0] * (1 - t) + scene.truth_ortho[1] * t
        s.add_pair(*uv, *cr)
    cal = s.calibration()
    assert cal["status"] == "failed" and "degenerate" in cal["message"]
    with pytest.raises(ConflictError, match="no calibrated camera"):
        s.save_camera("cam.json")
    assert not (work / "cam.json").exists()


def test_without_ground_z_is_typed(work, scene):
    s = _session(work, ground=None)
    p = s.add_pair(*scene.truth_pixels[0], *scene.truth_ortho[0])
    assert p["z"] == 0.0 and not p["z_auto"] and p["ground"] is None
    s.update_pair("P1", z=90.1)
    assert s.add_pair(*scene.truth_pixels[1], *scene.truth_ortho[1])["z"] == 90.1  # the others' median
    with pytest.raises(ConflictError, match="no ground"):
        s.update_pair("P1", z_auto=True)


def test_large_orthophoto_is_shown_downsampled_with_full_resolution_coordinates(tmp_path):
    from affine import Affine

    data = np.zeros((3, 12, MAX_DISPLAY_PX + 10), dtype=np.uint16)
    data[:, :, 100:] = 1000
    t = Affine(0.02, 0, 245000.0, 0, -0.02, 5182600.0)
    write_geotiff(tmp_path / "big.tif", data, t, CRS)
    o = load_ortho(tmp_path / "big.tif")
    assert o.display_factor == 2 and "downsampled 2x" in o.note
    img = cv2.imdecode(np.frombuffer(o.png, np.uint8), cv2.IMREAD_UNCHANGED)
    assert img.shape == (6, (MAX_DISPLAY_PX + 10) // 2, 4) and img.dtype == np.uint8
    assert img[0, 0, :3].max() == 0 and img[0, 60, :3].min() == 255  # stretched from uint16
    assert o.pixel_to_world(8000.5, 3.0) == (245000.0 + 8000.5 * 0.02, 5182600.0 - 3.0 * 0.02)
    assert o.display_extent == (MAX_DISPLAY_PX + 10, 12)
    # an image georeferenced by a world file (six lines: A, D, B, E, C, F; C, F = centre of the top-left pixel)
    cv2.imwrite(str(tmp_path / "small.png"), np.full((10, 20, 3), 128, np.uint8))
    (tmp_path / "small.pgw").write_text("0.5\n0\n0\n-0.5\n1000.25\n2000.0\n")
    o = load_ortho(tmp_path / "small.png")
    assert (o.cols, o.rows, o.display_factor, o.display_extent) == (20, 10, 1, (20, 10))
    assert o.pixel_to_world(0.0, 0.0) == (1000.0, 2000.25) and o.world_to_pixel(1010.0, 1995.25) == (20.0, 10.0)


def test_input_errors_for_the_ortho_and_ground(tmp_path, scene):
    from affine import Affine

    write_geotiff(tmp_path / "lonlat.tif", np.zeros((1, 4, 4), np.uint8), Affine(1e-5, 0, 10.0, 0, -1e-5, 50.0),
                  "EPSG:4326")
    with pytest.raises(InputError, match="geographic"):
        load_ortho(tmp_path / "lonlat.tif")
    cv2.imwrite(str(tmp_path / "plain.png"), np.zeros((4, 4, 3), np.uint8))
    with pytest.raises(InputError, match="no georeferencing"):
        load_ortho(tmp_path / "plain.png")
    write_geotiff(tmp_path / "dem32633.tif", np.full((4, 4), 90.0), Affine(1, 0, 500000, 0, -1, 5000000),
                  "EPSG:32633")
    with pytest.raises(InputError, match="differs from the orthophoto"):
        load_ground(dem=tmp_path / "dem32633.tif", ortho_crs=scene.ortho_raster.crs)
    with pytest.raises(InputError, match="not both"):
        load_ground(dem=scene.dem, cloud=scene.cloud)


FULL_DISK_SESSION = """
import resource, signal, sys
from pathlib import Path
from trafficgeo.ui.session import SessionError
from trafficgeo.ui.startup import open_session
work = Path(sys.argv[1])
session, _ = open_session(frame=work / "frame.png", ortho=work / "ortho.tif", gcps=work / "gcps.csv",
                          dem=work / "dem.tif")
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
resource.setrlimit(resource.RLIMIT_FSIZE, (60, 60))  # a full disk: the GCP CSV's header fits, its rows do not
session.add_pair(float(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4]), float(sys.argv[5]))
print("autosave:", session.state()["autosave"]["error"])
try:
    session.save_csv("other.csv")
    print("saved")
except SessionError as exc:
    print("refused:", exc)
print("pairs:", len(session.pairs))
"""


def test_a_full_disk_under_the_web_app_is_an_answer(work, scene):
    """Issue 43: a full disk while the web app autosaves or saves the GCPs raised OutputError, which the session did
    not catch (the disk-full error is not an OSError): the request failed. Now autosave reports it in the state and
    save answers with a SessionError; the pair is kept and no partial file is left."""
    import os
    import subprocess
    import sys

    src = Path(__file__).resolve().parents[1] / "src"
    u, v = scene.truth_pixels[0]
    x, y = scene.truth_ortho[0]
    run = subprocess.run([sys.executable, "-c", FULL_DISK_SESSION, str(work), str(u), str(v), str(x), str(y)],
                         env={**os.environ, "PYTHONPATH": str(src)}, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    lines = dict(line.split(": ", 1) for line in run.stdout.splitlines())
    assert "failed" in lines["autosave"] and "could not write" in lines["autosave"], run.stdout
    assert lines["refused"].startswith("cannot write") and "free space" in lines["refused"], run.stdout
    assert lines["pairs"] == "1"
    assert not (work / "other.csv").exists()
    assert not any(".tmp" in p.name for p in work.iterdir())
