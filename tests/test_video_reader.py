"""Video decoding (trafficgeo.video.reader), regions of interest (trafficgeo.video.roi) and the frame command.

The test videos are written here with PyAV; every frame shows its index as the x position of a bright square, so
a test can tell which frame it got.
"""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import av
import cv2
import numpy as np
import pytest

from cli_support import invoke
from trafficgeo.errors import InputError
from trafficgeo.video.reader import (
    VideoInfo,
    _rotation_from_tag,
    _upright,
    frame_times,
    iter_frames,
    read_frame_at,
    video_info,
)
from trafficgeo.video.roi import read_roi

W, H, FPS, N = 320, 240, 25, 75  # 3 s
SQUARE_Y = 100  # rows SQUARE_Y .. SQUARE_Y + 16 hold the index square (x = 4 * index)
VFR_PTS_MS = [0, 40, 80, 200, 240, 260, 400, 440, 480, 600, 640, 1000]
CAR = Path(__file__).parent / "data" / "intel-sample-video" / "car-detection.mp4"


def _frame_image(k: int) -> np.ndarray:
    img = np.full((H, W, 3), 40, np.uint8)
    img[:24, :24] = 255  # orientation marker in the stored top-left corner
    img[SQUARE_Y:SQUARE_Y + 16, 4 * k:4 * k + 16] = 255
    return img


def _index_of(img: np.ndarray) -> int:
    """The frame index drawn by _frame_image (upright, unrotated frames)."""
    profile = img[SQUARE_Y:SQUARE_Y + 16].mean(axis=(0, 2))
    cols = np.flatnonzero(profile > 150)
    return round((cols.mean() - 7.5) / 4)


def _write_video(path: Path, n: int = N, *, codec: str = "libx264", pts_ms: list[int] | None = None,
                 rotation_ccw: float | None = None) -> Path:
    with av.open(str(path), "w") as c:
        s = c.add_stream(codec, rate=FPS)
        s.width, s.height, s.pix_fmt = W, H, "yuv420p"
        s.gop_size = 10  # keyframes every 10 frames, so that seeking matters
        if codec == "libx264":
            s.options = {"preset": "veryfast", "crf": "16"}  # veryfast keeps B-frames: frames are reordered
        if pts_ms is not None:
            s.time_base = s.codec_context.time_base = Fraction(1, 1000)
        if rotation_ccw is not None:
            s.set_display_rotation(rotation_ccw)
        for k in range(n if pts_ms is None else len(pts_ms)):
            f = av.VideoFrame.from_ndarray(_frame_image(k), format="bgr24")
            if pts_ms is not None:
                f.pts, f.time_base = pts_ms[k], Fraction(1, 1000)
            for p in s.encode(f):
                c.mux(p)
        for p in s.encode():
            c.mux(p)
    return path


