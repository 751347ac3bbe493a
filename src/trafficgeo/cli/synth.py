"""``trafficgeo synth``: build a demo world (a thin wrapper over :func:`trafficgeo.synth.world.build_world`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from trafficgeo.cli import app, console, parse_image_size
from trafficgeo.errors import InputError


def _mix(text: str) -> dict[str, float]:
    """'car=0.8,van=0.1,truck=0.07,bus=0.03' -> dict."""
    out: dict[str, float] = {}
    for part in text.split(","):
        name, _, value = part.partition("=")
        try:
            out[name.strip()] = float(value)
        except ValueError:
            raise InputError(f"--mix '{text}': '{part}' is not CLASS=SHARE; "
                             "e.g. --mix car=0.8,van=0.1,truck=0.1") from None
    return out


@app.command()
def synth(
    out: Annotated[Path, typer.Option("--out", help="folder to write the world into")],
    seed: Annotated[int, typer.Option(help="random seed (same seed, same files)")] = 0,
    lanes: Annotated[int, typer.Option(help="lanes per direction")] = 2,
    one_way: Annotated[bool, typer.Option(help="one direction only")] = False,
    length: Annotated[float, typer.Option(help="road length (m)")] = 300.0,
    grade: Annotated[float, typer.Option(help="grade along the road, e.g. 0.03")] = 0.0,
    crossfall: Annotated[float, typer.Option(help="crossfall each way from the crown, e.g. 0.02")] = 0.02,
    crest_radius: Annotated[float, typer.Option(help="vertical crest radius (m); 0 = none")] = 0.0,
    curve_radius: Annotated[float, typer.Option(help="horizontal curve radius (m): > 0 right, < 0 left")] = 0.0,
    camera_height: Annotated[float, typer.Option(help="camera height above the road (m)")] = 8.0,
    heading: Annotated[float | None, typer.Option(help="camera heading (deg from north)")] = None,
    tilt: Annotated[float | None, typer.Option(help="camera tilt below the horizon (deg)")] = None,
    focal_px: Annotated[float | None, typer.Option(help="focal length (px); default 0.9 x width")] = None,
    image_size: Annotated[str, typer.Option(help="WIDTHxHEIGHT")] = "1920x1080",
    k1: Annotated[float, typer.Option(help="radial distortion k1")] = -0.06,
    demand: Annotated[float, typer.Option(help="vehicles per hour per lane")] = 600.0,
    mix: Annotated[str, typer.Option(help="class shares, e.g. car=0.8,van=0.1,truck=0.07,bus=0.03")] =
        "car=0.8,van=0.1,truck=0.07,bus=0.03",
    duration: Annotated[float, typer.Option(help="video length (s)")] = 60.0,
    fps: Annotated[float, typer.Option(help="frames per second (e.g. 25 or 30)")] = 25.0,
    outliers: Annotated[int, typer.Option(help="GCPs given a gross pixel error")] = 0,
    count_stations: Annotated[str, typer.Option(help="counting lines at these stations (m), e.g. -50,0,50")] = "0",
    no_video: Annotated[bool, typer.Option("--no-video", help="skip rendering the video")] = False,
    cameras: Annotated[int | None, typer.Option(
        "--cameras", help="build a city instead: N cameras along the road over the same traffic, their videos cut "
        "into files in videos/ and a cameras.csv for trafficgeo batch plan")] = None,
    file_s: Annotated[float | None, typer.Option(
        "--file-s", help="with --cameras: length of each video file (whole s; default the whole video)")] = None,
) -> None:
    """Generate a demo world: SUMO traffic, orthophoto, lidar, GCPs, true camera, H.264 video and truth
    (with --cameras: a city of several cameras and their cameras.csv)."""
    from rich.progress import BarColumn, Progress, TimeRemainingColumn

    from trafficgeo.io.run_manifest import check_writable_folder
    from trafficgeo.synth.world import WorldOptions, build_world

    check_writable_folder(out, "--out")
    size = parse_image_size(image_size)
    for name, value in (("--length", length), ("--camera-height", camera_height), ("--duration", duration),
                        ("--fps", fps)):
        if not value > 0:
            raise InputError(f"{name} {value} must be positive")
    if lanes < 1:
        raise InputError(f"--lanes {lanes} must be at least 1")
    try:
        stations = tuple(float(v) for v in count_stations.split(","))
    except ValueError:
        raise InputError(f"--count-stations '{count_stations}' is not a comma-separated list of metres, "
                         "e.g. -50,0,50") from None
    if not all(abs(v) < 0.5 * length for v in stations):
        raise InputError(f"--count-stations {count_stations}: every line must lie on the road (|station| < "
                         f"{0.5 * length:g} m)")
    if outliers < 0:
        raise InputError(f"--outliers {outliers} must be >= 0")
    opts = WorldOptions(seed=seed, lanes=lanes, two_way=not one_way, length_m=length, grade=grade,
                        crossfall=crossfall, crest_radius=crest_radius, curve_radius=curve_radius,
                        camera_height=camera_height,
                        heading_deg=heading, tilt_deg=tilt, focal_px=focal_px, image_size=size,
                        dist=(k1, 0.0, 0.0, 0.0, 0.0), veh_per_hour_per_lane=demand, mix=_mix(mix),
                        duration_s=duration, fps=fps, n_outliers=outliers, count_stations=stations)
    if cameras is not None or file_s is not None:
        _city(out, opts, cameras, file_s, no_video)
        return
    with Progress("[progress.description]{task.description}", BarColumn(), "{task.completed}/{task.total} frames",
                  TimeRemainingColumn(), console=console, transient=True) as progress:
        task = progress.add_task("rendering", total=None)
        summary = build_world(out, opts, video=not no_video,
                              progress=lambda i, n: progress.update(task, completed=i, total=n))
    console.print(f"{summary['vehicles']} vehicles, {summary['frames']} frames, {summary['gcps']} GCPs "
                  f"(SUMO {summary['sumo_version']}) -> {out}")


def _city(out: Path, opts, cameras: int | None, file_s: float | None, no_video: bool) -> None:
    """``synth --cameras N [--file-s S]``: a city of N cameras (one without --cameras)."""
    from trafficgeo.synth.city import CityOptions, build_city, spread_cameras

    if no_video:
        raise InputError("--no-video: a city needs its videos; leave out --no-video or --cameras")
    n = 1 if cameras is None else cameras
    if n < 1:
        raise InputError(f"--cameras {n} must be at least 1")
    try:
        city = CityOptions(cameras=spread_cameras(n, opts.length_m), world=opts,
                           file_s=opts.duration_s if file_s is None else file_s)
    except InputError as exc:
        raise InputError(exc.in_terms_of({"file_s": "--file-s", "cameras": "--cameras"})) from None
    with console.status(f"building {n} camera(s)") as status:
        path = build_city(out, city, progress=lambda i, k: status.update(f"built {i} of {k} camera(s)"))
    console.print(f"{n} camera(s), their videos in {out / 'videos'} -> {path}")
