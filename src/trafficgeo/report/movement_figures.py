"""The turning-movement diagram of a junction for the report: its gates, and an arrow per origin -> destination
movement from the origin gate, curving through the junction centre, to the destination gate, as wide as its count.

Conventions of :mod:`trafficgeo.site.gates` (arms, bearings, movements, approach bounds). Positions in the CRS's
units, drawn on :class:`~trafficgeo.report.figures.MapAxes` like the other plan views; widths in points.

Each arrow is a quadratic Bezier curve (:class:`MovementArrow`): it starts on the origin gate, has the junction
centre as its middle control point and ends on the destination gate. On each gate the arrows leaving the
junction are on one side of the gate's midpoint and those entering it on the other (the driver's right of
traffic entering, whatever side the country drives on), spread along the gate by the turn they make (U, left,
through, right from the middle outwards), so arrows do not lie on top of each other.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from trafficgeo.report.figures import Background, MapAxes, draw_background, new_figure, set_extent
from trafficgeo.site.gates import MOVEMENTS, Junction, turn_deg

MOVEMENT_COLOURS = {"left": "#1b9e77", "through": "#3867d6", "right": "#d95f02", "U": "#c2185b"}
MAX_WIDTH_PT = 14.0  # the busiest movement's arrow
MIN_WIDTH_PT = 0.8  # no arrow is drawn thinner, however few vehicles it carries
SPREAD = (0.12, 0.8)  # share of the half gate from its midpoint over which one side's arrows are spread


@dataclass(frozen=True)
class MovementArrow:
    """One origin -> destination movement as drawn: ``count`` complete movements, a quadratic Bezier curve from
    ``start`` (on the origin gate) via the control point ``control`` (the junction centre) to ``end`` (on the
    destination gate), all (x, y) in CRS units, ``width_pt`` wide (points)."""

    origin: str
    destination: str
    movement: str
    count: int
    start: np.ndarray
    control: np.ndarray
    end: np.ndarray
    width_pt: float

    def points(self, n: int = 33) -> np.ndarray:
        """(n, 2) points along the curve (CRS units), from start to end."""
        t = np.linspace(0.0, 1.0, n)[:, None]
        return (1 - t) ** 2 * self.start + 2 * (1 - t) * t * self.control + t ** 2 * self.end

    def at(self, t: float) -> np.ndarray:
        """The point (x, y) at parameter ``t`` in [0, 1] of the curve."""
        return (1 - t) ** 2 * self.start + 2 * (1 - t) * t * self.control + t ** 2 * self.end


def movement_flows(movements: pd.DataFrame) -> pd.DataFrame:
    """The complete movements of ``movements.csv`` per ``origin, destination, movement``, with their ``count``
    (largest first, then by origin and destination)."""
    cols = ["origin", "destination", "movement", "count"]
    if not len(movements):
        return pd.DataFrame(columns=cols)
    done = movements[movements["complete"].astype(bool)]
    if not len(done):
        return pd.DataFrame(columns=cols)
    keys = done[["origin", "destination", "movement"]].fillna("").astype(str)
    flows = keys.groupby(["origin", "destination", "movement"], sort=True).size().rename("count").reset_index()
    flows["count"] = flows["count"].astype(int)
    return flows.sort_values(["count", "origin", "destination"], ascending=[False, True, True],
                             kind="stable").reset_index(drop=True)[cols]


def _turn_key(junction: Junction, origin: str, destination: str) -> float:
    """Where a movement sits along a gate, from the middle outwards: U first, then by turn (left ... right)."""
    if origin == destination:
        return -1000.0
    return turn_deg(junction.bearings_deg[origin], junction.bearings_deg[destination])


def _slots(n: int) -> np.ndarray:
    """``n`` shares of the half gate, evenly over :data:`SPREAD`."""
    return np.array([sum(SPREAD) / 2]) if n == 1 else np.linspace(SPREAD[0], SPREAD[1], n)


def movement_arrows(junction: Junction, flows: pd.DataFrame, *, max_width_pt: float = MAX_WIDTH_PT,
                    min_width_pt: float = MIN_WIDTH_PT) -> list[MovementArrow]:
    """The arrows of :func:`movement_diagram` for ``flows`` (:func:`movement_flows`; rows whose origin or
    destination is not an arm of ``junction`` are left out): widths proportional to the count, the busiest
    ``max_width_pt`` wide, none under ``min_width_pt``; positions as in the module docstring."""
    gates = {g.arm: g for g in junction.gates}
    centre = np.asarray(junction.centre, dtype=np.float64)[:2]
    arms = junction.arms
    inbound, outbound = {}, {}  # arm -> unit vector along the gate towards its entering / leaving side
    for arm, g in gates.items():
        out = g.midpoint - centre
        out = out / np.linalg.norm(out)
        right_in = np.array([-out[1], out[0]])  # heading in is -out; its right is (hy, -hx)
        u = g.direction if float(g.direction @ right_in) >= 0 else -g.direction
        inbound[arm], outbound[arm] = u, -u
    # every possible movement has a fixed place on both of its gates, whether it has vehicles or not
    leave = {o: {d: s for d, s in zip(sorted(arms, key=lambda d, o=o: _turn_key(junction, o, d)),
                                      _slots(len(arms)), strict=True)} for o in arms}
    arrive = {d: {o: s for o, s in zip(sorted(arms, key=lambda o, d=d: _turn_key(junction, o, d)),
                                       _slots(len(arms)), strict=True)} for d in arms}
    rows = [r for r in flows.to_dict("records") if r["origin"] in gates and r["destination"] in gates
            and int(r["count"]) > 0]
    top = max((int(r["count"]) for r in rows), default=1)
    out_arrows = []
    for r in rows:
        o, d, n = str(r["origin"]), str(r["destination"]), int(r["count"])
        half_o, half_d = gates[o].geometry.length / 2, gates[d].geometry.length / 2
        start = gates[o].midpoint + inbound[o] * leave[o][d] * half_o
        end = gates[d].midpoint + outbound[d] * arrive[d][o] * half_d
        movement = str(r.get("movement") or junction.movement(o, d))
        out_arrows.append(MovementArrow(o, d, movement, n, start, centre.copy(), end,
                                        max(max_width_pt * n / top, min_width_pt)))
    return out_arrows


def movement_diagram(junction: Junction, flows: pd.DataFrame, axes: MapAxes, *,
                     background: Background | None = None) -> Any:
    """The junction's gates (labelled with arm and approach bound) and an arrow per movement of ``flows``
    (:func:`movement_arrows`), coloured by movement type (:data:`MOVEMENT_COLOURS`) and labelled with its count,
    on ``background`` (an orthophoto) or a plain one. Arrows have gid ``"movement-<origin>-<destination>"``, gates
    ``"gate-<arm>"``."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import ArrowStyle, FancyArrowPatch
    from matplotlib.path import Path

    fig, axs = new_figure(9.0, 8.0)
    ax = axs[0, 0]
    draw_background(ax, background, axes)
    if background is None:
        ax.set_facecolor("0.95")
    centre = np.asarray(junction.centre, dtype=np.float64)[:2]
    ex, ey = [], []
    for g in junction.gates:
        gx, gy = axes.local(*np.asarray(g.geometry.coords).T[:2])
        ax.plot(gx, gy, color="white", linewidth=4.0, zorder=3, solid_capstyle="butt")
        (line,) = ax.plot(gx, gy, color="black", linewidth=2.0, zorder=3, solid_capstyle="butt")
        line.set_gid(f"gate-{g.arm}")
        out = g.midpoint - centre
        out = out / np.linalg.norm(out)
        mx, my = axes.local(*g.midpoint)
        ax.annotate(f"{g.arm} ({junction.approach_bound(g.arm)})", (float(mx), float(my)),
                    xytext=(22 * out[0], 22 * out[1]), textcoords="offset points", ha="center", va="center",
                    fontsize=9, fontweight="bold", color="black", zorder=6,
                    bbox={"facecolor": "white", "alpha": 0.85, "lw": 0.5, "pad": 2.0})
        ex += [gx, np.array([mx + 0.35 * g.geometry.length * out[0]])]
        ey += [gy, np.array([my + 0.35 * g.geometry.length * out[1]])]
    cx, cy = axes.local(*centre)
    ax.plot([cx], [cy], marker="+", color="black", markersize=8, zorder=3)
    arrows = movement_arrows(junction, flows)
    for a in sorted(arrows, key=lambda a: -a.width_pt):  # the thin ones on top
        verts = np.array([axes.local(*p) for p in (a.start, a.control, a.end)], dtype=np.float64)
        path = Path(verts, [Path.MOVETO, Path.CURVE3, Path.CURVE3])
        w = a.width_pt
        style = ArrowStyle.Simple(head_length=1.4 * w + 5.0, head_width=1.8 * w + 5.0, tail_width=w)
        patch = FancyArrowPatch(path=path, arrowstyle=style, mutation_scale=1.0,
                                facecolor=MOVEMENT_COLOURS.get(a.movement, "0.4"), edgecolor="white",
                                linewidth=0.6, alpha=0.85, zorder=4)
        patch.set_gid(f"movement-{a.origin}-{a.destination}")
        ax.add_patch(patch)
        lx, ly = axes.local(*a.at(0.2))
        ax.annotate(str(a.count), (float(lx), float(ly)), ha="center", va="center", fontsize=7, zorder=5,
                    color=MOVEMENT_COLOURS.get(a.movement, "0.2"),
                    bbox={"facecolor": "white", "alpha": 0.85, "lw": 0, "pad": 1.0})
    set_extent(ax, np.concatenate(ex), np.concatenate(ey), margin=0.06)
    axes.label(ax)
    totals = {m: sum(a.count for a in arrows if a.movement == m) for m in MOVEMENTS}
    handles = [Line2D([], [], color=MOVEMENT_COLOURS[m], linewidth=6, label=f"{m} ({totals[m]})") for m in MOVEMENTS]
    ax.legend(handles=handles, title="movement (vehicles)", loc="upper left", fontsize=7, title_fontsize=7,
              framealpha=0.85)
    total = sum(a.count for a in arrows)
    ax.set_title(f"Turning movements: {total} complete movements through the junction; arrow width proportional to "
                 "the count", fontsize=9)
    return fig
