"""Geospatial commands: georef, project, dem, gcp-z, accuracy (thin wrappers over :mod:`trafficgeo.geo`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from trafficgeo.cli.app import app, console
from trafficgeo.errors import InputError
from trafficgeo.io.tables import check_table_output

SurfaceOpt = Annotated[str, typer.Option("--surface", "-s", help="number (constant Z in CRS units), 'plane' "
                                         "(GCP plane), a GeoTIFF DEM or a LAS/LAZ point cloud")]
SurfaceCrsOpt = Annotated[str | None, typer.Option(help="CRS of the surface file when it has none, e.g. EPSG:2994")]
ResolutionOpt = Annotated[float, typer.Option(help="DEM cell size (m) when the surface is a point cloud")]


def camera_argument(path: Path):
    from trafficgeo.camera.calibrated import CalibratedCamera

    return CalibratedCamera.read(path)


def surface_argument(spec: str, camera, surface_crs: str | None, resolution: float):
    from trafficgeo.site.surface import load_surface

    return load_surface(spec, camera, surface_crs=surface_crs, resolution_m=resolution)


def check_gis_path(path: Path | None, option: str) -> None:
    """Refuse an unknown GIS suffix before anything is computed or written."""
    from trafficgeo.io.gis import GIS_SUFFIXES

    if path is not None and path.suffix.lower() not in GIS_SUFFIXES:
        raise InputError(f"{option} {path}: unknown GIS format '{path.suffix}'; use .gpkg, .geojson or .parquet")


def _status_summary(status: np.ndarray) -> str:
    names, counts = np.unique(status.astype(str), return_counts=True)
    return ", ".join(f"{c} {n}" for n, c in sorted(zip(names, counts, strict=True), key=lambda p: -p[1]))


@app.command()
def georef(
    camera: Annotated[Path, typer.Argument(help="camera JSON from 'trafficgeo calibrate'")],
    pixels: Annotated[Path, typer.Argument(help="CSV with u,v pixel columns (other columns pass through)")],
    surface: SurfaceOpt,
    output: Annotated[Path, typer.Option("--output", "-o", help="output .csv, .gpkg, .geojson or .parquet")],
    height: Annotated[float, typer.Option(help="height of the points above the road (m), e.g. a roof")] = 0.0,
    min_incidence: Annotated[float, typer.Option(help="rays meeting the surface at less than this angle "
                                                 "(deg) are 'grazing'")] = 0.5,
    surface_crs: SurfaceCrsOpt = None,
    resolution: ResolutionOpt = 0.25,
) -> None:
    """Map pixels to the ground: x, y, z in the camera's CRS, lon/lat, and a status for pixels that cannot be."""
    from trafficgeo.crs import metres_per_unit
    from trafficgeo.geo.georef import georeference_table
    from trafficgeo.geo.mapping import camera_crs
    from trafficgeo.io.tables import read_point_table, write_point_table

    if not np.isfinite(height):
        raise InputError(f"--height {height} must be a finite height above the road in metres, e.g. 1.4")
    check_table_output(output)
    calibrated = camera_argument(camera)
    cam = calibrated.camera
    table = read_point_table(pixels, ("u", "v"), "pixels", "give a CSV with columns u,v (pixels, origin at the "
                             "centre of the top-left pixel)")
    surf = surface_argument(surface, calibrated, surface_crs, resolution)
    crs = camera_crs(cam)
    m = metres_per_unit(crs) if crs is not None else 1.0
    out = georeference_table(cam, table, surf, height=height / m, min_incidence_deg=min_incidence)
    write_point_table(output, out, crs, layer="points")
    console.print(f"surface: {surf.describe()}")
    console.print(f"{len(out)} pixels: {_status_summary(out['status'].to_numpy())}")
    console.print(f"wrote {output}")


@app.command()
def project(
    camera: Annotated[Path, typer.Argument(help="camera JSON from 'trafficgeo calibrate'")],
    world: Annotated[Path, typer.Argument(help="CSV with x,y,z in the camera's CRS (other columns pass through)")],
    output: Annotated[Path, typer.Option("--output", "-o", help="output CSV with u,v added")],
    surface: Annotated[str | None, typer.Option("--surface", "-s", help="surface for the occlusion test")] = None,
    surface_crs: SurfaceCrsOpt = None,
    resolution: ResolutionOpt = 0.25,
) -> None:
    """Project world points into the image (pixels, depth, status: ok, behind_camera, outside_image, occluded)."""
    from trafficgeo.geo.georef import lonlat_columns, project_table
    from trafficgeo.geo.mapping import camera_crs
    from trafficgeo.io.tables import read_point_table, write_point_table

    check_table_output(output)
    calibrated = camera_argument(camera)
    cam = calibrated.camera
    table = read_point_table(world, ("x", "y", "z"), "world points",
                             "give a CSV with columns x,y,z in the camera's CRS and units")
    surf = surface_argument(surface, calibrated, surface_crs, resolution) if surface else None
    out = lonlat_columns(project_table(cam, table, surf), camera_crs(cam))
    write_point_table(output, out, camera_crs(cam))
    console.print(f"{len(out)} points: {_status_summary(out['status'].to_numpy())}")
    console.print(f"wrote {output}")


