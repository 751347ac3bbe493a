"""Detector names (one table for the factory, the pipeline and the command line), the warm-up counted in seconds
of video whatever the frame rate, ONNX outputs that cannot be decoded, and a bad --detector refused before
anything is written."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cli_support import invoke
from trafficgeo.errors import InputError
from trafficgeo.video.detectors.background import BackgroundDetector
from trafficgeo.video.detectors.factory import make_detector
from trafficgeo.video.detectors.names import DETECTOR_HELP, DETECTOR_NAMES, detector_kind, is_background
from trafficgeo.video.detectors.onnx import OnnxDetector
from trafficgeo.video.pipeline import ProcessOptions, detect_and_track
from video_support import H, W, road, two_cars, write_two_car_video

ROWS = (60, 120)  # image rows of the two cars


def _scene(rng: np.random.Generator) -> np.ndarray:
    return road(rng, green=10.0)


def _frame(bg: np.ndarray, t: float, rng: np.random.Generator) -> np.ndarray:
    """Two cars (40 x 20 px) driving at 90 px/s across the frame, on screen from the first frame."""
    return two_cars(bg, t, rng, ROWS)


def _write_video(path: Path, fps: int, seconds: float) -> Path:
    return write_two_car_video(path, fps, seconds, rows=ROWS, seed=1, green=10.0)


# ---------------------------------------------------------------------------------------------------- names
@pytest.mark.slow
def test_one_table_of_detector_names(tmp_path: Path) -> None:
    assert {detector_kind(n) for n in ("background", "BG", " mog2 ")} == {"mog2"}
    assert detector_kind("knn") == "knn"
    assert {n for n in DETECTOR_NAMES if is_background(n)} == {"background", "bg", "mog2", "knn"}
    for name in DETECTOR_NAMES:  # every name the help offers builds the detector it stands for
        assert f"'{name}'" in DETECTOR_HELP
        built = make_detector(name)
        if is_background(name):
            assert built.method == DETECTOR_NAMES[name]
        else:  # the built-in learned detector: the shipped NanoDet model, untiled without a camera
            assert isinstance(built, OnnxDetector) and built.path.name == "nanodet-g-416.onnx"
    with pytest.raises(InputError, match="not known") as err:
        detector_kind("yolo-please")
    assert "'bg'" in str(err.value) and "\n" not in str(err.value)
    with pytest.raises(InputError, match=r"^detector ") as err:
        detector_kind(str(tmp_path / "yolo11n.onnx"))
    assert "--model" not in str(err.value)
    with pytest.raises(InputError, match="pass its path with `detector`"):
        OnnxDetector(tmp_path / "yolo11n.onnx")
    with pytest.raises(InputError, match="not known"):
        ProcessOptions(detector="mog3")


# ---------------------------------------------------------------------------------------------------- warm-up
def test_the_pipeline_primes_longer_than_the_warm_up() -> None:
    from trafficgeo.video.detectors.background import WARMUP_S
    from trafficgeo.video.pipeline import PRIME_S

    assert 0 < WARMUP_S < PRIME_S


def test_warm_up_is_counted_in_seconds_at_3_fps() -> None:
    """At 3 fps a 2 s warm-up is 6 frames: detections start with the frame at 2 s, not after 50 frames."""
    rng = np.random.default_rng(2)
    bg = _scene(rng)
    det = BackgroundDetector(warmup_s=2.0)
    found = []
    for k in range(30):
        found.append(len(det.detect(_frame(bg, k / 3, rng), k / 3)))
    assert found[:6] == [0] * 6
    assert all(n >= 1 for n in found[6:]), found  # a car is on screen in every frame


@pytest.mark.slow
@pytest.mark.parametrize(("fps", "detector"), [(3, "background"), (3, "bg"), (25, "bg")])
def test_process_detects_from_the_first_frame(tmp_path: Path, fps: int, detector: str) -> None:
    """The pipeline learns the background before the first frame for every background detector name, and the
    detector's warm-up fits in that priming at any frame rate: vehicles are found from the first frames on."""
    video = _write_video(tmp_path / f"cars{fps}.mp4", fps, 12.0 if fps == 3 else 6.0)
    dets = detect_and_track(video, None, None, tmp_path / "out", ProcessOptions(detector=detector))[0].to_table()
    first = dets.groupby("time").size()
    assert first.index.min() < 0.5, f"first detection at {first.index.min()} s"
    assert len(first.loc[first.index < 1.5]) >= (3 if fps == 3 else 30)  # and in (nearly) every frame after


