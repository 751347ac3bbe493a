"""Vehicles that pass a counting line while hidden behind a nearer one.

From a low camera looking along the road, a car close behind a truck can vanish from the image for seconds and
pass a counting line unseen. A track whose first or last image box is covered (by at least ``HIDDEN_COVER`` of its
area) by the box of a nearer vehicle - one whose box reaches lower in the image - and does not touch the frame's
edge went out of sight there, not out of the picture: a *hidden end*. :func:`hidden_crossings` carries each
hidden end on (a last point forwards, a first point backwards) at the track's mean velocity over its last (first)
second for up to ``coast_s`` seconds and counts the lines it passes in that time, in the lane it vanished in,
unless the same line has a crossing in the same lane within ``HIDDEN_MATCH_S`` seconds (the vehicle seen again, or
carried on from its other side). Such a crossing has no spot speed (the vehicle was not seen at the line).

"Track" is a world track: where its image track goes on with boxes ``analyze`` could not use (too far away, an
identity switch that split it into parts), the end of the usable part counts as well when a nearer box covers it.
On the video benchmark three of the four crossings this adds come from such ends (with ends where the image track
itself stops, give or take 0.5 s, it adds two and counts stay at 87.3 % instead of 89.1 %); with an ideal
detector both rules give the same 99.1 %.

Positions and velocities are in the CRS units of the points (``metres_per_unit`` gives metres, for the spacing
rule of :func:`~trafficgeo.traffic.counts.find_crossings`), times in seconds; boxes are image pixels
``x1, y1, x2, y2`` with y growing downwards.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from trafficgeo.run.tracks import ImageTracks
from trafficgeo.site.lanes import Lanes
from trafficgeo.site.lines import CountLine
from trafficgeo.traffic.counts import find_crossings

HIDDEN_COVER = 0.3  # fraction of an end's box that a nearer vehicle's box must cover for the end to be hidden
HIDDEN_MATCH_S = 1.0  # s: a carried-on crossing this close to another of the same line and lane is that vehicle
COAST_STEP_S = 0.1  # s between the carried-on positions


def _end_velocities(points: pd.DataFrame, window_s: float) -> pd.DataFrame:
    """Each track's first and last point with ``end`` (``"first"``/``"last"``) and ``vx, vy``: its mean velocity
    (CRS units per second) over the ``window_s`` s of the track at that end; tracks shorter than that are left out."""
    tid = points["track_id"].to_numpy()
    t = points["time"].to_numpy(dtype=np.float64)
    xy = points[["x", "y"]].to_numpy(dtype=np.float64)
    starts = np.flatnonzero(np.r_[True, tid[1:] != tid[:-1]])
    stops = np.r_[starts[1:], len(tid)] - 1
    long = t[stops] - t[starts] >= window_s
    starts, stops = starts[long], stops[long]
    # the point window_s into the track from each end (times rise within a track, not across tracks)
    inner_first = np.array([a + np.searchsorted(t[a:b + 1], t[a] + window_s) for a, b in zip(starts, stops,
                                                                                             strict=True)], dtype=int)
    inner_last = np.array([a + np.searchsorted(t[a:b + 1], t[b] - window_s, side="right") - 1
                           for a, b in zip(starts, stops, strict=True)], dtype=int)
    inner_first, inner_last = np.minimum(inner_first, stops), np.maximum(inner_last, starts)
    rows = []
    for end, at, inner in (("first", starts, inner_first), ("last", stops, inner_last)):
        dt = t[at] - t[inner]
        v = (xy[at] - xy[inner]) / np.where(dt != 0, dt, np.nan)[:, None]
        rows.append(points.iloc[at].assign(end=end, vx=v[:, 0], vy=v[:, 1]))
    out = pd.concat(rows)
    return out[np.isfinite(out["vx"].to_numpy()) & np.isfinite(out["vy"].to_numpy())]


def hidden_ends(points: pd.DataFrame, tracks: ImageTracks, image_size: tuple[int, int], *,
                cover: float = HIDDEN_COVER, margin_px: float = 2.0, window_s: float = 1.0) -> pd.DataFrame:
    """The first and last points of the world tracks (``points`` of :func:`world_trajectories`, sorted by track
    and time; tracks of at least ``window_s`` s) that are hidden ends (module docstring): the rows of ``points``
    with ``end`` (``"first"``/``"last"``) and ``vx, vy``, the track's mean velocity over ``window_s`` s at that
    end (CRS units per second)."""
    if not len(points) or not np.isfinite(tracks.box).any():
        return points.iloc[:0].assign(end=pd.Series(dtype=object), vx=pd.Series(dtype=float),
                                      vy=pd.Series(dtype=float))
    ends = _end_velocities(points, window_s)
    if not len(ends):
        return ends
    box = pd.DataFrame({"source_track": tracks.track_id.astype(str), "frame": tracks.frame,
                        "x1": tracks.box[:, 0], "y1": tracks.box[:, 1], "x2": tracks.box[:, 2], "y2": tracks.box[:, 3]})
    own = ends[["source_track", "frame"]].astype({"source_track": str}).merge(box, how="left",
                                                                               on=["source_track", "frame"])
    mine = own[["x1", "y1", "x2", "y2"]].to_numpy(dtype=np.float64)
    order = np.argsort(tracks.frame, kind="stable")
    frames = tracks.frame[order]
    w, h = image_size
    hidden = np.zeros(len(ends), dtype=bool)
    for k, (frame, src) in enumerate(zip(own["frame"].to_numpy(), own["source_track"].to_numpy(), strict=True)):
        b = mine[k]
        if not np.all(np.isfinite(b)) or b[0] <= margin_px or b[1] <= margin_px or b[2] >= w - 1 - margin_px \
                or b[3] >= h - 1 - margin_px:
            continue  # no box, or at the frame's edge: it may have left the picture
        same = order[np.searchsorted(frames, frame, "left"):np.searchsorted(frames, frame, "right")]
        others = tracks.box[same[tracks.track_id[same].astype(str) != src]]
        others = others[others[:, 3] > b[3]]  # nearer: their boxes reach lower in the image
        if not len(others):
            continue
        iw = np.clip(np.minimum(others[:, 2], b[2]) - np.maximum(others[:, 0], b[0]), 0.0, None)
        ih = np.clip(np.minimum(others[:, 3], b[3]) - np.maximum(others[:, 1], b[1]), 0.0, None)
        hidden[k] = np.nanmax(iw * ih) >= cover * max((b[2] - b[0]) * (b[3] - b[1]), 1.0)
    return ends[hidden]


def _coasted_points(ends: pd.DataFrame, coast_s: float) -> pd.DataFrame:
    """Positions of each hidden end carried on at its velocity for ``coast_s`` s, one pseudo-track per end
    (``track_id`` = ``"<track>|<end>"``), in time order and including the end itself."""
    steps = np.arange(0.0, coast_s + 1e-9, COAST_STEP_S)
    n = len(steps)
    forward = ends["end"].to_numpy() == "last"
    dt = np.where(forward[:, None], steps[None, :], -steps[None, ::-1])  # increasing in time along each row
    x = ends["x"].to_numpy(dtype=np.float64)[:, None] + dt * ends["vx"].to_numpy(dtype=np.float64)[:, None]
    y = ends["y"].to_numpy(dtype=np.float64)[:, None] + dt * ends["vy"].to_numpy(dtype=np.float64)[:, None]
    out = pd.DataFrame({
        "track_id": np.repeat(ends["track_id"].astype(str).to_numpy() + "|" + ends["end"].to_numpy(), n),
        "time": (ends["time"].to_numpy(dtype=np.float64)[:, None] + dt).ravel(),
        "x": x.ravel(), "y": y.ravel(),
        "speed_kmh": np.repeat(ends["speed_kmh"].to_numpy(dtype=np.float64), n),
    })
    for column in ("class", "length_m"):
        if column in ends.columns:
            out[column] = np.repeat(ends[column].to_numpy(), n)
    return out


def hidden_crossings(points: pd.DataFrame, tracks: ImageTracks, image_size: tuple[int, int],
                     lines: list[CountLine], lanes: Lanes | None, crossings: pd.DataFrame, *, coast_s: float,
                     period: tuple[float, float], metres_per_unit: float = 1.0) -> pd.DataFrame:
    """Crossings (the columns of ``crossings``) of the lines passed by hidden ends carried on for up to ``coast_s``
    s within ``period`` (s), less those within ``HIDDEN_MATCH_S`` of a crossing of the same line and lane in
    ``crossings`` or of an earlier carried-on one (module docstring)."""
    ends = hidden_ends(points, tracks, image_size) if coast_s > 0 and lines else points.iloc[:0]
    if not len(ends):
        return crossings.iloc[:0].copy()
    found = find_crossings(_coasted_points(ends, coast_s), lines, lanes, metres_per_unit=metres_per_unit)
    found = found[(found["time"] >= period[0]) & (found["time"] <= period[1])]
    if lanes is not None:  # a hidden vehicle keeps the lane it vanished in (carried-on positions drift sideways)
        lane_of = dict(zip(ends["track_id"].astype(str) + "|" + ends["end"], ends["lane"], strict=True))
        found = found.assign(lane=found["track_id"].map(lane_of))
        allowed = {line.name: set(line.lanes) for line in lines if line.lanes}
        counted = np.array([ln not in allowed or la in allowed[ln]
                            for ln, la in zip(found["line"], found["lane"], strict=True)], dtype=bool)
        found = found[(found["lane"] != "").to_numpy() & counted]
    found = found.assign(track_id=found["track_id"].str.rsplit("|", n=1).str[0]).sort_values("time", kind="stable")
    keep = []
    taken = crossings[["line", "lane", "time"]].to_numpy(dtype=object).tolist()
    for row in found.itertuples(index=False):
        if any(ln == row.line and la == row.lane and abs(t - row.time) < HIDDEN_MATCH_S for ln, la, t in taken):
            keep.append(False)
            continue
        keep.append(True)
        taken.append([row.line, row.lane, row.time])
    found = found[np.asarray(keep, dtype=bool)].assign(speed_kmh=np.nan)  # not seen at the line: no spot speed
    return found.reindex(columns=crossings.columns).reset_index(drop=True)
