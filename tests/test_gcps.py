"""Tests of the GCP table, reader and checks (trafficgeo.calibration.gcp_*): reading GCP files and validating
their geometry."""

from __future__ import annotations

import csv
import tempfile
from collections import defaultdict
from pathlib import Path

import numpy as np
import pyproj
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from trafficgeo.calibration.gcp_checks import validate_gcps
from trafficgeo.calibration.gcp_read import read_gcps
from trafficgeo.calibration.gcp_table import GCPTable
from trafficgeo.crs import looks_like_lonlat, parse_crs
from trafficgeo.errors import InputError

DATA = Path(__file__).parent / "data"
PAPER = DATA / "paper_table2_gcps.csv"
ODM_UTM = DATA / "odm-gcp-list-copr" / "gcp_list_utm10n.txt"
ODM_LONLAT = DATA / "odm-gcp-list-copr" / "gcp_list.txt"
I24 = DATA / "i24-camera-gcps" / "camera_calibration_points_I24_validation_system.csv"
I24_SIZE = (3840, 2160)
HEADER = "id,x,y,z,u,v\n"


def write(tmp_path: Path, text: str, name: str = "gcps.csv") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def raises_input(path: Path, *parts: str, **kwargs: object) -> str:
    """read_gcps must raise a one-line InputError containing every part as the command line shows it (parameter
    names turned into flags, the library's own message naming no flag); returns that message."""
    from trafficgeo.cli import FLAGS

    with pytest.raises(InputError) as info:
        read_gcps(path, **kwargs)  # type: ignore[arg-type]
    assert "--" not in str(info.value)
    msg = info.value.in_terms_of(FLAGS)
    assert "\n" not in msg
    for part in parts:
        assert part in msg, f"{part!r} not in {msg!r}"
    return msg


# ------------------------------------------------------------------------------------------ CSV reading


def test_read_paper_table2() -> None:
    t = read_gcps(PAPER, crs="EPSG:2949")
    assert t.n == 7
    assert t.ids == ("1", "2", "3", "4", "5", "6", "7")
    assert t.crs == pyproj.CRS.from_epsg(2949)
    assert t.world.shape == (7, 3) and t.world.dtype == np.float64
    assert t.pixels.shape == (7, 2) and t.pixels.dtype == np.float64
    np.testing.assert_array_equal(t.world[0], [245030.06, 5182608.21, 90.28])
    np.testing.assert_array_equal(t.world[6], [245031.21, 5182623.60, 98.18])  # Z 8 m too high, kept
    np.testing.assert_array_equal(t.pixels[:, 0], [372, 241, 336, 328, 292, 272, 56])
    np.testing.assert_array_equal(t.pixels[:, 1], [255, 252, 263, 283, 253, 274, 331])
    assert t.roles == ("control",) * 7
    np.testing.assert_array_equal(t.sigma_px, np.ones(7))
    assert t.lines == (2, 3, 4, 5, 6, 7, 8)
    assert t.where(3) == f'{PAPER} line 5 (id "4")'
    assert t.is_control.all() and not t.is_check.any()
    assert not t.world.flags.writeable


def test_read_paper_table2_gcp_crs_only_and_local() -> None:
    assert read_gcps(PAPER, gcp_crs="EPSG:2949").crs == pyproj.CRS.from_epsg(2949)
    local = read_gcps(PAPER)
    assert local.crs is None
    np.testing.assert_array_equal(local.world, read_gcps(PAPER, crs="EPSG:2949").world)


def test_paper_table2_validates_with_small_coverage_warning() -> None:
    t = read_gcps(PAPER, crs="EPSG:2949")
    warnings = validate_gcps(t, (848, 464))
    assert any("cover only" in w for w in warnings)
    assert not any("fewer than 6" in w for w in warnings)  # 7 control points


def test_role_and_sigma_columns_any_order_and_case(tmp_path: Path) -> None:
    path = write(
        tmp_path,
        "U,V,Note,ID,X,Y,Z,Role,Sigma_PX\n"
        "10,20,first,A,1000,2000,0,control,2.5\n"
        "11,21,,B,1010,2000,0,CHECK,\n"
        "\n"
        "12,22,x,C,1000,2010,0,,0.5\n",
    )
    t = read_gcps(path)
    assert t.ids == ("A", "B", "C")
    assert t.roles == ("control", "check", "control")
    np.testing.assert_array_equal(t.is_check, [False, True, False])
    np.testing.assert_array_equal(t.sigma_px, [2.5, 1.0, 0.5])
    np.testing.assert_array_equal(t.pixels, [[10, 20], [11, 21], [12, 22]])
    assert t.lines == (2, 3, 5)  # blank line skipped, line numbers kept


def test_semicolon_delimiter_and_bom(tmp_path: Path) -> None:
    path = tmp_path / "g.csv"
    path.write_bytes("\ufeffid;x;y;z;u;v\nP1;1000;2000;0;5;6\n".encode())
    t = read_gcps(path)
    assert t.ids == ("P1",) and t.world.tolist() == [[1000.0, 2000.0, 0.0]]


