"""``trafficgeo synth``: build a demo world (a thin wrapper over :func:`trafficgeo.synth.world.build_world`; with
``--junction`` over :func:`trafficgeo.synth.junction_world.build_junction_world`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from trafficgeo.cli.app import app, console, parse_image_size
from trafficgeo.errors import InputError


def _mix(text: str, flag: str = "--mix", example: str = "car=0.8,van=0.1,truck=0.1") -> dict[str, float]:
    """'car=0.8,van=0.1,truck=0.07,bus=0.03' -> dict."""
    out: dict[str, float] = {}
    for part in text.split(","):
        name, _, value = part.partition("=")
        try:
            out[name.strip()] = float(value)
        except ValueError:
            raise InputError(f"{flag} '{text}': '{part}' is not NAME=SHARE; e.g. {flag} {example}") from None
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
    camera_height: Annotated[float | None, typer.Option(
        help="camera height above the road (m); default 8 (road), 12 (junction)")] = None,
    heading: Annotated[float | None, typer.Option(help="camera heading (deg from north)")] = None,
    tilt: Annotated[float | None, typer.Option(help="camera tilt below the horizon (deg)")] = None,
    focal_px: Annotated[float | None, typer.Option(help="focal length (px); default 0.9 x width")] = None,
    image_size: Annotated[str, typer.Option(help="WIDTHxHEIGHT")] = "1920x1080",
    k1: Annotated[float, typer.Option(help="radial distortion k1")] = -0.06,
    demand: Annotated[float | None, typer.Option(
        help="vehicles per hour per lane (default 600); with --junction per arm (default 400)")] = None,
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
    junction: Annotated[bool, typer.Option(
        "--junction", help="build a signalised four-arm junction instead of a road (gates.gpkg, "
        "truth_movements.csv)")] = False,
    turning: Annotated[str, typer.Option(help="with --junction: turning shares per arm")] =
        "left=0.2,through=0.6,right=0.2",
    azimuth: Annotated[float, typer.Option(help="with --junction: bearing of the northern arm (deg)")] = 20.0,
    camera_corner: Annotated[str, typer.Option(help="with --junction: the camera's corner, NE, SE, SW or NW")] =
        "SE",
    camera_distance: Annotated[float, typer.Option(
        help="with --junction: camera pole distance from the centre (m)")] = 45.0,
    gate_distance: Annotated[float, typer.Option(help="with --junction: gates this far from the centre (m)")] =
        22.0,
) -> None:
    """Generate a demo world: SUMO traffic, orthophoto, lidar, GCPs, true camera, H.264 video and truth
    (with --cameras: a city of several cameras and their cameras.csv)."""
    from rich.progress import BarColumn, Progress, TimeRemainingColumn

    from trafficgeo.io.run_manifest import check_writable_folder
    from trafficgeo.synth.world import WorldOptions, build_world

    check_writable_folder(out, "--out")
    size = parse_image_size(image_size)
    junction_only = {"--turning": turning != "left=0.2,through=0.6,right=0.2", "--azimuth": azimuth != 20.0,
                     "--camera-corner": camera_corner != "SE", "--camera-distance": camera_distance != 45.0,
                     "--gate-distance": gate_distance != 22.0}
    if junction:
        road_only = {"--one-way": one_way, "--length": length != 300.0, "--grade": grade != 0.0,
                     "--crossfall": crossfall != 0.02, "--crest-radius": crest_radius != 0.0,
                     "--curve-radius": curve_radius != 0.0, "--heading": heading is not None,
                     "--tilt": tilt is not None, "--count-stations": count_stations != "0",
                     "--cameras": cameras is not None, "--file-s": file_s is not None}
        given = [flag for flag, on in road_only.items() if on]
        if given:
            raise InputError(f"{given[0]} applies to the road world only; leave it out with --junction")
        _junction(out, seed=seed, lanes=lanes, camera_height=12.0 if camera_height is None else camera_height,
                  focal_px=focal_px, size=size, k1=k1, demand=400.0 if demand is None else demand, mix=_mix(mix),
                  duration=duration, fps=fps, outliers=outliers, no_video=no_video,
                  turning=_mix(turning, "--turning", "left=0.2,through=0.6,right=0.2"), azimuth=azimuth,
                  camera_corner=camera_corner, camera_distance=camera_distance, gate_distance=gate_distance)
        return
    given = [flag for flag, on in junction_only.items() if on]
    if given:
        raise InputError(f"{given[0]} applies to the junction world only; add --junction")
    camera_height = 8.0 if camera_height is None else camera_height
    demand = 600.0 if demand is None else demand
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


_JUNCTION_FLAGS = {"seed": "--seed", "lanes": "--lanes", "camera_height": "--camera-height", "focal_px": "--focal-px",
                   "image_size": "--image-size", "dist": "--k1", "veh_per_hour_per_arm": "--demand", "mix": "--mix",
                   "duration_s": "--duration", "fps": "--fps", "n_outliers": "--outliers", "turning": "--turning",
                   "azimuth_deg": "--azimuth", "camera_corner": "--camera-corner",
                   "camera_distance_m": "--camera-distance", "gate_distance_m": "--gate-distance"}


def _junction(out: Path, *, seed, lanes, camera_height, focal_px, size, k1, demand, mix, duration, fps, outliers,
              no_video, turning, azimuth, camera_corner, camera_distance, gate_distance) -> None:
    """``synth --junction``: the signalised four-arm junction world."""
    from rich.progress import BarColumn, Progress, TimeRemainingColumn

    from trafficgeo.synth.junction_sumo import JunctionOptions
    from trafficgeo.synth.junction_world import build_junction_world

    try:  # every option is checked before anything is written
        opts = JunctionOptions(seed=seed, lanes=lanes, camera_height=camera_height, focal_px=focal_px,
                               image_size=size, dist=(k1, 0.0, 0.0, 0.0, 0.0), veh_per_hour_per_arm=demand,
                               mix=mix, duration_s=duration, fps=fps, n_outliers=outliers, turning=turning,
                               azimuth_deg=azimuth, camera_corner=camera_corner, camera_distance_m=camera_distance,
                               gate_distance_m=gate_distance)
    except InputError as exc:
        raise InputError(exc.in_terms_of(_JUNCTION_FLAGS)) from None
    with Progress("[progress.description]{task.description}", BarColumn(), "{task.completed}/{task.total} frames",
                  TimeRemainingColumn(), console=console, transient=True) as progress:
        task = progress.add_task("rendering", total=None)
        summary = build_junction_world(out, opts, video=not no_video,
                                       progress=lambda i, n: progress.update(task, completed=i, total=n))
    console.print(f"junction: {summary['vehicles']} vehicles, {summary['frames']} frames, {summary['gcps']} GCPs "
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
