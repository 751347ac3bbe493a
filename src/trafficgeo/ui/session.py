"""The state of a GCP-picking session, in plain Python: pairs, their ground heights, the autosave, files, and the
cached live calibration (computed by :mod:`trafficgeo.ui.live`; a session is opened by :mod:`trafficgeo.ui.startup`).

A *pair* joins a frame pixel ``(u, v)`` (camera convention: ``(0, 0)`` = centre of the top-left pixel) and a
world point ``(x, y, z)`` picked on the orthophoto at raster position ``(col, row)`` (corner convention), converted
through the orthophoto's affine transform in float64. Z comes from the ground (DEM or lidar ground points) unless
the user types it (``z_auto`` False). Every change bumps :attr:`Session.revision` and is written at once
(atomically) to the autosave CSV; the calibration is recomputed on demand for the current revision with the
project's calibration (:func:`trafficgeo.calibration.run_calibration`) and cached.

File names given through the session (save/load) are relative to the working folder and may not leave it.
Errors a user can fix raise :class:`SessionError` (``status_code`` is the HTTP status the web server answers with)
or :class:`~trafficgeo.errors.InputError` (bad files; HTTP 400).
"""

from __future__ import annotations

import logging
import math
import threading
from dataclasses import dataclass, replace
from pathlib import Path, PurePosixPath, PureWindowsPath
from typing import Any

import numpy as np

from trafficgeo.calibration import CalibrationOptions, GCPTable, read_gcps
from trafficgeo.calibration.camera_record import calibrated_camera
from trafficgeo.calibration.gcp_table import ROLE_CHECK, ROLE_CONTROL, ROLES
from trafficgeo.calibration.pipeline import required_points
from trafficgeo.calibration.run import CalibrationRun
from trafficgeo.crs import crs_label
from trafficgeo.errors import InputError, OutputError
from trafficgeo.io.atomic import to_json_safe
from trafficgeo.ui.inputs import FrameImage, Ground, GroundSample, Orthophoto
from trafficgeo.ui.live import calibration_answer, draw_overlays

log = logging.getLogger(__name__)

MAX_PAIRS = 1000
MAX_ID_LENGTH = 40
MAX_ABS_Z = 1e5
MAX_SIGMA_PX = 1000.0
MAX_NAME_LENGTH = 255
CSV_SUFFIXES = (".csv",)
CAMERA_SUFFIXES = (".json",)


class SessionError(Exception):
    """A request the session refuses, with a one-line message; ``status_code`` is the HTTP status to answer."""

    status_code = 400


class NotFoundError(SessionError):
    """An unknown pair id or a missing file."""

    status_code = 404


class ConflictError(SessionError):
    """The request clashes with the current state (duplicate id, no calibration yet, too many pairs)."""

    status_code = 409


@dataclass
class Pair:
    """One GCP: frame pixel (u, v) [px], world (x, y, z) [CRS units], role, pixel sigma [px].

    ``z_auto``: z follows the ground at (x, y); False when typed by the user or read from a file with another z.
    ``ground``: the ground around (x, y) (None without a DEM or point cloud).
    """

    id: str
    u: float
    v: float
    x: float
    y: float
    z: float
    role: str = ROLE_CONTROL
    sigma_px: float = 1.0
    z_auto: bool = True
    ground: GroundSample | None = None


def _q(text: str) -> str:
    text = str(text)
    return f'"{text[:37] + "..." if len(text) > 40 else text}"' if text.isprintable() else repr(text[:40])


