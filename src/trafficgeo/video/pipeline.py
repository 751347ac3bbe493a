"""``process``: video -> detections -> tracks -> traffic data, streaming, with checkpoints to resume from.

Frames are decoded one at a time (:func:`trafficgeo.video.reader.iter_frames`, real timestamps), detected
(:mod:`trafficgeo.video.detect`) and tracked (:mod:`trafficgeo.video.track`). Detections and track boxes are
buffered and flushed to ``OUT/.checkpoint/`` every ``checkpoint_s`` seconds of video together with the tracker's
state, so memory stays bounded and an interrupted run (Ctrl-C, a crash, a reboot) resumes where the last
checkpoint left off: the background model is re-learnt on the video just before it (as it is before the start of
a later time chunk) and the tracker is restored exactly. At the end the parts become ``detections.csv`` and
``tracks.csv``, ``analyze`` runs on the tracks (:mod:`trafficgeo.traffic.analyze`) and the checkpoint is removed.
Every output is written atomically.

Time chunks: ``start_s``/``end_s`` process one part of a video into its own folder; :func:`stitch_tracks` joins
the tracks of chunks that overlap by a few seconds (the same vehicles seen in both are matched by box overlap).
"""

from __future__ import annotations

import hashlib
import json
import pickle
import shutil
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from trafficgeo.camera.model import Camera
from trafficgeo.errors import InputError
from trafficgeo.geo.mapping import Surface
from trafficgeo.io.atomic import atomic_path, write_csv_atomic, write_json_atomic
from trafficgeo.video.detect import box_iou, check_detector
from trafficgeo.video.detector_names import is_background
from trafficgeo.video.track import TrackerOptions, VehicleTracker

CHECKPOINT_DIR = ".checkpoint"
DETECTION_COLUMNS = ["frame", "time", "x1", "y1", "x2", "y2", "score", "class"]
TRACK_COLUMNS = ["frame", "time", "track_id", "x1", "y1", "x2", "y2", "score", "class"]
PRIME_S = 4.0  # s of video the background detector learns on before detecting (see detect_and_track)


@dataclass(frozen=True)
class ProcessOptions:
    """What ``process`` does with a video (times in seconds of video)."""

    detector: str = "background"  # a name of detector_names.DETECTOR_NAMES, or the path of an ONNX model
    start_s: float = 0.0
    end_s: float | None = None
    every: int = 1  # use every n-th frame
    checkpoint_s: float = 30.0
    tracker: TrackerOptions = field(default_factory=TrackerOptions)

    def __post_init__(self) -> None:
        check_detector(self.detector)  # a bad name or model fails here, before anything is written
        if not (self.start_s >= 0 and (self.end_s is None or self.end_s > self.start_s)):
            raise InputError(f"--start {self.start_s} / --end {self.end_s}: need 0 <= start < end (seconds)")
        if not (isinstance(self.every, int) and self.every >= 1):
            raise InputError(f"--every {self.every}: must be a whole number >= 1")
        if not self.checkpoint_s > 0:
            raise InputError(f"--checkpoint {self.checkpoint_s}: must be a positive number of seconds")


@dataclass
class _State:
    """What a checkpoint holds: where to go on, the tracker, and the parts written so far."""

    key: str
    next_time_s: float
    frames_done: int
    parts: list[str]
    tracker: VehicleTracker


def _run_key(video: Path, camera: Camera | None, options: ProcessOptions) -> str:
    st = video.stat()
    doc = {"video": str(video.resolve()), "size": st.st_size, "mtime": st.st_mtime_ns,
           "camera": None if camera is None else camera.K.tolist() + camera.R.tolist() + camera.position.tolist(),
           "options": json.loads(json.dumps(asdict(options), default=str))}
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:16]


def _load_state(folder: Path, key: str) -> _State | None:
    path = folder / "state.pkl"
    if not path.is_file():
        return None
    try:
        with path.open("rb") as fh:
            state = pickle.load(fh)
    except Exception:  # a damaged or foreign checkpoint: start again
        return None
    return state if isinstance(state, _State) and state.key == key else None


def _save_state(folder: Path, state: _State) -> None:
    with atomic_path(folder / "state.pkl") as tmp, open(tmp, "wb") as fh:
        pickle.dump(state, fh)


