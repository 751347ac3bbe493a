"""Inputs in the wrong unit or CRS: analyze names the likely cause instead of writing empty results with
misleading advice (a DEM in feet read as metres, lanes with a wrong CRS label, counting lines behind the camera)."""

from __future__ import annotations

import json
from pathlib import Path

import geopandas as gpd
import numpy as np
import pytest
import rasterio
import shapely
from rasterio.transform import from_origin

from cli_support import invoke
from test_cli_traffic import CRS, E0, FPS, N0, Z0, scene  # noqa: F401  (scene is a fixture)
from trafficgeo.errors import InputError


def _dem(path: Path, z: float) -> Path:
    with rasterio.open(path, "w", driver="GTiff", height=400, width=200, count=1, dtype="float32", crs=CRS,
                       transform=from_origin(E0 - 100, N0 + 350, 1.0, 1.0)) as dst:
        dst.write(np.full((400, 200), z, dtype="float32"), 1)
    return path


def _analyze(scene: dict[str, Path], out: Path, *extra: object) -> tuple[int, str, str]:  # noqa: F811
    return invoke("analyze", scene["camera"], scene["tracks"], "--fps", FPS, "--out", out, *extra)


@pytest.mark.slow
def test_a_dem_in_feet_read_as_metres_is_named(scene: dict[str, Path], tmp_path: Path) -> None:  # noqa: F811
    code, _, stderr = _analyze(scene, tmp_path / "ok", "--surface", _dem(tmp_path / "m.tif", Z0))
    assert code == 0, stderr
    out = tmp_path / "out"
    code, _, stderr = _analyze(scene, out, "--surface", _dem(tmp_path / "ft.tif", Z0 / 0.3048))
    assert code == 2 and len(stderr.strip().splitlines()) == 1, stderr
    assert "220.1 m above the camera" in stderr and "probably in feet" in stderr
    assert not out.exists()


def test_a_surface_on_another_datum_is_named_without_feet(scene: dict[str, Path]) -> None:  # noqa: F811
    from trafficgeo.camera.calibrated import read_camera_json
    from trafficgeo.geo.surface import ConstantSurface
    from trafficgeo.site.checks import check_camera_above_surface

    cam = read_camera_json(scene["camera"])
    check_camera_above_surface(cam, ConstantSurface(Z0))
    with pytest.raises(InputError, match=r"42\.0 m above the camera") as err:
        check_camera_above_surface(cam, ConstantSurface(Z0 + 50))  # 50 m higher: feet would leave it 62 m up
    assert "feet" not in str(err.value)


@pytest.mark.slow
def test_lanes_with_a_wrong_crs_label_are_named(scene: dict[str, Path], tmp_path: Path) -> None:  # noqa: F811
    lanes = gpd.read_file(scene["lanes"]).to_crs(CRS).set_crs("EPSG:32634", allow_override=True)  # next UTM zone
    lanes.to_file(tmp_path / "lanes.gpkg")
    out = tmp_path / "out"
    code, stdout, stderr = _analyze(scene, out, "--surface", Z0, "--lanes", tmp_path / "lanes.gpkg")
    assert code == 0, stderr
    words = " ".join(stdout.split())
    assert "100% of the track points lie in no lane" in words and "not in the CRS their file declares" in words
    assert any("lie in no lane" in w for w in json.loads((out / "summary.json").read_text())["warnings"])
    code, stdout, stderr = _analyze(scene, tmp_path / "right", "--surface", Z0, "--lanes", scene["lanes"])
    assert code == 0 and "no lane" not in stdout, stderr


@pytest.mark.slow
@pytest.mark.parametrize(("where", "expect"), [
    ("behind", "counting line x lies behind the camera (50 m away towards 190 deg, while the camera looks towards "
               "350 deg)"),
    ("far", "counting line x lies 5050 m away towards 360 deg, while the camera looks towards 350 deg, far beyond what "
            "the camera can resolve"),
])
def test_counting_lines_out_of_view_are_named(where: str, expect: str, scene: dict[str, Path],  # noqa: F811
                                              tmp_path: Path) -> None:
    y = N0 - 60.0 if where == "behind" else N0 + 5040.0  # far: northings 5 km off (another false northing)
    line = gpd.GeoDataFrame({"name": ["x"]}, geometry=[shapely.LineString([(E0 - 8, y), (E0 + 1, y)])], crs=CRS)
    line.to_file(tmp_path / "lines.gpkg")
    code, stdout, stderr = _analyze(scene, tmp_path / "out", "--surface", Z0, "--lines", tmp_path / "lines.gpkg")
    assert code == 0, stderr
    words = " ".join(stdout.split())
    assert expect in words and "not in the CRS its file declares" in words
    assert "move the line nearer" not in words  # the old advice, wrong here
