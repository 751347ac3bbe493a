"""Fixtures shared by several test modules, built once per session.

Nothing built here may be changed by a test: :func:`small_world` is a folder the tests only read (its files are
hashed when built and checked again at the end of the session), :func:`roadside_camera` a camera whose arrays are
read-only. A test that needs to change one works on its own copy (``shutil.copytree``, ``dataclasses.replace``).

The ``slow`` marker (registered in pyproject.toml) marks the tests and modules too slow for a quick loop: each took
0.4 s or more on the shared 2-core machine, or the module builds a costly fixture (a world, a SUMO run, the browser).
``make test-fast`` runs ``pytest -m "not slow"``, ``make test`` everything.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest

from trafficgeo.camera.model import Camera

#: The small generated world of the video tests: 8 s of SUMO traffic at 25 fps seen by a 640x360 camera, 600
#: vehicles per hour and lane on 2 x 2 lanes (at 1200 the far road is covered most of the time and a 2 s warm-up
#: cannot see the background there), one counting line at station 20 m, a 0.2 m orthophoto (coarse: quick to build).
SMALL_WORLD = {"seed": 3, "duration_s": 8.0, "image_size": (640, 360), "count_stations": (20.0,),
               "veh_per_hour_per_lane": 600.0, "ortho_resolution": 0.2}

#: The roadside camera of the analyze and report tests: 1080p, f = 1700 px, 8 m up, 5 m east and 10 m south of
#: (E0, N0), looking 10 deg west of north and 10 deg down, in UTM 33N.
ROADSIDE_ORIGIN = (500000.0, 5000000.0, 100.0)  # E0, N0, Z0
ROADSIDE_CRS = "EPSG:32633"


def _digest(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha1(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="session", autouse=True)
def _own_cache_folder(tmp_path_factory: pytest.TempPathFactory):
    """The backend probe's cache (trafficgeo.video.detectors.backends) in a folder of the session, never the
    user's."""
    from trafficgeo.io.environment import environment

    with environment({"TRAFFICGEO_CACHE_DIR": str(tmp_path_factory.mktemp("trafficgeo-cache"))}):
        yield


@pytest.fixture(scope="session")
def small_world(tmp_path_factory: pytest.TempPathFactory):
    """Folder of :data:`SMALL_WORLD` built by ``trafficgeo.synth.world.build_world`` (video.mp4,
    camera_truth.json, cloud.laz, lanes.gpkg, count_lines.gpkg, truth_tracks.csv, ...). Read only: write outputs
    elsewhere. The session fails at teardown if any file in it was changed, added or removed."""
    from trafficgeo.synth.world import WorldOptions, build_world

    folder = tmp_path_factory.mktemp("small_world")
    build_world(folder, WorldOptions(**SMALL_WORLD))
    before = _digest(folder)
    yield folder
    assert _digest(folder) == before, f"a test changed the shared world in {folder}"


@pytest.fixture(scope="session")
def small_city(tmp_path_factory: pytest.TempPathFactory):
    """Folder of the default multi-camera city (``trafficgeo.synth.city.build_city``: 2 cameras on one road, 640x360,
    10 fps, two 10 s video files each in ``videos/``, ``cameras.csv``). Read only, checked like :func:`small_world`."""
    from trafficgeo.synth.city import CityOptions, build_city

    folder = tmp_path_factory.mktemp("small_city")
    build_city(folder, CityOptions())
    before = _digest(folder)
    yield folder
    assert _digest(folder) == before, f"a test changed the shared city in {folder}"


#: The registration scene of the orthophoto-refinement tests (test_registration, test_ui_refine, test_report_refine):
#: 960x540, 8 m up, 8 control + 3 check points clicked with 3 px noise; its ground rendered at 2x and averaged.
REGISTRATION_SCENE = {"seed": 1, "image_size": (960, 540), "supersample": 2}


@pytest.fixture(scope="session")
def registration_scene(tmp_path_factory: pytest.TempPathFactory):
    """Folder written by ``trafficgeo.synth.registration_scene.write_registration_scene`` for
    :data:`REGISTRATION_SCENE` (frame.png, ortho.tif, ortho_elsewhere.tif, dem.tif, gcps.csv, camera.json from
    them, and the truth: camera_truth.json, perfect_gcps.csv, truth_points.csv). Read only, checked like
    :func:`small_world`."""
    from trafficgeo.synth.registration_scene import RegistrationSceneOptions, write_registration_scene

    folder = tmp_path_factory.mktemp("registration_scene")
    write_registration_scene(folder, RegistrationSceneOptions(**REGISTRATION_SCENE))
    before = _digest(folder)
    yield folder
    assert _digest(folder) == before, f"a test changed the shared registration scene in {folder}"


@pytest.fixture(scope="session")
def roadside_camera() -> Camera:
    """The camera of :data:`ROADSIDE_ORIGIN` (frozen, read-only arrays)."""
    e0, n0, z0 = ROADSIDE_ORIGIN
    cam = Camera.from_orientation((1920, 1080), 1700.0, [e0 + 5.0, n0 - 10.0, z0 + 8.0], 350.0, 10.0,
                                  crs=ROADSIDE_CRS)
    for array in (cam.K, cam.dist, cam.R, cam.position):
        array.setflags(write=False)
    return cam
