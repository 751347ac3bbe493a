"""What ``process`` keeps in ``OUT/.checkpoint/`` to resume a run, and the lock on ``OUT``.

A checkpoint is data, never code: ``state.json`` (where to go on, and the parts written so far with their SHA-256)
and one ``partNNNNN.npz`` per stretch of video (read by ``numpy.load``, which refuses object arrays) holding, in
full float64 precision, the frame times and every detection and tracked box of that stretch. Everything is checked
before use (format, the run key, types, shapes, part files present and unchanged); a checkpoint that fails any check
is ignored, with the reason, and the run starts again.

The run key is a hash of every input that changes the detections or tracks: the video (path, size, modification
time and the SHA-256 of its first and last MiB), the camera, the surface's content, the region of interest, the
options, the detector model file's SHA-256 and the versions of trafficgeo, ``trackers`` and OpenCV. A changed input
means another run: its checkpoint is not resumed.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from trafficgeo.errors import InputError
from trafficgeo.io.atomic import atomic_open, write_json_atomic
from trafficgeo.io.json_text import loads_json

if TYPE_CHECKING:
    from trafficgeo.run.tracks import ImageTracks
    from trafficgeo.video.detections import DetectionFrames

CHECKPOINT_DIR = ".checkpoint"
STATE_FILE = "state.json"
FORMAT = "trafficgeo-process-checkpoint"
FORMAT_VERSION = 3
_PART_NAME = re.compile(r"part\d{5}\.npz")
_HEX64 = re.compile(r"[0-9a-f]{64}")
_PART_ARRAYS = {  # name: (dtype kind, ndim)
    "frame_index": ("i", 1), "frame_time": ("f", 1),
    "det_frame": ("i", 1), "det_box": ("f", 2), "det_score": ("f", 1), "det_class": ("U", 1),
    "trk_frame": ("i", 1), "trk_id": ("i", 1), "trk_box": ("f", 2), "trk_score": ("f", 1), "trk_class": ("U", 1),
}


# ------------------------------------------------------------------------------------------------ run key
def sha256_file(path: Path, *, head_tail: int | None = None) -> str:
    """SHA-256 of a file, or of its first and last ``head_tail`` bytes."""
    h = hashlib.sha256()
    with path.open("rb") as fh:
        if head_tail is None:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
        else:
            h.update(fh.read(head_tail))
            size = path.stat().st_size
            if size > head_tail:
                fh.seek(max(head_tail, size - head_tail))
                h.update(fh.read(head_tail))
    return h.hexdigest()


def _hash_value(h: Any, value: Any) -> None:
    if isinstance(value, np.ndarray):
        a = np.ascontiguousarray(value)
        h.update(f"array{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes() if a.dtype != object else repr(a.tolist()).encode())
    elif isinstance(value, bool | int | float | str | bytes | type(None) | np.generic):
        h.update(repr(value).encode())
    elif isinstance(value, tuple | list):
        h.update(b"[")
        for v in value:
            _hash_value(h, v)
        h.update(b"]")
    elif hasattr(value, "to_wkt"):  # a pyproj CRS
        h.update(value.to_wkt().encode())
    else:  # a helper object (an index, a cache): its type only
        h.update(type(value).__qualname__.encode())


def content_hash(obj: Any) -> str | None:
    """SHA-256 of an object's content (its type, ``describe()`` if it has one, and every array, number, string and
    CRS among its attributes), or None for None. Used for the surface, the camera and the region of interest."""
    if obj is None:
        return None
    h = hashlib.sha256(type(obj).__qualname__.encode())
    if callable(getattr(obj, "describe", None)):
        h.update(str(obj.describe()).encode())
    attrs = vars(obj) if hasattr(obj, "__dict__") else {}
    if isinstance(obj, np.ndarray):
        attrs = {"array": obj}
    for name in sorted(attrs):
        h.update(name.encode())
        _hash_value(h, attrs[name])
    return h.hexdigest()


def _package_version(name: str) -> str:
    try:
        return version(name)
    except PackageNotFoundError:
        return "?"


def run_key(video: Path, *, camera: Any, surface: Any, roi: np.ndarray | None, options: Mapping[str, Any],
            detector_file: Path | None) -> str:
    """The key of a run: equal keys mean the same detections and tracks (see the module docstring)."""
    import cv2

    from trafficgeo.version import __version__

    st = video.stat()
    doc = {"format": FORMAT_VERSION, "trafficgeo": __version__, "trackers": _package_version("trackers"),
           "opencv": cv2.__version__,
           "video": [str(video.resolve()), st.st_size, st.st_mtime_ns, sha256_file(video, head_tail=1 << 20)],
           "camera": content_hash(camera), "surface": content_hash(surface),
           "roi": content_hash(None if roi is None else np.asarray(roi)),
           "detector_file": None if detector_file is None else sha256_file(detector_file),
           "options": json.loads(json.dumps(dict(options), default=str, sort_keys=True))}
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:32]


# ------------------------------------------------------------------------------------------------ parts
@dataclass
class Part:
    """Frames, detections and tracked boxes of one stretch of video (arrays as in ``_PART_ARRAYS``; ``*_frame`` is
    the position of a row's frame in ``frame_index``)."""

    arrays: dict[str, np.ndarray]

    @property
    def n_frames(self) -> int:
        return int(self.arrays["frame_index"].size)

    def frame_slices(self, prefix: str) -> np.ndarray:
        """(n_frames + 1,) bounds: frame j's ``prefix`` rows are ``bounds[j]:bounds[j + 1]``."""
        return np.searchsorted(self.arrays[f"{prefix}_frame"], np.arange(self.n_frames + 1), side="left")


@dataclass
class PartBuffer:
    """Rows gathered frame by frame until the next checkpoint."""

    frames: list[tuple[int, float]] = field(default_factory=list)
    det: list[tuple[int, np.ndarray, np.ndarray, np.ndarray]] = field(default_factory=list)
    trk: list[tuple[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = field(default_factory=list)

    def add(self, index: int, time_s: float, dets: Any, tracked: Any) -> None:
        j = len(self.frames)
        self.frames.append((int(index), float(time_s)))
        if len(dets):
            self.det.append((j, dets.boxes, dets.scores, dets.classes))
        if len(tracked):
            self.trk.append((j, tracked.track_ids, tracked.boxes, tracked.scores, tracked.classes))

    def to_part(self) -> Part:
        def cat(items: list, k: int, shape: tuple, dtype: Any) -> np.ndarray:
            if not items:
                return np.zeros(shape, dtype=dtype)
            return np.concatenate([np.asarray(it[k], dtype=dtype).reshape((-1, *shape[1:])) for it in items])

        def rows(items: list) -> np.ndarray:
            return np.concatenate([np.full(len(it[1]), it[0], dtype=np.int64) for it in items]) if items else \
                np.zeros(0, dtype=np.int64)

        a = {"frame_index": np.asarray([f[0] for f in self.frames], dtype=np.int64),
             "frame_time": np.asarray([f[1] for f in self.frames], dtype=np.float64),
             "det_frame": rows(self.det), "det_box": cat(self.det, 1, (0, 4), np.float64),
             "det_score": cat(self.det, 2, (0,), np.float64),
             "det_class": np.asarray([str(c) for it in self.det for c in it[3]], dtype=str).reshape(-1),
             "trk_frame": rows(self.trk), "trk_id": cat(self.trk, 1, (0,), np.int64),
             "trk_box": cat(self.trk, 2, (0, 4), np.float64), "trk_score": cat(self.trk, 3, (0,), np.float64),
             "trk_class": np.asarray([str(c) for it in self.trk for c in it[4]], dtype=str).reshape(-1)}
        for name in ("det_class", "trk_class"):
            if a[name].size == 0:
                a[name] = np.zeros(0, dtype="<U1")
        return Part(a)


def write_part(folder: Path, number: int, part: Part) -> dict[str, Any]:
    """Write a part atomically; returns its entry for ``state.json``."""
    name = f"part{number:05d}.npz"
    with atomic_open(folder / name, "wb") as fh:
        np.savez_compressed(fh, **part.arrays)
    return {"name": name, "sha256": sha256_file(folder / name), "frames": part.n_frames}


def _check_part(a: dict[str, np.ndarray]) -> str | None:
    """Why a part's arrays are not a valid part, or None."""
    for name, (kind, ndim) in _PART_ARRAYS.items():
        if a[name].dtype.kind != kind or a[name].ndim != ndim:
            return f"array {name} has dtype {a[name].dtype} and {a[name].ndim} dimension(s)"
    n_f = a["frame_index"].size
    if a["frame_time"].size != n_f or not np.all(np.isfinite(a["frame_time"])):
        return "frame times do not match the frames"
    for p, cols in (("det", ("det_frame", "det_box", "det_score", "det_class")),
                    ("trk", ("trk_frame", "trk_id", "trk_box", "trk_score", "trk_class"))):
        n = a[f"{p}_frame"].size
        if any(a[c].shape[0] != n for c in cols) or a[f"{p}_box"].shape[1:] != (4,):
            return f"the {p} arrays differ in length"
        fr = a[f"{p}_frame"]
        if n and (fr.min() < 0 or fr.max() >= n_f or np.any(np.diff(fr) < 0)):
            return f"{p} rows name frames that the part does not hold"
    return None


def read_part(folder: Path, entry: Mapping[str, Any]) -> Part:
    """Read and check a part named in ``state.json``; :class:`ValueError` says what is wrong."""
    path = folder / entry["name"]
    if not path.is_file():
        raise ValueError(f"{entry['name']} is missing")
    if sha256_file(path) != entry["sha256"]:
        raise ValueError(f"{entry['name']} has changed since it was written")
    try:
        with np.load(path) as z:  # numbers and strings only: object arrays are refused
            if set(z.files) != set(_PART_ARRAYS):
                raise ValueError(f"{entry['name']} holds arrays {sorted(z.files)}")
            a = {k: z[k] for k in _PART_ARRAYS}
    except (OSError, EOFError, ValueError) as exc:
        raise ValueError(f"{entry['name']} cannot be read ({exc})") from None
    why = _check_part(a)
    if why is not None or a["frame_index"].size != entry["frames"]:
        raise ValueError(f"{entry['name']}: {why or 'frame count differs from state.json'}")
    return Part(a)


# ------------------------------------------------------------------------------------------------ state
@dataclass
class Checkpoint:
    """Where an interrupted run goes on: the segment ``segment`` (0-based) whose first frame is ``next_frame`` at
    ``next_time_s`` (s of video), after ``frames_done`` frames in ``parts``; ``complete`` once the whole time range
    is done (only collecting the parts and the analysis remain)."""

    key: str
    segment: int = 0
    next_time_s: float = 0.0
    next_frame: int = -1  # -1: the first frame of the range (not decoded yet)
    frames_done: int = 0
    complete: bool = False
    parts: list[dict[str, Any]] = field(default_factory=list)
    schedule: dict[str, Any] | None = None  # the tile schedule used ("all"/"sparse") and its state's file entry


def save_checkpoint(folder: Path, state: Checkpoint) -> None:
    """Write ``state.json`` atomically (after the parts it names)."""
    doc = {"format": FORMAT, "version": FORMAT_VERSION, "key": state.key, "segment": state.segment,
           "next_time_s": state.next_time_s, "next_frame": state.next_frame, "frames_done": state.frames_done,
           "complete": state.complete, "parts": state.parts, "schedule": state.schedule}
    write_json_atomic(folder / STATE_FILE, doc)


SCHEDULE_FILE = "schedule.npz"  # the tile schedule's and the tiled detector's memory at the last checkpoint


def write_schedule_state(folder: Path, arrays: Mapping[str, np.ndarray]) -> dict[str, Any]:
    """Write the schedule's state (numbers and strings only) atomically; returns its entry for ``state.json``."""
    with atomic_open(folder / SCHEDULE_FILE, "wb") as fh:
        np.savez_compressed(fh, **arrays)
    return {"used": "sparse", "name": SCHEDULE_FILE, "sha256": sha256_file(folder / SCHEDULE_FILE)}


def read_schedule_state(folder: Path, entry: Mapping[str, Any]) -> dict[str, np.ndarray]:
    """The arrays of the schedule state named in ``state.json``; :class:`ValueError` says what is wrong."""
    path = folder / SCHEDULE_FILE
    if not path.is_file() or sha256_file(path) != entry.get("sha256"):
        raise ValueError(f"{SCHEDULE_FILE} is missing or has changed since it was written")
    try:
        with np.load(path) as z:  # numbers and strings only: object arrays are refused
            return {k: z[k] for k in z.files}
    except (OSError, EOFError, ValueError) as exc:
        raise ValueError(f"{SCHEDULE_FILE} cannot be read ({exc})") from None


def _int(doc: Mapping[str, Any], name: str, least: int) -> int:
    v = doc.get(name)
    if isinstance(v, bool) or not isinstance(v, int) or v < least:
        raise ValueError(f"{name} is {v!r}, not a whole number >= {least}")
    return v


def load_checkpoint(folder: Path, key: str) -> Checkpoint:
    """Read and check ``state.json`` and the parts it names; :class:`ValueError` says why it cannot be resumed."""
    path = folder / STATE_FILE
    if not path.is_file():
        raise ValueError(f"it has no {STATE_FILE} (a checkpoint of another program or an older version)")
    try:
        if path.stat().st_size > 64 << 20:
            raise ValueError(f"{STATE_FILE} is too large")
        doc = loads_json(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{STATE_FILE} cannot be read ({exc})") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT or doc.get("version") != FORMAT_VERSION:
        raise ValueError(f"{STATE_FILE} is not a checkpoint of this version of trafficgeo")
    if doc.get("key") != key:
        raise ValueError("it belongs to a run with other inputs or options")
    t = doc.get("next_time_s")
    if isinstance(t, bool) or not isinstance(t, int | float) or not math.isfinite(t) or t < 0:
        raise ValueError(f"next_time_s is {t!r}")
    parts = doc.get("parts")
    if not isinstance(parts, list):
        raise ValueError("parts is not a list")
    for k, e in enumerate(parts):
        ok = (isinstance(e, dict) and set(e) == {"name", "sha256", "frames"} and e["name"] == f"part{k:05d}.npz"
              and isinstance(e["sha256"], str) and _HEX64.fullmatch(e["sha256"]) is not None
              and isinstance(e["frames"], int) and not isinstance(e["frames"], bool) and e["frames"] >= 0)
        if not ok:
            raise ValueError(f"parts[{k}] is not a part entry")
        if not (folder / e["name"]).is_file():
            raise ValueError(f"{e['name']} is missing")
    if not isinstance(doc.get("complete"), bool):
        raise ValueError("complete is not true or false")
    schedule = doc.get("schedule")
    if schedule is not None and not _schedule_entry(schedule, bool(parts)):
        raise ValueError("schedule is not a tile schedule entry")
    return Checkpoint(key=key, segment=_int(doc, "segment", 0), next_time_s=float(t),
                      next_frame=_int(doc, "next_frame", -1), frames_done=_int(doc, "frames_done", 0),
                      complete=doc["complete"], parts=parts, schedule=schedule)


def _schedule_entry(entry: object, has_parts: bool) -> bool:
    """Whether ``entry`` is a tile schedule entry of ``state.json``: ``{"used": "all"}``, or ``{"used":
    "sparse"}`` with the name and SHA-256 of its state (which a run without parts has not written yet)."""
    if not isinstance(entry, dict) or entry.get("used") not in ("all", "sparse"):
        return False
    if set(entry) == {"used"}:
        return entry["used"] == "all" or not has_parts
    return (entry["used"] == "sparse" and set(entry) == {"used", "name", "sha256"} and entry["name"] == SCHEDULE_FILE
            and isinstance(entry["sha256"], str) and _HEX64.fullmatch(entry["sha256"]) is not None)


def read_detections(out_dir: str | os.PathLike[str]) -> DetectionFrames:
    """The detections over time of a finished run in ``out_dir``, read from its checkpoint (a run whose detection
    did not finish, or whose checkpoint was removed when the run completed, is refused)."""
    ck = Path(out_dir) / CHECKPOINT_DIR
    try:
        state = loads_json((ck / STATE_FILE).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        state = None
    if not isinstance(state, dict) or not state.get("complete") or not isinstance(state.get("parts"), list):
        raise InputError(f"{ck}: no finished detection run here; run the detection again")
    return joined_parts([read_part(ck, e) for e in state["parts"]])[0]


def joined_parts(parts: list[Part]) -> tuple[DetectionFrames, ImageTracks]:
    """The detections over time and the tracks of ``parts``, in order, at full precision."""
    from trafficgeo.video.detections import DetectionFrames, Detections
    from trafficgeo.video.track import tracks_of

    arrays = [p.arrays for p in parts]
    offsets = np.cumsum([0] + [a["frame_index"].size for a in arrays])
    cat = np.concatenate

    def joined(prefix: str) -> tuple[np.ndarray, Detections]:
        row = cat([np.zeros(0, dtype=np.int64)] + [a[f"{prefix}_frame"] + o for a, o in zip(arrays, offsets,
                                                                                                  strict=False)])
        return row.astype(np.int64), Detections(
            boxes=cat([np.zeros((0, 4))] + [a[f"{prefix}_box"].reshape(-1, 4) for a in arrays]),
            scores=cat([np.zeros(0)] + [a[f"{prefix}_score"] for a in arrays]),
            classes=cat([np.zeros(0, dtype=object)] + [a[f"{prefix}_class"].astype(str).astype(object)
                                                          for a in arrays]),
            track_ids=cat([np.zeros(0, dtype=np.int64)] + [a["trk_id"] for a in arrays]) if prefix == "trk" else None)

    index = cat([np.zeros(0, dtype=np.int64)] + [a["frame_index"] for a in arrays]).astype(np.int64)
    times = cat([np.zeros(0)] + [a["frame_time"] for a in arrays]).astype(np.float64)
    det_row, det = joined("det")
    trk_row, trk = joined("trk")
    frames = DetectionFrames(frame_index=index, time_s=times, row=det_row, boxes=det.boxes, scores=det.scores,
                             classes=det.classes)
    return frames, tracks_of(index, times, trk_row, trk)
