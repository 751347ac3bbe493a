"""Tests of trafficgeo.io.gis (GeoPackage, RFC 7946 GeoJSON and GeoParquet output)."""

from __future__ import annotations

import json
import sqlite3
import sys
from pathlib import Path

import numpy as np
import pyogrio
import pyproj
import pytest
import shapely

from trafficgeo.errors import InputError
from trafficgeo.io import gis
from trafficgeo.io.gis import Layer, points_layer, read_gis, write_gis

OREGON_FT = pyproj.CRS.from_epsg(2994)  # NAD83(HARN) / Oregon GIC Lambert (ft), international feet
FT = 0.3048

# Points near Eugene, Oregon; row 2 has an unknown position (NaN x).
X = np.array([636500.0, 636510.25, np.nan, 636530.125])
Y = np.array([849200.0, 849205.5, 849210.0, 849215.75])
Z = np.array([400.0, 401.5, 402.0, 403.25])
SPEED = np.array([1.5, np.nan, 2.0, 3.0])
LABEL = ["car", "truck", "bus", None]
TRACK = np.array([7, 8, 9, 10], dtype=np.int64)
CAMERA = shapely.Point(636480.0, 849180.0, 455.5)
# Clockwise in the projected frame (up, right, down): GeoJSON output must turn it counter-clockwise.
FOOTPRINT = shapely.Polygon([(636400.0, 849100.0), (636400.0, 849300.0), (636600.0, 849300.0), (636600.0, 849100.0)])