def test_lonlat_csv_transformed_to_utm(tmp_path: Path) -> None:
    lon = [-86.60975, -86.609497, -86.61201, -86.610909]
    lat = [36.004546, 36.004659, 36.006424, 36.006121]
    rows = "".join(
        f"P{k},{lo!r},{la!r},150.5,{100 * k},{50 * k}\n"
        for k, (lo, la) in enumerate(zip(lon, lat, strict=True))
    )
    path = write(tmp_path, HEADER + rows)
    t = read_gcps(path, gcp_crs="EPSG:4326")
    assert t.crs == pyproj.CRS.from_epsg(32616)  # UTM zone of the points
    ref = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:32616", always_xy=True)
    ex, ey = ref.transform(lon, lat)
    np.testing.assert_allclose(t.world[:, 0], ex, rtol=0, atol=1e-6)
    np.testing.assert_allclose(t.world[:, 1], ey, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(t.world[:, 2], 150.5)  # Z untouched
    # explicit working CRS (feet) instead of the automatic UTM zone
    ft = read_gcps(path, gcp_crs="EPSG:4326", crs="EPSG:2274")  # NAD83 / Tennessee (ftUS)
    ref_ft = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:2274", always_xy=True)
    fx, fy = ref_ft.transform(lon, lat)
    assert ft.crs == pyproj.CRS.from_epsg(2274)
    np.testing.assert_allclose(ft.world[:, :2], np.column_stack([fx, fy]), rtol=0, atol=1e-6)


def test_projected_to_other_projected(tmp_path: Path) -> None:
    path = write(tmp_path, HEADER + "A,500000,3985000,10,1,2\nB,500100,3985050,11,3,4\n")
    t = read_gcps(path, gcp_crs="EPSG:32616", crs="+proj=utm +zone=16 +datum=WGS84 +units=ft +no_defs")
    np.testing.assert_allclose(t.world[:, 0], np.array([500000, 500100]) / 0.3048, rtol=1e-12)
    np.testing.assert_array_equal(t.world[:, 2], [10, 11])


# ------------------------------------------------------------------------------------------ bad inputs


def test_missing_file(tmp_path: Path) -> None:
    raises_input(tmp_path / "nope.csv", "nope.csv", "does not exist")


def test_folder_instead_of_file(tmp_path: Path) -> None:
    raises_input(tmp_path, str(tmp_path), "folder")


@pytest.mark.parametrize("text", ["", "\n\n  \n"])
def test_empty_file(tmp_path: Path, text: str) -> None:
    raises_input(write(tmp_path, text), "gcps.csv", "is empty", "id,x,y,z,u,v")


def test_header_only(tmp_path: Path) -> None:
    raises_input(write(tmp_path, HEADER), "gcps.csv", "no GCP rows")


def test_missing_columns(tmp_path: Path) -> None:
    msg = raises_input(write(tmp_path, "id,x,y,a,b\nA,1,2,3,4\n"), "gcps.csv line 1", "'z'", "'u'", "'v'")
    assert "'x'" not in msg
    # col, row are pixel columns people use (issue 42): only the height is missing, and said to be a height
    msg = raises_input(write(tmp_path, "id,x,y,col,row\nA,1,2,3,4\n"), "gcps.csv line 1", "'z'", "a height")
    assert "'u'" not in msg and "'x'" not in msg


def test_peers_column_names_are_read_with_a_note(tmp_path: Path) -> None:
    """GCP files as people have them (issue 42): a drone author's pixel_x/pixel_y/lat_deg/lon_deg with spaces
    after the commas and no id, surveyors' easting/northing/elevation with col/row, pixel x/y beside lat/lon."""
    from pyproj import Transformer

    lon, lat = -123.0712, 44.0521
    e, n = Transformer.from_crs("EPSG:4326", "EPSG:32610", always_xy=True).transform(lon, lat)
    author = write(tmp_path, f"pixel_x, pixel_y, lat_deg, lon_deg, alt\n100.5, 200.25, {lat}, {lon}, 131.5\n"
                             f"300, 400, {lat + 0.0001}, {lon + 0.0001}, 132\n", "author.csv")
    t = read_gcps(author, crs="EPSG:32610")
    assert t.ids == ("line2", "line3")
    np.testing.assert_allclose(t.pixels, [[100.5, 200.25], [300.0, 400.0]])
    np.testing.assert_allclose(t.world[0], [e, n, 131.5], atol=1e-6)
    assert t.columns_note == ("pixel_x -> u, pixel_y -> v, lon_deg -> x, lat_deg -> y, alt -> z (longitude, "
                              "latitude by their names), no id column: points named by their line")
    survey = write(tmp_path, "Name;Easting;Northing;Elevation;Col;Row\nP1;500000.5;4877000.25;131.5;10;20\n",
                   "survey.csv")
    t = read_gcps(survey, crs="EPSG:32610")
    assert t.ids == ("P1",) and t.columns_note.startswith("Name -> id, Col -> u, Row -> v, Easting -> x")
    np.testing.assert_allclose(t.world, [[500000.5, 4877000.25, 131.5]])
    beside = write(tmp_path, f"id,x,y,lat,lon,height\nA,12,34,{lat},{lon},130\n", "beside.csv")
    t = read_gcps(beside, crs="EPSG:32610")
    np.testing.assert_allclose(t.pixels, [[12.0, 34.0]])
    np.testing.assert_allclose(t.world[0, :2], [e, n], atol=1e-6)
    assert "x -> u, y -> v, lon -> x, lat -> y, height -> z" in t.columns_note
    assert read_gcps(write(tmp_path, HEADER + "A,500000,4877000,3,4,5\n", "plain.csv")).columns_note == ""


def test_the_i24_authors_file_is_read_as_published() -> None:
    """The I-24 camera GCPs as their author published them: 18 cameras in one file (column "Camera"), "GPS Lat,
    GPS Long, Camera X, Camera Y", no heights. One camera is chosen by odm_image, flat ground by ground_z."""
    with pytest.raises(InputError, match=r'18 images or cameras \(column "Camera"\) \(P1C1, P1C2.*odm_image') as exc:
        read_gcps(I24, ground_z=0.0)
    assert exc.value.parameters == ("odm_image",)
    with pytest.raises(InputError, match=r"lacks the column.*'z'.*ground_z") as exc:
        read_gcps(I24, odm_image="p2c3")
    assert exc.value.parameters == ("ground_z",)
    t = read_gcps(I24, odm_image="p2c3", ground_z=12.5)
    with open(I24, newline="") as fh:
        rows = [r for r in csv.DictReader(fh) if r["Camera"] == "P2C3"]
    assert len(t.ids) == len(rows) == 4
    np.testing.assert_allclose(t.pixels, [[float(r["Camera X"]), float(r["Camera Y"])] for r in rows])
    np.testing.assert_allclose(t.world[:, 2], 12.5)
    east, north = pyproj.Transformer.from_crs("EPSG:4326", t.crs, always_xy=True).transform(
        [float(r["GPS Long"]) for r in rows], [float(r["GPS Lat"]) for r in rows])
    np.testing.assert_allclose(t.world[:, :2], np.column_stack([east, north]), atol=1e-6)
    assert t.crs == parse_crs("EPSG:32616")  # Nashville
    assert t.columns_note.startswith("Camera X -> u, Camera Y -> v, GPS Long -> x, GPS Lat -> y, Camera -> image")
    with pytest.raises(InputError, match="no GCP rows for image \"P9C9\""):
        read_gcps(I24, odm_image="P9C9", ground_z=0.0)
    with pytest.raises(InputError, match="ground_z is nan"):
        read_gcps(I24, odm_image="p2c3", ground_z=float("nan"))


def test_qgis_points_files(tmp_path: Path) -> None:
    """QGIS Georeferencer .points (QGIS 3: a #CRS line; older: none, pixelX/pixelY): rows negated and pixel corners
    turned into trafficgeo's pixel centres, disabled points left out, heights from ground_z."""
    wkt = pyproj.CRS("EPSG:32610").to_wkt()
    qgis3 = write(tmp_path, f"#CRS: {wkt}\nmapX,mapY,sourceX,sourceY,enable,dX,dY,residual\n"
                            "500000.5,4877000.25,100.5,-200.5,1,0,0,0\n500010,4877020,0,0,0,0,0,0\n"
                            "500020,4877030,300,-400,1,0.1,0.2,0.3\n", "g.points")
    t = read_gcps(qgis3, ground_z=12.0)
    assert t.crs == parse_crs("EPSG:32610") and t.ids == ("line3", "line5")
    np.testing.assert_allclose(t.pixels, [[100.0, 200.0], [299.5, 399.5]])
    np.testing.assert_allclose(t.world, [[500000.5, 4877000.25, 12.0], [500020.0, 4877030.0, 12.0]])
    assert "1 disabled point(s) left out" in t.columns_note
    old = write(tmp_path, "mapX,mapY,pixelX,pixelY,enable\n-123.07,44.05,10.5,-20.5,1\n", "old.points")
    t = read_gcps(old, gcp_crs="EPSG:4326", crs="EPSG:32610", ground_z=0.0)
    np.testing.assert_allclose(t.pixels, [[10.0, 20.0]])
    raises_input(qgis3, "g.points", "no heights", "--ground-z")
    raises_input(write(tmp_path, "#CRS: EPSG:32610\nmapX,mapY,sourceX,sourceY,enable\n500000,4877000,5,6,1\n",
                       "geo.points"), "line 3", "negative", "georeferenced raster", ground_z=0.0)
    raises_input(write(tmp_path, "#CRS: not a crs\nmapX,mapY,sourceX,sourceY,enable\n500000,4877000,5,-6,1\n",
                       "bad.points"), "line 1", "not a CRS", "--gcp-crs", ground_z=0.0)


def test_not_a_header_nor_crs(tmp_path: Path) -> None:
    raises_input(
        write(tmp_path, "Station,Remarks,Date\nS1,kerb,2026-01-02\n"),  # the I-24 header is understood now (above)
        "gcps.csv line 1",
        "neither a CSV header",
        "WGS84 UTM 10N",
    )


@pytest.mark.parametrize(
    ("row", "parts"),
    [
        ("P4,1000,2000,0,abc,7", ['line 3 (id "P4")', 'column "u" is "abc", not a number', "pixel"]),
        ("P4,1000,2000,0,5,nan", ['line 3 (id "P4")', 'column "v" is "nan", not a finite number']),
        ("P4,1000,inf,0,5,6", ['line 3 (id "P4")', 'column "y"', "not a finite number"]),
        ("P4,1000,2000,,5,6", ['line 3 (id "P4")', 'column "z" is empty']),
        ("P4,1000,2000,1;5,5,6", ['line 3 (id "P4")', 'column "z"', "not a number"]),
        (",1000,2000,0,5,6", ["line 3", 'column "id" is empty']),
        ("P4,1000,2000,0,5", ["line 3", "5 values but the header has 6 columns"]),
        ("P4,1000,2000,0,5,6,7", ["line 3", "7 values but the header has 6 columns"]),
    ],
)
def test_bad_values(tmp_path: Path, row: str, parts: list[str]) -> None:
    raises_input(write(tmp_path, HEADER + "P1,1000,2000,0,1,1\n" + row + "\n"), "gcps.csv", *parts)


def test_decimal_comma_hint(tmp_path: Path) -> None:
    path = write(tmp_path, "id;x;y;z;u;v\nP1;1000,5;2000;0;1;1\n")
    raises_input(path, 'line 2 (id "P1")', '"1000,5"', "decimal separator")


def test_duplicate_ids(tmp_path: Path) -> None:
    path = write(tmp_path, HEADER + "P1,1000,2000,0,1,1\nP2,1010,2000,0,9,1\n\nP1,1020,2000,0,19,1\n")
    raises_input(path, 'gcps.csv line 5 (id "P1")', "also used on line 2", "unique")


def test_duplicate_header_column(tmp_path: Path) -> None:
    raises_input(write(tmp_path, "id,x,y,z,u,v,x\nP1,1,2,3,4,5,6\n"), "line 1", 'column "x" appears 2 times')


def test_unknown_role(tmp_path: Path) -> None:
    path = write(tmp_path, "id,x,y,z,u,v,role\nP1,1000,2000,0,1,1,control\nP2,1010,2000,0,9,1,verify\n")
    raises_input(path, 'line 3 (id "P2")', 'column "role" is "verify"', '"control"', '"check"')


@pytest.mark.parametrize(
    ("sigma", "part"), [("0", "not > 0"), ("-1.5", "not > 0"), ("nan", "not a finite"), ("x", "not a number")]
)
def test_bad_sigma(tmp_path: Path, sigma: str, part: str) -> None:
    path = write(tmp_path, f"id,x,y,z,u,v,sigma_px\nP1,1000,2000,0,1,1,1\nQ7,1010,2000,0,9,1,{sigma}\n")
    raises_input(path, 'line 3 (id "Q7")', 'column "sigma_px"', part)


def test_not_utf8(tmp_path: Path) -> None:
    path = tmp_path / "latin.csv"
    path.write_bytes(HEADER.encode() + "P1,1000,2000,0,1,1\nPé,1010,2000,0,9,1\n".encode("latin-1"))
    raises_input(path, "latin.csv line 3", "UTF-8")


def test_latitude_first_csv(tmp_path: Path) -> None:
    path = write(tmp_path, HEADER + "A,34.4082988,-119.879992,0,1,1\nB,34.4083427,-119.8799566,0,9,1\n")
    raises_input(path, "gcps.csv", "line 2", "latitude first", "swap", gcp_crs="EPSG:4326")


def test_latitude_first_csv_with_longitude_below_90(tmp_path: Path) -> None:
    # I-24 (lon -86.6): latitude first is a valid but Antarctic lon/lat, outside UTM, so it is still caught
    path = write(tmp_path, HEADER + "A,36.004546,-86.60975,0,1,1\nB,36.004659,-86.609497,0,9,1\n")
    raises_input(path, "gcps.csv", "line 2", "outside the UTM range", "latitude first", gcp_crs="EPSG:4326")


def test_lonlat_values_with_projected_crs(tmp_path: Path) -> None:
    path = write(tmp_path, HEADER + "A,-86.60975,36.004546,0,1,1\nB,-86.609497,36.004659,0,9,1\n")
    raises_input(path, "gcps.csv", "line 2", "longitude/latitude", "--gcp-crs EPSG:4326", crs="EPSG:32616")
    raises_input(path, "EPSG:2949", "--gcp-crs EPSG:4326", gcp_crs="EPSG:2949")
    raises_input(path, "no CRS was given", "--gcp-crs EPSG:4326")  # silently local degrees would be wrong


def test_projected_values_with_geographic_crs(tmp_path: Path) -> None:
    path = write(tmp_path, HEADER + "A,500000,3985000,0,1,1\n")
    raises_input(path, "line 2", "not longitude/latitude", "--gcp-crs", gcp_crs="EPSG:4326")


def test_geographic_working_crs_refused(tmp_path: Path) -> None:
    path = write(tmp_path, HEADER + "A,-86.60975,36.004546,0,1,1\n")
    raises_input(path, "--crs", "not a projected CRS", "--gcp-crs EPSG:4326", crs="EPSG:4326")
    raises_input(path, "--crs", "not a projected CRS", gcp_crs="EPSG:4326", crs="EPSG:4326")


@pytest.mark.slow
def test_bad_crs_text(tmp_path: Path) -> None:
    path = write(tmp_path, HEADER + "A,500000,3985000,0,1,1\n")
    raises_input(path, "--gcp-crs", '"EPSG:12"', gcp_crs="EPSG:12")
    raises_input(path, "--crs", '"UTM16"', crs="UTM16")


# ------------------------------------------------------------------------------------------ OpenDroneMap


def test_odm_utm_with_image_selection() -> None:
    t = read_gcps(ODM_UTM, odm_image="img_0031.JPG")  # case-insensitive
    assert t.crs == pyproj.CRS.from_epsg(32610)  # "WGS84 UTM 10N" header
    assert t.ids == ("row2", "row3")
    assert t.lines == (2, 3)
    np.testing.assert_array_equal(
        t.world, [[786791.731407357, 3811843.94849626, 0], [786794.844430210, 3811848.91972532, 0]]
    )
    np.testing.assert_array_equal(t.pixels, [[3483, 729], [731, 1017]])
    assert t.where(1) == f'{ODM_UTM} line 3 (id "row3")'
    t73 = read_gcps(ODM_UTM, odm_image="images/IMG_0073.jpg")  # a path to the image works too
    assert t73.ids == ("row8", "row9")


def test_odm_several_images_need_odm_image() -> None:
    msg = raises_input(ODM_UTM, "gcp_list_utm10n.txt", "8 images", "--odm-image")
    assert "IMG_0031.jpg" in msg and "IMG_0091.jpg" in msg


def test_odm_unknown_image() -> None:
    raises_input(ODM_UTM, '"IMG_9999.JPG"', "IMG_0031.jpg", "--odm-image", odm_image="IMG_9999.JPG")


@pytest.mark.parametrize("odm_image", [None, "IMG_0031.JPG"])
def test_odm_longlat_file_is_latitude_first(odm_image: str | None) -> None:
    raises_input(ODM_LONLAT, "gcp_list.txt", "line 2", "latitude first", "swap", odm_image=odm_image)


def swapped_longlat_copy(tmp_path: Path) -> Path:
    out = []
    for k, line in enumerate(ODM_LONLAT.read_text().splitlines()):
        parts = line.split()
        if k > 0 and parts:
            parts[0], parts[1] = parts[1], parts[0]
        out.append(" ".join(parts))
    return write(tmp_path, "\n".join(out) + "\n", "gcp_list_lonlat.txt")


def test_odm_utm_and_swapped_longlat_agree(tmp_path: Path) -> None:
    lonlat = swapped_longlat_copy(tmp_path)
    images = sorted(
        {line.split()[5].lower() for line in ODM_UTM.read_text().splitlines()[1:] if line.strip()}
    )
    assert len(images) == 8
    total = 0
    for image in images:
        utm = read_gcps(ODM_UTM, odm_image=image)
        geo = read_gcps(lonlat, crs="EPSG:32610", odm_image=image)
        assert geo.crs == utm.crs == pyproj.CRS.from_epsg(32610)
        assert np.max(np.abs(geo.world - utm.world)) < 1e-3  # < 1 mm
        np.testing.assert_array_equal(geo.pixels, utm.pixels)
        total += geo.n
    assert total == 10
    # without --crs the points go to the UTM zone they lie in (11), not the file's zone 10
    assert read_gcps(lonlat, odm_image="IMG_0031.JPG").crs == pyproj.CRS.from_epsg(32611)


def test_odm_gcp_names_single_image_and_override(tmp_path: Path) -> None:
    path = write(tmp_path, "# the first non-empty line must be the CRS\n", "bad.txt")
    raises_input(path, "bad.txt line 1", "neither")
    path = write(
        tmp_path,
        "EPSG:32610\n# a comment\n786791.7 3811843.9 12.5 3483 729 cam.jpg gcp_a extra words\n"
        "  786794.8\t3811848.9 12.0 731 1017 CAM.JPG\n",
        "odm.txt",
    )
    t = read_gcps(path)  # one image (case-insensitive), no --odm-image needed
    assert t.ids == ("gcp_a", "row4")
    np.testing.assert_array_equal(t.world[:, 2], [12.5, 12.0])
    assert t.crs == pyproj.CRS.from_epsg(32610)
    over = read_gcps(path, gcp_crs="EPSG:32610", crs="EPSG:32611")  # caller overrides / converts
    assert over.crs == pyproj.CRS.from_epsg(32611)
    assert np.all(np.abs(over.world[:, 0] - t.world[:, 0]) > 1000)


def test_odm_short_row_and_bad_number(tmp_path: Path) -> None:
    path = write(
        tmp_path, "WGS84 UTM 10N\n786791.7 3811843.9 0 3483 729 a.jpg\n786794.8 3811848.9 0 731\n", "o.txt"
    )
    raises_input(path, "o.txt line 3", "4 values", "at least 6")
    path = write(tmp_path, "WGS84 UTM 10N\n786791.7 3811843.9 0 3483 x7 a.jpg P9\n", "o.txt")
    raises_input(path, 'o.txt line 2 (id "P9")', 'column "im_y" is "x7"')
    path = write(tmp_path, "WGS84 UTM 10N\n\n", "o.txt")
    raises_input(path, "o.txt", "no GCP rows")


def test_odm_lonlat_under_utm_header(tmp_path: Path) -> None:
    path = write(tmp_path, "WGS84 UTM 10N\n-119.87999 34.40829 0 3483 729 a.jpg\n", "o.txt")
    raises_input(path, "o.txt", "line 2", "line 1 of the file", "--gcp-crs EPSG:4326")


# ------------------------------------------------------------------------------------------ GCPTable


def test_subset_where_and_from_arrays() -> None:
    t = read_gcps(PAPER, crs="EPSG:2949")
    s = t.subset([6, 0])
    assert s.ids == ("7", "1") and s.lines == (8, 2) and s.crs == t.crs
    np.testing.assert_array_equal(s.world, t.world[[6, 0]])
    m = t.subset(t.world[:, 2] < 95)
    assert m.n == 6 and "7" not in m.ids
    assert t.subset([]).n == 0
    with pytest.raises(ValueError):
        t.subset([True, False])
    mem = GCPTable.from_arrays(
        ["a", "b"], [[0, 0, 0], [1, 1, 1]], [[0, 0], [5, 5]], roles=["control", "check"]
    )
    assert mem.where(1) == '<memory> row 2 (id "b")'
    assert mem.is_check.tolist() == [False, True]
    with pytest.raises(ValueError):
        GCPTable.from_arrays(["a"], [[0, 0, np.nan]], [[0, 0]])
    with pytest.raises(ValueError):
        GCPTable.from_arrays(["a"], [[0, 0, 0]], [[0, 0]], roles=["fit"])
    with pytest.raises(ValueError):
        GCPTable.from_arrays(["a", "b", "c"], np.zeros((3, 2)), np.zeros((3, 2)))  # world needs X, Y, Z


def assert_same_table(a: GCPTable, b: GCPTable) -> None:
    assert a.ids == b.ids
    assert a.roles == b.roles
    assert np.array_equal(a.world, b.world)
    assert np.array_equal(a.pixels, b.pixels)
    assert np.array_equal(a.sigma_px, b.sigma_px)
    assert a.crs == b.crs


def test_to_csv_round_trip_exact(tmp_path: Path) -> None:
    t = read_gcps(PAPER, crs="EPSG:2949")
    t = GCPTable.from_arrays(
        t.ids,
        t.world + np.array([1e-7, 1 / 3, np.pi]),
        t.pixels + 0.1,
        roles=["control"] * 5 + ["check"] * 2,
        sigma_px=np.linspace(0.3, 3.1, 7),
        crs=t.crs,
    )
    out = tmp_path / "sub" / "out.csv"
    t.to_csv(out)
    assert out.read_text().splitlines()[0] == "id,x,y,z,u,v,role,sigma_px"
    back = read_gcps(out, crs="EPSG:2949")
    assert_same_table(t, back)
    assert [p.name for p in out.parent.iterdir()] == ["out.csv"]  # no temp file left behind


finite = st.floats(allow_nan=False, allow_infinity=False)
ids_strategy = st.text(
    alphabet=st.characters(blacklist_categories=("Cc", "Cs", "Zl", "Zp")), min_size=1, max_size=10
).map(str.strip)


@st.composite
def tables(draw: st.DrawFn) -> GCPTable:
    ids = draw(st.lists(ids_strategy.filter(bool), min_size=1, max_size=8, unique=True))
    n = len(ids)
    world = np.array(draw(st.lists(st.tuples(finite, finite, finite), min_size=n, max_size=n)))
    assume(
        not looks_like_lonlat(world[:, 0], world[:, 1]) and not looks_like_lonlat(world[:, 1], world[:, 0])
    )
    pixels = draw(st.lists(st.tuples(finite, finite), min_size=n, max_size=n))
    roles = draw(st.lists(st.sampled_from(["control", "check"]), min_size=n, max_size=n))
    sigma = draw(
        st.lists(
            st.floats(min_value=0, exclude_min=True, allow_infinity=False, allow_nan=False),
            min_size=n,
            max_size=n,
        )
    )
    return GCPTable.from_arrays(ids, world, pixels, roles=roles, sigma_px=sigma)


@pytest.mark.slow
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(table=tables())
def test_to_csv_read_gcps_round_trip_property(table: GCPTable) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "t.csv"
        table.to_csv(path)
        back = read_gcps(path)
    assert_same_table(table, back)


# ------------------------------------------------------------------------------------------ validation


def i24_camera_csv(camera: str, folder: Path) -> Path:
    """Convert the I-24 file's rows of one camera to a GCP CSV: x = longitude, y = latitude, z = 0."""
    by_camera: dict[str, list[dict[str, str]]] = defaultdict(list)
    with I24.open(newline="") as fh:
        for row in csv.DictReader(fh):
            by_camera[row["Camera"]].append(row)
    path = folder / f"{camera}.csv"
    with path.open("w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(["id", "x", "y", "z", "u", "v"])
        for k, row in enumerate(by_camera[camera], start=1):
            w.writerow(
                [f"{camera}_{k}", row["GPS Long"], row["GPS Lat"], "0", row["Camera X"], row["Camera Y"]]
            )
    return path


def i24_cameras() -> list[str]:
    with I24.open(newline="") as fh:
        return list(dict.fromkeys(row["Camera"] for row in csv.DictReader(fh)))


def test_i24_cameras_listed() -> None:
    cams = i24_cameras()
    assert len(cams) == 18 and "P3C4" in cams


@pytest.mark.parametrize("camera", [c for c in i24_cameras() if c != "P3C4"])
def test_i24_good_cameras_validate(tmp_path: Path, camera: str) -> None:
    t = read_gcps(i24_camera_csv(camera, tmp_path), gcp_crs="EPSG:4326")
    assert t.crs == pyproj.CRS.from_epsg(32616) and t.n == 4
    warnings = validate_gcps(t, I24_SIZE)
    assert any("fewer than 6" in w for w in warnings)  # exactly 4 points: no redundancy


def test_i24_p3c4_is_degenerate(tmp_path: Path) -> None:
    t = read_gcps(i24_camera_csv("P3C4", tmp_path), gcp_crs="EPSG:4326")
    d = np.linalg.norm(t.world[0, :2] - t.world[1, :2])
    assert 0.05 < d < 0.15  # two GPS points 1e-6 degree of longitude apart, pixels 2900 px apart
    with pytest.raises(InputError) as info:
        validate_gcps(t, I24_SIZE)
    msg = str(info.value)
    assert "\n" not in msg
    for part in ("P3C4.csv", "degenerate", 'line 2 (id "P3C4_1")', 'line 3 (id "P3C4_2")', "3 distinct"):
        assert part in msg


def grid_table(**kwargs: object) -> GCPTable:
    world = [[0, 0, 0], [40, 0, 0], [40, 30, 0], [0, 30, 0], [20, 15, 1], [10, 25, 0]]
    pixels = [[100, 900], [1800, 900], [1500, 200], [300, 200], [950, 500], [600, 300]]
    ids = ["A", "B", "C", "D", "E", "F"]
    lines = range(2, 8)
    return GCPTable.from_arrays(ids, world, pixels, source="g.csv", lines=lines, **kwargs)  # type: ignore


def test_validate_good_table_no_warnings() -> None:
    assert validate_gcps(grid_table(), (1920, 1080)) == []


def test_validate_pixel_outside() -> None:
    t = read_gcps(PAPER, crs="EPSG:2949")
    with pytest.raises(InputError) as info:
        validate_gcps(t, (300, 464))
    assert 'line 2 (id "1")' in str(info.value) and "300x464" in str(info.value)
    assert "check image_size" in str(info.value) and info.value.parameters == ("image_size",)


def test_validate_pixel_edges() -> None:
    t = grid_table()
    px = t.pixels.copy()
    px[0] = [-0.5, 1079.5]
    validate_gcps(GCPTable.from_arrays(t.ids, t.world, px), (1920, 1080))  # on the edge: inside
    px[0] = [-0.5001, 500]
    with pytest.raises(InputError, match=r'row 1 \(id "A"\)'):
        validate_gcps(GCPTable.from_arrays(t.ids, t.world, px), (1920, 1080))


@pytest.mark.parametrize("size", [(0, 10), (10.5, 10), ("a", 3), (5,)])
def test_validate_bad_image_size(size: tuple[int, int]) -> None:
    with pytest.raises(InputError, match="image_size"):
        validate_gcps(grid_table(), size)


def test_validate_duplicate_pixel() -> None:
    t = grid_table()
    px = t.pixels.copy()
    px[4] = px[1] + [0.3, -0.3]
    bad = GCPTable.from_arrays(t.ids, t.world, px, source="g.csv", lines=range(2, 8))
    with pytest.raises(
        InputError, match=r'g.csv line 3 \(id "B"\) and line 6 \(id "E"\) have the same pixel'
    ):
        validate_gcps(bad, (1920, 1080))


def test_validate_duplicate_world_point() -> None:
    t = grid_table()
    w = t.world.copy()
    w[5] = w[2] + 1e-4
    bad = GCPTable.from_arrays(t.ids, w, t.pixels, source="g.csv", lines=range(2, 8))
    with pytest.raises(
        InputError, match=r'line 4 \(id "C"\) and line 7 \(id "F"\) have the same world point'
    ):
        validate_gcps(bad, (1920, 1080))


def test_validate_too_few_control_points() -> None:
    roles = ["control", "control", "control", "check", "check", "check"]
    with pytest.raises(InputError) as info:
        validate_gcps(grid_table(roles=roles), (1920, 1080))
    msg = str(info.value)
    assert "3 control point" in msg and "at least 4" in msg and "don't count" in msg
    validate_gcps(grid_table(roles=roles), (1920, 1080), min_control=3)


def test_validate_collinear_world() -> None:
    t = grid_table()
    w = t.world.copy()
    w[:, 0] = [0, 40, 30, 10, 20, 5]
    w[:, 1] = w[:, 0] * 0.5 + np.array([0, 0.01, -0.01, 0, 0.02, 0])  # all near the line y = x / 2
    with pytest.raises(InputError, match="lie nearly on one line"):
        validate_gcps(GCPTable.from_arrays(t.ids, w, t.pixels), (1920, 1080))


def test_validate_three_of_four_collinear() -> None:
    world = [[0, 0, 0], [10, 0, 0], [20, 0.01, 0], [5, 20, 0]]
    pixels = [[100, 900], [900, 900], [1700, 880], [800, 100]]
    t = GCPTable.from_arrays(["a", "b", "c", "d"], world, pixels)
    with pytest.raises(InputError, match=r'row 1 \(id "a"\), row 2 \(id "b"\), row 3 \(id "c"\) lie nearly'):
        validate_gcps(t, (1920, 1080))


def test_validate_collinear_pixels() -> None:
    t = grid_table()
    px = np.column_stack(
        [np.linspace(100, 1800, 6), np.linspace(100, 1000, 6) + np.array([0, 1, -1, 0, 1, 0])]
    )
    with pytest.raises(InputError, match="pixels lie nearly on one line in the image"):
        validate_gcps(GCPTable.from_arrays(t.ids, t.world, px), (1920, 1080))


def test_validate_coincident_points_with_enough_left_warns() -> None:
    world = [[0, 0, 0], [40, 0, 0], [40, 30, 0], [0, 30, 0], [0.05, 0.05, 0]]
    pixels = [[100, 900], [1800, 900], [1500, 200], [300, 200], [600, 700]]
    t = GCPTable.from_arrays(list("abcde"), world, pixels, crs="EPSG:32616")
    warnings = validate_gcps(t, (1920, 1080))
    assert any('row 1 (id "a") and row 5 (id "e")' in w and "coincide" in w for w in warnings)
    assert any("fewer than 6" in w for w in warnings)


def test_validate_feet_crs_merge_tolerance() -> None:
    # 0.5 ft apart = 0.15 m: below the 0.2 m floor in a foot CRS, so the points merge -> 3 distinct -> error
    world = [[0, 0, 0], [10, 0, 0], [0, 8, 0], [0.5, 0, 0]]
    pixels = [[100, 900], [1800, 900], [300, 200], [900, 500]]
    t = GCPTable.from_arrays(list("abcd"), world, pixels, crs=parse_crs("EPSG:2240"))
    with pytest.raises(InputError, match="3 distinct ground points"):
        validate_gcps(t, (1920, 1080))


def test_validate_small_coverage_warning() -> None:
    t = grid_table()
    px = t.pixels * 0.1 + 50
    warnings = validate_gcps(GCPTable.from_arrays(t.ids, t.world, px), (1920, 1080))
    assert len(warnings) == 1 and "cover only" in warnings[0]


def test_calibrate_reads_a_lon_lat_file_and_asks_for_its_accuracy(tmp_path: Path) -> None:
    """``trafficgeo calibrate`` on a GCP file in lat_deg/lon_deg/alt (no --gcp-crs): the columns are said, the points
    are projected to --crs, the camera is right, and the terminal asks for --survey-sigma (map-picked points) unless
    it was given."""
    from cli_support import invoke
    from trafficgeo.camera.calibrated import read_camera_json
    from trafficgeo.camera.model import Camera

    truth = Camera.from_orientation((1920, 1080), 1500.0, (500000.0, 4877000.0, 112.0), 40.0, 12.0,
                                    crs="EPSG:32610")
    rng = np.random.default_rng(3)
    s, o = rng.uniform(20, 90, 12), rng.uniform(-12, 12, 12)
    h = np.radians(40.0)
    x = 500000.0 + s * np.sin(h) + o * np.cos(h)
    y = 4877000.0 + s * np.cos(h) - o * np.sin(h)
    z = 100.0 + rng.uniform(0, 3, 12)
    uv = truth.project(np.column_stack([x, y, z]))
    lon, lat = pyproj.Transformer.from_crs("EPSG:32610", "EPSG:4326", always_xy=True).transform(x, y)
    path = tmp_path / "map.csv"
    path.write_text("name, pixel_x, pixel_y, lat_deg, lon_deg, alt\n" + "".join(
        f"G{k}, {uv[k, 0]:.6f}, {uv[k, 1]:.6f}, {lat[k]:.9f}, {lon[k]:.9f}, {z[k]:.4f}\n" for k in range(12)),
        encoding="utf-8")
    code, out, err = invoke("calibrate", path, "--image-size", "1920x1080", "--crs", "EPSG:32610", "-o",
                            tmp_path / "camera.json", "--quiet")
    assert code == 0, out + err
    said = " ".join(out.split())
    assert "columns read as name -> id, pixel_x -> u, pixel_y -> v, lon_deg -> x, lat_deg -> y, alt -> z" in said
    assert "say how good with --survey-sigma" in said
    cam = read_camera_json(tmp_path / "camera.json")
    assert np.linalg.norm(cam.position - truth.position) < 0.05
    code, out, err = invoke("calibrate", path, "--image-size", "1920x1080", "--crs", "EPSG:32610", "-o",
                            tmp_path / "camera2.json", "--quiet", "--survey-sigma", "0.5")
    assert code == 0 and "--survey-sigma" not in " ".join(out.split())