def _finite(value: float, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise SessionError(f"{what} must be a finite number, got {value!r}")
    return float(value)


class Session:
    """GCP pairs picked between a frame and an orthophoto, with ground heights, autosave and live calibration.

    Args:
        frame: the video frame (pixels u, v).
        ortho: the orthophoto (raster positions col, row; world x, y in its CRS).
        ground: the DEM or lidar ground for Z and roughness; None to type Z by hand.
        workdir: the working folder; file names given to :meth:`save_csv`, :meth:`load_csv` and
            :meth:`save_camera` are relative to it and may not leave it.
        gcps_path: the GCP CSV given on the command line: the default of :meth:`save_csv`.
        autosave_path: the CSV rewritten after every change (default: ``<gcps>.autosave.csv`` beside
            ``gcps_path``, or ``gcps.autosave.csv`` in ``workdir``).
        options: calibration options (:class:`~trafficgeo.calibration.CalibrationOptions`).
        max_distance_m: the footprint and grid reach this far from the camera (m).

    All public methods are thread-safe (the web server calls them from several threads).
    """

    def __init__(self, frame: FrameImage, ortho: Orthophoto, ground: Ground | None = None, *,
                 workdir: str | Path = ".", gcps_path: str | Path | None = None,
                 autosave_path: str | Path | None = None, options: CalibrationOptions | None = None,
                 max_distance_m: float = 250.0) -> None:
        self.frame = frame
        self.ortho = ortho
        self.ground = ground
        self.crs = ortho.crs if ortho.crs is not None else (ground.crs if ground is not None else None)
        self.workdir = Path(workdir).resolve()
        if not self.workdir.is_dir():
            raise InputError(f"working folder {workdir} does not exist; create it or give another `workdir`",
                             parameters=("workdir",))
        self.gcps_path = Path(gcps_path) if gcps_path is not None else None
        if autosave_path is not None:
            self.autosave_path = Path(autosave_path)
        elif self.gcps_path is not None:
            self.autosave_path = self.gcps_path.with_name(self.gcps_path.stem + ".autosave.csv")
        else:
            self.autosave_path = self.workdir / "gcps.autosave.csv"
        self.options = options or CalibrationOptions()
        self.max_distance_m = float(max_distance_m)
        self._pairs: list[Pair] = []
        self._revision = 0
        self._next_number = 1
        self._lock = threading.RLock()
        self._calib_lock = threading.Lock()
        self._cache: tuple[int, dict[str, Any], CalibrationRun | None] | None = None
        self.autosave_error: str | None = None
        self.autosaved_revision: int | None = None
        self.last_saved: str | None = None

    # ---------------------------------------------------------------------------------------------- read-only
    @property
    def revision(self) -> int:
        """Incremented by every change of the pairs."""
        return self._revision

    @property
    def pairs(self) -> list[Pair]:
        """Copies of the pairs, in the order they were made."""
        with self._lock:
            return [replace(p) for p in self._pairs]

    @property
    def min_control(self) -> int:
        """Fewest control pairs the calibration needs."""
        return required_points(self.options)

    def display_name(self, path: Path) -> str:
        """``path`` relative to the working folder when inside it, else absolute."""
        try:
            return str(path.resolve().relative_to(self.workdir))
        except ValueError:
            return str(path.resolve())

    def info(self) -> dict[str, Any]:
        """Static facts for the browser: image sizes, sources, CRS, ground, files, calibration minimum."""
        w, h = self.frame.size
        ext_c, ext_r = self.ortho.display_extent
        return {
            "frame": {"width": w, "height": h, "source": self.frame.source},
            "ortho": {"cols": self.ortho.cols, "rows": self.ortho.rows, "extent_cols": ext_c, "extent_rows": ext_r,
                      "display_factor": self.ortho.display_factor, "note": self.ortho.note,
                      "source": self.ortho.source, "resolution": list(self.ortho.resolution)},
            "crs": crs_label(self.crs),
            "unit": self._unit(),
            "ground": None if self.ground is None else {"kind": self.ground.kind, "source": self.ground.source,
                                                        "describe": self.ground.describe()},
            "workdir": str(self.workdir),
            "gcps_name": self.display_name(self.gcps_path) if self.gcps_path is not None else "gcps.csv",
            "autosave": self.display_name(self.autosave_path),
            "camera_name": "camera.json",
            "min_control": self.min_control,
            "roles": list(ROLES),
        }

    def _unit(self) -> str:
        if self.crs is None or not self.crs.axis_info:
            return "m"
        name = self.crs.axis_info[0].unit_name
        return {"metre": "m", "foot": "ft", "US survey foot": "ftUS"}.get(name, name)

    def pair_dict(self, p: Pair) -> dict[str, Any]:
        """A pair as JSON-ready data, with its orthophoto position (col, row)."""
        col, row = self.ortho.world_to_pixel(p.x, p.y)
        g = p.ground
        return {
            "id": p.id, "role": p.role, "u": p.u, "v": p.v, "col": col, "row": row, "x": p.x, "y": p.y, "z": p.z,
            "z_auto": p.z_auto, "sigma_px": p.sigma_px, "on_ortho": self.ortho.contains(col, row),
            "ground": None if g is None else {"z": g.z, "spread_m": g.spread_m, "slope_deg": g.slope_deg,
                                              "points": g.points, "dz_m": g.dz_m, "check": g.check},
        }

    def state(self) -> dict[str, Any]:
        """The pairs and the autosave status (JSON-ready; NaN as None)."""
        with self._lock:
            return to_json_safe({
                "revision": self._revision,
                "pairs": [self.pair_dict(p) for p in self._pairs],
                "autosave": {"path": self.display_name(self.autosave_path), "revision": self.autosaved_revision,
                             "error": self.autosave_error},
                "last_saved": self.last_saved,
            })

    # ---------------------------------------------------------------------------------------------- checks
    def _check_frame(self, u: float, v: float) -> tuple[float, float]:
        u, v = _finite(u, "frame pixel u"), _finite(v, "frame pixel v")
        if not self.frame.contains(u, v):
            w, h = self.frame.size
            raise SessionError(f"frame pixel (u={u:g}, v={v:g}) is outside the {w}x{h} frame (u from -0.5 to "
                               f"{w - 0.5:g}, v from -0.5 to {h - 0.5:g}; (0, 0) = centre of the top-left pixel)")
        return u, v

    def _check_ortho(self, col: float, row: float) -> tuple[float, float]:
        col, row = _finite(col, "orthophoto column"), _finite(row, "orthophoto row")
        if not self.ortho.contains(col, row):
            raise SessionError(f"orthophoto position (col={col:g}, row={row:g}) is outside the {self.ortho.cols}x"
                               f"{self.ortho.rows} orthophoto (col from 0 to {self.ortho.cols}, row from 0 to "
                               f"{self.ortho.rows}; (0, 0) = its top-left corner)")
        return col, row

    @staticmethod
    def _check_z(z: float) -> float:
        z = _finite(z, "z")
        if abs(z) > MAX_ABS_Z:
            raise SessionError(f"z = {z:g} is out of range (|z| <= {MAX_ABS_Z:g} CRS units); give the elevation "
                               "of the point")
        return z

    @staticmethod
    def _check_sigma(sigma: float) -> float:
        sigma = _finite(sigma, "sigma_px")
        if not 0 < sigma <= MAX_SIGMA_PX:
            raise SessionError(f"sigma_px = {sigma:g} must be > 0 and <= {MAX_SIGMA_PX:g} px (1 for a careful click)")
        return sigma

    @staticmethod
    def _check_role(role: str) -> str:
        if role not in ROLES:
            raise SessionError(f"role {_q(role)} is unknown; use {' or '.join(ROLES)}")
        return role

    def _check_new_id(self, pair_id: str, current: str | None = None) -> str:
        if not isinstance(pair_id, str) or not pair_id or pair_id != pair_id.strip() or not pair_id.isprintable() \
                or len(pair_id) > MAX_ID_LENGTH:
            raise SessionError(f"id {_q(pair_id)} is not valid: give 1 to {MAX_ID_LENGTH} printable characters "
                               "without leading or trailing spaces")
        if pair_id != current and any(p.id == pair_id for p in self._pairs):
            raise ConflictError(f"id {_q(pair_id)} is already used by another pair; choose another id")
        return pair_id

    def _index(self, pair_id: str) -> int:
        for i, p in enumerate(self._pairs):
            if p.id == pair_id:
                return i
        raise NotFoundError(f"no pair with id {_q(pair_id)}; the pairs are "
                            f"{', '.join(p.id for p in self._pairs[:20]) or 'none yet'}")

    def _auto_id(self) -> str:
        used = {p.id for p in self._pairs}
        while f"P{self._next_number}" in used:
            self._next_number += 1
        return f"P{self._next_number}"

    # ---------------------------------------------------------------------------------------------- ground
    def _fallback_z(self, exclude: Pair | None = None) -> float:
        """Z for a point without ground data: the median z of the other pairs, else the ground's middle, else 0."""
        zs = [p.z for p in self._pairs if p is not exclude]
        if zs:
            return float(np.median(zs))
        if self.ground is not None:
            return self.ground.middle_z()
        return 0.0

    def _update_ground(self, pairs: list[Pair]) -> None:
        """Fill z of ``z_auto`` pairs from the ground and (re)check every pair's z against it."""
        if not pairs:
            return
        if self.ground is None:
            for p in pairs:
                p.ground = None
                if p.z_auto:
                    p.z, p.z_auto = self._fallback_z(p), False
            return
        x = np.array([p.x for p in pairs])
        y = np.array([p.y for p in pairs])
        z = np.array([np.nan if p.z_auto else p.z for p in pairs])
        for p, s in zip(pairs, self.ground.sample(x, y, z), strict=True):
            p.ground = s
            if p.z_auto:
                p.z = s.z if math.isfinite(s.z) else self._fallback_z(p)

    # ---------------------------------------------------------------------------------------------- changes
    def add_pair(self, u: float, v: float, col: float, row: float, *, pair_id: str | None = None,
                 role: str = ROLE_CONTROL, z: float | None = None, sigma_px: float = 1.0) -> dict[str, Any]:
        """Make a pair from a frame pixel (u, v) and an orthophoto position (col, row); returns it as data.

        ``z`` None takes Z from the ground at the point.
        """
        u, v = self._check_frame(u, v)
        col, row = self._check_ortho(col, row)
        role = self._check_role(role)
        sigma_px = self._check_sigma(sigma_px)
        zz = None if z is None else self._check_z(z)
        x, y = self.ortho.pixel_to_world(col, row)
        with self._lock:
            if len(self._pairs) >= MAX_PAIRS:
                raise ConflictError(f"a session holds at most {MAX_PAIRS} pairs; delete some first")
            new_id = self._check_new_id(pair_id) if pair_id is not None else self._auto_id()
            pair = Pair(new_id, u, v, x, y, zz if zz is not None else math.nan, role, sigma_px, z_auto=zz is None)
            self._update_ground([pair])
            self._pairs.append(pair)
            self._changed()
            return self.pair_dict(pair)

    def update_pair(self, pair_id: str, *, u: float | None = None, v: float | None = None, col: float | None = None,
                    row: float | None = None, new_id: str | None = None, role: str | None = None,
                    z: float | None = None, z_auto: bool | None = None, sigma_px: float | None = None
                    ) -> dict[str, Any]:
        """Move, rename, re-role or re-weight a pair, or set its z (``z``) / let it follow the ground
        (``z_auto=True``). Arguments left at None keep their value. Returns the pair as data."""
        if z is not None and z_auto:
            raise SessionError("give either z (typed elevation) or z_auto = true (elevation from the ground), "
                               "not both")
        if z_auto is False and z is None:
            raise SessionError("z_auto = false needs the elevation: give z")
        with self._lock:
            i = self._index(pair_id)
            p = replace(self._pairs[i])
            if u is not None or v is not None:
                p.u, p.v = self._check_frame(p.u if u is None else u, p.v if v is None else v)
            moved = col is not None or row is not None
            if moved:
                c0, r0 = self.ortho.world_to_pixel(p.x, p.y)
                c, r = self._check_ortho(c0 if col is None else col, r0 if row is None else row)
                p.x, p.y = self.ortho.pixel_to_world(c, r)
            if new_id is not None:
                p.id = self._check_new_id(new_id, current=pair_id)
            if role is not None:
                p.role = self._check_role(role)
            if sigma_px is not None:
                p.sigma_px = self._check_sigma(sigma_px)
            if z is not None:
                p.z, p.z_auto = self._check_z(z), False
            if z_auto:
                if self.ground is None:
                    raise ConflictError("there is no ground to take z from: start gcp-ui with --dem or --cloud, "
                                        "or type z")
                p.z_auto = True
            if moved or z is not None or z_auto:
                self._update_ground([p])
            self._pairs[i] = p
            self._changed()
            return self.pair_dict(p)

    def delete_pair(self, pair_id: str) -> None:
        """Remove a pair."""
        with self._lock:
            del self._pairs[self._index(pair_id)]
            self._changed()

    def set_table(self, table: GCPTable, *, autosave: bool = True, heights_from_ground: bool = False) -> None:
        """Replace every pair by the rows of a GCP table (pixels must lie in the frame).

        A row's z is taken as following the ground when it equals the ground's z (as the autosave writes it), or
        always with ``heights_from_ground`` (a file without heights). ``autosave=False`` (the table a session
        starts from) leaves the autosave file alone until the first change.
        """
        for i in range(table.n):
            u, v = table.pixels[i]
            if not self.frame.contains(float(u), float(v)):
                w, h = self.frame.size
                raise InputError(f"{table.where(i)}: pixel (u={u:g}, v={v:g}) is outside the {w}x{h} frame; was the "
                                 "GCP file made for another frame size?")
        pairs = [Pair(table.ids[i], float(table.pixels[i, 0]), float(table.pixels[i, 1]), float(table.world[i, 0]),
                      float(table.world[i, 1]), float(table.world[i, 2]), table.roles[i], float(table.sigma_px[i]),
                      z_auto=False) for i in range(table.n)]
        if heights_from_ground:
            for p in pairs:
                p.z_auto = True
            self._update_ground(pairs)
        elif self.ground is not None and pairs:
            samples = self.ground.sample([p.x for p in pairs], [p.y for p in pairs], [p.z for p in pairs])
            for p, s in zip(pairs, samples, strict=True):
                p.ground = s
                p.z_auto = bool(math.isfinite(s.z) and abs(s.z - p.z) <= 1e-9 * max(1.0, abs(p.z)))
        with self._lock:
            self._pairs = pairs
            if autosave:
                self._changed()
            else:
                self._revision += 1

    def _changed(self) -> None:
        self._revision += 1
        self._autosave()

    def table(self) -> GCPTable:
        """The pairs as a :class:`~trafficgeo.calibration.GCPTable` in the session's CRS."""
        with self._lock:
            return self._table(self._pairs)

    def _table(self, pairs: list[Pair]) -> GCPTable:
        return GCPTable.from_arrays(
            [p.id for p in pairs], np.array([[p.x, p.y, p.z] for p in pairs], dtype=np.float64).reshape(-1, 3),
            np.array([[p.u, p.v] for p in pairs], dtype=np.float64).reshape(-1, 2),
            roles=[p.role for p in pairs], sigma_px=[p.sigma_px for p in pairs], crs=self.crs, source="GCPs")

    def _autosave(self) -> None:
        try:
            self._table(self._pairs).to_csv(self.autosave_path)
        except (OSError, OutputError) as exc:  # OutputError: the disk full (the partial file is already removed)
            why = exc.strerror if isinstance(exc, OSError) and exc.strerror else exc
            self.autosave_error = (f"autosave to {self.autosave_path} failed ({why}); save the GCPs "
                                   "under another name")
            log.warning(self.autosave_error)
        else:
            self.autosave_error = None
            self.autosaved_revision = self._revision

    # ---------------------------------------------------------------------------------------------- files
    def resolve(self, name: str, suffixes: tuple[str, ...], *, must_exist: bool = False) -> Path:
        """The file ``name`` in the working folder; refuses absolute paths, ``..``, other suffixes, and names
        that lead out of the folder (also through symbolic links)."""
        if not isinstance(name, str) or not name.strip():
            raise SessionError("the file name is empty; give a name such as gcps.csv")
        if len(name) > MAX_NAME_LENGTH or not name.isprintable():
            raise SessionError(f"file name {_q(name)} is too long or holds control characters; give a plain name")
        posix, win = PurePosixPath(name), PureWindowsPath(name)
        if posix.is_absolute() or win.is_absolute() or win.drive or name.startswith(("/", "\\", "~")):
            raise SessionError(f"file name {_q(name)} is an absolute path; give a name inside the working folder "
                               f"{self.workdir}, e.g. gcps.csv")
        if ".." in win.parts or ".." in posix.parts:
            raise SessionError(f"file name {_q(name)} leaves the working folder ('..'); give a name inside "
                               f"{self.workdir}")
        if posix.suffix.lower() not in suffixes:
            raise SessionError(f"file name {_q(name)} must end with {' or '.join(suffixes)}")
        path = (self.workdir / posix).resolve()
        if not path.is_relative_to(self.workdir):
            raise SessionError(f"file name {_q(name)} leads out of the working folder {self.workdir}")
        if must_exist and not path.is_file():
            raise NotFoundError(f"file {_q(name)} does not exist in the working folder {self.workdir}")
        if not must_exist and not path.parent.is_dir():
            raise SessionError(f"folder {_q(str(posix.parent))} does not exist in the working folder; create it "
                               "first or give another name")
        if path.is_dir():
            raise SessionError(f"{_q(name)} is a folder; give a file name")
        return path

    def save_csv(self, name: str | None = None) -> dict[str, Any]:
        """Write the GCP CSV (``id,x,y,z,u,v,role,sigma_px``) atomically to ``name`` (default: the --gcps file)."""
        default = self.gcps_path if self.gcps_path is not None else self.workdir / "gcps.csv"
        if name is None or name == self.display_name(default):
            path = default
        else:
            path = self.resolve(name, CSV_SUFFIXES)
        with self._lock:
            table = self._table(self._pairs)
            try:
                table.to_csv(path)
            except (OSError, OutputError) as exc:
                why = exc.strerror if isinstance(exc, OSError) and exc.strerror else exc
                raise SessionError(f"cannot write {path} ({why}); check the folder's permissions and free space, "
                                   "or give another name") from None
            self.last_saved = self.display_name(path)
            return {"path": self.last_saved, "n": table.n}

    def load_csv(self, name: str) -> dict[str, Any]:
        """Replace the pairs by those of a GCP CSV (or OpenDroneMap list) in the working folder."""
        path = self.resolve(name, CSV_SUFFIXES + (".txt",), must_exist=True)
        table = read_gcps(path, crs=self.crs)
        self.set_table(table)
        return {"path": self.display_name(path), "n": table.n}

    def save_camera(self, name: str) -> dict[str, Any]:
        """Write the calibrated camera JSON (with its GCP residuals and statistics) for the current pairs."""
        path = self.resolve(name, CAMERA_SUFFIXES)
        payload, run = self._calibrate_cached()
        if run is None:
            raise ConflictError(f"no calibrated camera to save: {payload['message']}")
        try:
            calibrated_camera(run.calibration, run.report).write(path)
        except (OSError, OutputError) as exc:
            why = exc.strerror if isinstance(exc, OSError) and exc.strerror else exc
            raise SessionError(f"cannot write {path} ({why}); check the folder's permissions and free space, or "
                               "give another name") from None
        return {"path": self.display_name(path), "revision": payload["revision"]}

    # ---------------------------------------------------------------------------------------------- calibration
    def calibration(self) -> dict[str, Any]:
        """The live calibration of the current pairs (JSON-ready), see :meth:`_calibrate`."""
        return self._calibrate_cached()[0]

    def calibration_run(self) -> tuple[dict[str, Any], CalibrationRun | None]:
        """The live calibration's answer and its run (None unless calibrated), cached per revision."""
        return self._calibrate_cached()

    def _calibrate_cached(self) -> tuple[dict[str, Any], CalibrationRun | None]:
        with self._calib_lock:
            with self._lock:
                rev = self._revision
                pairs = [replace(p) for p in self._pairs]
                if self._cache is not None and self._cache[0] == rev:
                    return self._cache[1], self._cache[2]
            payload, run = self._calibrate(pairs, rev)
            with self._lock:
                if self._revision == rev:
                    self._cache = (rev, payload, run)
            return payload, run

    def _calibrate(self, pairs: list[Pair], revision: int) -> tuple[dict[str, Any], CalibrationRun | None]:
        """Calibrate on ``pairs`` (:func:`trafficgeo.ui.live.calibration_answer`) and draw the footprint and grid."""
        answer, run = calibration_answer(self._table(pairs), self.frame.size, self.options, revision=revision,
                                              min_control=self.min_control)
        if run is None:
            return answer, None
        draw_overlays(answer, run, ortho=self.ortho, ground=self.ground, crs=self.crs, unit=self._unit(),
                           max_distance_m=self.max_distance_m)
        return to_json_safe(answer), run


__all__ = ["ROLE_CHECK", "ROLE_CONTROL", "ConflictError", "NotFoundError", "Pair", "Session", "SessionError"]
