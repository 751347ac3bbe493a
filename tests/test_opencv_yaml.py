"""OpenCV FileStorage intrinsics: real and hand-written files, exact round trips, errors, atomic writes."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trafficgeo.camera.opencv_yaml import Intrinsics, read_intrinsics_yaml, write_intrinsics_yaml
from trafficgeo.errors import InputError

DATA = Path(__file__).parent / "data" / "opencv-chessboard"
LEFT_YML = DATA / "left_intrinsics.yml"

OPENCV_HEADER = "%YAML:1.0\n---\n"


def _matrix(name: str, rows: int, cols: int, values: list[str], dt: str = "d") -> str:
    return (
        f"{name}: !!opencv-matrix\n   rows: {rows}\n   cols: {cols}\n   dt: {dt}\n"
        f"   data: [ {', '.join(values)} ]\n"
    )


K_TEXT = ["800.", "0.", "320.", "0.", "810.", "240.", "0.", "0.", "1."]


def _write(tmp_path: Path, text: str, name: str = "cam.yml") -> Path:
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


# ---------------------------------------------------------------------------------------------- reading
def test_read_opencv_sample_left_intrinsics() -> None:
    intr = read_intrinsics_yaml(LEFT_YML)
    assert intr.K.shape == (3, 3) and intr.K.dtype == np.float64
    assert intr.dist.shape == (5,) and intr.dist.dtype == np.float64
    assert intr.fx == pytest.approx(535.9157, abs=1e-4)
    assert intr.fy == pytest.approx(535.9157, abs=1e-4)
    assert intr.cx == pytest.approx(342.2832, abs=1e-4)
    assert intr.cy == pytest.approx(235.5708, abs=1e-4)
    assert intr.K[0, 1] == 0.0 and intr.K[1, 0] == 0.0
    np.testing.assert_array_equal(intr.K[2], [0.0, 0.0, 1.0])
    np.testing.assert_allclose(intr.dist, [-0.26637, -0.038589, 0.0017832, -0.00028122, 0.23839], rtol=1e-4)
    assert intr.image_size == (640, 480)
    assert intr.rms_px == pytest.approx(0.3926, abs=1e-4)
    # exact decimal values of the file
    assert intr.K[0, 0] == 5.3591573396163199e02
    assert intr.dist[4] == 2.3839153080878486e-01


KEY_PAIRS = [
    ("camera_matrix", "distortion_coefficients"),
    ("cameraMatrix", "distCoeffs"),
    ("K", "D"),
    ("M", "dist_coeffs"),
    ("M1", "D1"),
]


@pytest.mark.parametrize(("kkey", "dkey"), KEY_PAIRS)
def test_read_accepts_common_key_names(tmp_path: Path, kkey: str, dkey: str) -> None:
    dist = ["0.1", "-0.2", "0.001", "0.002", "0.3"]
    text = OPENCV_HEADER + _matrix(kkey, 3, 3, K_TEXT) + _matrix(dkey, 1, 5, dist)
    intr = read_intrinsics_yaml(_write(tmp_path, text))
    np.testing.assert_array_equal(intr.K, [[800, 0, 320], [0, 810, 240], [0, 0, 1]])
    np.testing.assert_array_equal(intr.dist, [0.1, -0.2, 0.001, 0.002, 0.3])
    assert intr.image_size is None and intr.rms_px is None


def test_read_camera_matrix_first_key_wins(tmp_path: Path) -> None:
    other = ["500.", "0.", "1.", "0.", "500.", "2.", "0.", "0.", "1."]
    text = OPENCV_HEADER + _matrix("M1", 3, 3, other) + _matrix("camera_matrix", 3, 3, K_TEXT)
    assert read_intrinsics_yaml(_write(tmp_path, text)).fx == 800.0


def test_read_four_term_distortion_is_padded(tmp_path: Path) -> None:
    text = (
        OPENCV_HEADER
        + _matrix("camera_matrix", 3, 3, K_TEXT)
        + _matrix("distortion_coefficients", 4, 1, ["0.1", "-0.2", "0.001", "0.002"])
    )
    intr = read_intrinsics_yaml(_write(tmp_path, text))
    assert intr.dist.shape == (5,) and intr.dist.dtype == np.float64
    np.testing.assert_array_equal(intr.dist, [0.1, -0.2, 0.001, 0.002, 0.0])


def test_read_missing_distortion_means_zero(tmp_path: Path) -> None:
    intr = read_intrinsics_yaml(_write(tmp_path, OPENCV_HEADER + _matrix("K", 3, 3, K_TEXT)))
    np.testing.assert_array_equal(intr.dist, np.zeros(5))


def test_read_float32_matrix(tmp_path: Path) -> None:
    intr = read_intrinsics_yaml(_write(tmp_path, OPENCV_HEADER + _matrix("K", 3, 3, K_TEXT, dt="f")))
    assert intr.K.dtype == np.float64 and intr.fy == 810.0


def test_read_image_size_sequence_and_plain_lists(tmp_path: Path) -> None:
    text = (
        OPENCV_HEADER + "K: [[800, 0, 320], [0, 810, 240], [0, 0, 1]]\n"
        "D: [0.1, -0.2, 0.001, 0.002]\nimage_size: [1920, 1080]\n"
    )
    intr = read_intrinsics_yaml(_write(tmp_path, text))
    assert intr.fx == 800.0 and intr.image_size == (1920, 1080)
    np.testing.assert_array_equal(intr.dist, [0.1, -0.2, 0.001, 0.002, 0.0])


def test_read_ros_camera_info_yaml(tmp_path: Path) -> None:
    text = (
        "image_width: 1280\nimage_height: 720\ncamera_name: cam\n"
        "camera_matrix:\n  rows: 3\n  cols: 3\n  data: [800, 0, 640, 0, 800, 360, 0, 0, 1]\n"
        "distortion_model: plumb_bob\n"
        "distortion_coefficients:\n  rows: 1\n  cols: 5\n  data: [-0.1, 0.01, 0, 0, 0]\n"
    )
    intr = read_intrinsics_yaml(_write(tmp_path, text, "cam.yaml"))
    assert intr.image_size == (1280, 720)
    assert intr.cx == 640.0 and intr.cy == 360.0
    np.testing.assert_array_equal(intr.dist, [-0.1, 0.01, 0, 0, 0])


# ---------------------------------------------------------------------------------------------- round trip
_finite = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False, allow_infinity=False)
_positive = st.floats(min_value=1e-3, max_value=1e6, allow_nan=False, allow_infinity=False)
_dist_value = st.floats(min_value=-1e3, max_value=1e3, allow_nan=False) | st.sampled_from(
    [0.0, -0.0, 5e-324, -2.2250738585072014e-308, 1.0 / 3.0, 0.1 + 0.2]
)  # subnormals, signed zero


@pytest.mark.slow
@settings(max_examples=60, deadline=None)
@given(
    fx=_positive,
    fy=_positive,
    s=_finite,
    cx=_finite,
    cy=_finite,
    dist=st.lists(_dist_value, min_size=5, max_size=5),
    size=st.none() | st.tuples(st.integers(1, 100_000), st.integers(1, 100_000)),
    rms=st.none() | st.floats(min_value=0.0, max_value=1e3, allow_nan=False),
)
def test_write_read_round_trip_is_exact(
    tmp_path_factory: pytest.TempPathFactory,
    fx: float,
    fy: float,
    s: float,
    cx: float,
    cy: float,
    dist: list[float],
    size: tuple[int, int] | None,
    rms: float | None,
) -> None:
    path = tmp_path_factory.mktemp("rt") / "intrinsics.yml"
    intr = Intrinsics(
        K=np.array([[fx, s, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]),
        dist=np.array(dist),
        image_size=size,
        rms_px=rms,
    )
    write_intrinsics_yaml(path, intr)
    back = read_intrinsics_yaml(path)
    np.testing.assert_array_equal(back.K, intr.K)  # bit-exact: FileStorage prints 17 significant digits
    np.testing.assert_array_equal(back.dist, intr.dist)
    assert back.image_size == intr.image_size
    assert back.rms_px == intr.rms_px


@pytest.mark.parametrize("suffix", [".yml", ".yaml", ".xml", ".json"])
def test_round_trip_all_formats(tmp_path: Path, suffix: str) -> None:
    intr = read_intrinsics_yaml(LEFT_YML)
    path = tmp_path / f"out{suffix}"
    write_intrinsics_yaml(path, intr)
    back = read_intrinsics_yaml(path)
    np.testing.assert_array_equal(back.K, intr.K)
    np.testing.assert_array_equal(back.dist, intr.dist)
    assert back.image_size == (640, 480) and back.rms_px == intr.rms_px
    if suffix == ".json":
        assert json.loads(path.read_text())["image_width"] == 640  # strict JSON (no // comment)


def test_written_yaml_layout(tmp_path: Path) -> None:
    path = tmp_path / "cam.yml"
    write_intrinsics_yaml(path, read_intrinsics_yaml(LEFT_YML))
    text = path.read_text()
    assert text.startswith("%YAML")
    for key in (
        "image_width: 640",
        "image_height: 480",
        "camera_matrix: !!opencv-matrix",
        "distortion_coefficients: !!opencv-matrix",
        "avg_reprojection_error:",
    ):
        assert key in text
    no_extra = Intrinsics(K=np.eye(3), dist=np.zeros(5), image_size=None)
    write_intrinsics_yaml(path, no_extra)
    text = path.read_text()
    assert "image_width" not in text and "avg_reprojection_error" not in text


# ---------------------------------------------------------------------------------------------- errors
def _error(path: Path) -> str:
    with pytest.raises(InputError) as info:
        read_intrinsics_yaml(path)
    msg = str(info.value)
    assert "\n" not in msg
    assert str(path) in msg
    return msg


def test_missing_file(tmp_path: Path) -> None:
    assert "not found" in _error(tmp_path / "nope.yml")


def test_directory_is_not_a_file(tmp_path: Path) -> None:
    _error(tmp_path)


GARBAGE = [
    "this is not : a : yaml [file\n",
    "just some words\n",
    "",
    "\x00\x01\x02{{{",
    "%YAML:1.0\n---\n- 1\n- 2\n",
]


@pytest.mark.parametrize("text", GARBAGE)
def test_garbage_file(tmp_path: Path, text: str) -> None:
    _error(_write(tmp_path, text))


def test_no_camera_matrix(tmp_path: Path) -> None:
    msg = _error(_write(tmp_path, OPENCV_HEADER + "image_width: 640\nimage_height: 480\n"))
    assert "camera_matrix" in msg and "no camera matrix" in msg


def test_camera_matrix_3x2(tmp_path: Path) -> None:
    values = ["1.", "2.", "3.", "4.", "5.", "6."]
    msg = _error(_write(tmp_path, OPENCV_HEADER + _matrix("camera_matrix", 3, 2, values)))
    assert "'camera_matrix'" in msg and "(3, 2)" in msg


def test_camera_matrix_nan(tmp_path: Path) -> None:
    values = ["800.", "0.", ".nan", "0.", "810.", "240.", "0.", "0.", "1."]
    msg = _error(_write(tmp_path, OPENCV_HEADER + _matrix("camera_matrix", 3, 3, values)))
    assert "'camera_matrix'" in msg and "non-finite" in msg


def test_distortion_nan(tmp_path: Path) -> None:
    text = OPENCV_HEADER + _matrix("K", 3, 3, K_TEXT) + _matrix("D", 1, 5, ["0.1", ".nan", "0.", "0.", "0."])
    assert "'D'" in _error(_write(tmp_path, text))


@pytest.mark.parametrize("fx", ["0.", "-800."])
def test_non_positive_focal_length(tmp_path: Path, fx: str) -> None:
    values = [fx, *K_TEXT[1:]]
    assert "focal" in _error(_write(tmp_path, OPENCV_HEADER + _matrix("camera_matrix", 3, 3, values)))


def test_not_a_pinhole_matrix(tmp_path: Path) -> None:
    values = [*K_TEXT[:8], "2."]
    _error(_write(tmp_path, OPENCV_HEADER + _matrix("camera_matrix", 3, 3, values)))


def test_rational_model_refused(tmp_path: Path) -> None:
    eight = ["0.1", "-0.2", "0.001", "0.002", "0.3", "0.01", "0.02", "0.03"]
    text = OPENCV_HEADER + _matrix("M1", 3, 3, K_TEXT) + _matrix("D1", 1, 8, eight)
    msg = _error(_write(tmp_path, text))
    assert "'D1'" in msg and "5-term" in msg


def test_fisheye_model_refused(tmp_path: Path) -> None:
    text = (
        OPENCV_HEADER
        + _matrix("K", 3, 3, K_TEXT)
        + "distortion_model: equidistant\n"
        + _matrix("D", 1, 4, ["0.1", "0.01", "0.001", "0.0001"])
    )
    assert "equidistant" in _error(_write(tmp_path, text))


def test_too_few_distortion_terms(tmp_path: Path) -> None:
    text = OPENCV_HEADER + _matrix("K", 3, 3, K_TEXT) + _matrix("D", 1, 2, ["0.1", "0.2"])
    assert "'D'" in _error(_write(tmp_path, text))


@pytest.mark.parametrize(
    "extra",
    [
        "image_width: 640\n",
        "image_width: 640\nimage_height: -480\n",
        "image_width: 640.5\nimage_height: 480\n",
        "image_size: [640]\n",
    ],
)
def test_bad_image_size(tmp_path: Path, extra: str) -> None:
    _error(_write(tmp_path, OPENCV_HEADER + _matrix("K", 3, 3, K_TEXT) + extra))


def test_intrinsics_constructor_validates() -> None:
    with pytest.raises(InputError):
        Intrinsics(K=np.zeros((3, 3)), dist=np.zeros(5), image_size=None)
    with pytest.raises(InputError):
        Intrinsics(K=np.eye(3), dist=np.zeros(8), image_size=None)
    with pytest.raises(InputError):
        Intrinsics(K=np.eye(3), dist=np.zeros(5), image_size=(0, 10))
    intr = Intrinsics(K=np.eye(3).tolist(), dist=[0.1, 0.2, 0.0, 0.0], image_size=(np.int64(4), 3))
    assert intr.dist.shape == (5,) and intr.image_size == (4, 3) and type(intr.image_size[0]) is int


# ---------------------------------------------------------------------------------------------- atomic write
def test_write_replaces_existing_file_whole(tmp_path: Path) -> None:
    path = tmp_path / "cam.yml"
    path.write_text("x" * 100_000)  # longer than the new content: a truncating in-place write would show it
    write_intrinsics_yaml(path, read_intrinsics_yaml(LEFT_YML))
    assert "xxx" not in path.read_text()
    assert read_intrinsics_yaml(path).fx == pytest.approx(535.9157, abs=1e-4)
    assert sorted(os.listdir(tmp_path)) == ["cam.yml"]  # no temporary file left behind


def test_write_does_not_create_target_on_failure(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import trafficgeo.camera.opencv_yaml as mod

    path = tmp_path / "cam.yml"
    path.write_text("old content\n")

    class Boom(RuntimeError):
        pass

    def fail(*args: object, **kwargs: object) -> None:
        raise Boom

    monkeypatch.setattr(mod.os, "fsync", fail)  # fails after FileStorage wrote the temporary file
    with pytest.raises(Boom):
        write_intrinsics_yaml(path, read_intrinsics_yaml(LEFT_YML))
    assert path.read_text() == "old content\n"
    assert sorted(os.listdir(tmp_path)) == ["cam.yml"]


def test_write_bad_targets(tmp_path: Path) -> None:
    intr = read_intrinsics_yaml(LEFT_YML)
    with pytest.raises(InputError, match="suffix"):
        write_intrinsics_yaml(tmp_path / "cam.txt", intr)
    folder = tmp_path / "d.yml"
    folder.mkdir()
    with pytest.raises(InputError, match="directory"):
        write_intrinsics_yaml(folder, intr)


@pytest.mark.parametrize("shape", ["brackets", "indentation", "xml"])
def test_a_file_nested_too_deep_is_refused_before_opencv_parses_it(tmp_path: Path, shape: str) -> None:
    """Issue 43: a YAML nested 100,000 deep killed the process (OpenCV's recursive parser overflows its stack:
    exit 139, no message). Such files are refused with a one-line InputError; a real camera file still reads."""
    n = 100_000 if shape == "brackets" else 2_000
    text = {
        "brackets": "%YAML:1.0\n---\ncamera_matrix: " + "[" * n + "]" * n + "\n",
        "indentation": "%YAML:1.0\n---\n" + "".join(" " * (2 * i) + f"k{i}:\n" for i in range(n)) + " " * 2 * n
                       + "x: 1\n",
        "xml": '<?xml version="1.0"?>\n<opencv_storage>' + "<a>" * n + "1" + "</a>" * n + "</opencv_storage>\n",
    }[shape]
    path = tmp_path / ("deep.xml" if shape == "xml" else "deep.yml")
    path.write_text(text)
    with pytest.raises(InputError, match="nested more than 64 levels"):
        read_intrinsics_yaml(path)
    ok = tmp_path / "ok.yml"
    write_intrinsics_yaml(ok, Intrinsics(np.array([[800.0, 0, 320], [0, 800, 240], [0, 0, 1]]), np.zeros(5),
                                         (640, 480)))
    assert read_intrinsics_yaml(ok).K[0, 0] == 800.0
