"""The learned detector's runtime choice (trafficgeo.video.detectors.backends): a timed probe over fake backends, its
cache (written, reused, keyed, damaged), the fallback when OpenVINO is absent, and the cost printed before a run
(trafficgeo.video.cost) and recorded in process.json."""

from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from labelled_frames import INTEL_LABELS, load_labels
from trafficgeo.errors import InputError
from trafficgeo.video.cost import estimate_cost, plan_passes
from trafficgeo.video.detections import box_iou
from trafficgeo.video.detectors.backends import BackendChoice, cache_dir, choose_backend, probe
from trafficgeo.video.detectors.backends import int8_saturation as real_int8_saturation
from trafficgeo.video.detectors.builtin import builtin_model_path
from trafficgeo.video.detectors.learned import detector_backend
from trafficgeo.video.detectors.tiling import grid_plan

FEEDS = {"input": np.zeros((1, 3, 8, 8), dtype=np.float32)}
REFERENCE = [np.linspace(0.0, 1.0, 12, dtype=np.float32).reshape(1, 3, 4), np.full((1, 2), 7.0, dtype=np.float32)]


class Fake:
    """A backend taking ``ms`` per run and returning ``REFERENCE`` + ``offset``; counts its runs."""

    def __init__(self, name: str, ms: float, offset: float = 0.0) -> None:
        self.name, self.ms, self.offset, self.runs = name, ms, offset, 0

    def run(self, feeds):
        self.runs += 1
        time.sleep(self.ms / 1e3)
        return [a + self.offset for a in REFERENCE]


def _candidates(built: dict[str, Fake], specs: dict[str, tuple[float, float]]):
    def maker(name: str, ms: float, offset: float):
        def make() -> Fake:
            built[name] = Fake(name, ms, offset)
            return built[name]
        return make
    return {name: maker(name, ms, off) for name, (ms, off) in specs.items()}


def test_the_probe_picks_the_fastest_that_agrees_and_refuses_one_that_does_not() -> None:
    built: dict[str, Fake] = {}
    choice, backends = probe(_candidates(built, {"onnxruntime": (12.0, 0.0), "fast": (3.0, 0.005),
                                                 "wrong": (1.0, 0.5)}), FEEDS, (8, 8))
    assert choice.backend == "fast" and set(backends) == {"onnxruntime", "fast"}
    assert "differs by up to 0.5" in choice.refused["wrong"]
    # times: medians of sleeps of 12 / 3 / 1 ms (sleep overshoots; 2 ms of slack each way is ample)
    assert choice.times_ms["onnxruntime"] > choice.times_ms["fast"] + 5
    assert choice.ms_per_pass == choice.times_ms["fast"]
    assert "refused" in choice.summary() and choice.summary().startswith("backend: fast")
    # an agreeing but slower candidate is not chosen
    choice, _ = probe(_candidates({}, {"onnxruntime": (2.0, 0.0), "slow": (12.0, 0.0)}), FEEDS, (8, 8))
    assert choice.backend == "onnxruntime" and not choice.refused


def test_an_int8_version_is_held_to_a_wider_bound_that_still_catches_a_broken_one() -> None:
    # the reference's first output reaches 1: the INT8 bound there is 0.05 + 0.25 x 1, the float one 0.02 + 0.02 x 1
    specs = {"onnxruntime": (8.0, 0.0), "onnxruntime-int8": (2.0, 0.2), "openvino-int8": (1.0, 5.0),
             "openvino": (1.0, 0.2)}
    choice, backends = probe(_candidates({}, specs), FEEDS, (8, 8))
    assert choice.backend == "onnxruntime-int8" and set(backends) == {"onnxruntime", "onnxruntime-int8"}
    assert "tolerance 0.3)" in choice.refused["openvino-int8"] and "tolerance 0.04)" in choice.refused["openvino"]


def test_a_candidate_that_fails_to_build_is_refused_with_its_reason() -> None:
    def broken():
        raise RuntimeError("no such device")

    cands = {**_candidates({}, {"onnxruntime": (1.0, 0.0)}), "gpu": broken}
    choice, _ = probe(cands, FEEDS, (8, 8))
    assert choice.backend == "onnxruntime" and choice.refused == {"gpu": "no such device"}


