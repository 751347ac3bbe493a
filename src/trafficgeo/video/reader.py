"""Decoding videos for traffic analysis (PyAV, i.e. FFmpeg).

Frames come out as OpenCV-ordered **BGR** ``uint8`` images of shape (H, W, 3), already turned upright the way a
player shows them (phones store portrait videos as landscape frames plus a rotation in the container). Their
times are the frames' real presentation timestamps in seconds from the start of the video stream, so a
variable-frame-rate video (most phone videos) gets true times, not ``index / fps``.

Conventions:

* ``rotation_deg`` is the clockwise rotation (0, 90, 180 or 270 degrees) that turns the stored frames upright;
  it is the value of the legacy ``rotate`` tag phones write, and minus the angle of FFmpeg's display matrix
  (which is counter-clockwise). Mirroring in a display matrix is ignored.
* ``index`` is the 0-based position of a frame in the decoded stream (in presentation order).
* Time ranges are half-open: ``iter_frames(start_s=a, end_s=b)`` gives the frames with ``a <= time_s < b``.

A damaged or truncated file (a copy cut short, a recording that stopped) is read as far as it decodes: reading
ends there with a :class:`VideoReadWarning` (one line: where it stopped and why) instead of an error, so that
the frames before it are still used and the caller can say what was read.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Any

import av
import cv2
import numpy as np

from trafficgeo.errors import InputError

_VFR_SCAN_PACKETS = 300  # packets (frames) whose timestamps video_info inspects for variable frame rate
_VFR_TOLERANCE = 0.05  # a frame interval further than this fraction from the median one makes the video VFR
_RATE_TOLERANCE = 0.01  # relative difference of the stream's average and base frame rates that means VFR
_TICK_EPS = 1e-3  # fraction of a time-base tick forgiven when a time in seconds is turned into a timestamp
_STILL_IMAGE_FORMATS = ("image2", "image2pipe")  # and every "*_pipe" format (png_pipe, jpeg_pipe, ...)
_ROTATE = {90: cv2.ROTATE_90_CLOCKWISE, 180: cv2.ROTATE_180, 270: cv2.ROTATE_90_COUNTERCLOCKWISE}


class VideoReadWarning(UserWarning):
    """Decoding stopped before the end of the asked time range: damaged data, or a file cut short."""


@dataclass(frozen=True)
class VideoInfo:
    """What a video holds, as the frames are delivered by :func:`iter_frames` (i.e. after rotation)."""

    path: Path
    width: int  # pixels of the upright frames
    height: int  # pixels of the upright frames
    fps: float  # average frame rate (frames per second)
    duration_s: float  # length of the video stream (s)
    frame_count: int  # from the container if it says, else round(duration_s * fps)
    rotation_deg: int  # clockwise rotation applied to the stored frames: 0, 90, 180 or 270 (degrees)
    codec: str  # FFmpeg codec name, e.g. 'h264', 'hevc'
    variable_frame_rate: bool  # frame timestamps are not evenly spaced

    @property
    def image_size(self) -> tuple[int, int]:
        """(width, height) of the delivered frames (pixels)."""
        return self.width, self.height

    def describe(self) -> str:
        """One line for people: size, rate, length, rotation, codec."""
        rate = f"{self.fps:.3f}".rstrip("0").rstrip(".")
        parts = [f"{self.width}x{self.height} px", f"{rate} fps" + (" (variable frame rate)"
                                                                   if self.variable_frame_rate else ""),
                 f"{self.duration_s:.3f} s", f"{self.frame_count} frames", self.codec]
        if self.rotation_deg:
            parts.append(f"rotated {self.rotation_deg} deg clockwise to be upright")
        return ", ".join(parts)


@dataclass
class VideoFrame:
    """One decoded frame."""

    index: int  # 0-based position in the decoded stream (presentation order)
    time_s: float  # presentation time (s) from the start of the video stream
    image: np.ndarray  # (H, W, 3) uint8 BGR, upright


# --------------------------------------------------------------------------------------------------- public API


def video_info(path: str | Path) -> VideoInfo:
    """Read a video's size, frame rate, duration, rotation and codec.

    Demuxes the first few hundred packets (no decoding but of the first frame, which tells the rotation) to
    judge whether the frame rate is variable, and the last group of pictures for the duration (up to the end of
    the last frame; the container's own figure can stop short of it). A missing file, a file FFmpeg cannot read,
    a still image or a file without a video stream raises :class:`InputError`.
    """
    p = Path(path)
    container, stream = _open(p)
    with container:
        tb = _time_base(stream, p)
        pts: list[int] = []
        first = None
        try:
            for packet in container.demux(stream):
                if first is None:
                    frames = stream.decode(packet)
                    first = frames[0] if frames else None
                if packet.pts is not None and not packet.is_discard:
                    pts.append(packet.pts)
                if first is not None and len(pts) >= _VFR_SCAN_PACKETS:
                    break
        except av.FFmpegError as exc:
            raise InputError(f"video {p}: damaged data near the start ({_reason(exc)}); re-encode or re-copy "
                             "the file") from None
        if first is None:
            raise InputError(f"video {p}: no frame of its {stream.codec_context.name} stream could be decoded; "
                             "the file may be truncated or damaged")
        fps = _fps(stream, pts, tb)
        duration = _duration(p, fps)
        frame_count = stream.frames if stream.frames and stream.frames > 0 else round(duration * fps)
        rotation = _rotation_deg(first, stream)
        w, h = first.width, first.height
        if rotation in (90, 270):
            w, h = h, w
        return VideoInfo(path=p, width=w, height=h, fps=fps, duration_s=duration, frame_count=int(frame_count),
                         rotation_deg=rotation, codec=stream.codec_context.name,
                         variable_frame_rate=_uneven_timestamps(pts) or _rates_disagree(stream, frame_count))


def iter_frames(path: str | Path, *, start_s: float = 0.0, end_s: float | None = None, every: int = 1,
                threads: bool = True) -> Iterator[VideoFrame]:
    """Decode the frames with ``start_s <= time_s < end_s`` (s), yielding every ``every``-th of them.

    Seeks to the keyframe before ``start_s`` and decodes (without converting) the frames up to it. The frames'
    ``index`` is their position in the whole video; finding it for ``start_s > 0`` costs a demux pass (reading
    packets, no decoding) up to ``start_s``. ``threads`` lets FFmpeg decode with several threads (frame and
    slice threading): 1.1 to 1.7 times faster on two cores for 1080p H.264, the more the heavier the stream.
    Arguments are checked and the file opened when this is called; the frames are decoded as they are consumed.
    """
    p = Path(path)
    _check_time(start_s, "start_s")
    if end_s is not None:
        _check_time(end_s, "end_s")
        if end_s <= start_s:
            raise InputError(f"end_s {end_s:g} s must be after start_s {start_s:g} s")
    if isinstance(every, bool) or not isinstance(every, int | np.integer) or every < 1:
        raise InputError(f"every={every!r} must be a whole number >= 1 (1 = every frame, 3 = every third)")
    container, stream = _open(p)
    return _generate(p, container, stream, start_s, end_s, int(every), threads)


def read_frame_at(path: str | Path, time_s: float) -> VideoFrame:
    """The frame shown at ``time_s`` (s): the last frame whose time is at or before it.

    A time at or after the end of the video raises :class:`InputError` naming the duration.
    """
    p = Path(path)
    _check_time(time_s, "time")
    container, stream = _open(p)
    try:
        tb, origin = _time_base(stream, p), _origin(container, stream)
        duration = _duration(p, _fps(stream, [], tb))
        if duration > 0 and time_s >= duration:
            raise InputError(f"video {p}: time {time_s:g} s is beyond its end (duration {duration:.3f} s); "
                             f"give a time from 0 to {duration:.3f} s")
        target = origin + math.floor(time_s / tb + _TICK_EPS)
        n_upto, last, _ = _count_packets(container, stream, target, inclusive=True)
        chosen = None
        if n_upto > 0:
            chosen = _frame_at_or_before(p, container, stream, target, seek=True)
            if chosen is not None and chosen[1] != last:  # the seek landed after the frame shown at time_s
                chosen = None
        if chosen is None:  # no timestamps before the time, or the seek landed after it: decode from the start
            container.close()
            container, stream = _open(p)
            chosen = _frame_at_or_before(p, container, stream, target, seek=False)
            n_upto = chosen[2] + 1 if chosen is not None else 0
        if chosen is None:
            raise InputError(f"video {p}: no frame could be decoded at or before {time_s:g} s; the file may be "
                             "damaged")
        frame, pts, _ = chosen
        return VideoFrame(index=max(n_upto - 1, 0), time_s=_seconds(pts - origin, tb),
                          image=_to_bgr(frame, _rotation_deg(frame, stream)))
    finally:
        container.close()


def frame_times(path: str | Path) -> np.ndarray:
    """All frame timestamps (s from the start of the video stream), sorted, from the packets (no decoding).

    Cheap: it reads the file once but decodes nothing. One packet is one frame for the codecs cameras and
    phones write (H.264, HEVC, VP9, AV1, MJPEG).
    """
    p = Path(path)
    container, stream = _open(p)
    with container:
        tb, origin = _time_base(stream, p), _origin(container, stream)
        n_packets, pts = 0, []
        try:
            for packet in container.demux(stream):
                n_packets += packet.size > 0
                if packet.pts is not None and not packet.is_discard:
                    pts.append(packet.pts)
        except av.FFmpegError as exc:
            raise InputError(f"video {p}: damaged data ({_reason(exc)}); re-encode or re-copy the file") from None
    if n_packets and not pts:
        raise InputError(f"video {p}: its packets carry no timestamps (a raw stream); put it in a container, "
                         "e.g. ffmpeg -r FPS -i IN -c copy OUT.mp4")
    ticks = np.sort(np.asarray(pts, dtype=np.int64)) - origin
    return ticks * tb.numerator / tb.denominator


# --------------------------------------------------------------------------------------------------- internals


def _open(p: Path) -> tuple[Any, Any]:
    """Open ``p`` and pick its (first, non-cover-art) video stream; (container, stream)."""
    if not p.is_file():
        what = "is a folder, not a video file" if p.is_dir() else "not found"
        raise InputError(f"video {p}: {what}; check the path")
    try:
        container = av.open(str(p), mode="r")
    except (av.FFmpegError, OSError) as exc:
        raise InputError(f"video {p}: not a readable video ({_reason(exc)}); give a video file such as MP4, "
                         "MOV, MKV or AVI") from None
    fmt = container.format.name
    if fmt in _STILL_IMAGE_FORMATS or fmt.endswith("_pipe"):
        container.close()
        raise InputError(f"video {p}: is a still image ({fmt}), not a video; give the video file")
    streams = [s for s in container.streams.video if not (s.disposition & av.stream.Disposition.attached_pic)]
    if not streams:
        kinds = sorted({s.type for s in container.streams}) or ["nothing"]
        container.close()
        raise InputError(f"video {p}: has no video stream (it holds {', '.join(kinds)}); give a video file")
    return container, streams[0]


def _reason(exc: BaseException) -> str:
    text = getattr(exc, "strerror", None) or str(exc)
    return text.splitlines()[0] if text else type(exc).__name__


def _check_time(value: float, name: str) -> None:
    if isinstance(value, bool) or not isinstance(value, int | float | np.number) or not math.isfinite(value) \
            or value < 0:
        raise InputError(f"{name} {value!r} must be a time in seconds from the start of the video, >= 0")


def _time_base(stream: Any, p: Path) -> Fraction:
    tb = stream.time_base
    if tb is None or tb <= 0:
        raise InputError(f"video {p}: its video stream has no time base, so frames have no times; re-mux it, "
                         "e.g. ffmpeg -i IN -c copy OUT.mp4")
    return Fraction(tb)


def _origin(container: Any, stream: Any) -> int:
    """Timestamp (stream ticks) of the start of the stream, time 0 of every VideoFrame."""
    if stream.start_time is not None:
        return int(stream.start_time)
    if container.start_time is not None:  # AV_TIME_BASE units (microseconds)
        return round(Fraction(container.start_time, 1_000_000) / Fraction(stream.time_base))
    return 0


def _seconds(ticks: int, tb: Fraction) -> float:
    return ticks * tb.numerator / tb.denominator


def _fps(stream: Any, pts: list[int], tb: Fraction) -> float:
    for rate in (stream.average_rate, stream.guessed_rate, stream.base_rate):
        if rate is not None and rate > 0:
            return float(rate)
    if len(pts) >= 2:
        step = float(np.median(np.diff(np.unique(pts))))
        if step > 0:
            return 1.0 / (step * float(tb))
    return 0.0


def _nominal_duration(container: Any, stream: Any, tb: Fraction, origin: int) -> float:
    """The duration the container states (s), 0 if none."""
    if stream.duration is not None and stream.duration > 0:
        return _seconds(stream.duration, tb)
    if container.duration is not None and container.duration > 0:  # AV_TIME_BASE units (microseconds)
        start = container.start_time / 1e6 if container.start_time is not None else 0.0
        return max(container.duration / 1e6 - max(_seconds(origin, tb) - start, 0.0), 0.0)
    return 0.0


def _duration(p: Path, fps: float) -> float:
    """Duration (s) up to the end of the last frame: the stated one, extended to the last packets' pts + duration.

    Seeks to the last keyframe and demuxes to the end of the file. The stated duration can stop short: the MP4
    muxer derives it from decoding timestamps, which for a variable-frame-rate stream with B-frames end before the
    last presentation time. A raw stream (no timestamps, no stated duration) gets its packet count / ``fps``.
    """
    container, stream = _open(p)
    with container:
        tb, origin = _time_base(stream, p), _origin(container, stream)
        nominal = _nominal_duration(container, stream, tb, origin)
        step = round(1 / (fps * tb)) if fps > 0 else 0
        end: int | None = None
        try:
            _seek(container, stream, origin + math.ceil(nominal / tb) if nominal > 0 else 2**62)
            for packet in container.demux(stream):
                if packet.pts is not None and not packet.is_discard:
                    stop = packet.pts + (packet.duration or step)
                    end = stop if end is None else max(end, stop)
        except (av.FFmpegError, OverflowError):
            pass  # cannot seek or damaged end: keep the stated duration
    if end is not None:
        return max(nominal, _seconds(end - origin, tb))
    if nominal > 0 or fps <= 0:
        return nominal
    container, stream = _open(p)
    with container:
        try:
            n = sum(packet.size > 0 for packet in container.demux(stream))
        except av.FFmpegError:
            return 0.0
    return n / fps


def _uneven_timestamps(pts: list[int]) -> bool:
    """Are the sorted timestamps unevenly spaced (beyond one tick of rounding and 5 % jitter)?"""
    if len(pts) < 3:
        return False
    steps = np.diff(np.unique(np.asarray(pts, dtype=np.int64))).astype(float)
    median = float(np.median(steps))
    return bool(np.any(np.abs(steps - median) > max(1.0, _VFR_TOLERANCE * median)))


def _rates_disagree(stream: Any, frame_count: int) -> bool:
    """The average frame rate differs from the stream's base rate (not by a whole factor, as fields do)."""
    avg, base = stream.average_rate, stream.base_rate
    if not avg or not base or avg <= 0 or base <= 0 or frame_count < 50:
        return False
    ratio = float(base / avg)
    if ratio > 1.5 and abs(ratio - round(ratio)) < _RATE_TOLERANCE:  # interlaced: field rate = 2 x frame rate
        return False
    return abs(ratio - 1.0) > _RATE_TOLERANCE


def _quarter_turns(degrees: float) -> int:
    return round(degrees / 90.0) % 4 * 90


def _rotation_deg(frame: Any, stream: Any) -> int:
    """Clockwise rotation (deg) that shows ``frame`` upright: its display matrix, else the ``rotate`` tag."""
    ccw = frame.rotation  # display matrix angle, counter-clockwise; 0 without one
    if ccw:
        return _quarter_turns(-float(ccw))
    return _rotation_from_tag(stream.metadata.get("rotate"))


def _rotation_from_tag(tag: str | None) -> int:
    """The legacy ``rotate`` metadata tag (clockwise degrees, e.g. '90') as 0/90/180/270; 0 if absent/unreadable."""
    if not tag:
        return 0
    try:
        value = float(tag)
    except ValueError:
        return 0
    return _quarter_turns(value) if math.isfinite(value) else 0


def _upright(image: np.ndarray, rotation_deg: int) -> np.ndarray:
    """Rotate a stored frame clockwise by ``rotation_deg`` (0/90/180/270) so that it is upright."""
    if rotation_deg in _ROTATE:
        return cv2.rotate(image, _ROTATE[rotation_deg])
    return image


def _to_bgr(frame: Any, rotation_deg: int) -> np.ndarray:
    """FFmpeg (swscale) converts to BGR24, honouring the frame's colour range; then rotate upright."""
    image = _upright(frame.to_ndarray(format="bgr24"), rotation_deg)
    return image if image.flags.c_contiguous else np.ascontiguousarray(image)


def _set_threads(stream: Any, threads: bool) -> None:
    if threads:
        stream.thread_type = "AUTO"
    else:
        stream.thread_count = 1


def _decode(container: Any, stream: Any, p: Path, damage: list[str] | None = None) -> Iterator[tuple[Any, int]]:
    """Decoded frames with their timestamps (a frame without one gets the previous one plus a frame step).
    Damaged data raises an InputError, or, given a ``damage`` list, ends the frames and appends what happened."""
    prev: int | None = None
    step = 1
    rate = stream.average_rate or stream.guessed_rate
    if rate and stream.time_base:
        step = max(round(1 / (Fraction(rate) * Fraction(stream.time_base))), 1)
    try:
        for frame in container.decode(stream):
            pts = frame.pts if frame.pts is not None else (0 if prev is None else prev + step)
            prev = pts
            yield frame, pts
    except av.FFmpegError as exc:
        origin = _origin(container, stream)
        at = f" after {_seconds(prev - origin, Fraction(stream.time_base)):.3f} s" if prev is not None else ""
        if damage is None:
            raise InputError(f"video {p}: damaged data{at} ({_reason(exc)}); re-encode or re-copy the file") from None
        damage.append(f"damaged data{at} ({_reason(exc)})")


def _count_packets(container: Any, stream: Any, limit: int, *,
                   inclusive: bool) -> tuple[int, int | None, int | None]:
    """Demuxing from the start: (number of frames with pts < limit (<= if inclusive), the largest of their pts,
    the smallest pts of the other frames); None where there is no such frame.

    Stops a few packets past ``limit``: every packet has pts >= dts, and dts only grows in decoding order.
    """
    n, last, following = 0, None, None
    try:
        for packet in container.demux(stream):
            dts, pts = packet.dts, packet.pts
            if dts is not None and following is not None and dts > following:
                break  # no later packet can be counted or come earlier than `following`
            if pts is None or packet.is_discard:
                continue
            if pts < limit or (inclusive and pts == limit):
                n += 1
                last = pts if last is None else max(last, pts)
            else:
                following = pts if following is None else min(following, pts)
    except av.FFmpegError:
        pass  # damaged data: the decoding that follows reports it
    return n, last, following


def _seek(container: Any, stream: Any, pts: int) -> None:
    container.seek(pts, stream=stream, backward=True, any_frame=False)


def _decode_from(p: Path, container: Any, stream: Any, start_pts: int, seek: bool,
                 damage: list[str] | None = None) -> Iterator[tuple[Any, int, int]]:
    """(frame, pts, k) of the decoded frames with pts >= start_pts, k counting every frame decoded in this pass;
    with ``seek``, seek to the keyframe before start_pts first. Damage: see :func:`_decode`."""
    if seek:
        _seek(container, stream, start_pts)
    for k, (frame, pts) in enumerate(_decode(container, stream, p, damage)):
        if pts >= start_pts:
            yield frame, pts, k


def _generate(p: Path, container: Any, stream: Any, start_s: float, end_s: float | None, every: int,
              threads: bool) -> Iterator[VideoFrame]:
    try:
        _set_threads(stream, threads)
        tb, origin = _time_base(stream, p), _origin(container, stream)
        start_pts = origin + math.ceil(start_s / tb - _TICK_EPS)
        end_pts = None if end_s is None else origin + math.ceil(end_s / tb - _TICK_EPS)
        n_before, _, following = _count_packets(container, stream, start_pts, inclusive=False) if start_s > 0 \
            else (0, None, None)
        first = None
        damage: list[str] = []  # what ended the decoding early, if anything
        if n_before > 0:
            decoded = _decode_from(p, container, stream, start_pts, seek=True, damage=damage)
            first = next(decoded, None)
            if first is not None and first[1] != following:  # the seek landed after start_s: frames were missed
                n_before = 0
        if n_before == 0:  # nothing (with a timestamp) before start_s, or the seek overshot: from the beginning
            if start_s > 0:
                container.close()
                container, stream = _open(p)
                _set_threads(stream, threads)
            damage.clear()
            decoded = _decode_from(p, container, stream, start_pts, seek=False, damage=damage)
            first = next(decoded, None)
        stated = _nominal_duration(container, stream, tb, origin)
        if first is None:
            if stated > start_s or damage:
                _warn_short(p, start_s, None, stated, damage)
            return
        offset = n_before - first[2] if n_before else 0  # frame index = offset + k
        rotation = _rotation_deg(first[0], stream)
        item: tuple[Any, int, int] | None = first
        n = 0
        last = None
        while item is not None:
            frame, pts, k = item
            if end_pts is not None and pts >= end_pts:
                break
            if n % every == 0:
                yield VideoFrame(index=offset + k, time_s=_seconds(pts - origin, tb), image=_to_bgr(frame, rotation))
            n += 1
            last = pts
            item = next(decoded, None)
        if item is None and last is not None:  # the frames ran out: did the file end before its stated end?
            rate = stream.average_rate or stream.guessed_rate
            step = 1.0 / float(rate) if rate else 0.0
            end = _seconds(last - origin, tb) + step
            want = stated if end_s is None else min(end_s, stated)
            if want - end > max(1.5 * step, 0.1) or damage:
                _warn_short(p, start_s, end, want, damage)
    finally:
        container.close()


def _warn_short(p: Path, start_s: float, read_end_s: float | None, want_s: float, damage: list[str]) -> None:
    """A :class:`VideoReadWarning`: decoding from ``start_s`` ended at ``read_end_s`` (None: no frame), before
    ``want_s`` (s; the end asked for, or the file's stated duration), or on ``damage``."""
    got = f"no frame could be decoded from {start_s:g} s" if read_end_s is None else \
        f"frames end at {read_end_s:.2f} s"
    why = f": {damage[0]}" if damage else ""
    warnings.warn(VideoReadWarning(f"video {p}: {got} where {want_s:.2f} s was expected{why}; the file may be "
                                   "truncated or damaged"), stacklevel=3)


def _frame_at_or_before(p: Path, container: Any, stream: Any, target: int, *,
                        seek: bool) -> tuple[Any, int, int] | None:
    """(frame, pts, k) of the last decoded frame with pts <= target, k its position in this pass.

    After a seek, None if the first frame decoded is already later (the seek overshot); from the beginning of the
    file, the first frame if it is later than ``target`` (the time is before the first frame).
    """
    if seek:
        _seek(container, stream, target)
    prev = None
    for k, (frame, pts) in enumerate(_decode(container, stream, p)):
        if pts > target:
            if prev is None and not seek:
                return frame, pts, k
            break
        prev = (frame, pts, k)
    return prev
