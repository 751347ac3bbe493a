"""Tests of trafficgeo.geo.georef: pixel tables -> world, world tables -> pixels, GCP heights from the ground.

Cameras and surfaces are built by hand (analytic truth); the ground for GCP checks is a synthetic point cloud: a
tilted plane with a little noise, a rough patch, a hole, in metres (EPSG:2949) and in international feet
(EPSG:2994).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pyproj
import pytest

from trafficgeo.camera.model import Camera
from trafficgeo.crs import parse_crs
from trafficgeo.geo.georef import (
    GroundCheckOptions,
    check_gcp_heights,
    georeference_table,
    lonlat_columns,
    project_table,
)
from trafficgeo.geo.pointcloud import GroundIndex
from trafficgeo.geo.surface import ConstantSurface, DEMSurface, PlaneSurface

FT = 0.3048
X0, Y0 = 245_000.0, 5_182_600.0  # EPSG:2949 (MTM zone 7), metres
CRS_M = parse_crs("EPSG:2949")
CRS_FT = parse_crs("EPSG:2994")
TO_LONLAT = pyproj.Transformer.from_crs("EPSG:2949", "EPSG:4326", always_xy=True)


def camera(crs: str | None = "EPSG:2949", height: float = 10.0, x0: float = X0, y0: float = Y0,
           tilt: float = 30.0) -> Camera:
    """640x480, f = 500 px (vertical field of view +-25.6 deg), ``height`` above z = 0, looking north and ``tilt``
    deg down."""
    return Camera.from_orientation((640, 480), 500.0, [x0, y0, height], 0.0, tilt, crs=crs)


def pixel_grid() -> np.ndarray:
    u, v = np.meshgrid(np.linspace(20, 620, 7), np.linspace(260, 470, 5))
    return np.column_stack([u.ravel(), v.ravel()])


def plane_z(x: np.ndarray, y: np.ndarray, x0: float = X0, y0: float = Y0) -> np.ndarray:
    return 100.0 + 0.01 * (np.asarray(x) - x0) - 0.02 * (np.asarray(y) - y0)


def plane_dem(step: float = 1.0, n: int = 80, x0: float = X0, y0: float = Y0, crs=CRS_M) -> DEMSurface:
    """The tilted plane ``plane_z`` sampled at the centres of ``n`` x ``n`` cells starting at (x0, y0 + n step)."""
    top = y0 + n * step
    xc = x0 + (np.arange(n) + 0.5) * step
    yc = top - (np.arange(n) + 0.5) * step
    xx, yy = np.meshgrid(xc, yc)
    return DEMSurface(plane_z(xx, yy, x0, y0), x0, top, step, step, crs=crs)


# ------------------------------------------------------------------------------------------------ georeference


def test_georeference_table_constant_surface_and_renamed_columns() -> None:
    cam = camera()
    uv = pixel_grid()
    n = len(uv)
    table = pd.DataFrame({"u": uv[:, 0], "v": uv[:, 1], "x": np.arange(n), "lon": "a", "status": "given",
                          "distance_m": -1.0, "note": [f"n{i}" for i in range(n)]})
    out = georeference_table(cam, table, ConstantSurface(0.0, crs=CRS_M))
    assert list(out.columns) == ["u", "v", "x_in", "lon_in", "status_in", "distance_m_in", "note", "x", "y", "z",
                                 "lon", "lat", "distance_m", "incidence_deg", "status"]
    assert out["x_in"].tolist() == list(range(n)) and (out["lon_in"] == "a").all()
    assert (out["status_in"] == "given").all() and (out["distance_m_in"] == -1.0).all()
    assert out["note"].tolist() == table["note"].tolist()
    assert list(table.columns) == ["u", "v", "x", "lon", "status", "distance_m", "note"]  # input untouched
    assert (out["status"] == "ok").all()
    expected = cam.intersect_horizontal_plane(uv, 0.0)
    np.testing.assert_allclose(out[["x", "y", "z"]].to_numpy(), expected, atol=1e-8)
    np.testing.assert_allclose(out["distance_m"], np.linalg.norm(expected - cam.position, axis=1), rtol=1e-9)
    lon, lat = TO_LONLAT.transform(expected[:, 0], expected[:, 1])
    np.testing.assert_allclose(out["lon"], lon, atol=1e-10)
    np.testing.assert_allclose(out["lat"], lat, atol=1e-10)
    # incidence on a horizontal plane = angle of the ray below the horizon
    rays = cam.rays(uv)
    np.testing.assert_allclose(out["incidence_deg"], np.degrees(np.arcsin(-rays[:, 2])), atol=1e-9)


def test_georeference_table_statuses_and_height() -> None:
    cam = camera(tilt=10.0)  # the top rows see the sky
    table = pd.DataFrame({"u": [320.0, 320.0, -5.0, np.nan], "v": [400.0, 0.0, 300.0, 300.0]})
    out = georeference_table(cam, table, ConstantSurface(0.0, crs=CRS_M))
    assert out["status"].tolist() == ["ok", "above_horizon", "outside_image", "outside_image"]
    assert out.loc[1:, ["x", "y", "z", "lon", "lat", "distance_m", "incidence_deg"]].isna().all().all()
    lifted = georeference_table(cam, table.iloc[:1], ConstantSurface(0.0, crs=CRS_M), height=2.0)
    assert lifted["z"].iloc[0] == pytest.approx(2.0, abs=1e-9)
    expected = cam.intersect_horizontal_plane([[320.0, 400.0]], 2.0)[0]
    np.testing.assert_allclose(lifted[["x", "y", "z"]].to_numpy()[0], expected, atol=1e-8)
    # above the camera: the surface lies behind it
    high = georeference_table(cam, table.iloc[:1], ConstantSurface(50.0, crs=CRS_M))
    assert high["status"].iloc[0] == "behind_camera"


def test_georeference_table_without_crs_has_no_lonlat() -> None:
    cam = camera(crs=None)
    out = georeference_table(cam, pd.DataFrame({"u": [320.0], "v": [400.0]}), ConstantSurface(0.0))
    assert "lon" not in out.columns and "lat" not in out.columns
    assert out["status"].iloc[0] == "ok"


def test_georeference_table_feet_distance_in_metres() -> None:
    cam = camera(crs="EPSG:2994", height=10.0 / FT, x0=636600.0, y0=849200.0)
    m_cam = camera()
    uv = pixel_grid()
    out = georeference_table(cam, pd.DataFrame({"u": uv[:, 0], "v": uv[:, 1]}), ConstantSurface(0.0, crs=CRS_FT))
    ref = georeference_table(m_cam, pd.DataFrame({"u": uv[:, 0], "v": uv[:, 1]}), ConstantSurface(0.0, crs=CRS_M))
    np.testing.assert_allclose(out["distance_m"], ref["distance_m"], rtol=1e-9)
    np.testing.assert_allclose((out["y"] - 849200.0) * FT, ref["y"] - Y0, atol=1e-6)
    np.testing.assert_allclose(out["incidence_deg"], ref["incidence_deg"], atol=1e-9)
    # the height is in CRS units (feet) at this level: 2 m = 6.5617 ft
    lifted = georeference_table(cam, pd.DataFrame({"u": [320.0], "v": [400.0]}), ConstantSurface(0.0, crs=CRS_FT),
                                height=2.0 / FT)
    assert lifted["z"].iloc[0] == pytest.approx(2.0 / FT, abs=1e-9)


def test_dem_surface_gives_the_same_points_as_the_plane() -> None:
    cam = camera(height=110.0)  # the plane is at z ~ 100 below the camera
    cam = cam.replace(position=[X0 + 40.0, Y0 + 5.0, 112.0])
    dem = plane_dem()
    plane = PlaneSurface(point=[X0, Y0, 100.0], gx=0.01, gy=-0.02, crs=CRS_M)
    uv = pixel_grid()
    table = pd.DataFrame({"u": uv[:, 0], "v": uv[:, 1]})
    a = georeference_table(cam, table, dem)
    b = georeference_table(cam, table, plane)
    assert (b["status"] == "ok").all()
    inside = a["status"] == "ok"
    assert inside.sum() >= 20
    assert set(a.loc[~inside, "status"]) <= {"miss"}
    np.testing.assert_allclose(a.loc[inside, ["x", "y", "z"]].to_numpy(), b.loc[inside, ["x", "y", "z"]].to_numpy(),
                               atol=1e-6)
    np.testing.assert_allclose(a.loc[inside, "incidence_deg"], b.loc[inside, "incidence_deg"], atol=1e-6)
    np.testing.assert_allclose(a.loc[inside, "z"], plane_z(a.loc[inside, "x"], a.loc[inside, "y"]), atol=1e-6)


# ------------------------------------------------------------------------------------------------ project


def test_project_table_round_trip_and_renamed_columns() -> None:
    cam = camera()
    uv = pixel_grid()
    ground = georeference_table(cam, pd.DataFrame({"u": uv[:, 0], "v": uv[:, 1], "id": range(len(uv))}),
                                ConstantSurface(0.0, crs=CRS_M))
    ground["depth_m"] = "old"
    back = project_table(cam, ground)
    for col in ("u_in", "v_in", "status_in", "depth_m_in", "id", "x", "lon"):
        assert col in back.columns, col
    assert (back["depth_m_in"] == "old").all() and (back["status_in"] == "ok").all()
    assert (back["status"] == "ok").all()
    np.testing.assert_allclose(back[["u", "v"]].to_numpy(), uv, atol=1e-6)
    np.testing.assert_allclose(back["depth_m"], cam.world_to_camera(ground[["x", "y", "z"]].to_numpy())[:, 2],
                               rtol=1e-12)


def test_project_table_statuses_and_occlusion() -> None:
    cam = camera()
    fwd = np.array([0.0, np.cos(np.radians(30)), -np.sin(np.radians(30))])  # optical axis
    pts = np.array([
        cam.position + 15 * fwd,  # ok
        cam.position - 5 * fwd,  # behind
        cam.position + 10 * fwd + [40.0, 0.0, 0.0],  # far right: outside the image
        cam.position + 30 * fwd,  # 5 m below the ground z = 0: hidden by it
    ])
    table = pd.DataFrame({"x": pts[:, 0], "y": pts[:, 1], "z": pts[:, 2]})
    plain = project_table(cam, table)
    assert plain["status"].tolist() == ["ok", "behind_camera", "outside_image", "ok"]
    assert np.isnan(plain.loc[1, "u"]) and plain.loc[1, "depth_m"] == pytest.approx(-5.0)
    hidden = project_table(cam, table, ConstantSurface(0.0, crs=CRS_M))
    assert hidden["status"].tolist() == ["ok", "behind_camera", "outside_image", "occluded"]
    np.testing.assert_allclose(hidden.loc[3, ["u", "v"]].to_numpy(dtype=float), [319.5, 239.5], atol=1e-9)


def test_project_table_depth_in_metres_for_feet() -> None:
    cam = camera(crs="EPSG:2994", height=10.0 / FT, x0=636600.0, y0=849200.0)
    pts = cam.position + np.array([[0.0, 30.0 / FT, -10.0 / FT]])
    out = project_table(cam, pd.DataFrame({"x": pts[:, 0], "y": pts[:, 1], "z": pts[:, 2]}))
    expected_ft = cam.world_to_camera(pts)[0, 2]
    assert out["depth_m"].iloc[0] == pytest.approx(expected_ft * FT, rel=1e-12)


# ------------------------------------------------------------------------------------------------ GCP heights


def _cloud(crs, unit: float = 1.0, seed: int = 0) -> np.ndarray:
    """Ground points (CRS units) on ``plane_z`` over a 60 m square: 0.25 m grid + 1 cm noise, a rough patch
    (x, y in 40..55 m: +-0.5 m), a 3 m hole at (20, 45) m. ``unit`` = metres per CRS unit."""
    rng = np.random.default_rng(seed)
    g = np.arange(0.125, 60.0, 0.25)
    xx, yy = np.meshgrid(g, g)
    xm, ym = xx.ravel(), yy.ravel()
    keep = np.hypot(xm - 20.0, ym - 45.0) > 3.0
    xm, ym = xm[keep], ym[keep]
    zm = plane_z(xm, ym, 0.0, 0.0) + rng.normal(0.0, 0.01, xm.size)
    rough = (xm > 40) & (xm < 55) & (ym > 40) & (ym < 55)
    zm[rough] += rng.uniform(-0.5, 0.5, rough.sum())
    x0, y0 = (X0, Y0) if unit == 1.0 else (636600.0, 849200.0)
    return np.column_stack([x0 + xm / unit, y0 + ym / unit, zm / unit])


CASES = [  # id, x, y (m from the cloud's corner), z offset from the plane (m) or None (missing)
    ("filled", 10.0, 10.0, None),
    ("ok", 15.0, 10.0, 0.05),
    ("high", 20.0, 10.0, 1.0),
    ("low", 25.0, 10.0, -0.5),
    ("rough", 47.0, 47.0, 0.0),
    ("rough_missing", 50.0, 50.0, None),
    ("hole", 20.0, 45.0, 0.0),
    ("outside", 100.0, 100.0, 0.0),
]
EXPECTED = {"filled": "filled", "ok": "ok", "high": "disagrees", "low": "disagrees", "rough": "rough",
            "rough_missing": "rough", "hole": "empty", "outside": "outside"}


def _gcp_table(unit: float = 1.0) -> pd.DataFrame:
    x0, y0 = (X0, Y0) if unit == 1.0 else (636600.0, 849200.0)
    rows = []
    for name, xm, ym, dz in CASES:
        z = np.nan if dz is None else (float(plane_z(xm, ym, 0.0, 0.0)) + dz) / unit
        rows.append({"id": name, "x": x0 + xm / unit, "y": y0 + ym / unit, "z": z, "u": 1.0, "v": 2.0,
                     "role": "control"})
    return pd.DataFrame(rows)


@pytest.mark.parametrize(("crs", "unit"), [(CRS_M, 1.0), (CRS_FT, FT)], ids=["metres", "feet"])
def test_check_gcp_heights_statuses(crs, unit: float) -> None:
    ground = GroundIndex(_cloud(crs, unit), crs)
    table = _gcp_table(unit)
    out = check_gcp_heights(table, ground, crs, GroundCheckOptions(radius_m=0.5, tolerance_m=0.3, roughness_m=0.15))
    res = out.set_index("id")
    assert res["z_check"].to_dict() == EXPECTED
    for col in ("role", "u", "v"):
        assert out[col].tolist() == table[col].tolist()
    # heights in CRS units, differences and spreads in metres
    for name, xm, ym, dz in CASES:
        if name in ("hole", "outside"):
            continue
        zp = float(plane_z(xm, ym, 0.0, 0.0))
        if name not in ("rough", "rough_missing"):
            assert res.loc[name, "z_ground"] * unit == pytest.approx(zp, abs=0.01), name
            assert res.loc[name, "ground_spread_m"] == pytest.approx(0.01, abs=0.008), name
        if dz is not None and name not in ("rough",):
            assert res.loc[name, "dz_m"] == pytest.approx(dz, abs=0.01), name
    assert res.loc["rough", "ground_spread_m"] > 0.2
    assert res.loc["filled", "z"] == pytest.approx(res.loc["filled", "z_ground"])
    assert res.loc["rough_missing", "z"] == pytest.approx(res.loc["rough_missing", "z_ground"])
    assert res.loc["high", "z"] == pytest.approx(table.set_index("id").loc["high", "z"])  # given z kept
    # neighbours within 0.5 m: 0.25 m grid -> about pi 0.5^2 / 0.0625 = 12.6 points
    assert 9 <= res.loc["ok", "ground_points"] <= 16
    assert res.loc["hole", "ground_points"] == 0 and np.isnan(res.loc["hole", "z_ground"])
    assert np.isnan(res.loc["outside", "z_ground"])
    assert np.isnan(res.loc["hole", "dz_m"]) and res.loc["hole", "z"] == pytest.approx(
        table.set_index("id").loc["hole", "z"])


def test_check_gcp_heights_replace_and_tolerance() -> None:
    ground = GroundIndex(_cloud(CRS_M), CRS_M)
    table = _gcp_table()
    out = check_gcp_heights(table, ground, CRS_M, GroundCheckOptions(replace=True)).set_index("id")
    assert out.loc["ok", "z_check"] == "replaced"
    assert out.loc["filled", "z_check"] == "filled"
    assert out.loc["high", "z_check"] == "disagrees"  # still reported
    for name in ("ok", "high", "low", "filled"):
        assert out.loc[name, "z"] == pytest.approx(out.loc[name, "z_ground"]), name
    assert out.loc["high", "dz_m"] == pytest.approx(1.0, abs=0.01)  # the difference to what was given
    loose = check_gcp_heights(table, ground, CRS_M, GroundCheckOptions(tolerance_m=2.0)).set_index("id")
    assert loose.loc["high", "z_check"] == "ok" and loose.loc["low", "z_check"] == "ok"
    smooth = check_gcp_heights(table, ground, CRS_M, GroundCheckOptions(roughness_m=1.0)).set_index("id")
    assert smooth.loc["rough", "z_check"] == "ok"


def test_check_gcp_heights_without_z_column() -> None:
    ground = GroundIndex(_cloud(CRS_M), CRS_M)
    table = _gcp_table().drop(columns="z")
    out = check_gcp_heights(table, ground, CRS_M).set_index("id")
    assert set(out["z_check"]) <= {"filled", "rough", "empty", "outside"}
    assert out.loc["ok", "z_check"] == "filled"
    assert out.loc["ok", "z"] == pytest.approx(float(plane_z(15.0, 10.0, 0.0, 0.0)), abs=0.01)


def test_check_gcp_heights_on_a_dem_matches_the_surface() -> None:
    dem = plane_dem(step=0.5, n=120)  # 60 m square starting at (X0, Y0)
    table = _gcp_table()
    out = check_gcp_heights(table, dem, CRS_M, GroundCheckOptions()).set_index("id")
    x, y = out["x"].to_numpy(), out["y"].to_numpy()
    np.testing.assert_array_equal(out["z_ground"].to_numpy(), dem.elevation(x, y))
    assert "ground_points" not in out.columns
    inside = out.index != "outside"
    np.testing.assert_allclose(out.loc[inside, "z_ground"], plane_z(x[inside], y[inside]), atol=1e-9)
    assert out["z_check"].to_dict() == {"filled": "filled", "ok": "ok", "high": "disagrees", "low": "disagrees",
                                        "rough": "ok", "rough_missing": "filled", "hole": "ok",
                                        "outside": "outside"}
    assert (out.loc[inside, "ground_spread_m"] < 0.01).all()  # a plane sampled within 0.5 m
    assert out.loc["high", "dz_m"] == pytest.approx(1.0, abs=1e-9)
    # the same ground from points: the same heights within the noise
    pts = GroundIndex(_cloud(CRS_M), CRS_M)
    cloud = check_gcp_heights(table, pts, CRS_M).set_index("id")
    for name in ("filled", "ok", "high", "low"):
        assert cloud.loc[name, "z_ground"] == pytest.approx(out.loc[name, "z_ground"], abs=0.01), name


def test_check_gcp_heights_on_a_feet_dem() -> None:
    dem = plane_dem(step=1.0 / FT, n=60, x0=636600.0, y0=849200.0, crs=CRS_FT)
    table = pd.DataFrame({"id": ["a", "b"], "x": [636610.0, 636620.0], "y": [849210.0, 849220.0]})
    zg = dem.elevation(table["x"], table["y"])
    table["z"] = zg + np.array([0.2, 0.5]) / FT  # 0.2 m and 0.5 m too high, in feet
    out = check_gcp_heights(table, dem, CRS_FT, GroundCheckOptions(tolerance_m=0.3)).set_index("id")
    assert out["dz_m"].to_numpy() == pytest.approx([0.2, 0.5], abs=1e-9)
    assert out["z_check"].tolist() == ["ok", "disagrees"]


# ------------------------------------------------------------------------------------------------ lon/lat


def test_lonlat_columns() -> None:
    table = pd.DataFrame({"x": [X0, np.nan], "y": [Y0, Y0]})
    out = lonlat_columns(table, CRS_M)
    lon, lat = TO_LONLAT.transform(X0, Y0)
    assert out["lon"].iloc[0] == pytest.approx(lon, abs=1e-10) and out["lat"].iloc[0] == pytest.approx(lat, abs=1e-10)
    assert np.isnan(out["lon"].iloc[1])
    assert "lon" not in table.columns
    assert lonlat_columns(table, None) is table
    given = table.assign(lon=1.0)
    assert lonlat_columns(given, CRS_M) is given