@app.command()
def dem(
    cloud: Annotated[Path, typer.Argument(help="LAS/LAZ point cloud")],
    output: Annotated[Path, typer.Option("--output", "-o", help="DEM GeoTIFF to write")],
    resolution: Annotated[float, typer.Option(help="cell size in metres (converted to the CRS's units)")] = 0.25,
    crs: Annotated[str | None, typer.Option(help="CRS of the cloud when its header has none, e.g. EPSG:2994")] = None,
) -> None:
    """Ground DEM GeoTIFF from a point cloud.

    Ground points are class 2, else a low-percentile filter; each cell holds their median; holes inside the
    ground's hull are filled by TIN interpolation.
    """
    from trafficgeo.crs import crs_label
    from trafficgeo.geo.pointcloud import cloud_to_dem, read_point_cloud
    from trafficgeo.geo.raster import write_geotiff
    from trafficgeo.site.surface import check_resolution

    check_resolution(resolution)
    if output.suffix.lower() not in (".tif", ".tiff"):
        raise InputError(f"{output}: the DEM is written as a GeoTIFF; name it .tif")
    pc = read_point_cloud(cloud, crs=crs)
    if pc.crs is None:
        raise InputError(f"{cloud}: the cloud has no CRS; give it with --crs (e.g. EPSG:2994)")
    grid = cloud_to_dem(pc, resolution)
    write_geotiff(output, grid.data, grid.transform, grid.crs, nodata=float("nan"), descriptions=grid.descriptions)
    valid = np.isfinite(grid.data[0])
    console.print(f"{len(pc.xyz)} points -> {grid.cols}x{grid.rows} cells of {grid.resolution[0]:g} "
                  f"({crs_label(grid.crs)}), {valid.mean():.0%} with data, z {np.nanmin(grid.data):.2f}.."
                  f"{np.nanmax(grid.data):.2f}")
    console.print(f"wrote {output}")


@app.command("gcp-z")
def gcp_z(
    gcps: Annotated[Path, typer.Argument(help="GCP CSV with x,y (and z to check) in the cloud's/DEM's CRS")],
    output: Annotated[Path, typer.Option("--output", "-o", help="GCP CSV to write (z filled, checks added)")],
    cloud: Annotated[Path | None, typer.Option(help="LAS/LAZ point cloud")] = None,
    dem_path: Annotated[Path | None, typer.Option("--dem", help="GeoTIFF DEM")] = None,
    crs: Annotated[str | None, typer.Option(help="CRS of the cloud/DEM when the file has none")] = None,
    radius: Annotated[float, typer.Option(help="neighbourhood radius (m)")] = 0.5,
    tolerance: Annotated[float, typer.Option(help="largest accepted |z - ground| (m)")] = 0.3,
    roughness: Annotated[float, typer.Option(help="largest accepted local ground spread (m)")] = 0.15,
    replace: Annotated[bool, typer.Option(help="replace every z by the ground z")] = False,
) -> None:
    """Fill missing GCP heights from a point cloud or DEM and flag heights that disagree with the ground."""
    from trafficgeo.geo.georef import GroundCheckOptions, check_gcp_heights, lonlat_columns
    from trafficgeo.io.tables import read_point_table, write_point_table

    if (cloud is None) == (dem_path is None):
        raise InputError("give exactly one of --cloud CLOUD.laz or --dem DEM.tif")
    for name, value in (("--radius", radius), ("--tolerance", tolerance), ("--roughness", roughness)):
        if not value > 0:
            raise InputError(f"{name} {value} must be positive (metres)")
    check_table_output(output)
    table = read_point_table(gcps, ("x", "y"), "GCP", "give a CSV with columns id,x,y[,z],u,v in the CRS of the "
                             "cloud/DEM")
    if cloud is not None:
        from trafficgeo.geo.pointcloud import GroundIndex, read_point_cloud

        pc = read_point_cloud(cloud, crs=crs)
        ground: object = GroundIndex.from_cloud(pc)
        data_crs = pc.crs
    else:
        from trafficgeo.geo.raster import read_dem
        from trafficgeo.geo.surface import DEMSurface

        raster = read_dem(dem_path, crs=crs)  # type: ignore[arg-type]
        ground = DEMSurface.from_raster(raster)
        data_crs = raster.crs
    out = check_gcp_heights(table, ground, data_crs, GroundCheckOptions(radius, tolerance, roughness, replace))
    out = lonlat_columns(out, data_crs)
    write_point_table(output, out, data_crs)
    for _, row in out[out["z_check"].isin(["disagrees", "rough", "outside", "empty"])].iterrows():
        label = row.get("id", row.name)
        console.print(f"  GCP {label}: {row['z_check']}"
                      + (f" (z - ground = {row['dz_m']:+.2f} m)" if np.isfinite(row["dz_m"]) else "")
                      + (f", ground spread {row['ground_spread_m']:.2f} m" if np.isfinite(row["ground_spread_m"])
                         else ""))
    console.print(f"{len(out)} GCPs: {_status_summary(out['z_check'].to_numpy())}")
    console.print(f"wrote {output}")