def test_the_choice_is_cached_reused_keyed_and_a_damaged_cache_is_probed_again(tmp_path: Path,
                                                                               monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TRAFFICGEO_CACHE_DIR", str(tmp_path / "cache"))
    assert cache_dir() == tmp_path / "cache"
    specs = {"onnxruntime": (6.0, 0.0), "fast": (1.0, 0.0)}
    built: dict[str, Fake] = {}
    choice, backend = choose_backend(_candidates(built, specs), FEEDS, model_sha256="a" * 64, threads=2,
                                     input_hw=(8, 8))
    assert choice.backend == "fast" and not choice.cached and backend is built["fast"]
    files = list((tmp_path / "cache").glob("*.json"))
    assert len(files) == 1 and json.loads(files[0].read_text())["choice"]["backend"] == "fast"
    # again: from the cache, no probe (the reference is not even built, the chosen one not run)
    built = {}
    choice, backend = choose_backend(_candidates(built, specs), FEEDS, model_sha256="a" * 64, threads=2,
                                     input_hw=(8, 8))
    assert choice.cached and choice.backend == "fast" and set(built) == {"fast"} and built["fast"].runs == 0
    # another model: probed again, a second file
    built = {}
    choice, _ = choose_backend(_candidates(built, specs), FEEDS, model_sha256="b" * 64, threads=2, input_hw=(8, 8))
    assert not choice.cached and built["onnxruntime"].runs > 0
    assert len(list((tmp_path / "cache").glob("*.json"))) == 2
    # other threads: another key too
    choice, _ = choose_backend(_candidates({}, specs), FEEDS, model_sha256="a" * 64, threads=1, input_hw=(8, 8))
    assert not choice.cached
    # a damaged file: ignored, probed again and rewritten
    files[0].write_text('{"key": {"model_sha', encoding="utf-8")
    built = {}
    choice, _ = choose_backend(_candidates(built, specs), FEEDS, model_sha256="a" * 64, threads=2, input_hw=(8, 8))
    assert not choice.cached and built["onnxruntime"].runs > 0
    assert json.loads(files[0].read_text())["choice"]["backend"] == "fast"
    files[0].write_text('{"key": 3, "choice": []}', encoding="utf-8")  # valid JSON, wrong shape
    assert not choose_backend(_candidates({}, specs), FEEDS, model_sha256="a" * 64, threads=2,
                              input_hw=(8, 8))[0].cached


@pytest.fixture
def no_openvino(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """As if the OpenVINO runtime were not installed (``import openvino`` raises ImportError)."""
    monkeypatch.setitem(sys.modules, "openvino", None)
    monkeypatch.setenv("TRAFFICGEO_CACHE_DIR", str(tmp_path / "cache"))


def test_asking_for_openvino_without_it_is_a_one_line_error_naming_backend(no_openvino, tmp_path: Path) -> None:
    from cli_support import invoke
    from trafficgeo.video.detectors.onnx import OnnxDetector
    from trafficgeo.video.pipeline import ProcessOptions

    for make in (lambda: ProcessOptions(backend="openvino"),
                 lambda: OnnxDetector(builtin_model_path("nanodet"), format="nanodet", backend="openvino")):
        with pytest.raises(InputError) as caught:
            make()
        assert "\n" not in str(caught.value) and "pip install trafficgeo[openvino]" in str(caught.value)
        assert caught.value.parameters == ("backend",) and str(caught.value).startswith("backend openvino")
    with pytest.raises(InputError, match="backend 'tpu': use one of auto, onnxruntime, onnxruntime-int8, openvino"):
        ProcessOptions(backend="tpu")
    ProcessOptions(detector="background", backend="openvino")  # background subtraction runs no network
    out = tmp_path / "out"
    code, _, stderr = invoke("process", tmp_path / "v.mp4", "--camera", tmp_path / "c.json", "--surface", "0",
                             "--out", out, "--backend", "openvino")
    assert code == 2 and "--backend openvino: the OpenVINO runtime is not installed" in stderr, stderr
    assert not out.exists()


def test_auto_without_openvino_falls_back_to_onnxruntime(no_openvino) -> None:
    from trafficgeo.video.detectors.onnx import OnnxDetector

    path = builtin_model_path("nanodet")
    auto = OnnxDetector(path, format="nanodet", backend="auto", threads=1)
    assert auto.backend_choice.backend == "onnxruntime" and auto.backend_choice.ms_per_pass > 0
    assert auto.backend_choice.probe_input_hw == (416, 416) and not auto.backend_choice.cached
    plain = OnnxDetector(path, format="nanodet", threads=1)
    assert plain.backend_choice is None
    image = np.random.default_rng(1).integers(0, 256, (240, 320, 3), dtype=np.uint8)
    a, b = auto.detect(image), plain.detect(image)
    np.testing.assert_allclose(a.boxes, b.boxes, atol=1e-4)
    assert OnnxDetector(path, format="nanodet", backend="auto", threads=1).backend_choice.cached


@pytest.mark.parametrize("vnni", [True, False])
def test_the_builtin_model_offers_its_int8_version_to_the_probe(no_openvino, monkeypatch: pytest.MonkeyPatch,
                                                                vnni: bool) -> None:
    """Where the CPU has VNNI the probe times the INT8 version; where it has not (8-bit dot products saturate:
    backends.int8_saturation) the probe refuses it with that reason. Both CPUs are simulated by their flags."""
    from trafficgeo.video.detectors import backends
    from trafficgeo.video.detectors.learned import make_learned_detector
    from trafficgeo.video.detectors.onnx import OnnxDetector

    this_cpu_saturates = real_int8_saturation() is not None  # before the flags are simulated
    flags = frozenset({"sse2", "avx2", "fma"} | ({"avx512_vnni"} if vnni else set()))
    monkeypatch.setattr(backends, "cpu_flags", lambda: flags)
    monkeypatch.setattr(backends, "cpu_signature", lambda: f"simulated [{' '.join(sorted(flags))}]")  # cache key
    choice = detector_backend(make_learned_detector(backend="auto", threads=1))
    if vnni:
        assert set(choice.times_ms) == {"onnxruntime", "onnxruntime-int8"} and not choice.refused
    else:
        assert set(choice.times_ms) == {"onnxruntime"} and choice.backend == "onnxruntime"
        assert "no VNNI" in choice.refused["onnxruntime-int8"]
    int8 = make_learned_detector(backend="onnxruntime-int8", threads=1)  # asked for by name: runs on any CPU
    assert detector_backend(int8).backend == "onnxruntime-int8" and set(detector_backend(int8).times_ms) == {
        "onnxruntime-int8"}
    if vnni and not this_cpu_saturates:
        # on a VNNI CPU the INT8 version finds the same vehicles on a real frame (two cars of the Intel clip)
        frame = next(iter(load_labels(INTEL_LABELS).values())).image
        f32 = make_learned_detector(backend="onnxruntime", threads=1).detect(frame, 0.0)
        q = int8.detect(frame, 0.0)
        assert len(f32.boxes) == len(q.boxes) > 0
        assert np.all(np.max(box_iou(f32.boxes[:, None], q.boxes[None]), axis=1) > 0.8)
    with pytest.raises(InputError, match="has no INT8 version") as caught:
        OnnxDetector(builtin_model_path("nanodet"), format="nanodet", backend="onnxruntime-int8")
    assert caught.value.parameters == ("backend",)
    with pytest.raises(InputError, match="INT8 model not found"):
        OnnxDetector(builtin_model_path("nanodet"), format="nanodet", int8_model="no-such.onnx")


def test_the_cost_line_has_the_right_arithmetic() -> None:
    choice = BackendChoice("openvino", 41.0, {"openvino": 41.0, "onnxruntime": 80.0}, probe_input_hw=(416, 416))
    plan = grid_plan((1080, 1920), 2, input_size=416)  # 4 square tiles at the probe's input size
    assert plan_passes(plan, (416, 416)) == (5, 5.0)
    cost = estimate_cost(choice, plan, every=3, video_s=60.0, fps=30.0, decode_ms=4.0, track_ms=3.0)
    assert cost.detection_frames == 600 and cost.passes == 5
    assert math.isclose(cost.seconds, 600 * (5 * 41.0 + 4.0 + 3.0) / 1e3, rel_tol=1e-12)  # 127.2 s
    assert math.isclose(cost.realtime_factor, 60.0 / 127.2, rel_tol=1e-9)
    assert cost.summary() == ("detector: 5 passes per detection frame, every 3rd frame, 41 ms per pass (openvino) "
                              "-> about 2 min 7 s for 1 min of video (0.47x real time; 1 min 23 s to 3 min 24 s as "
                              "the machine's load goes, the progress bar follows the measured pace)")
    # no plan: one pass; every frame; a frame count that does not divide
    one = estimate_cost(choice, None, every=1, video_s=10.0, fps=25.0, decode_ms=0.0, track_ms=0.0)
    assert (one.passes, one.detection_frames) == (1, 250) and math.isclose(one.seconds, 250 * 0.041)
    assert "1 pass per detection frame, every frame" in one.summary()
    assert estimate_cost(choice, None, every=4, video_s=1.0, fps=30.0, decode_ms=0, track_ms=0).detection_frames == 8
    # a measured detection of 250 ms: 250 - 5 x 41 = 45 ms of work besides the network per detection frame
    full = estimate_cost(choice, plan, every=3, video_s=60.0, fps=30.0, decode_ms=4.0, track_ms=3.0, detect_ms=250.0)
    assert math.isclose(full.other_ms, 45.0) and math.isclose(full.seconds, 600 * (250.0 + 4.0 + 3.0) / 1e3)
    assert estimate_cost(choice, plan, every=3, video_s=60.0, fps=30.0, decode_ms=4.0, track_ms=3.0,
                         detect_ms=100.0).other_ms == 0.0  # faster than the probe: no negative allowance
    # ... and the run's own detection, 100 ms for 5 passes, is the time per pass: the probe (41 ms, timed once per
    # machine, maybe while it was busy) cannot be right when the whole detection took 20 ms a pass
    fast = estimate_cost(choice, plan, every=3, video_s=60.0, fps=30.0, decode_ms=4.0, track_ms=3.0, detect_ms=100.0)
    assert math.isclose(fast.ms_per_pass, 20.0) and fast.probe_ms_per_pass == 41.0
    assert math.isclose(fast.seconds, 600 * (100.0 + 4.0 + 3.0) / 1e3)
    assert full.ms_per_pass == 41.0  # slower than the probe: the probe's passes, the rest is other work


def test_a_tile_schedule_counts_each_tile_by_its_share_of_frames() -> None:
    choice = BackendChoice("onnxruntime", 80.0, {"onnxruntime": 80.0}, probe_input_hw=(416, 416))
    plan = grid_plan((1080, 1920), 2, input_size=416)
    share = np.array([1.0, 0.5, 0.25, 0.25])
    assert plan_passes(plan, (416, 416), share) == (5, 3.0)
    cost = estimate_cost(choice, plan, every=1, video_s=1.0, fps=10.0, decode_ms=0.0, track_ms=0.0,
                         detect_ms=500.0, tile_share=share)
    # the measured detection ran every tile: 500 - 5 x 80 = 100 ms besides the network, work per pass (crops,
    # letterboxing, decoding each pass's outputs), so the schedule's 3 of 5 passes run 60 ms of it
    assert math.isclose(cost.other_ms, 60.0) and math.isclose(cost.seconds, 10 * (3.0 * 80.0 + 60.0) / 1e3)
    assert cost.passes == 5 and cost.scheduled_passes == 3.0
    assert "5 passes per detection frame, about 3.0 with the tile schedule" in cost.summary()


def test_passes_at_other_input_sizes_count_by_input_pixels() -> None:
    from dataclasses import replace

    plan = grid_plan((1080, 1920), 2, input_size=416)
    banded = replace(plan, tile_input_hw=np.array([[208, 416]] * 4), full_input_hw=(256, 416))
    passes, units = plan_passes(banded, (416, 416))
    assert passes == 5 and math.isclose(units, (256 * 416 + 4 * 208 * 416) / 416**2)
    choice = BackendChoice("onnxruntime", 80.0, {"onnxruntime": 80.0}, probe_input_hw=(416, 416))
    cost = estimate_cost(choice, banded, every=1, video_s=1.0, fps=10.0, decode_ms=0.0, track_ms=0.0)
    assert math.isclose(cost.seconds, 10 * units * 0.080) and "probe-size passes" in cost.summary()


@pytest.mark.slow
@pytest.mark.parametrize("tile_schedule", ["auto", "sparse"])
def test_process_tells_and_records_the_backend_and_the_estimate(no_openvino, tmp_path: Path,
                                                               tile_schedule: str) -> None:
    from test_video_learned import FLAT, lanes_along_y
    from trafficgeo.camera.model import Camera
    from trafficgeo.pipeline.run import run_info
    from trafficgeo.video.pipeline import ProcessOptions, detect_and_track
    from video_support import write_two_car_video

    video = write_two_car_video(tmp_path / "v.mp4", 10, 1.0, rows=(60, 120), seed=2)
    cam = Camera.from_orientation((320, 180), 300.0, [13.0, 0.0, 8.0], 355.0, 4.0)
    opts = ProcessOptions(detector="nanodet", every=2, tile_schedule=tile_schedule)
    seen: dict = {}
    told: list[str] = []
    detect_and_track(video, cam, FLAT, tmp_path / "a", opts, lanes=lanes_along_y(), notice=told.append,
                     detector_info=seen.update)
    backend, estimate = seen["backend"], seen["estimate"]
    # onnxruntime on the float model or on its INT8 version, whichever was faster here
    assert backend["backend"] in ("onnxruntime", "onnxruntime-int8") and backend["ms_per_pass"] > 0
    passes = len(seen["tiling"]["tiles"]) + 1
    assert estimate["passes"] == passes and estimate["every"] == 2 and estimate["detection_frames"] == 5
    assert estimate["other_ms"] >= 0 and estimate["decode_ms"] > 0
    # the time per pass the estimate used: the probe's, or less where the run's own detection took less
    assert estimate["probe_ms_per_pass"] == backend["ms_per_pass"] >= estimate["ms_per_pass"] > 0
    per_frame = (estimate["pass_units"] * estimate["ms_per_pass"] + estimate["other_ms"] + estimate["decode_ms"]
                 + estimate["track_ms"])
    assert math.isclose(estimate["seconds"], 5 * per_frame / 1e3, rel_tol=1e-3)
    assert passes > 1
    chose = seen["tile_schedule"]
    # "auto": every tile where the estimate with every tile keeps real time, else the sparse schedule
    fast = chose["all_tiles_realtime_factor"] >= 1.0
    assert chose["asked"] == tile_schedule
    assert chose["used"] == ("all" if tile_schedule == "auto" and fast else "sparse"), chose
    if chose["used"] == "sparse":  # fewer passes expected, said, and what it did recorded
        assert 1.0 < estimate["scheduled_passes"] <= passes and estimate["pass_units"] <= passes
        assert any(line.startswith("tile schedule: each tile runs every") for line in told)
        assert seen["schedule"]["detection_frames"] == 5
    else:
        assert estimate["scheduled_passes"] is None and "schedule" not in seen
        assert math.isclose(estimate["realtime_factor"], chose["all_tiles_realtime_factor"], rel_tol=1e-3)
        assert any(line.startswith("tile schedule: every tile on every detection frame, as that keeps real time")
                   for line in told)
    assert any(line.startswith("backend: onnxruntime") for line in told)
    assert any(line.startswith(f"detector: {passes} passes per detection frame") and "every 2nd frame" in line
               for line in told)
    doc = run_info(video="v.mp4", camera="", options=opts, seconds=1.0, detections=0, track_rows=0,
                   detector=seen).to_dict()
    assert doc["options"]["backend"] == "auto"
    assert doc["detector"]["backend"]["backend"] == backend["backend"]
    assert doc["detector"]["estimate"]["passes"] == passes


@pytest.mark.slow
def test_the_openvino_runtime_agrees_with_onnxruntime(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip("openvino")
    from trafficgeo.video.detectors.backends import OpenVinoBackend
    from trafficgeo.video.detectors.onnx import OnnxDetector

    monkeypatch.setenv("TRAFFICGEO_CACHE_DIR", str(tmp_path))
    path = builtin_model_path("nanodet")
    ort = OnnxDetector(path, format="nanodet", threads=1)
    ov = OnnxDetector(path, format="nanodet", threads=1, backend="openvino")
    assert isinstance(ov._runner, OpenVinoBackend) and ov.backend_choice.backend == "openvino"
    image = np.random.default_rng(2).integers(0, 256, (416, 416, 3), dtype=np.uint8)
    blob, _g = ort.layout.pre.blob([image], ort.input_hw)
    feeds = ort._feeds(blob, (416, 416))
    for a, b in zip(ort._runner.run(feeds), ov._runner.run(feeds), strict=True):
        assert a.shape == b.shape
        assert np.max(np.abs(a - b)) <= 0.02 + 0.02 * np.max(np.abs(a))  # bf16 where the CPU has it


def test_a_fifo_in_the_cache_is_not_read(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Issue 43: a FIFO where the cached choice belongs hung process (reading it blocks until someone writes). Only
    a regular file is read; anything else is as no cache (the probe runs again)."""
    import os
    import threading

    from trafficgeo.video.detectors.backends import _cache_file, load_choice

    monkeypatch.setenv("TRAFFICGEO_CACHE_DIR", str(tmp_path))
    key = {"model": "x", "cpu": "y"}
    os.mkfifo(_cache_file(key))
    got: list[object] = []
    reader = threading.Thread(target=lambda: got.append(load_choice(key)), daemon=True)
    reader.start()
    reader.join(timeout=10)
    if reader.is_alive():  # unblock the reader before failing
        with open(_cache_file(key), "w") as fh:
            fh.write("{}")
    assert not reader.is_alive() and got == [None]