def _to_lonlat(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    transformer = pyproj.Transformer.from_crs(OREGON_FT, pyproj.CRS.from_epsg(4326), always_xy=True)
    lon, lat = transformer.transform(x, y)
    return np.asarray(lon), np.asarray(lat)


def _layers() -> list[Layer]:
    points = points_layer(
        "points", X, Y, Z, attributes={"speed": SPEED, "label": LABEL, "track": TRACK}, crs=OREGON_FT
    )
    camera = Layer("camera", [CAMERA], {"focal_px": [1234.5], "name": ["cam-1"]})
    footprint = Layer("footprint", [FOOTPRINT], {"area_ft2": [FOOTPRINT.area]})
    return [points, camera, footprint]


def _signed_area(ring: list[list[float]]) -> float:
    """Shoelace signed area: positive for a counter-clockwise ring (x=lon, y=lat)."""
    xy = np.asarray(ring, dtype=np.float64)[:, :2]
    return 0.5 * float(np.sum(xy[:-1, 0] * xy[1:, 1] - xy[1:, 0] * xy[:-1, 1]))


# ---------------------------------------------------------------------------------------------------- GeoPackage


@pytest.mark.slow
def test_gpkg_three_layers_roundtrip(tmp_path: Path) -> None:
    path = tmp_path / "scene.gpkg"
    write_gis(path, _layers(), OREGON_FT)

    info = pyogrio.list_layers(path)
    assert [str(n) for n in info[:, 0]] == ["points", "camera", "footprint"]
    assert [str(t) for t in info[:, 1]] == ["Point Z", "Point Z", "Polygon"]

    points = read_gis(path, "points")
    assert len(points) == 4
    assert pyproj.CRS(points.crs).equals(OREGON_FT)
    assert points.crs.to_epsg() == 2994
    finite = np.isfinite(X)
    assert points.geometry.isna().tolist() == (~finite).tolist()  # unknown position -> null geometry
    coords = shapely.get_coordinates(points.geometry.values[finite], include_z=True)
    np.testing.assert_array_equal(coords, np.column_stack([X, Y, Z])[finite])  # feet, unchanged, exact
    assert points["track"].tolist() == TRACK.tolist()
    lon, lat = _to_lonlat(X[finite], Y[finite])
    np.testing.assert_allclose(points["lon"].to_numpy()[finite], lon, rtol=0, atol=1e-12)
    np.testing.assert_allclose(points["lat"].to_numpy()[finite], lat, rtol=0, atol=1e-12)

    camera = read_gis(path, "camera")
    assert len(camera) == 1
    assert camera.geometry.iloc[0].equals_exact(CAMERA, tolerance=0)
    assert camera["name"].tolist() == ["cam-1"]
    footprint = read_gis(path, "footprint")
    assert len(footprint) == 1
    assert footprint.geometry.iloc[0].equals_exact(FOOTPRINT, tolerance=0)
    assert pyproj.CRS(footprint.crs).equals(OREGON_FT)

    # NaN and None are SQL NULL (not the text 'nan' / 'None'); checked in the GeoPackage's SQLite tables.
    with sqlite3.connect(path) as db:
        rows = db.execute(
            "SELECT typeof(speed), typeof(label), typeof(lon), label FROM points ORDER BY fid"
        ).fetchall()
    assert [r[0] for r in rows] == ["real", "null", "real", "real"]
    assert [r[1] for r in rows] == ["text", "text", "text", "null"]
    assert [r[2] for r in rows] == ["real", "real", "null", "real"]
    assert [r[3] for r in rows] == ["car", "truck", "bus", None]


def test_gpkg_accepts_crs_text(tmp_path: Path) -> None:
    path = tmp_path / "one.gpkg"
    write_gis(path, Layer("camera", [CAMERA], {}), "EPSG:2994")
    frame = read_gis(path)
    assert frame.crs.to_epsg() == 2994
    assert len(frame) == 1


def test_gpkg_overwrite_replaces_whole_file(tmp_path: Path) -> None:
    path = tmp_path / "scene.gpkg"
    write_gis(path, _layers(), OREGON_FT)
    write_gis(path, [Layer("gcps", [shapely.Point(636501.0, 849201.0)], {"id": ["A"]})], OREGON_FT)
    assert [str(n) for n in pyogrio.list_layers(path)[:, 0]] == ["gcps"]
    assert read_gis(path, "gcps")["id"].tolist() == ["A"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.gpkg"]


def test_gpkg_failure_midway_keeps_old_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "scene.gpkg"
    write_gis(path, [Layer("gcps", [shapely.Point(1.0, 2.0)], {"id": ["A"]})], OREGON_FT)
    before = path.read_bytes()

    real_writer = gis._write_gpkg_layer
    written: list[Path] = []

    def failing_writer(tmp: Path, layer: Layer, crs: pyproj.CRS) -> None:
        if written:
            assert tmp.exists()  # the first layer really went into the temporary GeoPackage
            raise RuntimeError("disk full")
        real_writer(tmp, layer, crs)
        written.append(tmp)

    monkeypatch.setattr(gis, "_write_gpkg_layer", failing_writer)
    with pytest.raises(RuntimeError, match="disk full"):
        write_gis(path, _layers(), OREGON_FT)

    assert written and written[0].parent == tmp_path and written[0] != path
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.gpkg"]  # no temp file or journal left


def test_object_columns_with_missing_values_keep_their_type(tmp_path: Path) -> None:
    geoms = [shapely.Point(636500.0 + i, 849200.0) for i in range(3)]
    columns = {"ok": [True, None, False], "n": [1, None, 3], "v": [1.5, np.nan, 2], "s": ["a", np.nan, "c"]}
    layer = Layer("p", geoms, columns)
    path = tmp_path / "p.gpkg"
    write_gis(path, layer, OREGON_FT)
    with sqlite3.connect(path) as db:
        sql = "SELECT ok, typeof(ok), n, typeof(n), v, typeof(v), s, typeof(s) FROM p ORDER BY fid"
        rows = db.execute(sql).fetchall()
    assert rows == [
        (1, "integer", 1, "integer", 1.5, "real", "a", "text"),
        (None, "null", None, "null", None, "null", None, "null"),
        (0, "integer", 3, "integer", 2.0, "real", "c", "text"),
    ]
    info = pyogrio.read_info(path)
    assert dict(zip(info["fields"], info["ogr_subtypes"], strict=True))["ok"] == "OFSTBoolean"
    write_gis(tmp_path / "p.geojson", layer, OREGON_FT)
    props = [f["properties"] for f in json.loads((tmp_path / "p.geojson").read_text())["features"]]
    assert [(p["ok"], p["n"], p["v"], p["s"]) for p in props] == [
        (True, 1, 1.5, "a"), (None, None, None, None), (False, 3, 2, "c")
    ]


# ---------------------------------------------------------------------------------------------------- GeoJSON


@pytest.mark.parametrize("suffix", [".geojson", ".json"])
def test_geojson_rfc7946(tmp_path: Path, suffix: str) -> None:
    path = tmp_path / f"scene{suffix}"
    write_gis(path, _layers(), OREGON_FT)
    text = path.read_text(encoding="utf-8")
    assert "NaN" not in text and "Infinity" not in text and '"nan"' not in text.lower()
    doc = json.loads(text)

    assert doc["type"] == "FeatureCollection"
    assert "crs" not in doc
    features = doc["features"]
    assert [f["properties"]["layer"] for f in features] == ["points"] * 4 + ["camera", "footprint"]
    assert all(f["type"] == "Feature" for f in features)

    # Points: lon/lat order, near Eugene, Oregon, 7+ decimals; z converted from feet to metres.
    lon, lat = _to_lonlat(X, Y)
    first = features[0]["geometry"]
    assert first["type"] == "Point"
    assert first["coordinates"][0] == pytest.approx(-123.0715322, abs=1e-7)
    assert first["coordinates"][1] == pytest.approx(44.0506752, abs=1e-7)
    for i in (0, 1, 3):
        got = features[i]["geometry"]["coordinates"]
        assert got[0] == pytest.approx(lon[i], abs=1e-7)
        assert got[1] == pytest.approx(lat[i], abs=1e-7)
        assert got[2] == pytest.approx(Z[i] * FT, abs=1e-4)
    assert features[2]["geometry"] is None  # unknown position

    # NaN / None attributes -> JSON null; numbers and strings kept.
    props = [f["properties"] for f in features[:4]]
    assert [p["speed"] for p in props] == [1.5, None, 2.0, 3.0]
    assert [p["label"] for p in props] == ["car", "truck", "bus", None]
    assert [p["track"] for p in props] == [7, 8, 9, 10]
    assert props[2]["lon"] is None and props[2]["lat"] is None
    assert props[0]["lon"] == pytest.approx(lon[0], abs=1e-12)

    camera = features[4]
    assert camera["properties"] == {"layer": "camera", "focal_px": 1234.5, "name": "cam-1"}
    assert camera["geometry"]["coordinates"][2] == pytest.approx(455.5 * FT, abs=1e-4)

    polygon = features[5]["geometry"]
    assert polygon["type"] == "Polygon"
    exterior = polygon["coordinates"][0]
    assert exterior[0] == exterior[-1]
    assert _signed_area(exterior) > 0  # counter-clockwise (right-hand rule)
    assert all(len(p) == 2 for p in exterior)
    assert all(-123.2 < p[0] < -123.0 and 44.0 < p[1] < 44.1 for p in exterior)

    # GDAL reads it back as one WGS 84 layer with every feature.
    frame = read_gis(path)
    assert len(frame) == 6
    assert frame.crs.to_epsg() == 4326


def test_geojson_drops_non_finite_z_only(tmp_path: Path) -> None:
    path = tmp_path / "p.geojson"
    layer = points_layer("points", [636500.0, 636501.0], [849200.0, 849201.0], [np.nan, 10.0], crs=OREGON_FT)
    write_gis(path, layer, OREGON_FT)
    coords = [f["geometry"]["coordinates"] for f in json.loads(path.read_text())["features"]]
    assert len(coords[0]) == 2
    assert coords[1][2] == pytest.approx(10.0 * FT)


# ---------------------------------------------------------------------------------------------------- points_layer


def test_points_layer_non_finite_rows_and_lonlat() -> None:
    x = np.array([636500.0, np.nan, 636520.0, 636530.0, np.inf])
    y = np.array([849200.0, 849210.0, -np.inf, 849230.0, 849240.0])
    layer = points_layer("points", x, y, attributes={"id": ["a", "b", "c", "d", "e"]}, crs="EPSG:2994")

    assert len(layer.geometries) == 5
    assert [g.is_empty for g in layer.geometries] == [False, True, True, False, True]
    assert not any(shapely.has_z(layer.geometries))
    assert layer.geometries[3].equals_exact(shapely.Point(636530.0, 849230.0), tolerance=0)
    assert list(layer.attributes["id"]) == ["a", "b", "c", "d", "e"]

    lon, lat = _to_lonlat(x[[0, 3]], y[[0, 3]])
    got_lon = np.asarray(layer.attributes["lon"])
    got_lat = np.asarray(layer.attributes["lat"])
    np.testing.assert_allclose(got_lon[[0, 3]], lon, rtol=0, atol=1e-12)
    np.testing.assert_allclose(got_lat[[0, 3]], lat, rtol=0, atol=1e-12)
    assert np.isnan(got_lon[[1, 2, 4]]).all() and np.isnan(got_lat[[1, 2, 4]]).all()


def test_points_layer_without_crs_or_lonlat_adds_no_columns() -> None:
    assert set(points_layer("p", [1.0], [2.0], attributes={"v": [1]}).attributes) == {"v"}
    assert set(points_layer("p", [1.0], [2.0], crs=OREGON_FT, lonlat=False).attributes) == set()
    layer = points_layer("p", [1.0, 2.0], [3.0, 4.0], z=5.0)
    assert shapely.get_coordinates(layer.geometries, include_z=True)[:, 2].tolist() == [5.0, 5.0]


def test_points_layer_errors() -> None:
    with pytest.raises(InputError, match="x has 2 values but y has 3"):
        points_layer("p", [1.0, 2.0], [1.0, 2.0, 3.0])
    with pytest.raises(InputError, match="'lon' clashes"):
        points_layer("p", [1.0], [2.0], attributes={"lon": [0.0]}, crs=OREGON_FT)
    with pytest.raises(InputError, match="x must be numbers"):
        points_layer("p", ["a"], [2.0])


# ---------------------------------------------------------------------------------------------------- errors


def _one_line_error(excinfo: pytest.ExceptionInfo[InputError]) -> str:
    message = str(excinfo.value)
    assert "\n" not in message
    return message


def test_unknown_suffix(tmp_path: Path) -> None:
    with pytest.raises(InputError) as excinfo:
        write_gis(tmp_path / "out.xyz", _layers(), OREGON_FT)
    message = _one_line_error(excinfo)
    assert "out.xyz" in message and "unknown GIS format '.xyz'" in message and ".gpkg" in message
    with pytest.raises(InputError, match="no suffix"):
        write_gis(tmp_path / "out", _layers(), OREGON_FT)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("crs", [None, pyproj.CRS.from_epsg(4326), "EPSG:4269"])
@pytest.mark.parametrize("suffix", [".gpkg", ".geojson"])
def test_missing_or_geographic_crs(tmp_path: Path, crs: object, suffix: str) -> None:
    with pytest.raises(InputError) as excinfo:
        write_gis(tmp_path / f"out{suffix}", _layers(), crs)  # type: ignore[arg-type]
    assert "projected CRS" in _one_line_error(excinfo)
    assert list(tmp_path.iterdir()) == []


def test_attribute_length_mismatch() -> None:
    with pytest.raises(InputError) as excinfo:
        Layer("points", [shapely.Point(0, 0)] * 3, {"speed": [1.0, 2.0]})
    message = _one_line_error(excinfo)
    assert "'points'" in message and "'speed' has 2 values" in message and "3 geometries" in message
    with pytest.raises(InputError, match="'speed'"):
        points_layer("points", [1.0, 2.0], [1.0, 2.0], attributes={"speed": [1.0]})


def test_layer_validation_errors(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="reserved"):
        Layer("p", [shapely.Point(0, 0)], {"geometry": [1]})
    with pytest.raises(InputError, match="differ only in case"):
        Layer("p", [shapely.Point(0, 0)], {"Speed": [1], "speed": [2]})
    with pytest.raises(InputError, match="not a shapely geometry"):
        Layer("p", [(0.0, 0.0)], {})  # type: ignore[list-item]
    with pytest.raises(InputError, match="not a 1-D column"):
        Layer("p", [shapely.Point(0, 0)], {"name": "abc"})
    with pytest.raises(InputError, match="name"):
        Layer("", [], {})
    twice = [Layer("gcps", [], {}), Layer("GCPs", [], {})]
    with pytest.raises(InputError, match="rename one"):
        write_gis(tmp_path / "x.gpkg", twice, OREGON_FT)
    with pytest.raises(InputError, match="no layers"):
        write_gis(tmp_path / "x.gpkg", [], OREGON_FT)
    with np.errstate(invalid="ignore"):
        bad = Layer("lines", [shapely.LineString([(0, 0), (np.nan, 1)])], {})
    with pytest.raises(InputError, match="feature 0 has coordinates"):
        write_gis(tmp_path / "x.gpkg", [bad], OREGON_FT)
    assert list(tmp_path.iterdir()) == []


def test_read_gis_errors(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="no such GIS file"):
        read_gis(tmp_path / "missing.gpkg")
    path = tmp_path / "scene.gpkg"
    write_gis(path, _layers(), OREGON_FT)
    with pytest.raises(InputError) as excinfo:
        read_gis(path, "tracks")
    message = _one_line_error(excinfo)
    assert "no layer 'tracks'" in message and "'points', 'camera', 'footprint'" in message
    assert len(read_gis(path)) == 4  # default: the first layer
    junk = tmp_path / "junk.gpkg"
    junk.write_text("not a geopackage")
    with pytest.raises(InputError, match="not a GIS vector file"):
        read_gis(junk)


# ---------------------------------------------------------------------------------------------------- GeoParquet


def test_parquet_needs_pyarrow(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "pyarrow", None)  # makes "import pyarrow" raise ImportError
    with pytest.raises(InputError) as excinfo:
        write_gis(tmp_path / "p.parquet", _layers()[:1], OREGON_FT)
    assert "pip install pyarrow" in _one_line_error(excinfo)
    assert list(tmp_path.iterdir()) == []


def test_parquet_one_layer_only(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="one layer but 3 were given"):
        write_gis(tmp_path / "p.parquet", _layers(), OREGON_FT)


def test_parquet_roundtrip(tmp_path: Path) -> None:
    pq = pytest.importorskip("pyarrow.parquet")
    path = tmp_path / "points.parquet"
    write_gis(path, _layers()[:1], OREGON_FT)
    frame = read_gis(path)
    assert len(frame) == 4
    assert frame.crs.to_epsg() == 2994
    assert frame.geometry.isna().tolist() == [False, False, True, False]
    assert frame.geometry.iloc[3].equals_exact(shapely.Point(X[3], Y[3], Z[3]), tolerance=0)
    assert pq.read_table(path).column("speed").null_count == 1  # NaN -> null
    assert sorted(p.name for p in tmp_path.iterdir()) == ["points.parquet"]
