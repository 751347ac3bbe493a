"""gcp-ui "Refine from orthophoto" through FastAPI's TestClient, on a generated registration scene with truth.

The session is opened on the scene's files with the user's rough GCPs (3 px click noise); the refinement must be
accepted, beat the rough camera on the ground at the scene's truth points, save its files, and refuse a wrong
orthophoto; the server keeps answering while it runs, and bad states get one-line 4xx answers.
"""

from __future__ import annotations

import json
import shutil
import threading
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from trafficgeo.camera.calibrated import CalibratedCamera
from trafficgeo.synth.registration_scene import ground_errors_m
from trafficgeo.ui.server import create_app
from trafficgeo.ui.startup import open_session
from ui_refine_support import IMAGE_SIZE, RefineScene, shared_refine_scene

with warnings.catch_warnings():
    warnings.simplefilter("ignore")  # starlette's deprecation note about httpx
    from fastapi.testclient import TestClient

pytestmark = pytest.mark.slow  # generated registration scene and two refinements (about 20 s)


@pytest.fixture(scope="module")
def rs(tmp_path_factory) -> RefineScene:
    return shared_refine_scene(tmp_path_factory)


def _client(rs: RefineScene, work: Path, ortho: str = "ortho.tif", dem: bool = True) -> TestClient:
    for p in (rs.frame, rs.ortho, rs.ortho_wrong, rs.dem, rs.gcps):
        shutil.copy(p, work / p.name)
    session, _ = open_session(frame=work / "frame.png", ortho=work / ortho, dem=work / "dem.tif" if dem else None,
                              gcps=work / "gcps.csv")
    client = TestClient(create_app(session))
    client.session = session
    return client


def _rms(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(e ** 2)))


@pytest.fixture(scope="module")
def refined(rs, tmp_path_factory):
    """A session on the right orthophoto, refined once while other requests are made: (client, answer, work,
    whether a state request was answered while the refinement ran)."""
    work = tmp_path_factory.mktemp("refine-ok")
    client = _client(rs, work)
    assert client.get("/api/calibration").json()["status"] == "ok"
    out: dict[str, object] = {}
    worker = threading.Thread(target=lambda: out.setdefault("r", client.post("/api/refine", json={})))
    worker.start()
    refiner = client.app.state.refiner
    deadline = time.monotonic() + 10
    while not refiner._running.locked() and worker.is_alive() and time.monotonic() < deadline:
        time.sleep(0.005)
    started = refiner._running.locked()
    state = client.get("/api/state")
    answered_meanwhile = started and worker.is_alive()  # answered before the refinement ended
    worker.join(60)
    r = out["r"]
    assert r.status_code == 200, r.text
    assert state.status_code == 200
    return client, r.json(), work, answered_meanwhile


def test_refine_is_accepted_and_beats_the_rough_camera_at_the_truth(refined, rs):
    client, ans, work, _ = refined
    sc = rs.scene
    assert ans["accepted"] is True, ans["reason"]
    assert "orthophoto matches" in ans["reason"]
    assert ans["n_kept"] > 30 and len(ans["matches"]) == ans["n_matches"] >= ans["n_kept"]
    assert sum(m["kept"] for m in ans["matches"]) == ans["n_kept"]
    assert ans["after"]["rmse_px"] < ans["before"]["rmse_px"]  # the verdict's statistic
    assert {p["id"] for p in ans["before"]["points"]} == set(sc.gcps.ids)
    assert ans["passes"] and ans["passes"][-1]["kept"] == ans["n_kept"]
    assert ans["surface"].startswith("DEM") and ans["frame"].startswith("the session's frame")
    # The matches sit on the frame: found pixels inside it, predicted pixels near them, scores above the threshold.
    uv = np.array([[m["u"], m["v"]] for m in ans["matches"]])
    pred = np.array([[m["u_predicted"], m["v_predicted"]] for m in ans["matches"]])
    w, h = IMAGE_SIZE
    assert np.all((uv >= -0.5) & (uv <= [w - 0.5, h - 0.5]))
    assert np.all(np.linalg.norm(uv - pred, axis=1) < 60)
    assert min(m["ncc"] for m in ans["matches"]) >= 0.55
    # Saved: the refined camera is at least 2x closer to the truth on the ground than the rough one.
    r = client.post("/api/refine/save", json={})
    assert r.status_code == 200, r.text
    assert r.json() == {"path": "camera_refined.json", "report": "refine.json", "frame": "refine_frame.jpg",
                        "revision": ans["revision"]}
    refined = CalibratedCamera.read(work / "camera_refined.json")
    camera, verdict = refined.camera, refined.refinement
    rough = client.session.calibration_run()[1].calibration.camera
    e_rough = _rms(ground_errors_m(rough, sc.camera, sc.truth_points))
    e_refined = _rms(ground_errors_m(camera, sc.camera, sc.truth_points))
    assert e_refined * 2 <= e_rough, (e_refined, e_rough)
    assert verdict is not None and verdict.accepted is True and verdict.report == "refine.json"
    assert verdict.matches_kept == ans["n_kept"]
    report = json.loads((work / "refine.json").read_text())
    assert report["format"] == "trafficgeo-refine/1" and report["accepted"] is True
    assert report["frame"] == "refine_frame.jpg" and (work / "refine_frame.jpg").stat().st_size > 1000
    assert len(report["matches"]["rows"]) == ans["n_matches"]
    assert not [p.name for p in work.iterdir() if p.name.startswith(".")]  # no temporary files left
    # Another name in the working folder; names leaving it are refused.
    assert client.post("/api/refine/save", json={"name": "cam2.json"}).json()["path"] == "cam2.json"
    r = client.post("/api/refine/save", json={"name": "../x.json"})
    assert r.status_code == 400 and "leaves the working folder" in r.json()["detail"]


