"""A multi-camera demo city: several cameras along one road over the same SUMO traffic, their videos cut into files
named like a real camera's, and the ``cameras.csv`` of a batch (``trafficgeo batch plan``).

:func:`build_city` builds one demo world (:func:`trafficgeo.synth.world.build_world`) per camera with the same
seed and road (so SUMO drives the same vehicles: every camera's ``truth_tracks.csv`` holds the same vehicles at the
same positions), each in its own folder ``<camera_id>/``; cuts each camera's ``video.mp4`` into files of ``file_s``
seconds named ``<camera_id>_%Y-%m-%d_%H-%M-%S.mp4`` (the local start time, the batch's default name pattern) in
``videos/``, decoding and re-encoding frame-exactly (the files hold, in order, exactly the frames of the
original); and writes ``cameras.csv`` (camera truth JSON, lidar point cloud surface, lanes, counting lines, time
zone, background subtraction detector).
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass, field, replace
from datetime import datetime, timedelta
from fractions import Fraction
from pathlib import Path

import numpy as np

from trafficgeo.errors import InputError
from trafficgeo.io.atomic import atomic_open, atomic_path
from trafficgeo.synth.world import WorldOptions, build_world

#: the name of a video file (the batch's default pattern, :data:`trafficgeo.batch.manifest.DEFAULT_NAME_PATTERN`)
CITY_NAME_PATTERN = "{camera}_%Y-%m-%d_%H-%M-%S"


@dataclass(frozen=True)
class CityCamera:
    """Where a camera of the city stands: at ``station`` (m along the road), ``height_m`` above the road,
    ``setback_m`` beyond its right edge, turned by ``heading_offset_deg`` / ``tilt_offset_deg`` from the view the
    demo world gives it (looking at the road axis 25 m past the origin)."""

    camera_id: str
    station: float = -60.0
    height_m: float = 8.0
    setback_m: float = 5.0
    heading_offset_deg: float = 0.0
    tilt_offset_deg: float = 0.0


def _small_world() -> WorldOptions:
    return WorldOptions(seed=1, duration_s=20.0, fps=10.0, image_size=(640, 360), length_m=200.0, focal_px=576.0,
                        ortho_resolution=0.1, view_half_size=70.0)


@dataclass(frozen=True)
class CityOptions:
    """A city: ``cameras`` along the road of ``world`` (its camera placement fields are replaced per camera; its
    ``duration_s`` is each camera's video length), video files of ``file_s`` seconds, the first starting at
    ``start_local`` (local time in ``timezone``, an IANA name). The defaults are small and quick: 2 cameras, 640x360,
    10 fps, two 10 s files each."""

    cameras: tuple[CityCamera, ...] = (CityCamera("cam1", station=-60.0), CityCamera("cam2", station=60.0))
    file_s: float = 10.0
    start_local: datetime = datetime(2026, 5, 4, 7, 30, 0)
    timezone: str = "Europe/Berlin"
    world: WorldOptions = field(default_factory=_small_world)
    detector: str = "background"
    options: dict[str, object] = field(default_factory=lambda: {"interval_s": 10})

    def __post_init__(self) -> None:
        from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

        if not self.cameras:
            raise InputError("cameras: give at least one camera", parameters=("cameras",))
        ids = [c.camera_id for c in self.cameras]
        if len(set(ids)) != len(ids) or not all(i and all(ch.isalnum() or ch in "-_" for ch in i) for i in ids):
            raise InputError(f"cameras {ids}: ids must be unique and of letters, digits, - and _",
                             parameters=("cameras",))
        frames = self.file_s * self.world.fps
        if not (self.file_s >= 1 and float(self.file_s).is_integer() and abs(frames - round(frames)) < 1e-6):
            raise InputError(f"file_s {self.file_s}: must be whole seconds (>= 1) holding a whole number of frames "
                             f"at {self.world.fps:g} fps", parameters=("file_s",))
        try:
            ZoneInfo(self.timezone)
        except (ZoneInfoNotFoundError, ValueError):
            raise InputError(f"timezone {self.timezone!r}: use an IANA name such as Europe/Berlin",
                             parameters=("timezone",)) from None


def spread_cameras(n: int, length_m: float) -> tuple[CityCamera, ...]:
    """``n`` cameras spread evenly along a road of ``length_m`` (from station -min(60, 0.3 L) to +min(60, 0.3 L)),
    ids ``cam1``, ``cam2``, ..."""
    if n < 1:
        raise InputError(f"cameras {n}: must be at least 1", parameters=("cameras",))
    reach = min(60.0, 0.3 * length_m)
    stations = [-reach] if n == 1 else list(np.linspace(-reach, reach, n))
    return tuple(CityCamera(f"cam{k + 1}", station=float(s)) for k, s in enumerate(stations))


def camera_world(base: WorldOptions, cam: CityCamera) -> WorldOptions:
    """The world options of one camera: ``base`` with its placement, and its orientation turned by the offsets."""
    opts = replace(base, camera_station=cam.station, camera_height=cam.height_m, camera_setback=cam.setback_m)
    if cam.heading_offset_deg == 0 and cam.tilt_offset_deg == 0:
        return opts
    from trafficgeo.synth.gcp_scene import RoadSurface
    from trafficgeo.synth.orthophoto import RoadMarkings
    from trafficgeo.synth.world import world_camera

    road = RoadSurface(origin=np.array(opts.origin), azimuth_deg=opts.azimuth_deg, grade=opts.grade,
                       crossfall=opts.crossfall, crest_radius=opts.crest_radius, curve_radius=opts.curve_radius)
    markings = RoadMarkings(lanes_right=opts.lanes, lanes_left=opts.lanes if opts.two_way else 0,
                            lane_width=opts.lane_width)
    o = world_camera(road, markings, opts).orientation
    return replace(opts, heading_deg=(o.heading_deg + cam.heading_offset_deg) % 360.0,
                   tilt_deg=o.tilt_deg + cam.tilt_offset_deg)


def cut_video(video: Path, out_dir: Path, camera_id: str, start_local: datetime, file_s: float,
              creation_utc: datetime | None = None) -> list[Path]:
    """Cut ``video`` into files of ``file_s`` seconds (the last may be shorter) in ``out_dir``, named by
    :data:`CITY_NAME_PATTERN` from ``start_local``: every frame decoded and re-encoded (H.264, the same frame rate)
    in order, so that the files together hold exactly the frames of ``video``. ``creation_utc``: the first file's
    UTC start, written (advanced per file) as the container's ``creation_time`` tag."""
    import itertools

    import av

    out_dir.mkdir(parents=True, exist_ok=True)
    paths: list[Path] = []
    with av.open(str(video)) as src:
        stream = src.streams.video[0]
        rate = Fraction(stream.average_rate or stream.guessed_rate).limit_denominator(1001)
        per_file = round(file_s * float(rate))
        numbered = enumerate(src.decode(stream))
        for k, group in itertools.groupby(numbered, key=lambda item: item[0] // per_file):
            name = (start_local + timedelta(seconds=k * file_s)).strftime(
                CITY_NAME_PATTERN.replace("{camera}", camera_id)) + ".mp4"
            when = None if creation_utc is None else creation_utc + timedelta(seconds=k * file_s)
            _encode(out_dir / name, (frame for _, frame in group), rate, when)
            paths.append(out_dir / name)
    return paths


def _encode(path: Path, frames, rate: Fraction, creation_utc: datetime | None) -> None:
    """Encode decoded frames into an H.264 MP4 at ``path`` (atomically; the demo world's encoder settings)."""
    import av

    with atomic_path(path) as tmp, av.open(str(tmp), mode="w", format="mp4") as container:
        if creation_utc is not None:
            container.metadata["creation_time"] = creation_utc.strftime("%Y-%m-%dT%H:%M:%S.000000Z")
        stream = None
        for frame in frames:
            if stream is None:
                stream = container.add_stream("libx264", rate=rate)
                stream.width, stream.height, stream.pix_fmt = frame.width, frame.height, "yuv420p"
                stream.options = {"crf": "23", "preset": "superfast"}
            for packet in stream.encode(av.VideoFrame.from_ndarray(frame.to_ndarray(format="rgb24"),
                                                                   format="rgb24")):
                container.mux(packet)
        if stream is not None:
            for packet in stream.encode():
                container.mux(packet)


def build_city(out_dir: str | Path, opts: CityOptions | None = None, *, progress=None) -> Path:
    """Build the city into ``out_dir`` (see the module docstring); returns the path of its ``cameras.csv``.
    ``progress(camera_index, n_cameras)`` is called as each camera is done."""
    from zoneinfo import ZoneInfo

    opts = opts or CityOptions()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    start_utc = opts.start_local.replace(tzinfo=ZoneInfo(opts.timezone), fold=0).astimezone(ZoneInfo("UTC"))
    rows = []
    for k, cam in enumerate(opts.cameras):
        folder = out / cam.camera_id
        build_world(folder, camera_world(opts.world, cam))
        cut_video(folder / "video.mp4", out / "videos", cam.camera_id, opts.start_local, opts.file_s, start_utc)
        rows.append([cam.camera_id, f"{cam.camera_id}/camera_truth.json", f"{cam.camera_id}/cloud.laz",
                     opts.timezone, f"{cam.camera_id}/lanes.gpkg", f"{cam.camera_id}/count_lines.gpkg",
                     opts.detector, json.dumps(opts.options) if opts.options else ""])
        if progress is not None:
            progress(k + 1, len(opts.cameras))
    path = out / "cameras.csv"
    with atomic_open(path, "w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(["camera_id", "camera", "surface", "timezone", "lanes", "lines", "detector", "options"])
        w.writerows(rows)
    return path


def files_per_camera(opts: CityOptions) -> int:
    """How many video files each camera of the city gets."""
    frames = math.ceil(opts.world.duration_s * opts.world.fps - 1e-9)
    return math.ceil(frames / round(opts.file_s * opts.world.fps))


__all__ = ["CITY_NAME_PATTERN", "CityCamera", "CityOptions", "build_city", "camera_world", "cut_video",
           "files_per_camera", "spread_cameras"]
