"""Per-point measurements of a track's boxes on the ground: the covariance of a ground point from the image's
pixel noise, the cuboid-fitted footprint centres of boxes (by their bottom edge, or by their top edge where the
frame cuts the bottom off), and a vehicle's length from its boxes. Used by :mod:`trafficgeo.traffic.trajectories`.

Units: positions in the camera CRS's units, covariances in m^2, dimensions in metres, pixels in the OpenCV
pixel-centre convention; conventions of the cuboids: :mod:`trafficgeo.geo.cuboids`.
"""

from __future__ import annotations

import numpy as np

from trafficgeo.camera.model import Camera
from trafficgeo.geo.mapping import Surface, pixels_to_world
from trafficgeo.run.tracks import ImageTracks

BOX_FIT_TOL_PX = 0.02  # the cuboid fit stops when the box's centre and bottom match to this (px): far below noise
BLOCK_POINTS = 8192  # per-point passes (ground points, covariances, cuboid fits) run over this many points at a time,
# so their temporaries stay a few MB whatever the number of points


def ground_covariance(camera: Camera, surface: Surface, uv: np.ndarray, xyz: np.ndarray,
                      pixel_sigma: float | np.ndarray, m_per_unit: float) -> np.ndarray:
    """(N, 2, 2) horizontal covariance (m^2) of ground points ``xyz`` from ``pixel_sigma`` px of image noise (one
    for all points, or (N,) one per point):
    ``pixel_sigma^2 J J^T`` with J the ground-from-pixel Jacobian by one-pixel differences. Where a neighbour pixel
    does not reach the road, an isotropic sigma of ``pixel_sigma * range / focal / sin(incidence)`` is used."""
    n = uv.shape[0]
    cols = []
    for du, dv in ((1.0, 0.0), (0.0, 1.0)):
        nb = pixels_to_world(camera, uv + [du, dv], surface, with_lonlat=False, frame_margin_px=2.0)
        cols.append((nb.xyz[:, :2] - xyz[:, :2]) * m_per_unit)
    J = np.stack(cols, axis=2)  # (N, 2, 2): d(x, y) / d(u, v)
    sigma = np.broadcast_to(np.asarray(pixel_sigma, dtype=np.float64), (n,))
    cov = sigma[:, None, None] ** 2 * np.einsum("nij,nkj->nik", J, J) + (0.02**2) * np.eye(2)
    bad = ~np.all(np.isfinite(cov.reshape(n, 4)), axis=1)
    if bad.any():
        rng = np.linalg.norm((xyz[bad] - camera.position) * m_per_unit, axis=1)
        sin_inc = np.clip(np.abs((xyz[bad, 2] - camera.position[2]) * m_per_unit) / np.maximum(rng, 1e-9), 0.05, 1)
        s = sigma[bad] * rng / camera.focal_px / sin_inc
        cov[bad] = s[:, None, None] ** 2 * np.eye(2)
    return cov


def blocks(n: int) -> list[slice]:
    """Slices covering range(n) in pieces of :data:`BLOCK_POINTS`."""
    return [slice(k, min(k + BLOCK_POINTS, n)) for k in range(0, n, BLOCK_POINTS)]


def majority(values: np.ndarray) -> str:
    vals = [str(v) for v in values if str(v)]
    if not vals:
        return ""
    names, counts = np.unique(vals, return_counts=True)
    return str(names[np.argmax(counts)])


def known_classes(tracks: ImageTracks) -> np.ndarray:
    """Per-point classes, those of unknown class (``""``: e.g. a blob of vehicles merged in the image) replaced
    by their track's majority class, so that a vehicle keeps its own dimensions in the frames where it is not
    told apart."""
    vclass = np.asarray(tracks.vclass, dtype=object).copy()
    blank = vclass == ""
    if blank.any() and not blank.all():
        for _tid, rows in track_slices(np.asarray(tracks.track_id)):
            hole = rows[blank[rows]]
            if hole.size:
                vclass[hole] = majority(vclass[rows])
    return vclass


