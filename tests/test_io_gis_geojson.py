"""Why trafficgeo.io.gis writes GeoJSON itself rather than through pyogrio/GDAL's GeoJSON driver.

The GDAL writer is given its best chance: geometries already in lon/lat (the same transform and orientation as
``write_gis``), ``RFC7946=YES``, ``COORDINATE_PRECISION=8`` (the hand writer's 8 decimals) and
``SIGNIFICANT_FIGURES=17``. Where both agree (positions of finite 3-D points) the tests check that too, so the
comparison is fair; where GDAL changes values, the test names what it changes. If a GDAL release stops doing
these things, these tests fail and the hand writer can go.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import geopandas as gpd
import numpy as np
import pandas as pd
import pyogrio
import pyproj
import shapely

from trafficgeo.io import gis
from trafficgeo.io.gis import Layer, points_layer, write_gis

OREGON_FT = pyproj.CRS.from_epsg(2994)  # NAD83(HARN) / Oregon GIC Lambert (international feet)
GDAL_OPTIONS = {"RFC7946": "YES", "COORDINATE_PRECISION": "8", "SIGNIFICANT_FIGURES": "17"}


def _gdal_geojson(path: Path, layers: list[Layer], crs: pyproj.CRS) -> dict:
    """The layers written by pyogrio's GeoJSON driver as one collection with a ``layer`` column (GeoJSON holds one
    layer per file), after the same lon/lat transform and ring orientation as write_gis."""
    frames = []
    for layer in layers:
        lonlat = gis._orient_ccw(gis._to_lonlat(gis._geometry_array(layer), crs))
        data = {"layer": [layer.name] * len(lonlat)} | {c: gis._column(v) for c, v in layer.attributes.items()}
        frames.append(gpd.GeoDataFrame(data, geometry=gpd.GeoSeries(lonlat, crs=4326), crs=4326))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # "Infinite or NaN coordinate encountered"
        pyogrio.write_dataframe(pd.concat(frames, ignore_index=True), path, driver="GeoJSON",
                                layer_options=GDAL_OPTIONS, nan_as_null=True)
    return json.loads(path.read_text(encoding="utf-8"))


def _hand_geojson(path: Path, layers: list[Layer], crs: pyproj.CRS) -> dict:
    write_gis(path, layers, crs)
    return json.loads(path.read_text(encoding="utf-8"))


def _both(tmp_path: Path, layers: list[Layer]) -> tuple[list[dict], list[dict]]:
    hand = _hand_geojson(tmp_path / "hand.geojson", layers, OREGON_FT)["features"]
    gdal = _gdal_geojson(tmp_path / "gdal.geojson", layers, OREGON_FT)["features"]
    assert len(hand) == len(gdal)
    return hand, gdal


def test_positions_agree_where_gdal_keeps_them(tmp_path: Path) -> None:
    """Finite 3-D points and a polygon: the same lon/lat to 8 decimals and z in metres in both writers."""
    pts = points_layer("p", [636500.0, 636510.25], [849200.0, 849205.5], [400.0, 401.5], crs=OREGON_FT)
    ring = shapely.Polygon([(636400.0, 849100.0), (636400.0, 849300.0), (636600.0, 849300.0), (636600.0, 849100.0)])
    hand, gdal = _both(tmp_path, [pts])
    assert [f["geometry"] for f in hand] == [f["geometry"] for f in gdal]
    assert hand[0]["geometry"]["coordinates"][2] == 121.92  # 400 ft in metres
    hand, gdal = _both(tmp_path, [Layer("area", [ring], {})])
    assert hand[0]["geometry"] == gdal[0]["geometry"]


def test_gdal_gives_every_feature_every_layers_fields(tmp_path: Path) -> None:
    """One GeoJSON layer has one schema: a camera feature gets the points' fields as nulls, and an integer column
    with nulls from the other layers becomes float; write_gis keeps each layer's own properties and types."""
    pts = points_layer("points", [636500.0], [849200.0], [400.0], attributes={"track": np.array([7])},
                       crs=OREGON_FT, lonlat=False)
    camera = Layer("camera", [shapely.Point(636480.0, 849180.0, 455.5)], {"focal_px": [1234.5]})
    hand, gdal = _both(tmp_path, [pts, camera])
    assert hand[1]["properties"] == {"layer": "camera", "focal_px": 1234.5}
    assert gdal[1]["properties"] == {"layer": "camera", "track": None, "focal_px": 1234.5}
    assert hand[0]["properties"] == {"layer": "points", "track": 7}
    assert gdal[0]["properties"]["track"] == 7.0 and isinstance(gdal[0]["properties"]["track"], float)


def test_gdal_drops_the_position_of_a_point_with_unknown_height(tmp_path: Path) -> None:
    """A 3-D point with NaN z (known x, y): write_gis writes its lon/lat, GDAL a null geometry."""
    layer = points_layer("p", [636500.0, 636501.0], [849200.0, 849201.0], [np.nan, 10.0], crs=OREGON_FT)
    hand, gdal = _both(tmp_path, [layer])
    assert hand[0]["geometry"]["coordinates"] == [-123.0715322, 44.05067519]
    assert gdal[0]["geometry"] is None
    assert hand[1]["geometry"] == gdal[1]["geometry"]


def test_gdal_rounds_attribute_values(tmp_path: Path) -> None:
    """Float attributes: GDAL writes 0.1 + 0.2 as 0.3 even with SIGNIFICANT_FIGURES=17, and timestamps to the
    millisecond; write_gis writes the float exactly (shortest round-trip text) and microseconds."""
    t = pd.Timestamp("2026-01-02T03:04:05.123456")
    layer = Layer("p", [shapely.Point(636500.0, 849200.0)], {"v": np.array([0.1 + 0.2]), "t": [t]})
    hand, gdal = _both(tmp_path, [layer])
    assert hand[0]["properties"]["v"] == 0.1 + 0.2 != 0.3
    assert gdal[0]["properties"]["v"] == 0.3
    assert hand[0]["properties"]["t"] == "2026-01-02T03:04:05.123456"
    assert gdal[0]["properties"]["t"] == "2026-01-02T03:04:05.123"
