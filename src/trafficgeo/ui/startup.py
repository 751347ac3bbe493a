"""Opening a ``trafficgeo gcp-ui`` session: the frame, orthophoto and ground loaded, and the GCPs it starts from
(the --gcps file, or the autosave of an earlier session when it holds newer, unsaved changes).

Errors a user can fix raise :class:`~trafficgeo.errors.InputError` with one line.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from trafficgeo.calibration import CalibrationOptions, GCPTable, read_gcps
from trafficgeo.errors import InputError
from trafficgeo.ui.session import Session, SessionError


def initial_table(gcps_path: Path | None, autosave_path: Path, crs: Any, gcp_crs: Any = None
                  ) -> tuple[GCPTable | None, Path | None, bool]:
    """The GCPs a session starts from, the file they came from, and whether that file had no heights (a QGIS
    ``.points`` file, lon/lat without heights: the session then takes them from the ground).

    The autosave when it is newer than the --gcps file (it holds changes made after the last save) or when there is
    no --gcps file; else the --gcps file; None when neither exists. An autosave with no rows gives an empty start.
    """
    gcps_exists = gcps_path is not None and gcps_path.is_file()
    path: Path | None = None
    if autosave_path.is_file() and (not gcps_exists or autosave_path.stat().st_mtime > gcps_path.stat().st_mtime):
        path = autosave_path
        if gcps_exists and autosave_path.read_bytes() == gcps_path.read_bytes():  # type: ignore[union-attr]
            path = gcps_path  # saved since: nothing new in the autosave
    elif gcps_exists:
        path = gcps_path
    if path is None:
        return None, None, False
    rows = [line for line in path.read_text(encoding="utf-8", errors="replace").splitlines() if line.strip()]
    if path == autosave_path and len(rows) <= 1:
        return None, path, False
    try:
        # the autosave is trafficgeo's own layout in the working CRS; the user's file is in gcp_crs when given
        return read_gcps(path, crs=crs, gcp_crs=gcp_crs if path != autosave_path else None), path, False
    except InputError as exc:
        if path != autosave_path:
            if exc.parameters == ("ground_z",):  # a file without heights (QGIS .points, lon/lat only): the
                # session takes them from the ground (or the other points), as for a pair clicked in the page
                return read_gcps(path, crs=crs, gcp_crs=gcp_crs, ground_z=0.0), path, True
            raise
        raise damaged_autosave(autosave_path, exc, gcps_path) from None


def damaged_autosave(autosave_path: Path, exc: Exception, gcps_path: Path | None) -> InputError:
    """The one-line error for an autosave that cannot be used: what is wrong, and that moving it aside starts over
    (from the --gcps file when there is one)."""
    reason = str(exc).removeprefix(f"{autosave_path} ").removeprefix(f"{autosave_path}: ")
    then = (f"continue from {gcps_path}" if gcps_path is not None and gcps_path.is_file()
            else "start with no GCPs")
    return InputError(f"the autosave {autosave_path} cannot be read ({reason}); move it aside (rename or delete "
                      f"it) to {then} (it only holds the unsaved changes of an earlier gcp-ui session)")


def open_session(*, frame: str | Path | None = None, video: str | Path | None = None, at_s: float | None = None,
                 ortho: str | Path, dem: str | Path | None = None, cloud: str | Path | None = None,
                 gcps: str | Path | None = None, workdir: str | Path | None = None,
                 options: CalibrationOptions | None = None, gcp_crs: str | None = None) -> tuple[Session, str]:
    """Load the inputs of ``trafficgeo gcp-ui`` and start a session; returns it and a line saying where its GCPs
    came from. ``gcp_crs`` is the CRS of the ``gcps`` file's x, y when it is not the orthophoto's (EPSG:4326 for
    longitude/latitude: the points are projected to the orthophoto's CRS, and saving writes beside the file).

    ``frame`` (an image) or ``video`` (with ``at_s`` seconds, default 0) gives the frame; ``ortho`` the GeoTIFF
    orthophoto; ``dem`` or ``cloud`` the ground for Z; ``gcps`` the GCP CSV to continue (if it exists) and save to.
    ``workdir`` defaults to the folder of ``gcps``, else the current folder. Raises
    :class:`~trafficgeo.errors.InputError` (one line) for anything a user can fix.
    """
    from trafficgeo.ui.inputs import load_frame, load_ground, load_ortho, load_video_frame

    if frame is not None and video is not None:
        raise InputError("give the frame to pick on with either `frame` (an image) or `video` (with at_s seconds), "
                         "not both", parameters=("frame", "video", "at_s"))
    if frame is None and video is None:
        raise InputError("give the frame to pick on with `frame` (an image) or `video` (with at_s seconds)",
                         parameters=("frame", "video", "at_s"))
    if at_s is not None and video is None:
        raise InputError("at_s picks a time in a `video`; with `frame` it has no meaning, leave it out",
                         parameters=("at_s", "video", "frame"))
    if dem is not None and cloud is not None:
        raise InputError("give either `dem` or `cloud` for the GCP heights, not both", parameters=("dem", "cloud"))
    gcps_path = Path(gcps) if gcps is not None else None
    if gcps_path is not None:
        if gcps_path.is_dir():
            raise InputError(f"gcps {gcps_path} is a folder; give the GCP CSV file to continue or create",
                             parameters=("gcps",))
        if not gcps_path.parent.resolve().is_dir():
            raise InputError(f"gcps {gcps_path}: folder {gcps_path.parent} does not exist; create it first",
                             parameters=("gcps",))
        theirs = gcps_path.suffix.lower() in (".points", ".txt") and gcps_path.is_file()  # read, saved beside
        if gcps_path.suffix.lower() != ".csv" and not theirs:
            raise InputError(f"gcps {gcps_path} must be a .csv file (id,x,y,z,u,v,role,sigma_px), or an existing "
                             "QGIS .points or OpenDroneMap gcp_list.txt to start from", parameters=("gcps",))
    img = load_frame(frame) if frame is not None else load_video_frame(video, 0.0 if at_s is None else at_s)
    orthophoto = load_ortho(ortho)
    ground = load_ground(dem=dem, cloud=cloud, ortho_crs=orthophoto.crs)
    wd = Path(workdir) if workdir is not None else (gcps_path.parent if gcps_path is not None else Path.cwd())
    session = Session(img, orthophoto, ground, workdir=wd, gcps_path=gcps_path, options=options)
    table, source, no_heights = initial_table(gcps_path, session.autosave_path, session.crs, gcp_crs)
    if table is not None:
        try:
            session.set_table(table, autosave=False, heights_from_ground=no_heights)
        except (InputError, SessionError) as exc:
            if source != session.autosave_path:
                raise
            raise damaged_autosave(session.autosave_path, exc, gcps_path) from None
        note = f"continuing with {table.n} GCP(s) from {source}"
        if source == session.autosave_path and gcps_path is not None and gcps_path.is_file():
            note += f" (newer than {gcps_path}: unsaved changes of the last session)"
        if (table.columns_note or table.from_lonlat or no_heights or source.suffix.lower() != ".csv") \
                and source == gcps_path:
            # the user's file keeps its own layout and CRS: Save writes trafficgeo's beside it
            session.gcps_path = gcps_path.with_name(gcps_path.stem + "_trafficgeo.csv")
            how = f"columns read as {table.columns_note}; " if table.columns_note else ""
            note += (f" ({how}Save writes id,x,y,z,u,v in the orthophoto's CRS to {session.gcps_path.name}, your "
                     "file stays as it is)")
            if table.from_lonlat and session.options.survey_sigma_m < 0.1:
                note += ("; longitude/latitude points are usually picked on a web map, good to decimetres or metres: "
                         "say how good with survey_sigma (e.g. 0.5 m)")
    elif source is not None:
        note = f"the autosave {source} holds no GCPs; starting empty"
    else:
        note = "no GCPs yet" + (f"; Save writes {gcps_path}" if gcps_path is not None else "")
    return session, note


__all__ = ["damaged_autosave", "initial_table", "open_session"]