# ---------------------------------------------------------------------------------------------------- ONNX shapes
def _constant_model(path: Path, values: np.ndarray, declared: list[object] | None = None) -> Path:
    """An ONNX model with a 640 px input whose output is the constant ``values`` (declared with the shape
    ``declared``, default its own; strings are dynamic dimensions)."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    const = numpy_helper.from_array(values.astype(np.float32), name="const")
    zero = numpy_helper.from_array(np.zeros((), dtype=np.float32), name="zero")
    nodes = [helper.make_node("ReduceMean", ["images"], ["mean"], keepdims=0),
             helper.make_node("Mul", ["mean", "zero"], ["nothing"]),
             helper.make_node("Add", ["const", "nothing"], ["output0"])]
    graph = helper.make_graph(nodes, "const_yolo",
                              [helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, 640, 640])],
                              [helper.make_tensor_value_info("output0", TensorProto.FLOAT,
                                                             declared or list(values.shape))],
                              initializer=[const, zero])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path


# [1, 300, 6] (end-to-end) and [1, 8400, 85] (YOLOX) are decoded now: tests/test_onnx_formats.py
@pytest.mark.parametrize("shape", [(1, 300, 84), (1, 84, 300), (2, 84, 8400)])
def test_onnx_outputs_that_cannot_be_decoded_are_refused(tmp_path: Path, shape: tuple[int, ...]) -> None:
    pytest.importorskip("onnx")
    path = _constant_model(tmp_path / "other.onnx", np.zeros(shape, dtype=np.float32))
    with pytest.raises(InputError) as err:
        OnnxDetector(path)
    msg = str(err.value)
    assert "\n" not in msg and str(path) in msg and str(list(shape)).replace(" ", "") in msg.replace(" ", "")
    assert "[1, 4 + classes, anchors]" in msg
    with pytest.raises(InputError, match="cannot decode"):  # and before a run writes anything
        ProcessOptions(detector=str(path))


# ---------------------------------------------------------------------------------------------------- CLI
@pytest.mark.slow
def test_process_with_a_bad_detector_writes_nothing(tmp_path: Path) -> None:
    from trafficgeo.camera.io import write_camera_json
    from trafficgeo.camera.model import Camera

    video = _write_video(tmp_path / "cars.mp4", 3, 2.0)
    cam = Camera.from_orientation((W, H), 300.0, [0.0, -20.0, 8.0], 0.0, 20.0, crs="EPSG:32633")
    write_camera_json(tmp_path / "camera.json", cam)
    for bad in ("yolo-please", str(tmp_path / "missing.onnx")):
        out = tmp_path / "out"
        code, _stdout, stderr = invoke("process", video, "--camera", tmp_path / "camera.json", "--surface", "0",
                                       "--out", out, "--detector", bad)
        assert code == 2 and len(stderr.strip().splitlines()) == 1 and "Traceback" not in stderr, stderr
        assert "--detector" in stderr and "--model" not in stderr
        assert not out.exists(), sorted(p.name for p in out.rglob("*"))


# ---------------------------------------------------------------------------------------------------- classes
def test_blobs_no_single_vehicle_explains_are_of_unknown_class(monkeypatch: pytest.MonkeyPatch) -> None:
    """Kept although no class fits them (merged vehicles), or truck-sized but filling little of their box: class
    "" (unknown), not "truck"/"van"; single vehicles keep their class."""
    from trafficgeo.camera.model import Camera
    from trafficgeo.geo.surface import ConstantSurface
    from trafficgeo.video.detectors.blobs import Blobs

    cam = Camera.from_orientation((400, 200), 300.0, [0.0, -20.0, 8.0], 0.0, 20.0, crs="EPSG:32633")
    det = BackgroundDetector(camera=cam, surface=ConstantSurface(0.0))
    det._small = (200, 100)
    # per box (by x1): class by size, length (m), plausible as one vehicle, ground width (m)
    sizes = {10: ("truck", 12.0, True, 2.8), 60: ("truck", 12.0, True, 2.8), 110: ("van", 11.0, False, 2.5),
             160: ("car", 4.5, True, 1.9)}

    def measure(boxes: np.ndarray) -> tuple[np.ndarray, ...]:
        rows = [sizes[int(b[0])] for b in boxes]
        return tuple(np.array([r[k] for r in rows], dtype=object if k == 0 else float if k != 2 else bool)
                     for k in range(4))

    monkeypatch.setattr(det, "_measure", measure)
    boxes = np.array([[10, 10, 49, 29], [60, 10, 99, 29], [110, 10, 149, 29], [160, 50, 179, 59]], dtype=float)
    areas = np.array([700.0, 300.0, 500.0, 190.0])  # boxes of 800, 800, 800 and 200 px: fill 0.88, 0.38, 0.63, 0.95
    kept, classes = det._metric(Blobs(boxes, areas, [[1], [2], [3], [4]]))
    assert len(kept.areas) == 4
    assert list(classes) == ["truck", "", "", "car"]


def test_counts_per_class_add_up_with_unknown_vehicles() -> None:
    import pandas as pd

    from trafficgeo.traffic.counts import aggregate_counts

    cr = pd.DataFrame({"line": "L1", "track_id": ["a", "b", "c", "d"], "class": ["car", "", "truck", None],
                       "lane": "1", "direction": 1, "time": [1.0, 2.0, 3.0, 4.0], "speed_kmh": 50.0,
                       "x": 0.0, "y": 0.0})
    counts = aggregate_counts(cr, 60.0, 0.0, 60.0)
    assert counts[["count", "count_car", "count_truck", "count_unknown"]].iloc[0].tolist() == [4, 1, 1, 2]
    assert "count_unknown" not in aggregate_counts(cr.assign(**{"class": "car"}), 60.0, 0.0, 60.0).columns
    assert "count_unknown" not in aggregate_counts(cr.assign(**{"class": ""}), 60.0, 0.0, 60.0).columns


def test_unknown_class_points_take_their_tracks_dimensions() -> None:
    """A vehicle of unknown class in some frames (merged with another in the image) is fitted with its track's
    class there, not a car's."""
    from trafficgeo.run.tracks import ImageTracks
    from trafficgeo.traffic.measurements import known_classes as _known_classes

    n = 6
    tracks = ImageTracks(track_id=np.array(["a", "a", "a", "b", "b", "c"]), frame=np.arange(n),
                         time=np.arange(n, dtype=float), u=np.zeros(n), v=np.zeros(n), box=np.zeros((n, 4)),
                         vclass=np.array(["truck", "", "truck", "", "", "car"], dtype=object),
                         score=np.ones(n))
    assert list(_known_classes(tracks)) == ["truck", "truck", "truck", "", "", "car"]