def test_the_server_answers_other_requests_while_refining(refined):
    client, _, _, answered_meanwhile = refined
    assert answered_meanwhile, "GET /api/state waited for the refinement to end"
    refiner = client.app.state.refiner
    with refiner._running:  # as while a refinement runs: a second one is refused at once
        r = client.post("/api/refine", json={})
    assert r.status_code == 409 and r.json()["detail"] == "a refinement is already running; wait for its answer"


def test_saving_needs_a_current_accepted_refinement(refined, rs, tmp_path):
    client, _, _, _ = refined
    p = client.session.pairs[0]
    client.patch(f"/api/pairs/{p.id}", json={"u": p.u + 1.0})
    r = client.post("/api/refine/save", json={})
    assert r.status_code == 409 and "changed since the refinement" in r.json()["detail"]
    fresh = _client(rs, tmp_path)
    r = fresh.post("/api/refine/save", json={})
    assert r.status_code == 409 and "press Refine from orthophoto first" in r.json()["detail"]


def test_a_wrong_orthophoto_is_refused_with_a_reason(rs, tmp_path):
    client = _client(rs, tmp_path, ortho="ortho_wrong.tif")
    r = client.post("/api/refine", json={})
    assert r.status_code == 200, r.text
    ans = r.json()
    assert ans["accepted"] is False
    assert "the orthophoto may show another place" in ans["reason"]
    r = client.post("/api/refine/save", json={})
    assert r.status_code == 409 and "refused" in r.json()["detail"]
    assert not (tmp_path / "camera_refined.json").exists()


def test_no_orthophoto_file_or_too_few_pairs_is_a_clear_error(rs, tmp_path):
    client = _client(rs, tmp_path)
    (tmp_path / "ortho.tif").unlink()
    r = client.post("/api/refine", json={})
    assert r.status_code == 409
    assert r.json()["detail"].startswith("no orthophoto file to refine with:") and "ortho.tif" in r.json()["detail"]
    for p in client.session.pairs[2:]:
        client.delete(f"/api/pairs/{p.id}")
    r = client.post("/api/refine", json={})
    assert r.status_code == 409 and r.json()["detail"].startswith("cannot refine yet:")
    assert "more control pair" in r.json()["detail"]
    # The body must be a JSON object (no plain form posts), with no unknown fields.
    assert client.post("/api/refine").status_code == 422
    assert client.post("/api/refine", json={"search_px": 5}).status_code == 422


def test_a_video_session_refines_on_the_scene_without_traffic(tmp_path):
    """Opened on a video, the still matched is the temporal mode around the frame's time: the cars are gone; a
    video that cannot give one falls back to the frame, saying why."""
    from trafficgeo.ui.inputs import FrameImage, load_video_frame
    from trafficgeo.ui.refine import still_frame
    from video_support import write_two_car_video

    video = write_two_car_video(tmp_path / "clip.mp4", 10, 4.0, rows=(40, 120), seed=1)
    frame = load_video_frame(video, 1.0)
    assert frame.video == video and frame.time_s == pytest.approx(1.0)
    still, note = still_frame(frame)
    assert note.startswith("the scene without traffic: temporal mode of 25 frames of clip.mp4")
    assert still.shape == frame.image.shape
    car = (slice(44, 56), slice(55, 85))  # the red car at 1 s (x 50-90, rows 40-60), inside its edges
    assert np.abs(frame.image[car].astype(float) - [40, 40, 200]).max() < 30
    assert np.abs(np.median(still[car].reshape(-1, 3), axis=0) - 110).max() < 10  # the road under it
    moved = FrameImage.from_array(frame.image, "gone.mp4 at 1 s", video=tmp_path / "gone.mp4", time_s=1.0)
    same, note = still_frame(moved)
    assert same is moved.image and note.startswith("the session's frame (no still without traffic from gone.mp4")


def test_without_dem_or_cloud_it_refines_on_the_plane_through_the_gcps(rs, tmp_path):
    client = _client(rs, tmp_path, dem=False)
    r = client.post("/api/refine", json={})
    assert r.status_code == 200, r.text
    ans = r.json()
    assert ans["surface"] == "no --dem or --cloud: the plane through the 8 control GCPs"
    assert ans["n_matches"] > 30 and ans["reason"]
