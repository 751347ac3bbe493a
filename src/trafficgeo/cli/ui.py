"""The ``gcp-ui`` command: a local web app to pick GCPs and calibrate live (:mod:`trafficgeo.ui`)."""

from __future__ import annotations

import ipaddress
from pathlib import Path
from typing import Annotated

import typer

from trafficgeo.cli.app import app, console
from trafficgeo.errors import InputError

LOOPBACK_NAMES = ("127.0.0.1", "localhost", "::1")


def _is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


@app.command("gcp-ui")
def gcp_ui(
    ortho: Annotated[Path, typer.Option("--ortho", help="orthophoto GeoTIFF (X, Y of the GCPs)")],
    frame: Annotated[Path | None, typer.Option("--frame", help="video frame to pick on (PNG/JPEG)")] = None,
    video: Annotated[Path | None, typer.Option("--video", help="video to take the frame from (see --at)")] = None,
    at: Annotated[float | None, typer.Option("--at", help="time of the frame in --video (s; default 0)")] = None,
    dem: Annotated[Path | None, typer.Option("--dem", help="DEM GeoTIFF for the GCP heights")] = None,
    cloud: Annotated[Path | None, typer.Option("--cloud", help="LAS/LAZ point cloud for the GCP heights")] = None,
    gcps: Annotated[Path | None, typer.Option("--gcps", help="GCP CSV to continue (if it exists) and save to; "
                                              "changes are autosaved to <name>.autosave.csv beside it (a file "
                                              "in other columns, or a QGIS .points file, is saved beside as "
                                              "<name>_trafficgeo.csv)")] = None,
    workdir: Annotated[Path | None, typer.Option("--workdir", help="folder for the file names typed in the page "
                                                 "(default: the folder of --gcps, else the current folder)")] = None,
    gcp_crs: Annotated[str | None, typer.Option(help="CRS of the --gcps file's x, y when not the orthophoto's, "
                                                     "e.g. EPSG:4326 (x = longitude, y = latitude); edits are saved "
                                                     "beside it, in the orthophoto's CRS")] = None,
    survey_sigma: Annotated[float, typer.Option(help="standard deviation of the GCPs' world coordinates (m): 0.03 "
                                                     "for surveyed points and a good orthophoto, 0.3-1 for points "
                                                     "picked on a web map")] = 0.03,
    focal_px: Annotated[float | None, typer.Option(help="hold the focal length at this value (px)")] = None,
    host: Annotated[str, typer.Option(help="address to serve on (127.0.0.1 = this computer only)")] = "127.0.0.1",
    port: Annotated[int, typer.Option(help="TCP port (0 = any free port)")] = 8765,
) -> None:
    """Pick GCPs in a browser: the frame and the orthophoto side by side, Z from the DEM/point cloud, live
    calibration with residuals, leave-one-out errors, outliers, the camera footprint and the world grid.

    Open the printed address in a browser; Ctrl+C stops the server. Every change is autosaved.
    """
    from trafficgeo.calibration import CalibrationOptions
    from trafficgeo.ui.server import bind_socket, create_app, make_server, url_of
    from trafficgeo.ui.startup import open_session

    options = CalibrationOptions(focal_px=focal_px, survey_sigma_m=survey_sigma)
    if not host.strip():
        raise InputError("--host is empty; give an address such as 127.0.0.1")
    sock = bind_socket(host, port)  # before loading: a port in use is reported at once
    try:
        session, note = open_session(frame=frame, video=video, at_s=at, ortho=ortho, dem=dem, cloud=cloud, gcps=gcps,
                                     workdir=workdir, options=options, gcp_crs=gcp_crs)
        url = url_of(sock)
        allowed = [*LOOPBACK_NAMES, host] if _is_loopback(host) else None
        server = make_server(create_app(session, allowed_hosts=allowed))
        console.print(f"frame {session.frame.source}: {session.frame.size[0]}x{session.frame.size[1]} px",
                      markup=False, highlight=False)
        console.print(f"orthophoto {session.ortho.source}: {session.ortho.cols}x{session.ortho.rows} px"
                      + (f" ({session.ortho.note})" if session.ortho.note else ""), markup=False, highlight=False)
        if session.ground is not None:
            console.print(f"Z from {session.ground.describe()}", markup=False, highlight=False)
        else:
            console.print("no --dem or --cloud: type the Z of each GCP in the page", markup=False, highlight=False)
        console.print(note.replace("survey_sigma", "--survey-sigma"), markup=False, highlight=False)
        console.print(f"autosave: {session.autosave_path}", markup=False, highlight=False)
        if not _is_loopback(host):
            console.print(f"warning: serving on {host}, reachable from other computers; anyone who can reach it "
                          "can edit the GCPs", markup=False, highlight=False)
        console.print(f"open {url} in a browser (Ctrl+C to stop)", markup=False, highlight=False)
        serve(server, sock)
    finally:
        sock.close()


def serve(server: object, sock: object) -> None:
    """Run the uvicorn ``server`` on the bound socket until Ctrl+C (a separate function so tests can replace it)."""
    server.run(sockets=[sock])  # type: ignore[attr-defined]