def _flush(folder: Path, state: _State, det_rows: list, trk_rows: list) -> None:
    """Write the buffered rows as a new part, then the state that names it (so a crash in between loses nothing
    that the state claims)."""
    name = f"part{len(state.parts):05d}"
    for suffix, rows, cols in (("det", det_rows, DETECTION_COLUMNS), ("trk", trk_rows, TRACK_COLUMNS)):
        table = pd.DataFrame(rows, columns=cols)
        write_csv_atomic(folder / f"{name}.{suffix}.csv", table, float_format="%.3f")
    state.parts.append(name)
    _save_state(folder, state)
    det_rows.clear()
    trk_rows.clear()


def _collect(folder: Path, parts: list[str], suffix: str, columns: list[str]) -> pd.DataFrame:
    tables = [pd.read_csv(folder / f"{p}.{suffix}.csv", dtype={"class": str}, keep_default_na=False,
                          na_values=[""]) for p in parts]
    tables = [t for t in tables if len(t)]
    out = pd.concat(tables, ignore_index=True) if tables else pd.DataFrame(columns=columns)
    if "class" in out.columns:
        out["class"] = out["class"].fillna("")
    return out


def detect_and_track(video: str | Path, camera: Camera | None, surface: Surface | None, out_dir: str | Path,
                     options: ProcessOptions | None = None, *, roi: np.ndarray | None = None,
                     restart: bool = False,
                     progress: Callable[[int, int, float], None] | None = None) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Decode, detect and track (with checkpoints); returns the detections and track tables (also written as
    ``detections.csv`` and ``tracks.csv`` in ``out_dir``). ``progress(frames_done, frames_total, video_time_s)``
    is called per frame. Without a ``camera`` (and ``surface``) the detector has no size filter in metres."""
    from trafficgeo.video.detect import make_detector
    from trafficgeo.video.reader import iter_frames, video_info

    opts = options or ProcessOptions()
    video = Path(video)
    info = video_info(video)
    if camera is not None and (info.width, info.height) != tuple(camera.image_size):
        raise InputError(f"{video}: frames are {info.width}x{info.height} but the camera was calibrated for "
                         f"{camera.image_size[0]}x{camera.image_size[1]}; calibrate on a frame of this video "
                         "(trafficgeo frame)")
    end_s = min(opts.end_s, info.duration_s) if opts.end_s is not None else info.duration_s
    if opts.start_s >= end_s:
        raise InputError(f"--start {opts.start_s:g} s is past the end of {video} ({info.duration_s:.2f} s)")
    out = Path(out_dir)
    ck = out / CHECKPOINT_DIR
    key = _run_key(video, camera, opts)
    state = None if restart else _load_state(ck, key)
    if state is None:
        if ck.exists():
            shutil.rmtree(ck)
        ck.mkdir(parents=True)
        fps = info.fps / opts.every
        state = _State(key, opts.start_s, 0, [], VehicleTracker(fps, opts.tracker))
    total = max(1, round((end_s - opts.start_s) * info.fps / opts.every))
    detector = make_detector(opts.detector, camera=camera if surface is not None else None, surface=surface, roi=roi)
    if is_background(opts.detector):
        # Learn the background before detecting, so that vehicles are found from the first frame on.
        t0 = state.next_time_s
        if t0 - opts.start_s < PRIME_S:
            # A run learns on its first PRIME_S seconds (or the video before them, if there is that much), then
            # processes them from their beginning; a run resumed within them repeats that exactly.
            if opts.start_s >= PRIME_S:
                windows = [(opts.start_s - PRIME_S, opts.start_s)]
            else:
                windows = [(opts.start_s, min(opts.start_s + PRIME_S, end_s))]
            windows.append((opts.start_s, t0))
        else:  # resumed later on: learn on the video just before the checkpoint
            windows = [(t0 - PRIME_S, t0)]
        for lo, hi in windows:
            if hi > lo:
                for frame in iter_frames(video, start_s=lo, end_s=hi, every=opts.every):
                    if frame.time_s < hi - 1e-6:
                        detector.detect(frame.image, frame.time_s)
    det_rows: list = []
    trk_rows: list = []
    next_flush = state.next_time_s + opts.checkpoint_s
    done = state.frames_done
    for frame in iter_frames(video, start_s=state.next_time_s, end_s=end_s, every=opts.every):
        if frame.time_s < state.next_time_s - 1e-6:
            continue
        if frame.time_s >= next_flush:
            state.next_time_s, state.frames_done = frame.time_s, done
            _flush(ck, state, det_rows, trk_rows)
            next_flush = frame.time_s + opts.checkpoint_s
        dets = detector.detect(frame.image, frame.time_s)
        tracked = state.tracker.update(dets, frame.time_s if info.variable_frame_rate else None)
        t = round(frame.time_s, 6)
        det_rows += [(frame.index, t, *b, s, c) for b, s, c in zip(dets.boxes, dets.scores, dets.classes,
                                                                   strict=True)]
        trk_rows += [(frame.index, t, int(i), *b, s, c) for i, b, s, c in
                     zip(tracked.ids, tracked.boxes, tracked.scores, tracked.classes, strict=True)]
        done += 1
        if progress is not None:
            progress(done, total, frame.time_s)
    state.next_time_s, state.frames_done = end_s, done
    _flush(ck, state, det_rows, trk_rows)
    detections = _collect(ck, state.parts, "det", DETECTION_COLUMNS)
    tracks = _collect(ck, state.parts, "trk", TRACK_COLUMNS)
    for name, table in (("detections.csv", detections), ("tracks.csv", tracks)):
        write_csv_atomic(out / name, table, float_format="%.3f")
    return detections, tracks


def finish_run(out_dir: str | Path) -> None:
    """Remove the checkpoint of a completed run."""
    ck = Path(out_dir) / CHECKPOINT_DIR
    if ck.exists():
        shutil.rmtree(ck)


def write_run_info(out_dir: str | Path, *, video: str, camera: str, options: ProcessOptions, seconds: float,
                   detections: int, track_rows: int, read: dict | None = None) -> None:
    """``process.json``: what was processed (``video``, ``camera``: paths as given, or relative to ``out_dir``), how
    (the detector and time range asked for in ``options``), what was read (``read``: ``start_s``/``end_s`` of the
    frames decoded (s, the end of the last frame), ``frames``, and ``complete``: false when the video ended before
    the asked end, e.g. a truncated file), and how fast (``seconds`` of wall clock)."""
    doc = {"video": video, "camera": camera,
           "options": {"detector": options.detector, "start_s": options.start_s, "end_s": options.end_s,
                       "every": options.every},
           "read": read, "seconds": seconds, "detections": detections, "track_rows": track_rows}
    write_json_atomic(Path(out_dir) / "process.json", doc)


# ------------------------------------------------------------------------------------------------ chunks
def stitch_tracks(chunks: list[pd.DataFrame], *, min_iou: float = 0.5) -> pd.DataFrame:
    """Join the track tables of consecutive, overlapping time chunks of one video into one table.

    Chunk ``k``'s ids become ``c<k>:<id>``. In the time both chunks cover, a track of chunk ``k+1`` whose boxes
    overlap a track of chunk ``k`` with a mean IoU of at least ``min_iou`` over their common frames is the same
    vehicle: it takes the earlier id. Each chunk keeps the frames up to the middle of the overlap, so no frame
    is counted twice.
    """
    if not chunks:
        raise InputError("no chunks to stitch; give the --out folders of 'trafficgeo process --start/--end'")
    out = []
    names = {}
    prev = None
    for k, table in enumerate(chunks):
        t = table.copy()
        t["track_id"] = [f"c{k}:{i}" for i in t["track_id"]]
        if prev is not None and len(prev) and len(t):
            lo, hi = t["time"].min(), prev["time"].max()
            if hi > lo:  # overlap
                a = prev[prev["time"] >= lo]
                b = t[t["time"] <= hi]
                m = a.merge(b, on="frame", suffixes=("_a", "_b"))
                if len(m):
                    m["iou"] = box_iou(m[["x1_a", "y1_a", "x2_a", "y2_a"]].to_numpy(),
                                        m[["x1_b", "y1_b", "x2_b", "y2_b"]].to_numpy())
                    score = m.groupby(["track_id_b", "track_id_a"])["iou"].mean().reset_index()
                    score = score[score["iou"] >= min_iou].sort_values("iou", ascending=False)
                    used_a, used_b = set(), set()
                    for _, r in score.iterrows():
                        if r["track_id_a"] not in used_a and r["track_id_b"] not in used_b:
                            names[r["track_id_b"]] = names.get(r["track_id_a"], r["track_id_a"])
                            used_a.add(r["track_id_a"])
                            used_b.add(r["track_id_b"])
                mid = 0.5 * (lo + hi)
                out[-1] = out[-1][out[-1]["time"] < mid]
                t = t[t["time"] >= mid]
        t["track_id"] = [names.get(i, i) for i in t["track_id"]]
        out.append(t)
        prev = table.assign(track_id=[f"c{k}:{i}" for i in table["track_id"]])
    return pd.concat(out, ignore_index=True).sort_values(["track_id", "time"], kind="stable").reset_index(drop=True)
