"""Automatic correspondences between an orthophoto and a video frame, through a camera that is roughly right.

For each textured spot of the orthophoto as the current camera sees it (:func:`trafficgeo.geo.drape.drape_orthophoto`,
one spot per cell of a grid over the frame, ranked by the Shi-Tomasi corner strength: a lane-marking corner or a
blotch, not an edge), a small patch of the orthophoto is rendered through the camera onto the surface's tangent
plane at that spot, and searched for in the frame by zero-mean normalised cross-correlation (OpenCV's
``TM_CCOEFF_NORMED``: insensitive to the gain and offset between an orthophoto flown at another time and the video).
The peak, refined to sub-pixel by a quadratic fit of the 3x3 scores around it, tells where the frame shows the
spot's ground point: one correspondence (world point of the spot, frame pixel). Matches are kept only when the peak
is strong (``min_ncc``), lies inside the search window, is curved in both directions (not an edge: an edge fixes only
one coordinate) and no other hill of the scores comes within ``min_margin`` of it (repeated dashes).

Coordinates: frame pixels follow the camera model (``(0, 0)`` = centre of the top-left pixel); matching at scale
``s`` works on the frame resized by ``s`` (INTER_AREA), whose pixel ``i`` is centred on full-resolution
``(i + 0.5) / s - 0.5``. The orthophoto is sampled from the level of a Gaussian pyramid whose cells match the
patch's footprint on the ground (no aliasing where the camera looks far along the road).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from trafficgeo.camera.model import Camera
from trafficgeo.geo.drape import drape_orthophoto
from trafficgeo.geo.mapping import Surface
from trafficgeo.geo.raster import GeoRaster

TEXTURE_STEP_PX = 4  # rays every 4 px for the texture map that places the patches


@dataclass(frozen=True)
class MatchSettings:
    """One matching pass.

    Attributes:
        scale: frame scale of the pass (0.5 = half resolution).
        search_px: search radius in full-resolution pixels around where the camera puts each spot.
        patch_px: side of a template in pixels at the pass's scale (odd).
        cell_px: one spot per cell of this size (full-resolution pixels).
        min_ncc: lowest accepted peak score.
        min_margin: every other hill of the score map must stay this far below the peak.
        min_roundness: lowest accepted ratio of the peak's smaller to larger curvature (edges are weak across).
    """

    scale: float = 1.0
    search_px: float = 8.0
    patch_px: int = 25
    cell_px: int = 40
    min_ncc: float = 0.55
    min_margin: float = 0.08
    min_roundness: float = 0.02


@dataclass(frozen=True)
class Matches:
    """Correspondences found by one pass: ``world`` (N, 3) in the camera CRS, ``pixels`` (N, 2) in the frame,
    ``predicted`` (N, 2) where the camera put them, ``ncc`` (N,) peak scores, ``roundness`` (N,) the peak's smaller
    over larger curvature (1: a corner, pinned in every direction; near 0: an edge, pinned across it only).
    ``tried`` spots were searched."""

    world: np.ndarray
    pixels: np.ndarray
    predicted: np.ndarray
    ncc: np.ndarray
    roundness: np.ndarray
    tried: int

    def select(self, keep: np.ndarray) -> Matches:
        """The matches where ``keep`` (N,) is True."""
        return Matches(self.world[keep], self.pixels[keep], self.predicted[keep], self.ncc[keep], self.roundness[keep],
                       self.tried)

    @classmethod
    def empty(cls, tried: int = 0) -> Matches:
        return cls(np.zeros((0, 3)), np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), np.zeros(0), tried)

    def __len__(self) -> int:
        return int(self.world.shape[0])


def gray(image: np.ndarray, *, bgr: bool) -> np.ndarray:
    """(H, W) float32 grey levels of an (H, W), (H, W, 3) or (H, W, 4) image (BGR order when ``bgr``)."""
    a = np.asarray(image)
    if a.ndim == 2:
        return a.astype(np.float32)
    code = cv2.COLOR_BGR2GRAY if bgr else cv2.COLOR_RGB2GRAY
    if a.dtype == np.uint8:  # convert the 8-bit image first: 4x less memory traffic than float
        return cv2.cvtColor(np.ascontiguousarray(a[..., :3]), code).astype(np.float32)
    return cv2.cvtColor(np.ascontiguousarray(a[..., :3], dtype=np.float32), code)


class OrthoPyramid:
    """Grey-level Gaussian pyramid of an orthophoto and its data mask, sampled at map coordinates."""

    def __init__(self, ortho: GeoRaster, levels: int = 6) -> None:
        data = ortho.data
        g = gray(data[:3].transpose(1, 2, 0), bgr=False) if data.shape[0] >= 3 else data[0].astype(np.float32)
        valid = np.ones(g.shape, dtype=np.float32)
        if ortho.nodata is not None and np.isfinite(ortho.nodata):
            valid[np.any(data == ortho.nodata, axis=0)] = 0.0
        valid[~np.isfinite(g)] = 0.0
        g = np.where(valid > 0, g, 0.0).astype(np.float32)
        self.ortho = ortho
        self.levels = [g]
        self.valid = [valid]
        for _ in range(levels - 1):
            if min(self.levels[-1].shape) < 16:
                break
            self.levels.append(cv2.pyrDown(self.levels[-1]))
            self.valid.append(cv2.pyrDown(self.valid[-1]))

    def sample(self, x: np.ndarray, y: np.ndarray, level: int) -> tuple[np.ndarray, np.ndarray]:
        """Grey values and data flags (True = all cells of the footprint hold data) at map (x, y), from ``level``."""
        col, row = self.ortho.map_to_pixel(x, y)
        k = 2.0 ** level
        # cv2.pyrDown keeps the even cells: cell j of level L is centred on level-0 cell j 2^L, whose centre is at
        # j 2^L + 0.5 in cell-corner units; cv2 coordinates put integers on cell centres.
        mx = ((np.asarray(col, dtype=np.float64) - 0.5) / k).astype(np.float32)
        my = ((np.asarray(row, dtype=np.float64) - 0.5) / k).astype(np.float32)
        mx = np.nan_to_num(mx, nan=-1e6)
        my = np.nan_to_num(my, nan=-1e6)
        val = cv2.remap(self.levels[level], mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        ok = cv2.remap(self.valid[level], mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        return val, ok > 0.99


def _scaled(frame_gray: np.ndarray, scale: float) -> np.ndarray:
    if scale == 1.0:
        return frame_gray
    h, w = frame_gray.shape
    size = (max(round(w * scale), 1), max(round(h * scale), 1))
    return cv2.resize(frame_gray, size, interpolation=cv2.INTER_AREA)


def _spots(camera: Camera, surface: Surface, pyramid: OrthoPyramid, settings: MatchSettings, shape_s: tuple[int, int],
           margin_s: int) -> np.ndarray:
    """Candidate spot centres (M, 2) as integer pixels of the scaled frame: per cell the strongest corner of the
    orthophoto as the camera sees it, on visible ground far enough from the edges of the frame and of the view."""
    s = settings.scale
    view = drape_orthophoto(camera, surface, pyramid.ortho, step_px=TEXTURE_STEP_PX)
    g = gray(view.image[..., :3], bgr=False) if view.image.shape[2] >= 3 else view.image[..., 0]
    h_s, w_s = shape_s
    g_s = cv2.resize(g, (w_s, h_s), interpolation=cv2.INTER_AREA)
    vis_s = cv2.resize(view.visible.astype(np.uint8), (w_s, h_s), interpolation=cv2.INTER_NEAREST)
    half = settings.patch_px // 2
    vis_s = cv2.erode(vis_s, np.ones((2 * half + 3, 2 * half + 3), np.uint8)) > 0
    score = cv2.cornerMinEigenVal(g_s, blockSize=7, ksize=3)
    score[~vis_s] = 0.0
    score[:margin_s, :] = 0.0
    score[-margin_s:, :] = 0.0
    score[:, :margin_s] = 0.0
    score[:, -margin_s:] = 0.0
    positive = score[score > 0]
    if positive.size == 0:
        return np.zeros((0, 2), dtype=int)
    floor = max(0.05 * float(np.percentile(positive, 90)), 1e-3)
    cell = max(round(settings.cell_px * s), 2 * half + 1)
    out = []
    for y0 in range(0, h_s, cell):
        for x0 in range(0, w_s, cell):
            block = score[y0:y0 + cell, x0:x0 + cell]
            j = int(np.argmax(block))
            r, c = divmod(j, block.shape[1])
            if block[r, c] > floor:
                out.append((x0 + c, y0 + r))
    return np.asarray(out, dtype=int).reshape(-1, 2)


def _to_full(uv_s: np.ndarray, scale: float) -> np.ndarray:
    return (uv_s + 0.5) / scale - 0.5


def _templates(camera: Camera, surface: Surface, pyramid: OrthoPyramid, centres_s: np.ndarray, settings: MatchSettings
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Templates (M, P, P) float32 of the orthophoto around each spot, rendered onto the tangent plane of the surface
    at the spot; the spots' world points (M, 3); and which spots gave a usable template (M,) bool."""
    s = settings.scale
    p = settings.patch_px
    half = p // 2
    m = centres_s.shape[0]
    centres = _to_full(centres_s.astype(np.float64), s)
    hits = surface.intersect(camera.position, camera.rays(centres), min_incidence_deg=0.5)
    world = hits.points
    ok = hits.ok & np.all(np.isfinite(world), axis=1)
    normal = np.full((m, 3), np.nan)
    if ok.any():
        normal[ok] = surface.normal(world[ok, 0], world[ok, 1])
    ok &= np.all(np.isfinite(normal), axis=1)
    off = np.arange(-half, half + 1, dtype=np.float64)
    ou, ov = np.meshgrid(off, off)
    grid_s = centres_s[:, None, :].astype(np.float64) + np.stack([ou.ravel(), ov.ravel()], axis=1)[None]
    rays = camera.rays(_to_full(grid_s.reshape(-1, 2), s)).reshape(m, p * p, 3)
    # Ray-plane intersection: position + t d with n . (position + t d - X) = 0.
    with np.errstate(invalid="ignore", divide="ignore"):
        num = np.einsum("mk,mk->m", normal, world - camera.position)
        den = np.einsum("mk,mpk->mp", normal, rays)
        t = num[:, None] / den
    pts = camera.position + t[..., None] * rays
    ok &= np.all(np.isfinite(pts), axis=(1, 2)) & np.all(t > 0, axis=1)
    # The tangent plane must stand for the surface over the patch: check its four corners against the ray march.
    corners = [0, p - 1, p * p - p, p * p - 1]
    res_m = min(abs(pyramid.ortho.resolution[0]), abs(pyramid.ortho.resolution[1]))
    corner_rays = rays[:, corners].reshape(-1, 3)
    corner_rays = np.where(np.isfinite(corner_rays), corner_rays, 0.0)
    exact = surface.intersect(camera.position, corner_rays, min_incidence_deg=0.2).points.reshape(m, 4, 3)
    # Footprint of one template pixel on the orthophoto (level-0 cells), the larger of its two sides.
    step_u = np.linalg.norm(pts[:, half * p + half + 1] - pts[:, half * p + half], axis=1)
    step_v = np.linalg.norm(pts[:, (half + 1) * p + half] - pts[:, half * p + half], axis=1)
    footprint = np.maximum(step_u, step_v) / res_m
    with np.errstate(invalid="ignore"):
        level = np.clip(np.floor(np.log2(np.maximum(footprint, 1.0))), 0, len(pyramid.levels) - 1)
    level = np.nan_to_num(level, nan=0.0).astype(int)
    gap = np.linalg.norm(exact - pts[:, corners], axis=2).max(axis=1)
    ok &= np.nan_to_num(gap, nan=np.inf) < np.maximum(2.0 ** level, 1.0) * res_m
    templates = np.zeros((m, p, p), dtype=np.float32)
    for lv in np.unique(level[ok]):
        sel = np.flatnonzero(ok & (level == lv))
        val, data = pyramid.sample(pts[sel, :, 0], pts[sel, :, 1], int(lv))
        templates[sel] = val.reshape(-1, p, p)
        ok[sel] &= data.reshape(-1, p * p).all(axis=1)
    ok &= templates.reshape(m, -1).std(axis=1) > 1.0
    return templates, world, ok


