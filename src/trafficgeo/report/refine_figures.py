"""Figures of the report's Orthophoto refinement section: the automatic correspondences on the frame.

Image positions in pixels, (0, 0) the centre of the top-left pixel, v down (the camera module's convention).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from trafficgeo.report.figures import frame_axes, new_figure, rectangle_patch

KEPT_COLOUR = "#1a9850"  # the green of the calibration figures' inliers
REJECTED_COLOUR = "#d73027"  # and the red of their outliers
SHIFT_FACTOR = 5.0  # the offset from predicted to found position is drawn this many times its length
FIGURE_WIDTH_IN = 7.5


def matches_on_frame(pixels: np.ndarray, predicted: np.ndarray, kept: np.ndarray, image_size: tuple[int, int],
                     image: np.ndarray | None = None, *, factor: float = SHIFT_FACTOR) -> Any:
    """The automatic correspondences of the last pass on the frame: a dot where each was found (``pixels`` (N, 2)
    px), green when the re-fit kept it (``kept`` (N,) bool), red when it rejected it, and a line from where the
    camera predicted it (``predicted`` (N, 2) px) to where it was found, the offset magnified ``factor`` times
    (the line starts at ``found + factor * (predicted - found)``). ``image`` (H, W, 3) RGB is drawn behind them,
    stretched over the ``image_size`` (W, H) frame; without it the frame is an empty rectangle.

    Artists: dots with gid ``"refine-kept"`` / ``"refine-rejected"``, lines ``"refine-shift-kept"`` /
    ``"refine-shift-rejected"``, one segment per match.
    """
    from matplotlib.collections import LineCollection

    w, h = image_size
    fig, axs = new_figure(FIGURE_WIDTH_IN, FIGURE_WIDTH_IN * h / w + 0.8)
    ax = axs[0, 0]
    if image is not None:
        ax.imshow(image, extent=(-0.5, w - 0.5, h - 0.5, -0.5), interpolation="bilinear")
    else:
        ax.add_patch(rectangle_patch((-0.5, -0.5), w, h))
    found = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    start = found + factor * (np.asarray(predicted, dtype=np.float64).reshape(-1, 2) - found)
    kept = np.asarray(kept, dtype=bool)
    for sel, colour, name, label in ((kept, KEPT_COLOUR, "kept", "kept by the re-fit"),
                                     (~kept, REJECTED_COLOUR, "rejected", "rejected as outlier")):
        segments = np.stack([start[sel], found[sel]], axis=1)
        lines = LineCollection(list(segments), colors=colour, linewidths=0.9, zorder=3)
        lines.set_gid(f"refine-shift-{name}")
        ax.add_collection(lines)
        dots = ax.scatter(found[sel, 0], found[sel, 1], s=12, c=colour, edgecolors="black", linewidths=0.3,
                          label=f"{label} ({int(sel.sum())})", zorder=4)
        dots.set_gid(f"refine-{name}")
    frame_axes(ax, w, h)
    ax.set_title(f"Orthophoto matches in the frame ({w}x{h} px): lines from the predicted to the found position, "
                 f"x{factor:g}", fontsize=9)
    ax.legend(loc="lower right", fontsize=7, framealpha=0.8)
    return fig
