"""An orthophoto from a georeferenced image that is not a GeoTIFF (issue 29, part 4): a PNG/JPG with a world file
(parameters of the top-left pixel's centre) or 3+ control points, and a CRS; compared with a GeoTIFF of the same
data."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from affine import Affine

from cli_support import invoke
from trafficgeo.errors import InputError
from trafficgeo.geo.image_ortho import fit_affine, image_to_geotiff, read_image_ortho
from trafficgeo.geo.raster import pixel_to_map, read_raster, write_geotiff

CRS = "EPSG:2949"
# 0.1 m pixels, rotated 10 degrees, top-left corner at large coordinates (5e6: precision matters)
_ROT = Affine.rotation(-10.0)
TRUTH = Affine.translation(245010.0, 5182620.0) @ _ROT @ Affine.scale(0.1, -0.1)


def _data(rows: int = 60, cols: int = 80) -> np.ndarray:
    rng = np.random.default_rng(4)
    return rng.integers(0, 256, (3, rows, cols), dtype=np.uint8)


def _write_png(path: Path, data: np.ndarray) -> Path:
    cv2.imwrite(str(path), np.ascontiguousarray(data[::-1].transpose(1, 2, 0)))  # RGB bands -> BGR for OpenCV
    return path


def _world_file_text(t: Affine) -> str:
    """A, D, B, E, C, F with (C, F) the centre of the top-left pixel."""
    c, f = t @ (0.5, 0.5)
    return "\n".join(f"{v:.12f}" for v in (t.a, t.d, t.b, t.e, c, f)) + "\n"


@pytest.fixture
def geotiff(tmp_path: Path) -> Path:
    write_geotiff(tmp_path / "truth.tif", _data(), TRUTH, CRS)
    return tmp_path / "truth.tif"


def _same_as(raster, truth_path: Path, tol: float) -> None:
    truth = read_raster(truth_path)
    assert raster.crs == truth.crs
    np.testing.assert_array_equal(raster.data, truth.data)
    # transform coefficients: CRS units (the translation) and CRS units per pixel
    np.testing.assert_allclose(np.array(raster.transform)[:6], np.array(truth.transform)[:6], rtol=0, atol=tol)


def test_a_png_with_a_world_file_is_the_geotiff_of_the_same_data(tmp_path: Path, geotiff: Path) -> None:
    img = _write_png(tmp_path / "ortho.png", _data())
    (tmp_path / "ortho.pgw").write_text(_world_file_text(TRUTH))
    out = tmp_path / "ortho.tif"
    image_to_geotiff(img, out, CRS)
    _same_as(read_raster(out), geotiff, 1e-6)  # 12 decimals in the world file


def test_a_world_file_given_by_name(tmp_path: Path, geotiff: Path) -> None:
    img = _write_png(tmp_path / "photo.png", _data())
    (tmp_path / "georef.wld").write_text(_world_file_text(TRUTH))
    raster, fit = read_image_ortho(img, CRS, world_file=tmp_path / "georef.wld")
    assert fit is None
    _same_as(raster, geotiff, 1e-6)


def test_control_points_fit_the_affine(tmp_path: Path, geotiff: Path) -> None:
    img = _write_png(tmp_path / "photo.png", _data())
    # the four outer corners by name, plus a point in the middle given as a pixel centre
    corners = {"top-left": (0, 0), "top-right": (80, 0), "bottom-right": (80, 60), "bottom-left": (0, 60)}
    lines = ["corner,u,v,x,y"]
    for name, (c, r) in corners.items():
        x, y = TRUTH @ (c, r)
        lines.append(f"{name},,,{x:.6f},{y:.6f}")
    x, y = TRUTH @ (30.5, 20.5)  # centre of pixel (30, 20)
    lines.append(f",30,20,{x:.6f},{y:.6f}")
    (tmp_path / "control.csv").write_text("\n".join(lines) + "\n")
    raster, fit = read_image_ortho(img, CRS, control=tmp_path / "control.csv", model="affine")
    assert fit.n_points == 5 and fit.rmse < 1e-5  # CRS units: the coordinates are written to 1e-6
    _same_as(raster, geotiff, 1e-5)


def test_a_perspective_image_is_orthorectified_by_a_projective_fit(tmp_path: Path) -> None:
    """Issue 42: an oblique photo of flat ground (a homography of a north-up texture) from 6 control points: the
    projective fit is exact where an affine is metres off, and the orthophoto's cells hold the image's values at
    their map positions."""
    import cv2

    from trafficgeo.geo.image_projective import fit_projective

    rng = np.random.default_rng(5)
    truth = cv2.GaussianBlur(rng.uniform(0, 255, (400, 400)).astype(np.float32), (0, 0), 3.0)
    truth = cv2.normalize(truth, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)  # 0.1 m cells, 40 m x 40 m
    left, top, res = 245000.0, 5182700.0, 0.1
    # the photo: ground cell (col, row) seen obliquely (the far side shrinks), 480 x 360 px
    src = np.float32([[0, 0], [400, 0], [400, 400], [0, 400]])
    dst = np.float32([[150, 40], [330, 40], [470, 350], [10, 350]])
    G = cv2.getPerspectiveTransform(src, dst)  # ground cell corner coords -> photo pixel corner coords
    photo = cv2.warpPerspective(truth, G, (480, 360), flags=cv2.INTER_LINEAR)
    img = _write_png(tmp_path / "oblique.png", np.stack([photo] * 3))
    cells = np.array([[40, 60], [350, 50], [360, 340], [60, 330], [200, 200], [120, 250]], dtype=np.float64)
    uv = cv2.perspectiveTransform(cells[None].astype(np.float64), G)[0] - 0.5  # pixel centres on integers
    xy = np.column_stack([left + cells[:, 0] * res, top - cells[:, 1] * res])
    (tmp_path / "control.csv").write_text("u,v,x,y\n" + "".join(f"{u:.9f},{v:.9f},{x:.9f},{y:.9f}\n"
                                                                 for (u, v), (x, y) in zip(uv, xy, strict=True)))
    assert fit_affine(uv, xy).rmse > 0.5  # metres off: an affine cannot describe the oblique view
    raster, fit = read_image_ortho(img, CRS, control=tmp_path / "control.csv")
    assert fit.n_points == 6 and fit.rmse < 1e-4  # CRS units (0.1 mm)
    assert fit_projective(uv, xy).max_error < 1e-4
    # the orthophoto at the map positions of interior ground cells holds the truth texture there
    probe = rng.uniform(60, 340, (300, 2))
    px, py = left + probe[:, 0] * res, top - probe[:, 1] * res
    col, row = raster.map_to_pixel(px, py)
    got = raster.data[0][row.astype(int), col.astype(int)].astype(float)
    want = truth[probe[:, 1].astype(int), probe[:, 0].astype(int)].astype(float)
    assert np.median(np.abs(got - want)) < 12.0 and np.corrcoef(got, want)[0, 1] > 0.9
    assert raster.is_north_up and abs(raster.resolution[0] - raster.resolution[1]) < 1e-12


def test_the_affine_fit_reports_what_does_not_fit() -> None:
    uv = np.array([[0.0, 0.0], [99.0, 0.0], [99.0, 49.0], [0.0, 49.0]])
    xy = np.column_stack(pixel_to_map(TRUTH, uv[:, 0] + 0.5, uv[:, 1] + 0.5))
    exact = fit_affine(uv[:3], xy[:3])
    assert exact.rmse < 1e-9
    np.testing.assert_allclose(np.array(exact.transform)[:6], np.array(TRUTH)[:6], atol=1e-7)
    xy[2] += (3.0, 0.0)  # one point 3 CRS units off
    fit = fit_affine(uv, xy)
    # an affine through four corners of a rectangle spreads one point's error d as d / 4 on each of them
    assert fit.rmse == pytest.approx(0.75, abs=1e-6) and fit.max_error == pytest.approx(0.75, abs=1e-6)


@pytest.mark.parametrize(("kwargs", "needle"), [
    ({"crs": None}, "needs a projected CRS"),
    ({"crs": "EPSG:4326"}, "needs a projected CRS"),
    ({"world_file": "missing.wld"}, "world_file"),
    ({"control": "line.csv"}, "on one line"),
    ({"control": "two.csv"}, "at least 3"),
    ({"control": "bad.csv"}, "columns"),
    ({"control": "corner.csv"}, "corner 'middle' is not one of"),
    ({"control": "photo.png"}, "not a text CSV"),
    ({"control": "huge.csv"}, "a map coordinate reaches 1e+300, beyond any projected CRS"),
    ({"control": "huge_px.csv"}, "a pixel coordinate reaches 1e+12, beyond any image"),
    ({"control": "same_map.csv"}, "no usable map position"),
    ({"control": "same_map4.csv"}, "do not fix a projective fit"),
    ({"control": "two.csv", "model": "projective"}, "a projective fit needs at least 4"),
    ({"model": "bent"}, "model 'bent' is not one of auto, affine, projective"),
    ({}, "no world file"),
])
def test_bad_inputs_raise_one_line(tmp_path: Path, kwargs: dict, needle: str) -> None:
    img = _write_png(tmp_path / "photo.png", _data())
    (tmp_path / "line.csv").write_text("u,v,x,y\n0,0,1,1\n10,10,2,2\n20,20,3,3\n")
    (tmp_path / "two.csv").write_text("u,v,x,y\n0,0,1,1\n10,10,2,2\n")
    (tmp_path / "bad.csv").write_text("a,b\n1,2\n")
    (tmp_path / "corner.csv").write_text("corner,x,y\ntop-left,1,1\nmiddle,3,4\nbottom-right,5,5\n")
    (tmp_path / "huge.csv").write_text("u,v,x,y\n0,0,1e300,4877000\n100,0,1e300,4877000\n0,90,500000,-1e300\n")
    (tmp_path / "huge_px.csv").write_text("u,v,x,y\n0,0,1,1\n1e12,0,2,1\n0,90,1,2\n")
    (tmp_path / "same_map4.csv").write_text("u,v,x,y\n0,0,500000,4877000\n100,0,500000,4877000\n"
                                            "0,90,500000,4877000\n100,90,500000,4877000\n")
    (tmp_path / "same_map.csv").write_text("u,v,x,y\n0,0,500000,4877000\n100,0,500000,4877000\n0,90,500000,4877000\n")
    args = {"crs": CRS, **kwargs}
    for key in ("world_file", "control"):
        if key in args:
            args[key] = tmp_path / args[key]
    with pytest.raises(InputError) as info:
        read_image_ortho(img, args.pop("crs"), **args)
    assert needle in str(info.value) and "\n" not in str(info.value)


def test_the_command_writes_the_orthophoto(tmp_path: Path, geotiff: Path) -> None:
    img = _write_png(tmp_path / "ortho.png", _data())
    (tmp_path / "ortho.pgw").write_text(_world_file_text(TRUTH))
    code, stdout, stderr = invoke("ortho-from-image", img, "--crs", CRS, "-o", tmp_path / "out.tif")
    assert code == 0, stderr
    _same_as(read_raster(tmp_path / "out.tif"), geotiff, 1e-6)
    assert "80x60 px" in stdout
    code, _out, stderr = invoke("ortho-from-image", img, "--crs", CRS, "-o", tmp_path / "o2.tif",
                                "--corners", tmp_path / "nope.csv")
    assert code == 2 and "--corners" in stderr


def test_an_image_too_large_once_decoded_is_refused_before_it_is_decoded(tmp_path: Path) -> None:
    """Issue 43: a 437 kB PNG made ortho-from-image use 7.2 GB. The decoded size is read from the header first: an
    image over MAX_IMAGE_BYTES is refused (exit 2, one line) without decoding it."""
    import resource
    import struct
    import zlib

    from trafficgeo.geo.image_ortho import MAX_IMAGE_BYTES

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    w, h = 20000, 17000  # RGB: 1.02 GB decoded, about 1 MB of zeros on disk
    assert 3 * w * h > MAX_IMAGE_BYTES
    z = zlib.compressobj(9)
    row = b"\x00" * (1 + 3 * w)
    idat = b"".join(z.compress(row) for _ in range(h)) + z.flush()
    bomb = tmp_path / "bomb.png"
    bomb.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
                     + chunk(b"IDAT", idat) + chunk(b"IEND", b""))
    (tmp_path / "bomb.pgw").write_text("1\n0\n0\n-1\n500000\n5000000\n")
    assert bomb.stat().st_size < 2_000_000
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    code, _stdout, stderr = invoke("ortho-from-image", bomb, "--crs", "EPSG:32633", "-o", tmp_path / "out.tif")
    assert code == 2 and "GB decoded" in stderr and len(stderr.strip().splitlines()) == 1, stderr
    assert not (tmp_path / "out.tif").exists()
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before < 500_000  # kB: it was never decoded
