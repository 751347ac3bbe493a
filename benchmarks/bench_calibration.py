"""Benchmark: trafficgeo's GCP calibration against OpenCV baselines and the achievable limit.

Every method runs on the same random synthetic road scenes (``trafficgeo.synth.make_gcp_scene``) in the same run:

* ``trafficgeo``       -- ``calibrate(scene.gcps, image_size)`` with default options (finds the outliers itself);
* ``solvePnP(true K)`` -- OpenCV SQPnP + ``solvePnPRefineLM`` given the TRUE K and zero distortion, on all control
                          points (no outlier handling);
* ``calibrateCamera``  -- OpenCV ``calibrateCamera`` (single view, CALIB_USE_INTRINSIC_GUESS, f0 = image width,
                          principal point fixed at the centre, k1 and k2 free) on all control points;
* ``limit``            -- maximum-likelihood fit (pose, f, k1, k2) on the TRUE inliers started from the TRUE
                          camera: the accuracy achievable with the scene's noise.

Run ``python benchmarks/bench_calibration.py --help``; see benchmarks/README.md for the columns and the targets.
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import json
import os
import platform
import subprocess
import sys
import time
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from trafficgeo.calibration.params import ParameterModel
from trafficgeo.calibration.pipeline import calibrate
from trafficgeo.calibration.refine import fit_camera
from trafficgeo.camera.model import Camera
from trafficgeo.camera.parameters import camera_to_full, full_to_camera
from trafficgeo.synth.gcp_scene import GCPScene, make_gcp_scene

METHODS = ("trafficgeo", "solvePnP(true K)", "calibrateCamera", "limit")
PARAM_STREAM = 20261123  # second word of the seed of the scene-parameter draws (the scene itself uses seed = i)
SIZES = {"4K": (3840, 2160), "1080p": (1920, 1080)}

# Targets (printed next to the measured values).
TARGET_GROUND_RATIO = 1.2  # trafficgeo median ground error / limit median ground error
TARGET_RECALL = 1.0  # outlier recall
TARGET_FP_RATE = 0.05  # flagged good control points / all good control points
TARGET_TIME_MS = 50.0  # median trafficgeo time (incl. leave-one-out) for scenes with >= 18 control points
TIME_MIN_CONTROL = 18


# ------------------------------------------------------------------------------------------------ scenes
@dataclass(frozen=True)
class SceneSpec:
    """The random options of one scene (drawn deterministically from its seed)."""

    seed: int
    size: str
    n_control: int
    n_check: int
    n_outliers: int
    n_elevated: int
    pixel_sigma: float
    survey_sigma: float
    grade: float
    crossfall: float
    crest_radius: float
    camera_height: float

    def make(self) -> GCPScene:
        return make_gcp_scene(
            self.seed, image_size=SIZES[self.size], n_control=self.n_control, n_check=self.n_check,
            n_outliers=self.n_outliers, n_elevated=self.n_elevated, pixel_sigma=self.pixel_sigma,
            survey_sigma=self.survey_sigma, grade=self.grade, crossfall=self.crossfall,
            crest_radius=self.crest_radius, camera_height=self.camera_height)


def scene_spec(i: int) -> SceneSpec:
    """Scene options for seed ``i``: even seeds 4K, odd seeds 1080p; the rest uniform as in the README."""
    rng = np.random.default_rng((i, PARAM_STREAM))
    return SceneSpec(
        seed=i,
        size="4K" if i % 2 == 0 else "1080p",
        n_control=int(rng.integers(8, 21)),
        n_check=5,
        n_outliers=int(rng.integers(0, 4)),
        n_elevated=int(rng.integers(1, 4)),
        pixel_sigma=1.0,
        survey_sigma=float(rng.uniform(0.02, 0.03)),
        grade=float(rng.uniform(0.0, 0.04)),
        crossfall=0.02,
        crest_radius=float(rng.uniform(2000.0, 6000.0)) if rng.random() < 0.5 else 0.0,
        camera_height=float(rng.uniform(5.0, 12.0)),
    )


# ------------------------------------------------------------------------------------------------ methods
@dataclass
class Outcome:
    """What one method produced on one scene."""

    camera: Camera | None = None
    time_ms: float = float("nan")
    error: str = ""  # "ExceptionType: message" or a reason when no usable camera came out
    inlier: np.ndarray | None = None  # trafficgeo only: control points kept in the final fit


def _control_local(scene: GCPScene, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    world = scene.gcps.world[mask]
    origin = world.mean(axis=0)
    return origin, world - origin, scene.gcps.pixels[mask]


def run_trafficgeo(scene: GCPScene) -> Outcome:
    t0 = time.perf_counter()
    cal = calibrate(scene.gcps, scene.camera.image_size)
    dt = 1e3 * (time.perf_counter() - t0)
    return Outcome(camera=cal.camera, time_ms=dt, inlier=np.asarray(cal.inlier, dtype=bool))


def run_solvepnp(scene: GCPScene) -> Outcome:
    truth = scene.camera
    ctrl = scene.gcps.is_control
    t0 = time.perf_counter()
    origin, loc, pix = _control_local(scene, ctrl)
    K = np.array([[truth.K[0, 0], 0.0, truth.K[0, 2]], [0.0, truth.K[1, 1], truth.K[1, 2]], [0.0, 0.0, 1.0]])
    dist = np.zeros(5)
    obj = np.ascontiguousarray(loc, dtype=np.float64).reshape(-1, 1, 3)
    img = np.ascontiguousarray(pix, dtype=np.float64).reshape(-1, 1, 2)
    ok, rvec, tvec = cv2.solvePnP(obj, img, K, dist, flags=cv2.SOLVEPNP_SQPNP)
    if not ok:
        return Outcome(time_ms=1e3 * (time.perf_counter() - t0), error="solvePnP returned False")
    rvec, tvec = cv2.solvePnPRefineLM(obj, img, K, dist, rvec, tvec)
    dt = 1e3 * (time.perf_counter() - t0)
    cam = Camera.from_rvec_tvec(truth.image_size, K, dist, rvec, tvec, origin=origin, crs=truth.crs)
    return Outcome(camera=cam, time_ms=dt)


def run_calibrate_camera(scene: GCPScene) -> Outcome:
    w, h = scene.camera.image_size
    ctrl = scene.gcps.is_control
    flags = (cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_FIX_ASPECT_RATIO | cv2.CALIB_FIX_PRINCIPAL_POINT
             | cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K3)
    t0 = time.perf_counter()
    origin, loc, pix = _control_local(scene, ctrl)
    K0 = np.array([[float(w), 0.0, (w - 1) / 2.0], [0.0, float(w), (h - 1) / 2.0], [0.0, 0.0, 1.0]])
    obj = [np.ascontiguousarray(loc, dtype=np.float32)]
    img = [np.ascontiguousarray(pix, dtype=np.float32)]
    _rms, K, dist, rvecs, tvecs = cv2.calibrateCamera(obj, img, (w, h), K0, np.zeros(5), flags=flags)
    dt = 1e3 * (time.perf_counter() - t0)
    cam = Camera.from_rvec_tvec((w, h), K, dist, rvecs[0], tvecs[0], origin=origin, crs=scene.camera.crs)
    return Outcome(camera=cam, time_ms=dt)


def run_limit(scene: GCPScene) -> Outcome:
    truth = scene.camera
    good = scene.gcps.is_control & ~scene.outlier
    model = ParameterModel("single", False, ("k1", "k2"))
    t0 = time.perf_counter()
    origin, loc, pix = _control_local(scene, good)
    fit = fit_camera(loc, pix, scene.gcps.sigma_px[good], camera_to_full(truth, origin), model, loss="linear")
    dt = 1e3 * (time.perf_counter() - t0)
    if not fit.success:
        return Outcome(time_ms=dt, error="fit_camera: success=False")
    return Outcome(camera=full_to_camera(fit.full, origin, truth.image_size, truth.crs), time_ms=dt)


RUNNERS = {"trafficgeo": run_trafficgeo, "solvePnP(true K)": run_solvepnp,
           "calibrateCamera": run_calibrate_camera, "limit": run_limit}


def run_method(name: str, scene: GCPScene) -> Outcome:
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return RUNNERS[name](scene)
    except Exception as exc:  # a baseline or the library failing on a scene is a result, not a crash
        msg = " ".join(str(exc).split())
        return Outcome(error=f"{type(exc).__name__}: {msg[:200]}")


# ------------------------------------------------------------------------------------------------ metrics
@dataclass
class Row:
    """One method on one scene (also the CSV/JSON record)."""

    seed: int
    size: str
    n_control: int
    n_outliers: int
    method: str
    ok: bool
    error: str
    time_ms: float
    position_error_m: float
    focal_error_pct: float
    ground_rms_m: float
    tp: int = 0
    fp: int = 0
    fn: int = 0
    n_good: int = 0
    missed: list[str] = field(default_factory=list)
    false_flags: list[str] = field(default_factory=list)
    worst_good: str = ""  # the good control point farthest from the true camera (only when a mistake was made)


def ground_rms(camera: Camera, scene: GCPScene) -> float:
    """RMS horizontal error (m) at the check points: ray of the observed pixel meets the plane Z = true Z."""
    chk = scene.gcps.is_check
    if not chk.any():
        return float("nan")
    hit = camera.intersect_horizontal_plane(scene.gcps.pixels[chk], scene.true_world[chk, 2])
    d = np.hypot(*(hit[:, :2] - scene.true_world[chk, :2]).T)
    if not np.all(np.isfinite(d)):
        return float("inf")  # a check ray misses its plane (points above the horizon / behind the camera)
    return float(np.sqrt(np.mean(d ** 2)))


def _world_jacobian(camera: Camera, world: np.ndarray, step: float = 1e-3) -> np.ndarray:
    """(N, 2, 3) derivative of the projection w.r.t. the world point (central differences, CRS units)."""
    J = np.zeros((world.shape[0], 2, 3))
    for k in range(3):
        d = np.zeros(3)
        d[k] = step
        J[:, :, k] = (camera.project(world + d) - camera.project(world - d)) / (2.0 * step)
    return J


def true_residual_sigmas(scene: GCPScene) -> tuple[np.ndarray, np.ndarray]:
    """Residual of every GCP against the TRUE camera, in px and in sigmas of the actual noise.

    The actual noise of a point in the image is the pixel noise plus its survey noise projected into the image
    (covariance ``pixel_sigma^2 I + survey_sigma^2 J J^T``); at 10 m in a 4K frame 2.5 cm of survey noise is
    ~10 px, far more than the 1 px the table's ``sigma_px`` states. Returns (px (N,), Mahalanobis length (N,)).
    """
    g = scene.gcps
    r = scene.camera.project(g.world) - g.pixels
    J = _world_jacobian(scene.camera, scene.true_world)
    cov = scene.survey_sigma ** 2 * np.einsum("nik,njk->nij", J, J) + scene.pixel_sigma ** 2 * np.eye(2)
    z = np.sqrt(np.einsum("ni,ni->n", r, np.linalg.solve(cov, r[:, :, None])[:, :, 0]))
    return np.hypot(r[:, 0], r[:, 1]), z


def _point_note(scene: GCPScene, i: int, px: np.ndarray, z: np.ndarray) -> str:
    """A GCP described for the report: id, kind, elevated or not, its residual against the TRUE camera."""
    elevated = scene.true_world[i, 2] - float(scene.road.z(scene.true_world[i, 0], scene.true_world[i, 1])) > 0.3
    kind = scene.outlier_kind[i] or "good"
    return f"{scene.gcps.ids[i]} {kind}{' elevated' if elevated else ''} {px[i]:.1f} px = {z[i]:.1f} sigma"


def evaluate(spec: SceneSpec, scene: GCPScene, name: str, out: Outcome) -> Row:
    nan = float("nan")
    row = Row(spec.seed, spec.size, spec.n_control, int(scene.outlier.sum()), name, False, out.error,
              out.time_ms, nan, nan, nan)
    if out.camera is None:
        if not row.error:
            row.error = "no camera"
        row.position_error_m = row.ground_rms_m = float("inf")
        return row
    truth = scene.camera
    row.position_error_m = float(np.linalg.norm(out.camera.position - truth.position))
    row.focal_error_pct = float(100.0 * abs(out.camera.focal_px - truth.focal_px) / truth.focal_px)
    row.ground_rms_m = ground_rms(out.camera, scene)
    row.ok = bool(np.isfinite(row.ground_rms_m) and np.isfinite(row.position_error_m))
    if not row.ok:
        row.error = "check-point ray misses its plane"
    if out.inlier is not None:
        ctrl = scene.gcps.is_control
        flagged = ctrl & ~out.inlier
        truth_out = ctrl & scene.outlier
        row.tp = int(np.sum(flagged & truth_out))
        row.fp = int(np.sum(flagged & ~truth_out))
        row.fn = int(np.sum(~flagged & truth_out))
        row.n_good = int(np.sum(ctrl & ~scene.outlier))
        if row.fn or row.fp:
            px, z = true_residual_sigmas(scene)
            row.missed = [_point_note(scene, i, px, z) for i in np.nonzero(~flagged & truth_out)[0]]
            row.false_flags = [_point_note(scene, i, px, z) for i in np.nonzero(flagged & ~truth_out)[0]]
            good = np.nonzero(ctrl & ~scene.outlier)[0]
            if good.size:
                j = good[np.argmax(z[good])]
                row.worst_good = f"{scene.gcps.ids[j]} {px[j]:.1f} px = {z[j]:.1f} sigma"
    return row


# ------------------------------------------------------------------------------------------------ summary
def _pct(values: list[float], q: float) -> float:
    """Percentile with failures as +inf (np.percentile would give nan between inf and a finite value)."""
    a = np.sort(np.asarray(values, dtype=np.float64))
    if a.size == 0:
        return float("nan")
    pos = q / 100.0 * (a.size - 1)
    lo, hi = int(np.floor(pos)), int(np.ceil(pos))
    if lo == hi or a[lo] == a[hi]:
        return float(a[lo])
    if np.isinf(a[hi]):
        return float("inf")
    return float(a[lo] + (pos - lo) * (a[hi] - a[lo]))


def summarize(rows: list[Row]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for m in METHODS:
        rs = [r for r in rows if r.method == m]
        pos = [r.position_error_m if r.ok else float("inf") for r in rs]
        foc = [r.focal_error_pct if np.isfinite(r.focal_error_pct) else float("inf") for r in rs]
        gnd = [r.ground_rms_m if r.ok else float("inf") for r in rs]
        tms = [r.time_ms for r in rs if np.isfinite(r.time_ms)]
        tms_big = [r.time_ms for r in rs if np.isfinite(r.time_ms) and r.n_control >= TIME_MIN_CONTROL]
        errors: dict[str, int] = {}
        for r in rs:
            if not r.ok:
                key = r.error.split(":")[0] if r.error else "unknown"
                errors[key] = errors.get(key, 0) + 1
        s: dict[str, Any] = {
            "n": len(rs), "n_ok": sum(r.ok for r in rs), "failures": errors,
            "position_m": {"median": _pct(pos, 50), "p90": _pct(pos, 90)},
            "focal_pct": {"median": _pct(foc, 50), "p90": _pct(foc, 90)},
            "ground_m": {"median": _pct(gnd, 50), "p90": _pct(gnd, 90)},
            "time_ms": {"median": _pct(tms, 50), "median_big": _pct(tms_big, 50), "n_big": len(tms_big)},
        }
        if m == "trafficgeo":
            tp = sum(r.tp for r in rs if r.ok)
            fp = sum(r.fp for r in rs if r.ok)
            fn = sum(r.fn for r in rs if r.ok)
            good = sum(r.n_good for r in rs if r.ok)
            s["outliers"] = {
                "planted": tp + fn, "tp": tp, "fp": fp, "fn": fn, "good_points": good,
                "precision": tp / (tp + fp) if tp + fp else float("nan"),
                "recall": tp / (tp + fn) if tp + fn else float("nan"),
                "fp_rate": fp / good if good else float("nan"),
                "not_evaluated_outliers": sum(r.n_outliers for r in rs if not r.ok),
            }
        out[m] = s
    tg, lim = out["trafficgeo"]["ground_m"]["median"], out["limit"]["ground_m"]["median"]
    out["ground_ratio"] = tg / lim if lim > 0 else float("nan")
    return out


def _f(x: float, fmt: str) -> str:
    if x is None or (isinstance(x, float) and np.isnan(x)):
        return "-"
    if np.isinf(x):
        return "inf"
    return format(x, fmt)


def render(summary: dict[str, Any], rows: list[Row], meta: dict[str, Any]) -> str:
    lines: list[str] = []
    add = lines.append
    add(f"trafficgeo calibration benchmark: {meta['n_scenes']} scenes (seeds {meta['seeds']}), "
        f"{meta['n_skipped']} skipped by the generator; {meta['n_4k']} x 4K, {meta['n_1080']} x 1080p; "
        f"{meta['n_outliers']} planted outliers")
    add(f"{meta['source']}; python {meta['python']}, numpy {meta['numpy']}, opencv {meta['opencv']}, "
        f"{meta['cpus']} cpu(s); wall time {meta['wall_s']:.1f} s")
    add("")
    head = ["method", "ok", "pos med m", "pos p90 m", "f med %", "f p90 %", "ground med m", "ground p90 m",
            "t med ms", f"t med ms (n>={TIME_MIN_CONTROL})"]
    body = []
    for m in METHODS:
        s = summary[m]
        given = m == "solvePnP(true K)"
        body.append([
            m, f"{s['n_ok']}/{s['n']}",
            _f(s["position_m"]["median"], ".3f"), _f(s["position_m"]["p90"], ".3f"),
            "given" if given else _f(s["focal_pct"]["median"], ".2f"),
            "given" if given else _f(s["focal_pct"]["p90"], ".2f"),
            _f(s["ground_m"]["median"], ".3f"), _f(s["ground_m"]["p90"], ".3f"),
            _f(s["time_ms"]["median"], ".1f"), _f(s["time_ms"]["median_big"], ".1f"),
        ])
    widths = [max(len(str(r[k])) for r in [head, *body]) for k in range(len(head))]

    def fmt_row(r: list[str]) -> str:
        return "  ".join(str(c).ljust(widths[0]) if k == 0 else str(c).rjust(widths[k]) for k, c in enumerate(r))

    add(fmt_row(head))
    add("  ".join("-" * wd for wd in widths))
    for r in body:
        add(fmt_row(r))
    add("")
    o = summary["trafficgeo"]["outliers"]
    add(f"trafficgeo outliers: {o['planted']} planted, {o['tp']} flagged correctly, {o['fn']} missed, "
        f"{o['fp']} good points flagged (of {o['good_points']}): precision {_f(100 * o['precision'], '.1f')} %, "
        f"recall {_f(100 * o['recall'], '.1f')} %, false-positive rate {_f(100 * o['fp_rate'], '.2f')} %"
        + (f"; {o['not_evaluated_outliers']} outliers in scenes where trafficgeo failed are not counted"
           if o["not_evaluated_outliers"] else ""))
    add("")
    add("targets")
    ratio = summary["ground_ratio"]
    tg, lim = summary["trafficgeo"]["ground_m"]["median"], summary["limit"]["ground_m"]["median"]
    t_big = summary["trafficgeo"]["time_ms"]["median_big"]
    checks = [
        (f"median ground error <= {TARGET_GROUND_RATIO}x limit",
         f"{_f(tg, '.3f')} m / {_f(lim, '.3f')} m = {_f(ratio, '.2f')}x", ratio <= TARGET_GROUND_RATIO),
        ("outlier recall 100 %", f"{_f(100 * o['recall'], '.1f')} %",
         o["recall"] >= TARGET_RECALL and o["not_evaluated_outliers"] == 0),
        (f"false positives <= {100 * TARGET_FP_RATE:.0f} % of good points", f"{_f(100 * o['fp_rate'], '.2f')} %",
         o["fp_rate"] <= TARGET_FP_RATE),
        (f"time < {TARGET_TIME_MS:.0f} ms incl. leave-one-out (median, n_control >= {TIME_MIN_CONTROL}, "
         f"{summary['trafficgeo']['time_ms']['n_big']} scenes)", f"{_f(t_big, '.1f')} ms", t_big < TARGET_TIME_MS),
    ]
    wl = max(len(c[0]) for c in checks)
    wv = max(len(c[1]) for c in checks)
    for label, value, ok in checks:
        add(f"  {label.ljust(wl)}  {value.rjust(wv)}  {'PASS' if ok else 'MISS'}")
    add("")
    add("failures (no usable camera; counted as infinite error in the position and ground columns)")
    add(f"  scene generator (ValueError, skipped for all methods): {meta['n_skipped']}"
        + (f"  seeds {meta['skipped_seeds']}" if meta["skipped_seeds"] else ""))
    for m in METHODS:
        fails = summary[m]["failures"]
        text = ", ".join(f"{k} x{v}" for k, v in sorted(fails.items())) if fails else "none"
        seeds = [r.seed for r in rows if r.method == m and not r.ok]
        add(f"  {m.ljust(max(len(x) for x in METHODS))}  {sum(fails.values()):3d}  {text}"
            + (f"  seeds {seeds}" if seeds else ""))
    notes = [r for r in rows if r.method == "trafficgeo" and (r.missed or r.false_flags)]
    if notes:
        add("")
        add("trafficgeo outlier mistakes: residual against the TRUE camera in px and in sigmas of the actual noise "
            "(pixel + projected survey noise); 'worst good' = the good control point with the largest one")
        for r in notes:
            parts = []
            if r.missed:
                parts.append("missed " + "; ".join(r.missed))
            if r.false_flags:
                parts.append("flagged " + "; ".join(r.false_flags))
            parts.append(f"worst good {r.worst_good}")
            add(f"  seed {r.seed:3d} ({r.size}, {r.n_control} control, {r.n_outliers} outliers): " + " | ".join(parts))
    lim_by_seed = {r.seed: r.ground_rms_m for r in rows if r.method == "limit" and r.ok}
    worse = [(r.seed, r.ground_rms_m, lim_by_seed[r.seed]) for r in rows
             if r.method == "trafficgeo" and r.seed in lim_by_seed
             and (not r.ok or r.ground_rms_m > 2.0 * lim_by_seed[r.seed] + 0.02)]
    if worse:
        add("")
        add("trafficgeo scenes with ground RMS > 2x limit + 2 cm: "
            + ", ".join(f"seed {s} ({_f(g, '.3f')} vs {_f(lim_g, '.3f')} m)" for s, g, lim_g in worse))
    return "\n".join(lines)


def source_version() -> str:
    """Git commit of the checkout plus a hash of the library sources (the working tree may hold uncommitted edits)."""
    root = Path(__file__).resolve().parent.parent
    h = hashlib.sha1()
    for f in sorted((root / "src" / "trafficgeo").rglob("*.py")):
        h.update(f.relative_to(root).as_posix().encode())
        h.update(f.read_bytes())
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True, text=True,
                              timeout=10).stdout.strip() or "no git"
    except (OSError, subprocess.SubprocessError):
        head = "no git"
    return f"git {head}, src/trafficgeo sha1 {h.hexdigest()[:10]}"


# ------------------------------------------------------------------------------------------------ output files
def _clean(x: Any) -> Any:
    if isinstance(x, float):
        return None if np.isnan(x) else ("inf" if np.isinf(x) else x)
    if isinstance(x, dict):
        return {k: _clean(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_clean(v) for v in x]
    return x


def write_out(path: Path, rows: list[Row], specs: list[SceneSpec], summary: dict[str, Any],
              meta: dict[str, Any]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix.lower() == ".csv":
        spec_by_seed = {s.seed: s for s in specs}
        fields = [*Row.__dataclass_fields__.keys(), "n_elevated", "survey_sigma", "grade", "crest_radius",
                  "camera_height"]
        with path.open("w", newline="") as fh:
            wr = csv.DictWriter(fh, fieldnames=fields)
            wr.writeheader()
            for r in rows:
                d = asdict(r)
                d["missed"] = "; ".join(r.missed)
                d["false_flags"] = "; ".join(r.false_flags)
                sp = spec_by_seed[r.seed]
                d.update(n_elevated=sp.n_elevated, survey_sigma=sp.survey_sigma, grade=sp.grade,
                         crest_radius=sp.crest_radius, camera_height=sp.camera_height)
                wr.writerow(d)
    else:
        doc = {"meta": meta, "summary": summary, "scenes": [asdict(s) for s in specs],
               "rows": [asdict(r) for r in rows]}
        path.write_text(json.dumps(_clean(doc), indent=1) + "\n")


# ------------------------------------------------------------------------------------------------ main
def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", type=int, default=60, help="number of scenes, seeds first..first+N-1 (default 60)")
    ap.add_argument("--quick", action="store_true", help="smoke run with 12 scenes")
    ap.add_argument("--first-seed", type=int, default=0, help="first seed (default 0)")
    ap.add_argument("--out", type=Path, help="also write per-scene results: .csv (one row per scene and method) "
                                             "or .json (meta, summary, scenes, rows)")
    ap.add_argument("-v", "--verbose", action="store_true", help="print one line per scene while running")
    args = ap.parse_args(argv)
    n = 12 if args.quick else args.scenes
    if n < 1:
        ap.error("--scenes must be >= 1")
    seeds = list(range(args.first_seed, args.first_seed + n))

    # Warm-up (imports, OpenCV/SciPy first-call costs) on a scene that is not part of the benchmark.
    warm = scene_spec(10**6)
    try:
        warm_scene = warm.make()
        for m in METHODS:
            run_method(m, warm_scene)
    except ValueError:
        pass

    t_start = time.perf_counter()
    rows: list[Row] = []
    specs: list[SceneSpec] = []
    skipped: list[int] = []
    for seed in seeds:
        spec = scene_spec(seed)
        try:
            scene = spec.make()
        except ValueError as exc:
            skipped.append(seed)
            if args.verbose:
                print(f"seed {seed}: scene skipped ({exc})", file=sys.stderr)
            continue
        specs.append(spec)
        scene_rows = [evaluate(spec, scene, m, run_method(m, scene)) for m in METHODS]
        rows += scene_rows
        if args.verbose:
            print(f"seed {seed:3d} {spec.size:5s} n={spec.n_control:2d} out={spec.n_outliers} | "
                  + " | ".join(f"{r.method} {_f(r.ground_rms_m, '.3f')} m {_f(r.time_ms, '.0f')} ms"
                               + (f" ({r.error})" if r.error else "") for r in scene_rows), file=sys.stderr)
    wall = time.perf_counter() - t_start
    if not specs:
        print("no scene could be generated", file=sys.stderr)
        return 1

    meta = {
        "seeds": f"{seeds[0]}..{seeds[-1]}", "n_scenes": len(specs), "n_skipped": len(skipped),
        "skipped_seeds": skipped, "n_4k": sum(s.size == "4K" for s in specs),
        "n_1080": sum(s.size == "1080p" for s in specs), "n_outliers": sum(s.n_outliers for s in specs),
        "python": platform.python_version(), "numpy": np.__version__, "opencv": cv2.__version__,
        "cpus": os.cpu_count(), "wall_s": wall, "source": source_version(),
    }
    summary = summarize(rows)
    print(render(summary, rows, meta))
    if args.out is not None:
        write_out(args.out, rows, specs, summary, meta)
        print(f"\nwrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