def test_a_vehicle_mostly_of_unknown_class_is_unknown() -> None:
    """A track whose boxes are mostly blobs no single vehicle explains is not a "truck" for a few truck-like ones."""
    from trafficgeo.traffic.trajectories import _vehicle_class

    assert _vehicle_class(np.array(["truck", "", "", ""], dtype=object)) == ""
    assert _vehicle_class(np.array(["truck", "truck", "", "van"], dtype=object)) == "truck"
    assert _vehicle_class(np.array(["car", "", "car", "van", ""], dtype=object)) == "car"
    assert _vehicle_class(np.array(["", ""], dtype=object)) == ""


def test_detector_threads_follow_the_batch_worker_setting(monkeypatch: pytest.MonkeyPatch) -> None:
    from trafficgeo.video.detectors.builtin import builtin_model_path
    from trafficgeo.video.detectors.learned import BUILTIN
    from trafficgeo.video.detectors.onnx import OnnxDetector, default_threads

    path = builtin_model_path(BUILTIN)
    monkeypatch.delenv("TRAFFICGEO_THREADS", raising=False)
    assert default_threads() == 2
    monkeypatch.setenv("TRAFFICGEO_THREADS", "1")  # what a batch worker of one thread sets
    assert OnnxDetector(path)._session.get_session_options().intra_op_num_threads == 1
    assert OnnxDetector(path, threads=3)._session.get_session_options().intra_op_num_threads == 3
    for bad in ("0", "x", "-2"):
        monkeypatch.setenv("TRAFFICGEO_THREADS", bad)
        assert default_threads() == 2