@pytest.fixture(scope="module")
def videos(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("videos")
    return {
        "cfr": _write_video(d / "cfr.mp4"),
        "vfr": _write_video(d / "vfr.mp4", pts_ms=VFR_PTS_MS),
        "rot": _write_video(d / "rot.mp4", n=5, rotation_ccw=90),
        "mkv": _write_video(d / "cfr.mkv", n=50, codec="mpeg4"),
    }


# ------------------------------------------------------------------------------------------------ info, frames


def test_video_info(videos):
    info = video_info(videos["cfr"])
    assert (info.width, info.height, info.image_size) == (W, H, (W, H))
    assert info.fps == pytest.approx(25.0)
    assert info.frame_count == N
    assert info.duration_s == pytest.approx(3.0)
    assert (info.rotation_deg, info.codec, info.variable_frame_rate) == (0, "h264", False)
    assert "320x240 px" in info.describe() and "25 fps" in info.describe()


def test_frame_count_estimated_when_the_container_has_none(videos):
    info = video_info(videos["mkv"])  # Matroska stores no frame count
    assert (info.codec, info.frame_count, info.variable_frame_rate) == ("mpeg4", 50, False)
    assert info.duration_s == pytest.approx(2.0, abs=0.05)


def test_iter_frames_all_in_order(videos):
    frames = list(iter_frames(videos["cfr"]))
    assert [f.index for f in frames] == list(range(N))
    assert [_index_of(f.image) for f in frames] == list(range(N))
    np.testing.assert_allclose([f.time_s for f in frames], np.arange(N) / FPS, atol=1e-9)
    img = frames[0].image
    assert img.shape == (H, W, 3) and img.dtype == np.uint8 and img.flags.c_contiguous
    assert img[5, 5].min() > 230 and abs(int(img[50, 200, 0]) - 40) < 6  # white marker, grey (40) background
    np.testing.assert_allclose(frame_times(videos["cfr"]), np.arange(N) / FPS, atol=1e-9)


def test_iter_frames_range_and_every(videos):
    got = list(iter_frames(videos["cfr"], start_s=1.0, end_s=2.0))  # half-open: frames 25 .. 49
    assert [f.index for f in got] == list(range(25, 50))
    assert [_index_of(f.image) for f in got] == list(range(25, 50))
    got = list(iter_frames(videos["cfr"], start_s=1.0, end_s=2.0, every=3, threads=False))
    assert [f.index for f in got] == list(range(25, 50, 3))
    assert [_index_of(f.image) for f in got] == list(range(25, 50, 3))
    first = next(iter(iter_frames(videos["cfr"], start_s=7 / 25)))  # 0.28 s is not exact in binary
    assert (first.index, _index_of(first.image)) == (7, 7)
    first = next(iter(iter_frames(videos["cfr"], start_s=1.01)))  # between frames: the next one
    assert (first.index, first.time_s) == (26, pytest.approx(1.04))
    assert list(iter_frames(videos["cfr"], start_s=5.0)) == []


def test_a_seek_that_overshoots_falls_back_to_decoding_from_the_start(videos, monkeypatch):
    from trafficgeo.video import reader

    seek = reader._seek
    calls = []

    def bad_seek(container, stream, pts):  # lands a second too late, as in a file without a usable index
        calls.append(pts)
        seek(container, stream, pts + round(1.0 / stream.time_base))

    open_ = reader._open
    opened = []

    def counting_open(p):
        opened.append(p)
        return open_(p)

    monkeypatch.setattr(reader, "_open", counting_open)
    first = next(iter(iter_frames(videos["cfr"], start_s=0.4)))  # a keyframe (gop_size 10): the seek lands on it
    assert (first.index, _index_of(first.image), len(opened)) == (10, 10, 1)
    opened.clear()
    monkeypatch.setattr(reader, "_seek", bad_seek)
    got = list(iter_frames(videos["cfr"], start_s=1.0, end_s=1.2))
    assert [(f.index, _index_of(f.image)) for f in got] == [(k, k) for k in range(25, 30)]
    assert len(calls) == 1 and len(opened) == 2  # opened again to decode from the start
    f = read_frame_at(videos["cfr"], 1.5)
    assert (f.index, _index_of(f.image)) == (37, 37)


@pytest.mark.parametrize("kwargs", [{"start_s": -1.0}, {"start_s": float("nan")}, {"start_s": 2.0, "end_s": 1.0},
                                    {"every": 0}, {"every": 1.5}])
def test_iter_frames_bad_arguments(videos, kwargs):
    with pytest.raises(InputError):
        iter_frames(videos["cfr"], **kwargs)  # raised on the call, before iterating


def test_variable_frame_rate_gives_true_times(videos):
    info = video_info(videos["vfr"])
    assert info.variable_frame_rate is True
    assert info.frame_count == len(VFR_PTS_MS)
    # to the end of the last frame (1.0 s + 40 ms); the MP4 muxer itself states 0.72 s (from the B-frames' dts)
    assert info.duration_s == pytest.approx(1.04)
    frames = list(iter_frames(videos["vfr"]))
    np.testing.assert_allclose([f.time_s for f in frames], np.array(VFR_PTS_MS) / 1000, atol=1e-9)
    assert [_index_of(f.image) for f in frames] == list(range(len(VFR_PTS_MS)))
    np.testing.assert_allclose(frame_times(videos["vfr"]), np.array(VFR_PTS_MS) / 1000, atol=1e-9)
    got = list(iter_frames(videos["vfr"], start_s=0.21, end_s=0.45))  # 0.24, 0.26, 0.40, 0.44
    assert [f.index for f in got] == [4, 5, 6, 7]
    f = read_frame_at(videos["vfr"], 0.39)  # in the gap 0.26 .. 0.40: the frame shown is the one from 0.26
    assert (f.index, f.time_s, _index_of(f.image)) == (5, pytest.approx(0.26), 5)
    f = read_frame_at(videos["vfr"], 0.9)
    assert (f.index, f.time_s) == (10, pytest.approx(0.64))


def test_read_frame_at(videos):
    for t, k in [(0.0, 0), (1.0, 25), (1.03, 25), (1.039, 25), (1.04, 26), (2.0, 50), (2.99, 74)]:
        f = read_frame_at(videos["cfr"], t)
        assert (f.index, _index_of(f.image)) == (k, k), t
        assert f.time_s == pytest.approx(k / FPS)
    with pytest.raises(InputError, match=r"beyond its end \(duration 3.000 s\)"):
        read_frame_at(videos["cfr"], 3.0)
    with pytest.raises(InputError, match="must be a time"):
        read_frame_at(videos["cfr"], -0.5)


def test_rotation_metadata_gives_upright_frames(videos):
    info = video_info(videos["rot"])  # stored 320x240 with a display matrix 'rotate 90 deg counter-clockwise'
    assert (info.width, info.height, info.rotation_deg) == (H, W, 270)
    frames = list(iter_frames(videos["rot"]))
    assert len(frames) == 5
    img = frames[0].image
    assert img.shape == (W, H, 3)
    corners = {"bottom-left": img[-10:, :10], "top-left": img[:10, :10], "top-right": img[:10, -10:],
               "bottom-right": img[-10:, -10:]}
    assert corners["bottom-left"].min() > 230  # the stored top-left marker, turned 90 deg counter-clockwise
    assert all(v.max() < 80 for k, v in corners.items() if k != "bottom-left")
    assert read_frame_at(videos["rot"], 0.1).image.shape == (W, H, 3)


def test_rotation_helpers():
    img = np.zeros((2, 3), np.uint8)
    img[0, 0] = 1  # top-left
    assert np.argwhere(_upright(img, 90)).tolist() == [[0, 1]]  # clockwise: top-left -> top-right
    assert np.argwhere(_upright(img, 180)).tolist() == [[1, 2]]
    assert np.argwhere(_upright(img, 270)).tolist() == [[2, 0]]  # -> bottom-left
    assert _upright(img, 0) is img
    for tag, deg in [("90", 90), ("-90", 270), ("180", 180), ("270", 270), ("0", 0), (None, 0), ("x", 0),
                     ("89.6", 90)]:
        assert _rotation_from_tag(tag) == deg, tag


def test_not_a_video(tmp_path):
    with pytest.raises(InputError, match="not found"):
        video_info(tmp_path / "missing.mp4")
    text = tmp_path / "notes.mp4"
    text.write_text("not a video\n")
    with pytest.raises(InputError, match="not a readable video"):
        video_info(text)
    png = tmp_path / "frame.png"
    cv2.imwrite(str(png), _frame_image(0))
    with pytest.raises(InputError, match="still image"):
        video_info(png)
    wav = tmp_path / "sound.wav"
    with av.open(str(wav), "w") as c:
        s = c.add_stream("pcm_s16le", rate=8000)
        frame = av.AudioFrame.from_ndarray(np.zeros((1, 800), np.int16), format="s16", layout="mono")
        frame.sample_rate = 8000
        for p in s.encode(frame):
            c.mux(p)
        for p in s.encode():
            c.mux(p)
    with pytest.raises(InputError, match="no video stream"):
        iter_frames(wav)


# ------------------------------------------------------------------------------------------------ real clip


@pytest.mark.slow
def test_real_clip_car_detection():
    info = video_info(CAR)
    assert (info.width, info.height, info.frame_count, info.codec) == (768, 432, 377, "h264")
    assert info.fps == pytest.approx(12.5)
    assert info.duration_s == pytest.approx(377 / 12.5)
    assert (info.rotation_deg, info.variable_frame_rate) == (0, False)
    n, last = 0, -1.0
    for f in iter_frames(CAR):
        assert f.index == n and f.time_s > last and f.image.shape == (432, 768, 3)
        n, last = n + 1, f.time_s
    assert n == 377
    assert last == pytest.approx(376 / 12.5)


# ------------------------------------------------------------------------------------------------ frame command


def test_cli_frame_writes_the_decoded_frame(videos, tmp_path):
    out = tmp_path / "frame.png"
    code, stdout, stderr = invoke("frame", videos["cfr"], "--at", 1.0, "-o", out)
    assert code == 0, stderr
    written = cv2.imread(str(out), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(written, read_frame_at(videos["cfr"], 1.0).image)
    assert "320x240" in stdout and "25 fps" in stdout and "frame 25 at 1.000000 s" in stdout
    code, stdout, _ = invoke("frame", videos["vfr"], "--info")
    assert code == 0 and "variable frame rate" in stdout
    code, _, _ = invoke("frame", videos["cfr"], "--at", 0.5, "-o", tmp_path / "f.jpg")
    assert code == 0 and cv2.imread(str(tmp_path / "f.jpg")).shape == (H, W, 3)


@pytest.mark.parametrize("args", [("missing.mp4", "--at", 1.0), ("{video}", "--at", -1.0), ("{video}", "--at", 9.0),
                                  ("{video}", "--at", "nan")])
def test_cli_frame_bad_input(videos, tmp_path, args):
    out = tmp_path / "frame.png"
    args = tuple(str(a).replace("{video}", str(videos["cfr"])) for a in args)
    code, _, stderr = invoke("frame", *args, "-o", out)
    assert code == 2
    assert len(stderr.strip().splitlines()) == 1 and "Traceback" not in stderr
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_cli_frame_bad_suffix(videos, tmp_path):
    code, _, stderr = invoke("frame", videos["cfr"], "-o", tmp_path / "frame.gif")
    assert code == 2 and "unknown image format" in stderr and len(stderr.strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------------------------------ ROI


def test_roi_from_csv_polygon(tmp_path):
    csv_path = tmp_path / "roi.csv"
    csv_path.write_text("u,v\n2,1\n7,1\n7,4\n2,4\n")  # vertices at pixel centres: the pixels 2..7 x 1..4
    mask = read_roi(csv_path, (10, 6))
    expected = np.zeros((6, 10), bool)
    expected[1:5, 2:8] = True
    np.testing.assert_array_equal(mask, expected)
    two = tmp_path / "two.csv"
    two.write_text("polygon,u,v\na,0,0\na,2,0\na,0,2\nb,9,5\nb,7,5\nb,9,3\n")
    mask = read_roi(two, (10, 6))
    assert mask[0, 0] and mask[5, 9] and not mask[3, 5]
    headerless = tmp_path / "plain.csv"
    headerless.write_text("2,1\n7,1\n7,4\n2,4\n")
    np.testing.assert_array_equal(read_roi(headerless, (10, 6)), expected)


def test_roi_from_mask_image(tmp_path):
    img = np.zeros((6, 10), np.uint8)
    img[2:4, 3:9] = 255
    png = tmp_path / "roi.png"
    cv2.imwrite(str(png), img)
    mask = read_roi(png, (10, 6))
    assert mask.dtype == bool and mask.shape == (6, 10)
    np.testing.assert_array_equal(mask, img > 0)
    with pytest.raises(InputError, match=r"10x6 px but the video frames are 12x6"):
        read_roi(png, (12, 6))


@pytest.mark.parametrize("content, match", [("u,v\n1,1\n5,1\n", "at least 3"), ("u,v\n1,a\n", "line 2"),
                                            ("u,v\n50,50\n60,50\n60,60\n", "no pixel"), ("", "empty")])
def test_roi_csv_errors(tmp_path, content, match):
    path = tmp_path / "roi.csv"
    path.write_text(content)
    with pytest.raises(InputError, match=match):
        read_roi(path, (10, 6))


def test_roi_bad_files(tmp_path):
    with pytest.raises(InputError, match="not found"):
        read_roi(tmp_path / "missing.png", (10, 6))
    other = tmp_path / "roi.txt"
    other.write_text("1,1\n")
    with pytest.raises(InputError, match="unknown format"):
        read_roi(other, (10, 6))


def test_video_info_is_frozen():
    info = VideoInfo(Path("a.mp4"), 10, 6, 25.0, 1.0, 25, 0, "h264", False)
    with pytest.raises(AttributeError):
        info.width = 3  # type: ignore[misc]
