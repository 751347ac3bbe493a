"""Benchmark: zero-click calibration (``calibrate_from_ortho``, ``trafficgeo calibrate-ortho``) over generated worlds,
beside ``calibrate`` from 8 rough clicks and from 20 perfect GCPs (issue 40).

Per world (``make_registration_scene`` at 1080p; seed, camera height and lighting vary; seeds from ``--first-seed``,
default 500, never used while the method was built, which used seeds 1-7 and the tests' 11):

* the orthophoto differs from the frame as a real one does ("another day": ``ortho_season`` 0.5, the grass dried
  to straw, its pattern faded and a third new; 6 shadows of trees or buildings; 10 cars of its own; plus the
  lighting's gain, offset, gamma and blur); ``--season`` sets the season's strength;
* ``zero-click``: ``calibrate_from_ortho(frame, ortho, surface, near)`` with ``near`` the true camera position moved
  5 m in a random direction, the focal length unknown; a refusal counts as no camera;
* ``8 clicks``: ``calibrate(scene.gcps)``: 8 control points clicked with 3 px noise (the user's rough start);
* ``20 GCPs``: ``calibrate(scene.perfect_gcps)``: 20 points with exact world coordinates clicked at the nearest
  whole pixel.

Ground error (m): the true camera's rays through a pixel grid meet the surface; the points 20-120 m from the camera
(horizontally) are mapped back by each camera onto the horizontal plane at their height (``ground_errors_m``); the
median and the 95th percentile over them. Run time: wall time of ``calibrate_from_ortho`` alone, after a warm-up on
a small world.

Then the refusals, each on ``--refusals`` worlds: an orthophoto flown in winter (snow on the verges, slush over the
markings), a pole position 60 m off, a frame without texture (fog), and an orthophoto of another place.

Run ``python benchmarks/bench_calibrate_ortho.py [--quick] [--worlds N] [--first-seed S] [--refusals N]``.
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from trafficgeo.calibration.pipeline import calibrate
from trafficgeo.camera.model import Camera
from trafficgeo.errors import CalibrationError, InputError
from trafficgeo.geo.mapping import pixels_to_world
from trafficgeo.registration.from_ortho import OrthoCalibration, calibrate_from_ortho
from trafficgeo.synth.registration_scene import (
    RegistrationScene,
    RegistrationSceneOptions,
    ground_errors_m,
    make_registration_scene,
)

ROOT = Path(__file__).resolve().parents[1]
HEIGHTS_M = (9.0, 12.0, 16.0, 20.0, 25.0, 6.0)
sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_refine import LIGHTINGS  # noqa: E402  (the same four lightings as the refinement benchmark)

TARGET_M = 0.05
BAND_M = (20.0, 120.0)


@dataclass(frozen=True)
class World:
    index: int
    seed: int
    height_m: float
    lighting: str
    season: float

    def options(self, **changes: object) -> RegistrationSceneOptions:
        o = RegistrationSceneOptions(seed=self.seed, image_size=(1920, 1080), camera_height=self.height_m,
                                     ortho_season=self.season, ortho_shadows=6, ortho_vehicles=10,
                                     **LIGHTINGS[self.lighting])  # type: ignore[arg-type]
        return replace(o, **changes)  # type: ignore[arg-type]

    @property
    def label(self) -> str:
        return f"#{self.index:02d} seed {self.seed} {self.height_m:.0f} m {self.lighting}"


def band_points(scene: RegistrationScene, step_px: int = 8) -> np.ndarray:
    cam = scene.camera
    w, h = cam.image_size
    u, v = np.meshgrid(np.arange(step_px / 2, w, step_px), np.arange(step_px / 2, h, step_px))
    g = pixels_to_world(cam, np.column_stack([u.ravel(), v.ravel()]), scene.surface, with_lonlat=False)
    xyz = g.xyz[g.ok]
    d = np.hypot(xyz[:, 0] - cam.position[0], xyz[:, 1] - cam.position[1])
    return xyz[(d >= BAND_M[0]) & (d <= BAND_M[1])]


def errors(camera: Camera | None, truth: Camera, points: np.ndarray) -> tuple[float, float]:
    """(median, 95th percentile) ground error (m); NaN without a camera, inf where a point leaves the plane."""
    if camera is None or len(points) == 0:
        return float("nan"), float("nan")
    e = ground_errors_m(camera, truth, points)
    e = np.where(np.isfinite(e), e, np.inf)
    return float(np.median(e)), float(np.percentile(e, 95))


def near_of(scene: RegistrationScene, seed: int, metres: float = 5.0) -> tuple[float, float]:
    a = np.random.default_rng(seed + 99).uniform(0.0, 2 * np.pi)
    p = scene.camera.position[:2] + metres * np.array([np.cos(a), np.sin(a)])
    return float(p[0]), float(p[1])


@dataclass
class Row:
    world: World
    result: OrthoCalibration
    seconds: float
    zero: tuple[float, float]
    clicks: tuple[float, float]
    perfect: tuple[float, float]
    n_points: int


def _calibrated(gcps: object, size: tuple[int, int]) -> Camera | None:
    try:
        return calibrate(gcps, size).camera  # type: ignore[arg-type]
    except (CalibrationError, InputError):
        return None


def run_world(world: World) -> Row:
    scene = make_registration_scene(world.options())
    pts = band_points(scene)
    t = time.perf_counter()
    res = calibrate_from_ortho(scene.frame, scene.ortho, scene.surface, near_of(scene, world.seed))
    seconds = time.perf_counter() - t
    size = scene.camera.image_size
    return Row(world, res, seconds, errors(res.camera, scene.camera, pts),
               errors(_calibrated(scene.gcps, size), scene.camera, pts),
               errors(_calibrated(scene.perfect_gcps, size), scene.camera, pts), len(pts))


def fmt(x: float, nd: int = 3) -> str:
    return "-" if not np.isfinite(x) else f"{x:.{nd}f}"


def table(rows: list[Row]) -> None:
    head = ["world", "verdict", "kept", "time s", "zero-click med / p95 m", "8 clicks med / p95 m",
            "20 GCPs med / p95 m", "zero / 20 GCPs"]
    body = []
    for r in rows:
        ratio = r.zero[0] / r.perfect[0] if np.isfinite(r.zero[0]) and r.perfect[0] > 0 else float("nan")
        body.append([r.world.label, "camera" if r.result.accepted else "REFUSED", str(int(r.result.kept.sum())),
                     f"{r.seconds:.1f}", f"{fmt(r.zero[0])} / {fmt(r.zero[1])}", f"{fmt(r.clicks[0])} / "
                     f"{fmt(r.clicks[1])}", f"{fmt(r.perfect[0])} / {fmt(r.perfect[1])}", fmt(ratio, 2)])
    widths = [max(len(h), *(len(b[i]) for b in body)) for i, h in enumerate(head)]
    print(" | ".join(h.ljust(w) for h, w in zip(head, widths, strict=True)))
    print("-|-".join("-" * w for w in widths))
    for b in body:
        print(" | ".join(c.ljust(w) for c, w in zip(b, widths, strict=True)))


def summary(rows: list[Row]) -> None:
    ok = [r for r in rows if r.result.accepted]
    med = [r.zero[0] for r in ok]
    print(f"\nzero-click: {len(ok)} of {len(rows)} worlds calibrated; median ground error at 20-120 m per world "
          f"<= {TARGET_M} m on {sum(m <= TARGET_M for m in med)} of them; median over worlds "
          f"{fmt(float(np.median(med))) if med else '-'} m (8 clicks "
          f"{fmt(float(np.median([r.clicks[0] for r in rows])))}, 20 GCPs "
          f"{fmt(float(np.median([r.perfect[0] for r in rows])))}); time median "
          f"{np.median([r.seconds for r in rows]):.1f} s, max {max(r.seconds for r in rows):.1f} s")
    for r in rows:
        if not r.result.accepted:
            print(f"  {r.world.label} refused: {r.result.reason}")


def refusals(n: int, first_seed: int) -> None:
    cases = {
        "winter orthophoto": lambda w: (w.options(ortho_snow=True), 5.0, False),
        "pole 60 m off": lambda w: (w.options(), 60.0, False),
        "no texture (fog)": lambda w: (w.options(), 5.0, True),
        "another place": lambda w: (w.options(wrong_place=True), 5.0, False),
    }
    print(f"\nrefusals ({n} worlds each; every one must be refused):")
    for name, make in cases.items():
        said = []
        for k in range(n):
            w = World(k, first_seed + 100 + k, HEIGHTS_M[k % 5], "default", 0.5)
            opts, off, fog = make(w)
            scene = make_registration_scene(opts)
            frame = np.full_like(scene.frame, 128) if fog else scene.frame
            res = calibrate_from_ortho(frame, scene.ortho, scene.surface, near_of(scene, w.seed, off))
            said.append(res)
        refused = sum(not r.accepted for r in said)
        print(f"  {name}: {refused} of {n} refused; e.g. \"{said[0].reason[:160]}\"")


def header(n: int) -> None:
    import cv2

    commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                            check=False).stdout.strip()
    flags = sorted({f for line in open("/proc/cpuinfo", encoding="utf-8") if line.startswith("flags")
                    for f in line.split() if f.startswith("avx") or f == "fma"}) if os.path.exists("/proc/cpuinfo") \
        else []
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    print(f"trafficgeo zero-click calibration benchmark: {n} worlds at 1080p; git {commit}; python "
          f"{platform.python_version()}, numpy {np.__version__}, opencv {cv2.__version__}; {cores} cpu(s), flags "
          f"{' '.join(flags) or '?'}; load average {os.getloadavg()[0]:.2f}", flush=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="6 worlds, 1 refusal world per case")
    ap.add_argument("--worlds", type=int, default=12)
    ap.add_argument("--first-seed", type=int, default=500)
    ap.add_argument("--refusals", type=int, default=None, help="worlds per refusal case (default 3, --quick 1)")
    ap.add_argument("--season", type=float, default=0.5, help="strength of the orthophoto's other season (0-1)")
    args = ap.parse_args(argv)
    n = 6 if args.quick else args.worlds
    names = list(LIGHTINGS)
    todo = [World(k, args.first_seed + k, HEIGHTS_M[k % len(HEIGHTS_M)], names[(k // 2) % len(names)], args.season)
            for k in range(n)]
    t0 = time.perf_counter()
    header(n)
    warm = make_registration_scene(RegistrationSceneOptions(seed=10 ** 6, image_size=(640, 360)))
    calibrate_from_ortho(warm.frame, warm.ortho, warm.surface, near_of(warm, 0))
    rows = []
    for k, w in enumerate(todo):
        r = run_world(w)
        print(f"[{k + 1}/{n}] {w.label}: {'camera' if r.result.accepted else 'REFUSED'} in {r.seconds:.1f} s, "
              f"median {fmt(r.zero[0])} m (8 clicks {fmt(r.clicks[0])}, 20 GCPs {fmt(r.perfect[0])}) over "
              f"{r.n_points} points; {r.result.reason[:200]}", flush=True)
        rows.append(r)
    print()
    table(rows)
    summary(rows)
    refusals(args.refusals if args.refusals is not None else (1 if args.quick else 3), args.first_seed)
    print(f"\nwall time {(time.perf_counter() - t0) / 60:.1f} min")
    return 0


if __name__ == "__main__":
    sys.exit(main())
