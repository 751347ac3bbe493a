"""`process --gates` and `stitch --gates` on a small rendered junction world (the background detector: fast, and the
plumbing is what is tested here; the movements' accuracy is tests/test_junction_movements.py and
benchmarks/bench_junction.py), and `demo --junction`."""

from __future__ import annotations

import json
from dataclasses import asdict

import pytest

from cli_support import invoke
from trafficgeo.run.folder import MOVEMENT_COUNTS, MOVEMENTS, RunFolder
from trafficgeo.synth.junction_sumo import JunctionOptions
from trafficgeo.synth.junction_world import build_junction_world
from trafficgeo.video.track import TrackerOptions

pytest.importorskip("sumolib")
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    out = tmp_path_factory.mktemp("junction_video")
    build_junction_world(out, JunctionOptions(seed=12, duration_s=8.0, image_size=(640, 360), ortho_resolution=0.2,
                                              veh_per_hour_per_arm=900.0))
    return out


def _junction_outputs(run) -> dict:
    folder = RunFolder(run)
    moves, counts = folder.movements(), folder.movement_counts()
    assert list(moves.columns) == MOVEMENTS.names and list(counts.columns) == MOVEMENT_COUNTS.names
    table = folder.turning_movements()
    assert {"N_left", "E_through", "S_right", "W_U", "total", "heavy", "heavy_pct"} <= set(table.columns)
    junction = json.loads((run / "summary.json").read_text())["junction"]
    assert sorted(junction["arms"]) == ["E", "N", "S", "W"]
    assert junction["complete"] + junction["incomplete"] == len(moves) == junction["vehicles"]
    assert counts["count"].sum() == junction["complete"] == int(moves["complete"].sum())
    assert "movements.csv" in json.loads((run / "run.json").read_text())["files"]
    return junction


def test_process_and_stitch_with_gates_write_the_movements(world, tmp_path) -> None:
    common = ("--camera", world / "camera_truth.json", "--surface", world / "dem.tif", "--gates", world / "gates.gpkg",
              "--detector", "background")
    code, out, err = invoke("process", world / "video.mp4", *common, "-o", tmp_path / "run")
    assert code == 0, err
    assert "turning movements" in out
    _junction_outputs(tmp_path / "run")
    tracker = json.loads((tmp_path / "run" / "process.json").read_text())["options"]["tracker"]
    assert tracker == asdict(TrackerOptions())  # the background detector's tracker, at a junction too
    for k, (start, end) in enumerate(((0.0, 5.0), (3.0, 8.0))):
        code, _, err = invoke("process", world / "video.mp4", *common, "--start", start, "--end", end, "-o",
                              tmp_path / f"chunk{k}")
        assert code == 0, err
    code, out, err = invoke("stitch", tmp_path / "chunk0", tmp_path / "chunk1", "--camera",
                            world / "camera_truth.json", "--surface", world / "dem.tif", "--gates",
                            world / "gates.gpkg", "-o", tmp_path / "stitched")
    assert code == 0, err
    _junction_outputs(tmp_path / "stitched")
    # a run without gates afterwards in the same folder leaves no movement tables behind
    code, _, err = invoke("process", world / "video.mp4", *common[:4], "--detector", "background", "-o",
                          tmp_path / "run")
    assert code == 0, err
    assert not (tmp_path / "run" / "movements.csv").exists()
    assert not (tmp_path / "run" / "turning_movements.csv").exists()
    assert "junction" not in json.loads((tmp_path / "run" / "summary.json").read_text())


def test_demo_junction_quick(tmp_path) -> None:
    code, out, err = invoke("demo", "--junction", "--quick", "--duration", 6, "--out", tmp_path / "demo")
    assert code == 0, err
    assert "Junction demo: turning movements measured vs truth" in " ".join(out.split())
    html = (tmp_path / "demo" / "report.html").read_text(encoding="utf-8")
    assert "Turning-movement diagram" in html
    assert (tmp_path / "demo" / "traffic" / "movements.csv").is_file()


class _Settled(Exception):
    """Raised by the spy below once process_video has settled its options."""


def test_process_with_gates_tracks_with_the_junction_tracker(world, tmp_path, monkeypatch) -> None:
    """A site with gates settles on the junction tracker (video.pipeline.JUNCTION_TRACKER), one without on the
    road's."""
    import trafficgeo.video.pipeline as vp
    from trafficgeo.pipeline.run import process_video
    from trafficgeo.site.site import Site

    asked = []

    def spy(options, fps, *, junction=False):
        asked.append(junction)
        raise _Settled

    monkeypatch.setattr(vp, "settled_options", spy)
    for k, gates in enumerate((world / "gates.gpkg", None)):
        site = Site.load(world / "camera_truth.json", world / "dem.tif", gates=gates)
        with pytest.raises(_Settled):
            process_video(world / "video.mp4", site, tmp_path / f"run{k}")
    assert asked == [True, False]
