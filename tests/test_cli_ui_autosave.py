"""gcp-ui with a damaged autosave: exit 2 with one line naming the file and saying to move it aside; once moved
aside, it starts (from the --gcps file when there is one)."""

from __future__ import annotations

import os
import shutil

import pytest

from cli_support import invoke
from trafficgeo.cli import ui as cli_ui
from ui_support import shared_scene


@pytest.fixture()
def served(monkeypatch):
    calls = []
    monkeypatch.setattr(cli_ui, "serve", lambda server, sock: calls.append(server))
    return calls


DAMAGED = {
    "truncated": b"id,x,y,z,u,v,role,sigma_px\nP1,245000.5,5182600.5,90.1,100.5,2",
    "binary": bytes(range(256)) * 3,
    "duplicate ids": b"id,x,y,z,u,v,role,sigma_px\nP1,245000.5,5182600.5,90.1,100.5,200,control,1\n"
                     b"P1,245001.5,5182601.5,90.1,110.5,210,control,1\n",
}


@pytest.mark.slow
@pytest.mark.parametrize("kind", list(DAMAGED))
@pytest.mark.parametrize("with_gcps", [False, True])
def test_a_damaged_autosave_says_to_move_it_aside(tmp_path_factory, tmp_path, served, kind, with_gcps):
    scene = shared_scene(tmp_path_factory)
    gcps = tmp_path / "gcps.csv"
    if with_gcps:
        gcps.write_text("id,x,y,z,u,v\nA,245000.5,5182600.5,90.1,100.5,200\n")
        os.utime(gcps, (1_600_000_000, 1_600_000_000))  # older than the autosave: the autosave is what is loaded
    autosave = tmp_path / "gcps.autosave.csv"
    autosave.write_bytes(DAMAGED[kind])
    argv = ["gcp-ui", "--frame", str(scene.frame), "--ortho", str(scene.ortho), "--gcps", str(gcps), "--port", "0"]
    code, out, err = invoke(*argv)
    assert code == 2 and not served, (code, out, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("trafficgeo: error: the autosave ") and "Traceback" not in err
    assert str(autosave) in lines[0] and "move it aside" in lines[0]
    assert ("continue from " + str(gcps) if with_gcps else "start with no GCPs") in lines[0]
    assert autosave.read_bytes() == DAMAGED[kind]  # left as it was
    # Moved aside as told: it starts, from the --gcps file when there is one.
    shutil.move(autosave, tmp_path / "moved.csv")
    code, out, err = invoke(*argv)
    assert code == 0 and len(served) == 1, (code, out, err)
    said = "continuing with 1 GCP(s) from " + str(gcps) if with_gcps else "no GCPs yet"
    assert "".join(said.split()) in "".join(out.split())  # the terminal may wrap the line
