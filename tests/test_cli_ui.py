"""The gcp-ui command: bad input exits with code 2 and one line; good input serves the app (serving replaced)."""

from __future__ import annotations

import socket
import warnings
from pathlib import Path

import av
import cv2
import numpy as np
import pytest

from cli_support import invoke
from trafficgeo.cli import ui as cli_ui
from trafficgeo.geo.raster import write_geotiff
from ui_support import Scene, shared_scene

with warnings.catch_warnings():
    warnings.simplefilter("ignore")  # starlette's deprecation note about httpx
    from fastapi.testclient import TestClient


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Scene:
    return shared_scene(tmp_path_factory)


@pytest.fixture(scope="module")
def video(tmp_path_factory) -> Path:
    """A 1 s, 10 fps, 64x48 H.264 video."""
    path = tmp_path_factory.mktemp("video") / "clip.mp4"
    with av.open(str(path), "w") as c:
        s = c.add_stream("libx264", rate=10)
        s.width, s.height, s.pix_fmt = 64, 48, "yuv420p"
        for k in range(10):
            img = np.full((48, 64, 3), 20 * k, np.uint8)
            for packet in s.encode(av.VideoFrame.from_ndarray(img, format="bgr24")):
                c.mux(packet)
        for packet in s.encode():
            c.mux(packet)
    return path


@pytest.fixture()
def served(monkeypatch):
    """Replace the blocking serve() by one that records what would be served."""
    calls = []
    monkeypatch.setattr(cli_ui, "serve", lambda server, sock: calls.append((server, sock.getsockname())))
    return calls