def _distinct(scores: np.ndarray, r: int, c: int, margin: float) -> bool:
    """Whether no other hill of the score map comes within ``margin`` of the peak at (r, c): the scores above
    ``peak - margin`` form one connected region around the peak (repeated dashes make two)."""
    high = (scores >= scores[r, c] - margin).astype(np.uint8)
    n, labels = cv2.connectedComponents(high, connectivity=8)
    return n <= 2 or bool(np.all(labels[high > 0] == labels[r, c]))


def _subpixel(scores: np.ndarray, r: int, c: int) -> tuple[float, float, float]:
    """Quadratic fit of the 3x3 scores around (r, c): (dx, dy) of the peak and the smaller/larger curvature ratio."""
    z = scores[r - 1:r + 2, c - 1:c + 2].astype(np.float64)
    gx = 0.5 * (z[1, 2] - z[1, 0])
    gy = 0.5 * (z[2, 1] - z[0, 1])
    hxx = z[1, 2] - 2 * z[1, 1] + z[1, 0]
    hyy = z[2, 1] - 2 * z[1, 1] + z[0, 1]
    hxy = 0.25 * (z[2, 2] - z[2, 0] - z[0, 2] + z[0, 0])
    H = np.array([[hxx, hxy], [hxy, hyy]])
    ev = np.linalg.eigvalsh(H)
    if not (ev[1] < 0):  # both eigenvalues negative: a peak
        return 0.0, 0.0, 0.0
    d = -np.linalg.solve(H, [gx, gy])
    if np.any(np.abs(d) > 1.0):
        return 0.0, 0.0, 0.0
    return float(d[0]), float(d[1]), float(ev[1] / ev[0])


