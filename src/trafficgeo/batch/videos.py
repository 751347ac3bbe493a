"""Video files of a batch: found by globs, dated by their names (:mod:`trafficgeo.batch.names`) or the container's
``creation_time`` tag, probed (length, frame rate, fingerprint), and kept per camera in time order without overlaps.
A file that cannot be used is a problem line, never an exception."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from datetime import UTC, datetime, timedelta
from pathlib import Path

from trafficgeo.batch.model import CameraEntry, VideoFile, utc_text
from trafficgeo.batch.names import DEFAULT_NAME_PATTERN, compile_pattern, local_to_utc
from trafficgeo.errors import InputError

_FINGERPRINT_BYTES = 1 << 20  # head and tail (bytes) of a video hashed for its fingerprint


def fingerprint(path: Path, size_bytes: int) -> str:
    """SHA-256 over a file's size and the hash of its first and last MiB (cheap, changes with the content)."""
    import hashlib

    from trafficgeo.video.checkpoint import sha256_file

    head_tail = sha256_file(path, head_tail=_FINGERPRINT_BYTES)
    return hashlib.sha256(f"{size_bytes}:{head_tail}".encode()).hexdigest()


def _creation_time(path: Path) -> datetime | None:
    """The container's ``creation_time`` tag (UTC), or None."""
    import av

    try:
        with av.open(str(path)) as container:
            tags = dict(container.metadata)
            for s in container.streams.video:
                tags.setdefault("creation_time", s.metadata.get("creation_time", ""))
    except (av.FFmpegError, OSError):
        return None
    text = str(tags.get("creation_time", "")).strip()
    if not text:
        return None
    try:
        t = datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError:
        return None
    return (t if t.tzinfo else t.replace(tzinfo=UTC)).astimezone(UTC)


def probe_video(path: Path, camera_id: str, start: datetime) -> VideoFile:
    """The VideoFile of ``path`` starting at ``start`` (UTC): length and rate from the stream, size, fingerprint;
    an InputError for an unreadable file."""
    from trafficgeo.video.reader import video_info

    info = video_info(path)
    if not (info.duration_s > 0 and info.fps > 0):
        raise InputError(f"video {path}: no duration or frame rate ({info.describe()})")
    size = path.stat().st_size
    return VideoFile(camera_id, path, start, float(info.duration_s), float(info.fps), size, fingerprint(path, size))


def find_videos(cameras: Mapping[str, CameraEntry], videos: Sequence[str], *,
                name_pattern: str = DEFAULT_NAME_PATTERN) -> tuple[list[VideoFile], list[str]]:
    """The video files the globs ``videos`` find (relative globs from the working folder; ``{camera}`` in a glob
    stands for each camera id and tells a file's camera), dated and probed, per camera in time order without
    overlaps; and the problems (one line each)."""
    import glob

    pattern = compile_pattern(name_pattern)
    ids = tuple(cameras)
    found: dict[Path, str | None] = {}
    problems: list[str] = []
    for g in videos:
        per_camera = [(g.replace("{camera}", cid), cid) for cid in ids] if "{camera}" in g else [(g, None)]
        n = 0
        for text, cid in per_camera:
            for name in sorted(glob.glob(os.path.expanduser(text), recursive=True)):
                p = Path(name).resolve()
                if p.is_file():
                    found.setdefault(p, cid)
                    n += 1
        if n == 0:
            problems.append(f"{g}: no video file matches this glob")
    files: list[VideoFile] = []
    for p, hint in found.items():
        example = pattern.example(hint or ids[0]) + p.suffix
        try:
            parsed = pattern.parse(p.stem, ids)
        except ValueError as exc:
            problems.append(f"{p}: its name does not give a valid time ({exc}); rename it like {example}")
            continue
        if parsed is not None:
            cid, local = parsed
            if hint is not None and cid not in (None, hint):
                problems.append(f"{p}: named for camera {cid} but found by the glob of camera {hint}; move or "
                                "rename it")
                continue
            cid = cid or hint
            if cid is None:
                problems.append(f"{p}: cannot tell which camera: name it like {example} or put {{camera}} in "
                                "its glob")
                continue
            start = local_to_utc(local, cameras[cid].timezone)
        else:
            created = _creation_time(p)
            if created is None:
                problems.append(f"{p}: no start time: the name does not match {name_pattern!r} and the file has no "
                                f"creation_time tag; rename it like {example}")
                continue
            if hint is None:
                problems.append(f"{p}: cannot tell which camera: name it like {example} or put {{camera}} in "
                                "its glob")
                continue
            cid, start = hint, created
        try:
            files.append(probe_video(p, cid, start))
        except InputError as exc:
            problems.append(f"{p}: unreadable: {str(exc).removeprefix(f'video {p}: ')}")
        except OSError as exc:
            problems.append(f"{p}: unreadable: {exc.strerror or exc}")
    return _without_overlaps(files, ids, problems), problems


def _without_overlaps(files: list[VideoFile], ids: Sequence[str], problems: list[str]) -> list[VideoFile]:
    """Per camera in time order, dropping (with a problem line) each file that starts before the kept one before
    it ends (half a frame of slack)."""
    out: list[VideoFile] = []
    for cid in ids:
        last: VideoFile | None = None
        for v in sorted((f for f in files if f.camera_id == cid), key=lambda f: (f.start_utc, str(f.path))):
            slack = timedelta(seconds=0.5 / v.fps)
            if last is not None and v.start_utc < last.end_utc - slack:
                problems.append(f"{v.path}: overlaps {last.path.name} of camera {cid} ({utc_text(v.start_utc)} is "
                                f"before its end {utc_text(last.end_utc)}); skipped")
                continue
            out.append(v)
            last = v
    return out
