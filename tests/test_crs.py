"""Tests of trafficgeo.crs (CRS parsing, units, UTM zones, lon/lat transforms)."""

from __future__ import annotations

import numpy as np
import pyproj
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trafficgeo.crs import (
    is_geographic,
    lonlat_to_projected,
    looks_like_lonlat,
    metres_per_unit,
    parse_crs,
    projected_to_lonlat,
    transform_xy,
    utm_crs_for,
)
from trafficgeo.errors import InputError


@pytest.mark.parametrize(
    ("code", "expected"),
    [
        ("EPSG:2994", 0.3048),  # NAD83(HARN) / Oregon GIC Lambert (ft): international foot
        ("EPSG:2240", 1200 / 3937),  # NAD83 / Georgia West (ftUS): US survey foot
        ("EPSG:2949", 1.0),  # NAD83(CSRS) / MTM zone 7
        ("EPSG:32616", 1.0),
        ("EPSG:2949+6647", 1.0),  # compound: horizontal part decides
    ],
)
def test_metres_per_unit(code: str, expected: float) -> None:
    assert metres_per_unit(parse_crs(code)) == pytest.approx(expected, rel=1e-15, abs=0)


def test_metres_per_unit_international_and_survey_foot_differ() -> None:
    assert metres_per_unit(parse_crs("EPSG:2994")) == 0.3048
    assert metres_per_unit(parse_crs("EPSG:2240")) != 0.3048


def test_metres_per_unit_none_is_metre() -> None:
    assert metres_per_unit(None) == 1.0


def test_metres_per_unit_geographic_raises() -> None:
    with pytest.raises(InputError, match="geographic"):
        metres_per_unit(parse_crs("EPSG:4326"))


@pytest.mark.parametrize(
    ("text", "epsg"),
    [
        ("WGS84 UTM 10N", 32610),
        ("WGS84 UTM 10N\t\t", 32610),  # as in the ODM COPR file
        ("wgs84 utm 17s", 32717),
        ("WGS84 UTM 1N", 32601),
        ("EPSG:2949", 2949),
        ("  EPSG:32616 ", 32616),
        ("+proj=utm +zone=16 +datum=WGS84 +units=m +no_defs", 32616),
    ],
)
def test_parse_crs_forms(text: str, epsg: int) -> None:
    crs = parse_crs(text)
    assert crs is not None
    assert crs == pyproj.CRS.from_epsg(epsg)


def test_parse_crs_odm_utm_is_epsg_32610() -> None:
    assert parse_crs("WGS84 UTM 10N") == pyproj.CRS.from_epsg(32610)
    assert parse_crs("WGS84 UTM 10N").to_epsg() == 32610


@pytest.mark.parametrize("text", ["WGS84 longlat", "WGS84 lonlat", "wgs84 LONGLAT"])
def test_parse_crs_odm_lonlat(text: str) -> None:
    crs = parse_crs(text)
    assert crs is not None and is_geographic(crs)
    assert crs.to_epsg() == 4326


def test_parse_crs_wkt_and_passthrough() -> None:
    ref = pyproj.CRS.from_epsg(2949)
    assert parse_crs(ref.to_wkt()) == ref
    assert parse_crs(ref) is ref
    assert parse_crs(None) is None


@pytest.mark.parametrize("text", ["not a crs", "EPSG:99999", "WGS84 UTM 61N", "WGS84 UTM 0S", "", "   "])
def test_parse_crs_bad_text_raises(text: str) -> None:
    with pytest.raises(InputError) as info:
        parse_crs(text)
    msg = str(info.value)
    assert "\n" not in msg
    assert "EPSG:32616" in msg  # shows a valid example
    if text.strip():
        assert text.strip() in msg  # names the bad text


def test_is_geographic() -> None:
    assert is_geographic(parse_crs("EPSG:4326"))
    assert not is_geographic(parse_crs("EPSG:32616"))
    assert not is_geographic(None)


@pytest.mark.parametrize(
    ("lon", "lat", "epsg"),
    [
        (-86.6, 36.0, 32616),  # I-24, Nashville
        (-119.88, 34.41, 32611),  # COPR, Goleta: zone 11 (the ODM file uses zone 10 on purpose)
        (-73.6, 45.5, 32618),
        (151.2, -33.9, 32756),  # southern hemisphere
        (5.3, 60.4, 32632),  # Norway exception (32V)
        (15.0, 78.0, 32633),  # Svalbard exception
        (180.0, 0.0, 32660),
        (-180.0, 0.0, 32601),
    ],
)
def test_utm_crs_for(lon: float, lat: float, epsg: int) -> None:
    assert utm_crs_for(lon, lat).to_epsg() == epsg