@app.command()
def accuracy(
    camera: Annotated[Path, typer.Argument(help="camera JSON from 'trafficgeo calibrate' (with its covariance)")],
    surface: SurfaceOpt,
    output: Annotated[Path, typer.Option("--output", "-o", help="GeoTIFF of expected ground error (m)")],
    pixel_sigma: Annotated[float, typer.Option(help="pixel noise of the points you will map (px, 1 sigma)")] = 1.0,
    cell: Annotated[float | None, typer.Option(help="grid cell size (m); default ~500 cells across")] = None,
    max_distance: Annotated[float, typer.Option(help="ignore ground farther than this from the camera (m)")] = 250.0,
    gis: Annotated[Path | None, typer.Option(help="also write camera, GCPs and footprint (.gpkg/.geojson)")] = None,
    surface_crs: SurfaceCrsOpt = None,
    resolution: ResolutionOpt = 0.25,
) -> None:
    """Map the expected ground error over the visible road, and the camera footprint.

    The calibration covariance stored in the camera JSON and the pixel noise are propagated to 1-sigma ground errors
    in metres.
    """
    from trafficgeo.geo.raster import write_geotiff
    from trafficgeo.geo.uncertainty import accuracy_grid, footprint_polygon
    from trafficgeo.io.gis import write_gis
    from trafficgeo.site.layers import site_layers

    if not pixel_sigma >= 0:
        raise InputError(f"--pixel-sigma {pixel_sigma} must be >= 0 px")
    if cell is not None and not cell > 0:
        raise InputError(f"--cell {cell} must be a positive size in metres")
    if not max_distance > 0:
        raise InputError(f"--max-distance {max_distance} must be positive (m)")
    if output.suffix.lower() not in (".tif", ".tiff"):
        raise InputError(f"{output}: the accuracy map is a GeoTIFF; name it .tif")
    check_gis_path(gis, "--gis")
    calibrated = camera_argument(camera)
    cam = calibrated.camera
    if cam.crs is None:
        raise InputError(f"{camera}: the camera has no CRS, so the map cannot be georeferenced; calibrate with --crs")
    cov = calibrated.covariance
    if cov is None:
        console.print("[yellow]no calibration covariance in the camera JSON: mapping pixel noise only[/]")
    surf = surface_argument(surface, calibrated, surface_crs, resolution)
    grid = accuracy_grid(cam, surf, cov, pixel_sigma=pixel_sigma, resolution_m=cell, max_distance_m=max_distance)
    foot = footprint_polygon(grid)
    layers = site_layers(calibrated, foot) if gis is not None else None
    write_geotiff(output, grid.bands, grid.transform, grid.crs, nodata=float("nan"), descriptions=grid.band_names)
    if layers is not None:
        write_gis(gis, layers, grid.crs)
    r = grid.bands[0][grid.visible]
    if r.size:
        q = np.nanpercentile(r, [50, 90])
        console.print(f"visible ground {foot.area * _m2(grid):,.0f} m2; expected error (1 sigma) median "
                      f"{q[0]:.2f} m, 90th percentile {q[1]:.2f} m, worst {np.nanmax(r):.2f} m")
    console.print(f"wrote {output}" + (f" and {gis}" if gis else ""))


def _m2(grid) -> float:
    from trafficgeo.crs import metres_per_unit

    m = metres_per_unit(grid.crs) if grid.crs is not None else 1.0
    return m * m