def match_orthophoto(camera: Camera, surface: Surface, pyramid: OrthoPyramid, frame_gray: np.ndarray,
                     settings: MatchSettings) -> Matches:
    """One matching pass (see the module docstring): the frame ``frame_gray`` (H, W) float32 at full resolution."""
    s = settings.scale
    frame_s = _scaled(frame_gray, s)
    h_s, w_s = frame_s.shape
    half = settings.patch_px // 2
    r = max(int(np.ceil(settings.search_px * s)), 2)
    centres_s = _spots(camera, surface, pyramid, settings, (h_s, w_s), half + r + 2)
    if centres_s.shape[0] == 0:
        return Matches.empty()
    templates, world, ok = _templates(camera, surface, pyramid, centres_s, settings)
    keep, found, score, roundness = [], [], [], []
    for i in np.flatnonzero(ok):
        cx, cy = centres_s[i]
        win = frame_s[cy - half - r:cy + half + r + 1, cx - half - r:cx + half + r + 1]
        res = cv2.matchTemplate(win, templates[i], cv2.TM_CCOEFF_NORMED)
        rr, cc = np.unravel_index(int(np.argmax(res)), res.shape)
        best = float(res[rr, cc])
        if best < settings.min_ncc or not (0 < rr < res.shape[0] - 1 and 0 < cc < res.shape[1] - 1):
            continue
        if not _distinct(res, rr, cc, settings.min_margin):
            continue
        dx, dy, ratio = _subpixel(res, rr, cc)
        if ratio < settings.min_roundness:
            continue
        keep.append(i)
        found.append((cx + (cc - r) + dx, cy + (rr - r) + dy))
        score.append(best)
        roundness.append(ratio)
    idx = np.asarray(keep, dtype=int)
    pixels = _to_full(np.asarray(found, dtype=np.float64).reshape(-1, 2), s) if keep else np.zeros((0, 2))
    predicted = _to_full(centres_s[idx].astype(np.float64), s) if keep else np.zeros((0, 2))
    return Matches(world=world[idx], pixels=pixels, predicted=predicted, ncc=np.asarray(score, dtype=np.float64),
                   roundness=np.asarray(roundness, dtype=np.float64), tried=int(ok.sum()))