def test_utm_crs_for_matches_pyproj_database() -> None:
    from pyproj.aoi import AreaOfInterest
    from pyproj.database import query_utm_crs_info

    info = query_utm_crs_info(datum_name="WGS 84", area_of_interest=AreaOfInterest(-86.6, 36.0, -86.6, 36.0))
    assert [int(i.code) for i in info] == [utm_crs_for(-86.6, 36.0).to_epsg()]


@pytest.mark.parametrize(
    ("lon", "lat"), [(200.0, 0.0), (0.0, 91.0), (float("nan"), 0.0), (36.0, -86.6), (0.0, 85.0)]
)
def test_utm_crs_for_bad_position(lon: float, lat: float) -> None:
    with pytest.raises(InputError, match="latitude"):
        utm_crs_for(lon, lat)


def test_lonlat_round_trip_and_against_pyproj() -> None:
    crs = parse_crs("EPSG:32616")
    lon = np.array([-86.609750, -86.606736, -86.604408])
    lat = np.array([36.004546, 36.001877, 36.000434])
    x, y = lonlat_to_projected(lon, lat, crs)
    ref = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:32616", always_xy=True)
    rx, ry = ref.transform(lon, lat)
    np.testing.assert_allclose(x, rx, rtol=0, atol=1e-9)
    np.testing.assert_allclose(y, ry, rtol=0, atol=1e-9)
    assert x.dtype == np.float64 and x.shape == (3,)
    assert 500_000 < x.min() < x.max() < 600_000 and 3_980_000 < y.min()  # easting first, not lat/lon swapped
    lon2, lat2 = projected_to_lonlat(x, y, crs)
    np.testing.assert_allclose(lon2, lon, rtol=0, atol=1e-10)
    np.testing.assert_allclose(lat2, lat, rtol=0, atol=1e-10)


def test_northing_first_crs_still_gives_easting_first() -> None:
    crs = parse_crs("EPSG:31468")  # DHDN / 3-degree Gauss-Kruger zone 4: axes declared northing, easting
    x, y = lonlat_to_projected(12.0, 48.0, crs)
    assert 4_400_000 < float(x) < 4_600_000  # easting
    assert 5_300_000 < float(y) < 5_400_000  # northing


def test_lonlat_to_projected_needs_projected_crs() -> None:
    with pytest.raises(InputError, match="projected"):
        lonlat_to_projected(0.0, 0.0, parse_crs("EPSG:4326"))


def test_transform_xy_same_crs_is_exact_copy() -> None:
    crs = parse_crs("EPSG:2949")
    x = np.array([245030.06, 245033.02])
    tx, _ = transform_xy(x, x + 1, crs, crs)
    assert np.array_equal(tx, x) and tx is not x


def test_transform_xy_feet() -> None:
    m = parse_crs("+proj=utm +zone=16 +datum=WGS84 +units=m +no_defs")
    ft = parse_crs("+proj=utm +zone=16 +datum=WGS84 +units=ft +no_defs")
    tx, ty = transform_xy(500_000.0, 3_985_000.0, m, ft)
    assert float(tx) == pytest.approx(500_000 / 0.3048, rel=1e-12)
    assert float(ty) == pytest.approx(3_985_000 / 0.3048, rel=1e-12)


def test_looks_like_lonlat() -> None:
    assert looks_like_lonlat([-86.6097, -86.6120], [36.0045, 36.0064])
    assert not looks_like_lonlat([245030.06, 245033.02], [5182608.21, 5182608.47])  # projected
    assert not looks_like_lonlat([34.408, 34.409], [-119.880, -119.881])  # latitude first
    assert not looks_like_lonlat([0.0, 50.0], [0.0, 40.0])  # small local scene spanning metres
    assert not looks_like_lonlat([], [])
    assert not looks_like_lonlat([float("nan")], [0.0])


@pytest.mark.slow
@settings(max_examples=50, deadline=None)
@given(
    lon=st.floats(min_value=-179.9, max_value=179.9),
    lat=st.floats(min_value=-79.9, max_value=83.9),
)
def test_utm_round_trip_property(lon: float, lat: float) -> None:
    crs = utm_crs_for(lon, lat)
    x, y = lonlat_to_projected(lon, lat, crs)
    assert 100_000 < float(x) < 900_000
    lon2, lat2 = projected_to_lonlat(x, y, crs)
    assert float(lon2) == pytest.approx(lon, abs=1e-9)
    assert float(lat2) == pytest.approx(lat, abs=1e-9)
