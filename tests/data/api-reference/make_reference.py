"""Write the reference outputs of ``analyze`` on real NGSIM trajectories seen by a fixed synthetic camera.

Run from a trafficgeo checkout:  python tests/data/api-reference/make_reference.py [OUT]  (default: this folder).
The inputs are deterministic (no noise; written as input_tracks.csv): NGSIM Peachtree positions
(tests/data/ngsim-peachtree-subset, US survey feet, EPSG:2240) projected through a camera 10 m up, one counting line
across the street, no lanes. It uses only functions that existed before the Python API (the camera, analyze,
write_analysis), so a reference written by an older trafficgeo can be compared with the outputs of a newer one
(tests/test_api.py).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd
import shapely

HERE = Path(__file__).resolve().parent
DATA = HERE.parent / "ngsim-peachtree-subset" / "peachtree_27s_positions.csv"
FT = 1200.0 / 3937.0  # US survey foot in metres


def scene():
    """(camera, surface, tracks table, count lines) of the reference run."""
    from trafficgeo.camera.model import Camera
    from trafficgeo.geo.surface import ConstantSurface
    from trafficgeo.site.lines import CountLine

    df = pd.read_csv(DATA)
    df["track_id"] = df["Vehicle_ID"].astype(str) + "/" + df["v_length"].map("{:g}".format)
    df["time"] = (df["Global_Time"] - df["Global_Time"].min()) / 1000.0
    x, y = df["Global_X"].to_numpy(), df["Global_Y"].to_numpy()
    c = np.array([np.median(x), np.median(y)])
    *_, vt = np.linalg.svd(np.column_stack([x - c[0], y - c[1]]), full_matrices=False)
    axis = vt[0] if vt[0][1] > 0 else -vt[0]
    normal = np.array([axis[1], -axis[0]])
    pos = c - axis * (60.0 / FT) + normal * (12.0 / FT)
    heading = float(np.degrees(np.arctan2(axis[0], axis[1])) % 360.0)
    cam = Camera.from_orientation((1920, 1080), 1500.0, [pos[0], pos[1], 10.0 / FT], heading - 8.0, 12.0,
                                  crs="EPSG:2240")
    uv = cam.project(np.column_stack([x, y, np.zeros(x.size)]))
    ok = cam.in_image(np.nan_to_num(uv, nan=-1e9))
    table = pd.DataFrame({"frame": np.rint(df["time"].to_numpy() * 10).astype(int), "time": df["time"],
                          "track_id": df["track_id"], "u": uv[:, 0], "v": uv[:, 1]})[ok].reset_index(drop=True)
    mid = c + axis * (60.0 / FT)
    line = shapely.LineString([mid - normal * (80.0 / FT), mid + normal * (80.0 / FT)])
    return cam, ConstantSurface(0.0), table, [CountLine("across", line, ())]


def main(out: Path) -> None:
    from trafficgeo.traffic.analyze import analyze, write_analysis
    from trafficgeo.traffic.tracks import read_tracks

    cam, surf, table, lines = scene()
    out.mkdir(parents=True, exist_ok=True)
    table.to_csv(out / "input_tracks.csv", index=False, float_format="%.4f")
    result = analyze(cam, surf, read_tracks(out / "input_tracks.csv"), lines=lines, interval_s=10.0)
    write_analysis(out, result, cam)
    print(f"{len(result.vehicles)} vehicles, {len(result.crossings)} crossings -> {out}")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else HERE)