def fit_boxes(camera: Camera, surface: Surface, tracks: ImageTracks, heading: np.ndarray, ok: np.ndarray,
               measured: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cuboid-fitted footprint centres of all usable boxes, written into ``measured`` (CRS units) where the fit
    succeeds. Where it fails, the bottom-centre point is up to half a vehicle off; it stays in its track only as
    a hint (the caller gives it a 100 m sigma) so that the smoother bridges it from its neighbours. Returns the
    success mask (N,) and the class dimensions used (N, 3) m."""
    from trafficgeo.geo.cuboids import dimensions_for
    from trafficgeo.traffic.box_points import box_ground_points

    dims = dimensions_for(known_classes(tracks))
    good = np.zeros(len(tracks), dtype=bool)
    usable = np.flatnonzero(ok & np.all(np.isfinite(tracks.box), axis=1))
    for sl in blocks(usable.size):
        use = usable[sl]
        fit = box_ground_points(camera, surface, tracks.box[use], heading[use], dims[use], iterations=15,
                                tol_px=BOX_FIT_TOL_PX)
        good[use] = fit.status == "ok"
        measured[use[good[use]]] = fit.xyz[good[use], :2]
    return good, dims


def vehicle_length(camera: Camera, surface: Surface, heading: np.ndarray, boxes: np.ndarray, dims: np.ndarray,
                    good: np.ndarray, pixel_sigma: float, max_frames: int = 40) -> tuple[float, float]:
    """Length (m) and its 1-sigma (m) of one vehicle from up to ``max_frames`` of its boxes (NaN where the view
    does not determine it, e.g. seen only from behind; see :func:`trafficgeo.traffic.box_points.estimate_length_refit`).
    The box's top edge is not used: real roofs are shorter than their vehicles."""
    from trafficgeo.traffic.box_length import estimate_length_refit

    idx = np.flatnonzero(good)
    if idx.size < 5:
        return float("nan"), float("nan")
    idx = idx[np.linspace(0, idx.size - 1, min(max_frames, idx.size)).round().astype(int)]
    length0, width, height = np.median(dims[idx], axis=0)
    return estimate_length_refit(camera, surface, heading[idx], boxes[idx], float(width), float(height),
                                 length0_m=float(length0), pixel_sigma=pixel_sigma, use_top=False)


def fit_top_edges(camera: Camera, surface: Surface, tracks: ImageTracks, heading: np.ndarray, rows: np.ndarray,
                   dims: np.ndarray, measured: np.ndarray, pixel_sigma: float,
                   m: float) -> tuple[np.ndarray, np.ndarray]:
    """The ``rows`` whose box (cut off by the frame's bottom) a cuboid fits by its top edge
    (:func:`~trafficgeo.traffic.box_points.box_ground_points` with ``top_edge``), and their covariances (M, 2, 2)
    m^2; their footprint centres are written into ``measured`` (CRS units).

    A top edge is where the vehicle's far end and roof are, so the point moves with the vehicle's true length and
    height: the covariance adds, to the pixel noise, the shift of the fit when the class's length is
    :data:`TOP_EDGE_LENGTH_SIGMA_M` longer and when its height is :data:`TOP_EDGE_HEIGHT_SIGMA_M` higher (small
    from a camera looking down on the road, metres from a low one looking along it)."""
    from trafficgeo.traffic.box_points import TOP_EDGE, box_ground_points

    def fit(use: np.ndarray, size: np.ndarray) -> np.ndarray:
        got = box_ground_points(camera, surface, tracks.box[use], heading[use], size, iterations=15,
                                tol_px=BOX_FIT_TOL_PX, top_edge=True)
        return np.where((got.status == TOP_EDGE)[:, None], got.xyz, np.nan)

    fitted, covs = [], []
    for sl in blocks(rows.size):
        use = rows[sl]
        xyz = fit(use, dims[use])
        shifts = [(fit(use, dims[use] + step) - xyz)[:, :2] * m
                  for step in ([TOP_EDGE_LENGTH_SIGMA_M, 0.0, 0.0], [0.0, 0.0, TOP_EDGE_HEIGHT_SIGMA_M])]
        done = np.all(np.isfinite(xyz), axis=1) & np.all(np.isfinite(np.hstack(shifts)), axis=1)
        measured[use[done]] = xyz[done, :2]
        cov = ground_covariance(camera, surface, camera.project(xyz[done]), xyz[done], pixel_sigma, m)
        for d in shifts:
            cov += np.einsum("ni,nj->nij", d[done], d[done])
        fitted.append(use[done])
        covs.append(cov)
    if not fitted:
        return np.zeros(0, dtype=np.int64), np.zeros((0, 2, 2))
    return np.concatenate(fitted), np.concatenate(covs)


TOP_EDGE_LENGTH_SIGMA_M = 0.6  # m, 1-sigma of a vehicle's length about its class's, its roof's set-back included
TOP_EDGE_HEIGHT_SIGMA_M = 0.3  # m, 1-sigma of a vehicle's height about its class's


def track_slices(track_id: np.ndarray) -> list[tuple[str, np.ndarray]]:
    """(track id, row indices) per track of rows grouped by track, in order of first appearance."""
    keys, first = np.unique(track_id, return_index=True)
    order = np.argsort(first)
    bounds = np.append(np.sort(first), track_id.size)
    return [(str(keys[o]), np.arange(bounds[k], bounds[k + 1])) for k, o in enumerate(order)]


# A vehicle's class from its measured length (m), where the detector could not tell it: the boundaries of the size
# rules' classes (trafficgeo.video.detectors.sizes.SizeRules: car 3.0-5.3, van 4.6-7.5, truck and bus from 7.5).
LENGTH_CLASS_MAX_STD_M = 1.0  # only a length measured at least this well decides a class
CAR_MIN_LENGTH_M = 3.0
CAR_MAX_LENGTH_M = 5.0  # between a car and a van
HEAVY_MIN_LENGTH_M = 7.5  # a truck or a bus: "truck", as the size rules name both
HEAVY_CLASSES = ("truck", "bus")  # heavy vehicles, as junction studies count them
RELABEL_HEAVY_MIN_LENGTH_M = 8.0  # a "car" or "van" this long (well measured) is a truck or bus the detector missed


def classes_by_length(vehicle_class: np.ndarray, length_m: np.ndarray, length_std_m: np.ndarray) -> np.ndarray:
    """Vehicle classes completed by their measured length: a vehicle of unknown class (``""``) whose length is known
    to :data:`LENGTH_CLASS_MAX_STD_M` becomes a car (from :data:`CAR_MIN_LENGTH_M`), a van (from
    :data:`CAR_MAX_LENGTH_M`) or a truck (from :data:`HEAVY_MIN_LENGTH_M`); a car or van at least
    :data:`RELABEL_HEAVY_MIN_LENGTH_M` long becomes a truck. Seen broadside at a junction a bus's box is too wide
    for the detector's size rule, which judges a box's size along the line of sight; the track's length, fitted
    with its heading, is not."""
    cls = np.asarray(vehicle_class, dtype=object).copy()
    length = np.asarray(length_m, dtype=np.float64)
    sure = np.isfinite(length) & (np.asarray(length_std_m, dtype=np.float64) <= LENGTH_CLASS_MAX_STD_M)
    blank = sure & (cls == "")
    cls[blank & (length >= CAR_MIN_LENGTH_M)] = "car"
    cls[blank & (length >= CAR_MAX_LENGTH_M)] = "van"
    cls[blank & (length >= HEAVY_MIN_LENGTH_M)] = "truck"
    cls[sure & np.isin(cls, ["car", "van"]) & (length >= RELABEL_HEAVY_MIN_LENGTH_M)] = "truck"
    return cls