@app.command("ortho-from-image")
def ortho_from_image(
    image: Annotated[Path, typer.Argument(help="georeferenced image that is not a GeoTIFF (PNG, JPEG, ...)")],
    crs: Annotated[str, typer.Option(help="projected CRS of the map coordinates, e.g. EPSG:32633")],
    output: Annotated[Path, typer.Option("--output", "-o", help="orthophoto GeoTIFF to write")],
    world_file: Annotated[Path | None, typer.Option(help="world file (.pgw/.jgw/.wld: six lines, parameters of the "
                                                    "top-left pixel's centre); default: the one beside IMAGE")] = None,
    corners: Annotated[Path | None, typer.Option(help="control-point CSV instead: u,v,x,y (pixel centres on integers) "
                                                 "or corner,x,y (top-left, top-right, bottom-right, bottom-left); 3 "
                                                 "or more, fitted by least squares")] = None,
    model: Annotated[str, typer.Option(help="how --corners are fitted: 'auto' (projective from 4 points, the image "
                                            "resampled north-up; affine from 3), 'affine' or 'projective'")] = "auto",
    camera: Annotated[Path | None, typer.Option(help="the image's camera (pose and lens): a camera JSON, or an "
                                                "OpenCV pose YAML/XML in --crs; with --surface the image is "
                                                "orthorectified (--corners then check it)")] = None,
    surface: Annotated[str | None, typer.Option("--surface", "-s", help="with --camera: the ground, a number "
                                                "(constant Z in CRS units), a GeoTIFF DEM or a LAS/LAZ point "
                                                "cloud")] = None,
    surface_crs: SurfaceCrsOpt = None,
    resolution: ResolutionOpt = 0.25,
    cell: Annotated[float | None, typer.Option(help="with --camera: the orthophoto's cell size (m); default: the "
                                               "image's median pixel on the ground")] = None,
    max_distance: Annotated[float | None, typer.Option(help="with --camera: leave out ground farther than this "
                                                       "from the camera (m)")] = None,
) -> None:
    """Turn a georeferenced image (world file or 3+ control points, and a CRS) into an orthophoto GeoTIFF. From 4
    control points a projective fit makes a perspective image (an oblique drone photo) an orthophoto of flat
    ground, resampled onto a north-up grid. With the image's camera and the surface it is orthorectified: every
    ground cell takes the colour where the camera sees it, following the terrain and the lens."""
    from trafficgeo.geo.image_ortho import image_corners, image_to_geotiff

    if output.suffix.lower() not in (".tif", ".tiff"):
        raise InputError(f"--output {output}: write the orthophoto as a GeoTIFF (.tif)")
    if (surface is None) != (camera is None):
        raise InputError("--camera and --surface go together: the camera places each pixel's ray, the surface "
                         "where it meets the ground")
    for name, value in (("--cell", cell), ("--max-distance", max_distance)):
        if value is not None and not (np.isfinite(value) and value > 0):
            raise InputError(f"{name} {value}: give a positive number of metres")
    cam = surf = None
    if camera is not None:
        from trafficgeo.crs import parse_crs
        from trafficgeo.site.surface import surface_in_crs

        if camera.suffix.lower() == ".json":
            cam = camera_argument(camera).camera
        else:
            from trafficgeo.camera.pose_file import read_pose_file

            cam = read_pose_file(camera, crs=crs)
        surf = surface_in_crs(surface, parse_crs(crs), surface_crs=surface_crs, resolution_m=resolution)
    raster, fit = image_to_geotiff(image, output, crs, world_file=world_file, control=corners, model=model,
                                   camera=cam, surface=surf, resolution_m=cell, max_distance_m=max_distance)
    res = raster.resolution
    console.print(f"{raster.cols}x{raster.rows} px, {raster.count} band(s), pixel {res[0]:.4g} x {res[1]:.4g} CRS "
                  f"units, top-left corner at {image_corners(raster)[0][0]:.3f}, {image_corners(raster)[0][1]:.3f}")
    if cam is not None:
        seen = float(np.mean(np.any(raster.data != 0, axis=0)))
        console.print(f"orthorectified through the camera onto the surface: {seen:.0%} of the grid seen")
        if fit is not None:
            console.print(f"{fit.n_points} control points as checks: their pixels land {fit.rmse:.3f} RMS, "
                          f"{fit.max_error:.3f} at most from their x, y (CRS units)")
    elif fit is not None:
        kind, exact = ("projective", 4) if type(fit).__name__ == "ProjectiveFit" else ("affine", 3)
        console.print(f"{kind} fitted to {fit.n_points} control points: RMS {fit.rmse:.3f}, max {fit.max_error:.3f} "
                      "CRS units" + (f" ({exact} points: an exact fit, nothing checks it)" if fit.n_points == exact
                                     else ""))
    console.print(f"wrote {output}")
