"""Shared helper of the gcp-ui refinement tests: a generated registration scene with truth, written as the files
gcp-ui opens (frame.png, ortho.tif, dem.tif, gcps.csv with the rough clicks), and a wrong orthophoto of the same
ground extent showing another road (ortho_wrong.tif).

960x540: at 640x360 the refinement's default patches (25 px every 40 px) find fewer than the 30 matches it needs on
this scene. The orthophoto is 0.1 m over +-60 m and the frame's ground is rendered at 2x (not the scene's default
0.05 m over +-85 m at 3x) so the scene builds in a few seconds. Seed 2: the user's held-out error goes from 5.2 to
3.3 m (a clear margin for the verdict), the ground error at the truth points from 1.1 m to about 0.01 m.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from affine import Affine

from trafficgeo.geo.raster import write_geotiff
from trafficgeo.synth.registration_scene import RegistrationScene, RegistrationSceneOptions, make_registration_scene

IMAGE_SIZE = (960, 540)
SCENE_OPTIONS = dict(seed=2, image_size=IMAGE_SIZE, ortho_resolution=0.1, half_size=60.0, supersample=2)


@dataclass(frozen=True)
class RefineScene:
    folder: Path
    scene: RegistrationScene
    frame: Path
    ortho: Path
    ortho_wrong: Path
    dem: Path
    gcps: Path


def build_refine_scene(folder: Path) -> RefineScene:
    """Write the scene's files into ``folder``; returns them with the scene (its truth)."""
    folder.mkdir(parents=True, exist_ok=True)
    sc = make_registration_scene(RegistrationSceneOptions(**SCENE_OPTIONS))
    # only its orthophoto is used (same extent, another road): a small frame is enough
    wrong = make_registration_scene(RegistrationSceneOptions(**{**SCENE_OPTIONS, "image_size": (160, 90),
                                                                "supersample": 1, "vehicles": 0}, wrong_place=True))
    paths = {k: folder / n for k, n in (("frame", "frame.png"), ("ortho", "ortho.tif"),
                                         ("ortho_wrong", "ortho_wrong.tif"), ("dem", "dem.tif"),
                                         ("gcps", "gcps.csv"))}
    cv2.imwrite(str(paths["frame"]), sc.frame)
    for key, ortho in (("ortho", sc.ortho), ("ortho_wrong", wrong.ortho)):
        write_geotiff(paths[key], ortho.data, ortho.transform, ortho.crs, descriptions=ortho.descriptions)
    s = sc.surface
    write_geotiff(paths["dem"], s.values, Affine(s.xres, 0, s.left, 0, -s.yres, s.top), sc.ortho.crs,
                  nodata=-9999.0, dtype=np.float64)
    sc.gcps.to_csv(paths["gcps"])
    return RefineScene(folder, sc, paths["frame"], paths["ortho"], paths["ortho_wrong"], paths["dem"],
                       paths["gcps"])


_SCENES: dict[str, RefineScene] = {}


def shared_refine_scene(tmp_path_factory) -> RefineScene:
    """One scene per test session (its files are only read; tests copy them to write beside them)."""
    key = str(tmp_path_factory.getbasetemp())
    if key not in _SCENES:
        _SCENES[key] = build_refine_scene(tmp_path_factory.mktemp("ui-refine-scene"))
    return _SCENES[key]
