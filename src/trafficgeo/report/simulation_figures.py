"""Figures of the report's Simulation section (``sumo-validate``): observed against simulated spot speeds.

Speeds in km/h; one panel per counting line and lane with vehicles on both sides, all panels on the same bins.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pandas as pd

from trafficgeo.report.figures import new_figure
from trafficgeo.traffic.compare import compare_speeds

OBSERVED_COLOUR = "#3182bd"
SIMULATED_COLOUR = "#e6550d"


def _speeds_by_line_lane(crossings: pd.DataFrame) -> dict[tuple[str, str], np.ndarray]:
    """Finite spot speeds (km/h) of a crossings table per (line, lane); a missing lane is ""."""
    if not len(crossings):
        return {}
    keys = pd.DataFrame({"line": crossings["line"].fillna("").astype(str),
                         "lane": crossings["lane"].fillna("").astype(str)})
    speed = pd.to_numeric(crossings["speed_kmh"], errors="coerce").to_numpy(np.float64)
    out = {}
    for key, idx in keys.groupby(["line", "lane"], sort=True).indices.items():
        s = speed[idx]
        s = s[np.isfinite(s)]
        if s.size:
            out[(str(key[0]), str(key[1]))] = s
    return out


def speed_panels(observed: pd.DataFrame, simulated: pd.DataFrame) -> list[tuple[str, str, np.ndarray, np.ndarray]]:
    """(line, lane, observed km/h, simulated km/h) of each line and lane with finite spot speeds on both sides
    (crossings tables: ``line, lane, speed_kmh``), sorted by line then lane."""
    obs, sim = _speeds_by_line_lane(observed), _speeds_by_line_lane(simulated)
    return [(line, lane, obs[(line, lane)], sim[(line, lane)]) for line, lane in sorted(set(obs) & set(sim))]


def speed_bins(panels: list[tuple[str, str, np.ndarray, np.ndarray]], n_bins: int = 20) -> np.ndarray:
    """Common bin edges (km/h) over every panel's speeds: ``n_bins`` equal bins from the slowest to the fastest,
    widened to whole km/h."""
    values = np.concatenate([np.concatenate([o, s]) for _, _, o, s in panels]) if panels else np.zeros(1)
    lo, hi = math.floor(float(values.min())), math.ceil(float(values.max()))
    return np.linspace(lo, max(hi, lo + 1), n_bins + 1)


def observed_vs_simulated_speeds(observed: pd.DataFrame, simulated: pd.DataFrame, *, n_bins: int = 20) -> Any:
    """Spot speeds at the counting lines (km/h), observed against simulated, as histograms side by side: one panel
    per line and lane with vehicles on both sides (:func:`speed_panels`; a row per line, its lanes across), the
    same bins in all (:func:`speed_bins`),
    the two-sample Kolmogorov-Smirnov distance in each panel's title. Bars have gid ``"sim-speed-observed-<line>-
    <lane>"`` and ``"sim-speed-simulated-<line>-<lane>"``; None when no line and lane has vehicles on both sides."""
    from matplotlib.ticker import MaxNLocator

    panels = speed_panels(observed, simulated)
    if not panels:
        return None
    bins = speed_bins(panels, n_bins)
    lines = list(dict.fromkeys(line for line, _, _, _ in panels))  # one row per line, its lanes across
    cells = [(lines.index(line), sum(1 for p in panels[:k] if p[0] == line)) for k, (line, _, _, _) in
             enumerate(panels)]
    nrows, ncols = len(lines), max(c for _, c in cells) + 1
    fig, axs = new_figure(min(2.6 * ncols + 0.6, 12.0), 0.6 + 2.1 * nrows, nrows, ncols, sharex=True)
    width = np.diff(bins) / 2.0
    for k, ((r, c), (line, lane, o, s)) in enumerate(zip(cells, panels, strict=True)):
        ax = axs[r, c]
        ho, _ = np.histogram(o, bins)
        hs, _ = np.histogram(s, bins)
        for heights, offset, colour, side in ((ho, 0.0, OBSERVED_COLOUR, "observed"),
                                              (hs, 1.0, SIMULATED_COLOUR, "simulated")):
            bars = ax.bar(bins[:-1] + offset * width, heights, width=width, align="edge", color=colour,
                          label=side if k == 0 else None)
            for p in bars:
                p.set_gid(f"sim-speed-{side}-{line}-{lane}")
        ks = compare_speeds(o, s)["ks_statistic"]
        ax.set_title(f"line {line}, lane {lane or '-'}: KS {ks:.2f}\nn {o.size} obs / {s.size} sim", fontsize=7,
                     loc="left")
        ax.yaxis.set_major_locator(MaxNLocator(integer=True))
        ax.tick_params(labelsize=7, labelbottom=True)
    used = set(cells)
    for r, c in np.ndindex(nrows, ncols):
        if (r, c) not in used:
            axs[r, c].remove()
    for ax in axs[:, 0]:
        ax.set_ylabel("vehicles", fontsize=7)
    fig.supxlabel("spot speed at the line (km/h)", fontsize=8)
    fig.legend(loc="outside upper right", fontsize=7, ncol=2)
    return fig
