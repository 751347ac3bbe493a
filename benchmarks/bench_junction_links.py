"""Benchmark: whole journeys at a junction - whether the pieces of track joined into one vehicle are one vehicle's,
and what the joins do to the turning-movement counts (issue 39).

For each junction world that ``bench_junction.py`` has run (``out/bench-junction-world-*`` with
``run-process/tracks.csv``), ``process``'s tracks are analysed with gates (the junction's smoother) three ways:

* ``glimpses joined``: the journeys' road defaults (:class:`~trafficgeo.traffic.journeys.JourneyOptions`), where a
  glimpse (a piece too short to show its own motion) may extend a longer piece;
* ``junction default``: :meth:`JourneyOptions.at_junction` (what ``analyze``/``process --gates`` use): glimpses
  join nothing;
* ``no joins``: ``JourneyOptions(enabled=False)`` (``--join-gap 0``).

Per setting: the joins made, split by kind (a glimpse at one end or both ends' motion known) and by truth (the two
pieces are one true vehicle's, two vehicles', or a piece matches no vehicle: each piece is matched to the true
vehicle within 3 m at most of its points, :func:`trafficgeo.synth.scoring.truth_of_run_vehicles`), and the
per-movement counts scored as ``bench_junction.py`` scores them. Run ``python benchmarks/bench_junction_links.py
[--seeds 5,6,7]`` (default: every world run).
"""

from __future__ import annotations

import argparse
import io
import re
from pathlib import Path

import pandas as pd

from bench_junction import OUT
from bench_video import cpu_flags

SETTINGS = ("glimpses joined", "junction default", "no joins")


def options(name: str):
    from trafficgeo.traffic.journeys import JourneyOptions

    return {"glimpses joined": JourneyOptions(), "junction default": JourneyOptions.at_junction(),
            "no joins": JourneyOptions(enabled=False)}[name]


def link_truth(result, truth_tracks: pd.DataFrame, opts) -> pd.DataFrame:
    """The joins of ``result`` (its ``links``) with ``kind`` (glimpse / both known) and ``truth`` (one vehicle, two
    vehicles, unknown)."""
    from trafficgeo.synth.scoring import truth_of_run_vehicles
    from trafficgeo.traffic.journeys import fragment_ends

    links = result.links if result.links is not None else pd.DataFrame(columns=["from_fragment", "to_fragment"])
    pts = result.points.assign(track_id=result.points["fragment"].astype(str))
    of = truth_of_run_vehicles(truth_tracks, pts)
    frags = pts.groupby("track_id", sort=False)["class"].agg(lambda c: c.mode().iloc[0] if c.notna().any() else "")
    ends = fragment_ends(pts, pd.DataFrame({"track_id": frags.index, "class": frags.to_numpy()}),
                         options=opts).set_index("track_id")
    rows = []
    for a, b in zip(links["from_fragment"].astype(str), links["to_fragment"].astype(str), strict=True):
        if a not in ends.index or b not in ends.index:  # a piece merged into another or dropped afterwards
            kind = "piece gone"
        else:
            weak = ends.at[a, "sv1"] > opts.weak_velocity_sigma_mps or ends.at[b, "sv0"] > opts.weak_velocity_sigma_mps
            kind = "glimpse" if weak else "both known"
        ta, tb = of.get(a), of.get(b)
        rows.append({"kind": kind,
                     "truth": "unknown" if ta is None or tb is None else "one vehicle" if ta == tb else "two vehicles"})
    return pd.DataFrame(rows, columns=["kind", "truth"])


def world_rows(world: Path) -> tuple[list[dict], pd.DataFrame]:
    from trafficgeo import analyze_tracks
    from trafficgeo.site.site import Site
    from trafficgeo.synth.scoring import movement_scores, truth_of_run_vehicles
    from trafficgeo.traffic.tracks import read_tracks

    truth_tracks = pd.read_csv(world / "truth_tracks.csv")
    truth = pd.read_csv(world / "truth_movements.csv", keep_default_na=False)
    site = Site.load(world / "camera_truth.json", world / "dem.tif", gates=world / "gates.gpkg")  # read once
    tracks = read_tracks(world / "run-process" / "tracks.csv")
    out, links = [], []
    for name in SETTINGS:
        opts = options(name)
        result = analyze_tracks(site, None, tracks, journeys=opts)
        moves = pd.read_csv(io.StringIO(result.movements.to_csv(index=False)), keep_default_na=False,
                            dtype={"track_id": str, "track_ids": str})
        of = truth_of_run_vehicles(truth_tracks, result.points.assign(track_id=result.points["track_id"].astype(str)))
        s = movement_scores(truth, moves, of)
        seed = int(re.search(r"seed(\d+)", world.name).group(1))
        out.append({"seed": seed, "setting": name, "true": int(s.table["true"].sum()),
                    "errors": int((s.table["counted"] - s.table["true"]).abs().sum()), **s.outcomes,
                    "duplicates": s.duplicates})
        links.append(link_truth(result, truth_tracks, opts).assign(setting=name, seed=seed))
    return out, pd.concat(links, ignore_index=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="", help="comma-separated seeds (default: every world bench_junction.py ran)")
    args = ap.parse_args()
    print(f"CPU: {cpu_flags()}")
    worlds = sorted(OUT.glob("bench-junction-world-seed*"), key=lambda p: int(re.search(r"seed(\d+)", p.name)[1]))
    worlds = [w for w in worlds if (w / "run-process" / "tracks.csv").is_file()]
    if args.seeds:
        want = {int(s) for s in args.seeds.split(",")}
        worlds = [w for w in worlds if int(re.search(r"seed(\d+)", w.name)[1]) in want]
    rows, links = [], []
    for world in worlds:
        r, k = world_rows(world)
        rows += r
        links.append(k)
        print(pd.DataFrame(r).to_string(index=False), flush=True)
    table = pd.DataFrame(rows)
    pooled = table.groupby("setting", sort=False)[["true", "errors", "counted", "wrong arm", "incomplete", "missed",
                                                  "duplicates"]].sum()
    pooled.insert(2, "per-movement counts", (1 - pooled["errors"] / pooled["true"]).round(3))
    print(f"\nPooled over {len(worlds)} worlds (seeds {', '.join(str(s) for s in table['seed'].unique())}):")
    print(pooled.to_string())
    allk = pd.concat(links, ignore_index=True)
    print("\nJoins made, by kind and truth:")
    print(allk.groupby(["setting", "kind", "truth"], sort=False).size().unstack(fill_value=0).to_string())


if __name__ == "__main__":
    main()