def _one_line_error(code: int, out: str, err: str) -> str:
    assert code == 2, (code, out, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("trafficgeo: error: "), err
    assert "Traceback" not in err + out
    return lines[0]


@pytest.mark.slow
def test_serves_the_session_and_prints_the_address(scene, tmp_path, served):
    gcps = tmp_path / "gcps.csv"
    code, out, err = invoke("gcp-ui", "--frame", scene.frame, "--ortho", scene.ortho, "--dem", scene.dem,
                            "--gcps", gcps, "--port", 0)
    assert code == 0, err
    assert len(served) == 1
    server, (host, port) = served[0]
    assert host == "127.0.0.1" and port > 0
    assert f"open http://127.0.0.1:{port}/ in a browser" in out
    assert "autosave" in out and "gcps.autosave.csv" in out
    with TestClient(server.config.app, base_url=f"http://127.0.0.1:{port}") as c:
        info = c.get("/api/info").json()
        assert info["frame"]["width"] == 800 and info["ground"]["kind"] == "dem"
        assert c.get("/", headers={"host": "evil.example"}).status_code == 400  # loopback: Host is checked


@pytest.mark.slow
def test_frame_from_a_video(scene, video, tmp_path, served):
    code, out, err = invoke("gcp-ui", "--video", video, "--at", 0.55, "--ortho", scene.ortho, "--port", 0,
                            "--workdir", tmp_path)
    assert code == 0, err
    assert "at 0.500 s (frame 5)" in out and "type the Z" in out
    session = served[0][0].config.app.state.session
    assert session.frame.size == (64, 48) and abs(float(session.frame.image.mean()) - 100) < 6


def test_continues_an_existing_gcp_file(scene, tmp_path, served):
    gcps = tmp_path / "gcps.csv"
    gcps.write_text("id,x,y,z,u,v,role\n"
                    f"A,{scene.truth_world[0, 0]},{scene.truth_world[0, 1]},90,{scene.truth_pixels[0, 0]},"
                    f"{scene.truth_pixels[0, 1]},check\n")
    code, out, err = invoke("gcp-ui", "--frame", scene.frame, "--ortho", scene.ortho, "--gcps", gcps, "--port", 0)
    assert code == 0, err
    assert "continuing with 1 GCP(s)" in out
    pairs = served[0][0].config.app.state.session.pairs
    assert [(p.id, p.role) for p in pairs] == [("A", "check")]


@pytest.fixture()
def bad_files(tmp_path, scene):
    (tmp_path / "notimage.png").write_text("this is not a PNG")
    cv2.imwrite(str(tmp_path / "plain.png"), np.zeros((8, 8, 3), np.uint8))
    (tmp_path / "bad.csv").write_text("id,x,y,z,u,v\nA,1,2,3,four,5\n")
    from affine import Affine

    write_geotiff(tmp_path / "dem_other_crs.tif", np.full((4, 4), 90.0), Affine(1, 0, 500000, 0, -1, 5000000),
                  "EPSG:32633")
    return tmp_path


@pytest.mark.parametrize("args, words", [
    (["--ortho", "{ortho}"], "with --frame (an image) or --video (with --at seconds)"),
    (["--frame", "{frame}", "--video", "{video}", "--ortho", "{ortho}"], "not both"),
    (["--frame", "{tmp}/missing.png", "--ortho", "{ortho}"], "does not exist"),
    (["--frame", "{tmp}/notimage.png", "--ortho", "{ortho}"], "not an image"),
    (["--frame", "{tmp}", "--ortho", "{ortho}"], "is a folder"),
    (["--frame", "{frame}", "--ortho", "{tmp}/plain.png"], "no georeferencing"),
    (["--frame", "{frame}", "--ortho", "{tmp}/notimage.png"], "not a raster"),
    (["--frame", "{frame}", "--ortho", "{tmp}/missing.tif"], "does not exist"),
    (["--video", "{video}", "--at", "5", "--ortho", "{ortho}"], "beyond its end"),
    (["--video", "{video}", "--at", "-1", "--ortho", "{ortho}"], ">= 0"),
    (["--video", "{frame}", "--ortho", "{ortho}"], "not a video"),
    (["--frame", "{frame}", "--at", "1", "--ortho", "{ortho}"], "--at"),
    (["--frame", "{frame}", "--ortho", "{ortho}", "--dem", "{dem}", "--cloud", "{tmp}/c.laz"], "not both"),
    (["--frame", "{frame}", "--ortho", "{ortho}", "--dem", "{tmp}/dem_other_crs.tif"], "differs from the orthophoto"),
    (["--frame", "{frame}", "--ortho", "{ortho}", "--cloud", "{tmp}/notimage.png"], "LAS/LAZ"),
    (["--frame", "{frame}", "--ortho", "{ortho}", "--gcps", "{tmp}/bad.csv"], "bad.csv line 2"),
    (["--frame", "{frame}", "--ortho", "{ortho}", "--gcps", "{tmp}/nofolder/g.csv"], "does not exist"),
    (["--frame", "{frame}", "--ortho", "{ortho}", "--gcps", "{tmp}/g.txt"], ".csv"),
    (["--frame", "{frame}", "--ortho", "{ortho}", "--port", "70000"], "not a TCP port"),
    (["--frame", "{frame}", "--ortho", "{ortho}", "--host", "no.such.host.invalid"], "not a known address"),
    (["--frame", "{frame}", "--ortho", "{ortho}", "--focal-px", "-5"], "focal length"),
])
def test_bad_input_exits_2_with_one_line(scene, video, bad_files, served, args, words):
    names = {"frame": scene.frame, "ortho": scene.ortho, "dem": scene.dem, "video": video, "tmp": bad_files}
    argv = ["gcp-ui", *[a.format(**names) for a in args]]
    if "--port" not in argv:
        argv += ["--port", "0"]
    line = _one_line_error(*invoke(*argv))
    assert words in line, line
    assert not served


def test_port_in_use(scene, served):
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen(1)
        port = busy.getsockname()[1]
        line = _one_line_error(*invoke("gcp-ui", "--frame", scene.frame, "--ortho", scene.ortho, "--port", port))
    assert f"port {port} on 127.0.0.1 is in use" in line and "--port" in line
    assert not served
