"""A truncated or damaged video: read as far as it decodes, with one warning saying where it stopped; ``process``
says what it read (terminal and process.json) and fails with --strict."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from cli_support import invoke
from trafficgeo.video.reader import VideoReadWarning, iter_frames, video_info
from video_support import H, W, write_two_car_video

FPS, SECONDS = 10, 8.0


@pytest.fixture(scope="module")
def videos(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A whole MP4 (index first, as cameras and streaming copies write it), the same cut to half its bytes, and
    the same with garbage written over 20 kB in the middle."""
    d = tmp_path_factory.mktemp("truncated")
    whole = write_two_car_video(d / "whole.mp4", FPS, SECONDS, rows=(100, 140), seed=3, faststart=True)
    data = whole.read_bytes()
    cut = d / "cut.mp4"
    cut.write_bytes(data[: len(data) // 2])
    damaged = bytearray(data)
    damaged[len(data) // 2: len(data) // 2 + 20000] = np.random.default_rng(1).integers(0, 255, 20000,
                                                                                           dtype=np.uint8).tobytes()
    (d / "damaged.mp4").write_bytes(bytes(damaged))
    return {"whole": whole, "cut": cut, "damaged": d / "damaged.mp4"}


def _read(path: Path, **kw: object) -> tuple[list[float], list[str]]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        times = [f.time_s for f in iter_frames(path, **kw)]
    return times, [str(w.message) for w in caught if issubclass(w.category, VideoReadWarning)]


@pytest.mark.slow
def test_a_whole_video_reads_without_warning(videos: dict[str, Path]) -> None:
    times, said = _read(videos["whole"])
    assert len(times) == FPS * SECONDS and said == []
    assert _read(videos["whole"], start_s=2.0, end_s=3.0) == ([2.0 + k / FPS for k in range(10)], [])


@pytest.mark.parametrize("name", ["cut", "damaged"])
def test_a_cut_or_damaged_video_is_read_up_to_the_damage_with_one_warning(videos: dict[str, Path],
                                                                           name: str) -> None:
    info = video_info(videos[name])  # the container still says 8 s
    assert info.duration_s == pytest.approx(SECONDS, abs=0.2)
    times, said = _read(videos[name])
    assert 1.0 < times[-1] < SECONDS - 1.0, times[-1]
    assert len(said) == 1 and "\n" not in said[0] and str(videos[name]) in said[0]
    assert f"frames end at {times[-1] + 1 / FPS:.2f} s" in said[0] and "8.00 s was expected" in said[0]
    if name == "damaged":
        assert "damaged data" in said[0]
    # A range that ends before the damage is read in full, without a warning.
    assert _read(videos[name], end_s=1.0) == ([k / FPS for k in range(10)], [])


@pytest.mark.slow
def test_process_says_what_it_read(videos: dict[str, Path], tmp_path: Path) -> None:
    from trafficgeo.camera.io import write_camera_json
    from trafficgeo.camera.model import Camera

    cam = Camera.from_orientation((W, H), 300.0, [500000.0, 5000000.0, 8.0], 0.0, 30.0, crs="EPSG:32633")
    write_camera_json(tmp_path / "camera.json", cam)
    cut_s = _read(videos["cut"])[0][-1] + 1 / FPS
    args = ["--camera", tmp_path / "camera.json", "--surface", "0", "--start", 0, "--end", 7, "--detector",
            "background"]  # the video's two coloured rectangles are no vehicles to a learned detector
    code, stdout, stderr = invoke("process", videos["cut"], *args, "--out", tmp_path / "cut")
    assert code == 0, stderr
    warning = [line for line in stdout.splitlines() if line.startswith("warning: read")]
    assert len(warning) == 1, stdout
    assert f"read 0.00-{cut_s:.2f} s" in warning[0] and "of the asked 0-7.00 s" in warning[0]
    doc = json.loads((tmp_path / "cut" / "process.json").read_text())
    assert doc["options"]["end_s"] == 7
    assert doc["read"]["end_s"] == pytest.approx(cut_s) and doc["read"]["complete"] is False
    assert doc["read"]["frames"] == round(cut_s * FPS)
    # --strict: the same outputs, exit 1
    code, stdout, _ = invoke("process", videos["cut"], *args, "--out", tmp_path / "strict", "--strict")
    assert code == 1 and "warning: read" in stdout and (tmp_path / "strict" / "process.json").is_file()
    # A whole video: no warning, the range read is the one asked.
    code, stdout, stderr = invoke("process", videos["whole"], *args, "--out", tmp_path / "whole", "--strict")
    assert code == 0 and "warning" not in stdout, stderr
    doc = json.loads((tmp_path / "whole" / "process.json").read_text())
    assert doc["read"] == {"start_s": 0.0, "end_s": pytest.approx(7.0), "frames": 70, "complete": True}


def test_a_resume_after_detection_finished_still_says_what_was_read(videos: dict[str, Path], tmp_path: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """Issue 43: a run that stopped after its detection had finished (here: the analysis fails) resumed without
    decoding a frame and forgot what the first attempt read: process.json said nothing was read, the truncated
    video's warning was gone and --strict exited 0."""
    import trafficgeo.pipeline.run as run_module
    from trafficgeo.camera.io import write_camera_json
    from trafficgeo.camera.model import Camera
    from trafficgeo.video.checkpoint import CHECKPOINT_DIR

    cam = Camera.from_orientation((W, H), 300.0, [500000.0, 5000000.0, 8.0], 0.0, 30.0, crs="EPSG:32633")
    write_camera_json(tmp_path / "camera.json", cam)
    args = ["process", videos["cut"], "--camera", tmp_path / "camera.json", "--surface", "0", "--start", 0, "--end",
            7, "--detector", "background", "--out", tmp_path / "run"]
    code, whole_out, _ = invoke(*args[:-1], tmp_path / "whole")
    assert code == 0
    first = json.loads((tmp_path / "whole" / "process.json").read_text())["read"]

    def stop(*_a, **_k):
        raise KeyboardInterrupt  # as Ctrl-C in the analysis: the checkpoint stays, detection complete

    with monkeypatch.context() as m:
        m.setattr(run_module, "analyze", stop)
        assert invoke(*args)[0] != 0
    assert (tmp_path / "run" / CHECKPOINT_DIR).is_dir()
    code, stdout, _ = invoke(*args, "--strict")
    assert "had finished" in stdout  # nothing decoded this time
    assert code == 1 and [ln for ln in stdout.splitlines() if ln.startswith("warning: read")] == \
        [ln for ln in whole_out.splitlines() if ln.startswith("warning: read")]
    assert json.loads((tmp_path / "run" / "process.json").read_text())["read"] == first
    assert first["complete"] is False and first["frames"] > 0
