"""The report's Orthophoto refinement section (``trafficgeo refine --report``) as data
(:mod:`trafficgeo.report.blocks`): the verdict and its reason, the user's points' held-out ground errors before and
after, the automatic correspondences and the passes that found them, the refined model, and the matches on the
frame.

Units: ground errors in metres; image positions and distances in pixels; camera positions in the CRS's units;
angles in degrees.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from trafficgeo.registration.refine_record import HeldOutSummary, RefineRecord
from trafficgeo.report.blocks import Block, Heading, Part, Section, Text, figure, num, table
from trafficgeo.report.context import MAX_FRAME_PX, ReportContext
from trafficgeo.report.refine_figures import SHIFT_FACTOR, matches_on_frame

TITLE = "Orthophoto refinement"
PARAMETER_WORDS = {  # a camera JSON's free parameter names -> words
    "rx": "rotation", "ry": "rotation", "rz": "rotation", "tx": "position", "ty": "position", "tz": "position",
    "f": "one focal length f", "fx": "focal length fx", "fy": "focal length fy", "cx": "principal point",
    "cy": "principal point", "k1": "radial distortion k1", "k2": "radial distortion k2",
    "k3": "radial distortion k3", "p1": "tangential distortion p1", "p2": "tangential distortion p2"}
DIST_NAMES = ("k1", "k2", "p1", "p2", "k3")


def refinement_section(b: ReportContext, rec: RefineRecord | None) -> Section | None:
    """The section of the refinement report ``rec`` (read from the file the inputs found,
    :func:`~trafficgeo.registration.refine_record.read_refine_record`); None without one, with a note in ``b``
    when the camera JSON names a report that is not there, silently when there was no refinement."""
    if rec is None:
        if b.inputs.refine_named is not None:
            b.skip(TITLE.lower(), f"the camera JSON names the refinement report {b.inputs.refine_named}, which is "
                   "not beside it: pass --refine-report with the file 'trafficgeo refine --report' wrote")
        return None
    b.used.append(("orthophoto refinement report", str(rec.path)))
    disagree = _disagreement(b, rec)
    parts: list[Part] = [(_verdict(rec), *((Text(disagree, "warn"),) if disagree else ()))]
    parts.append((Heading("The user's points, held out", 3), *_errors(rec)))
    parts.append((Heading("Automatic correspondences", 3), *_correspondences(rec)))
    parts.append((Heading("The refined model", 3), *_model(rec, b)))
    parts.append(_figure(rec, b))
    return Section("refinement", TITLE, tuple(parts))


def _verdict(rec: RefineRecord) -> Text:
    if rec.accepted:
        head = "Accepted: the refined camera is the one in the camera JSON."
    else:
        head = "Refused: the camera JSON keeps the original camera."
    return Text(f"{head} Reason: {rec.reason.rstrip('.')}.", "summary")


def _disagreement(b: ReportContext, rec: RefineRecord) -> str:
    """Why the camera JSON's ``refinement`` block does not describe this report (verdict, matches kept, RMS before
    and after), or "" when it does or the camera JSON has no such block."""
    block = b.calibrated.refinement if b.calibrated is not None else None
    if block is None:
        return ""
    after = rec.after.rmse_m if rec.after is not None else float("nan")
    differ = []
    for key, mine in (("accepted", rec.accepted), ("matches_kept", rec.matches_kept),
                      ("before_rmse_m", rec.before.rmse_m), ("after_rmse_m", after)):
        theirs = getattr(block, key)
        if isinstance(mine, int):  # and bool
            same = theirs == mine and isinstance(theirs, bool) == isinstance(mine, bool)
        else:
            theirs = theirs if np.isfinite(theirs) else None  # null in the file
            same = (theirs is None and not np.isfinite(mine)) or (theirs is not None and abs(theirs - mine) <= 1e-3)
        if not same:
            differ.append(f"{key} {theirs} against {num(mine, 4) if isinstance(mine, float) else mine}")
    if not differ:
        return ""
    return (f"The camera JSON's refinement block does not match {rec.path.name} ({'; '.join(differ)}): the report "
            "may be from another run of 'trafficgeo refine'.")


def _rms_rows(before: HeldOutSummary, after: HeldOutSummary | None) -> list[list[object]]:
    rows = []
    for label, key in (("check points (never fitted)", "check_rmse"),
                       ("control points, leave-one-out", "loo_rmse"), ("all the user's points", "rmse")):
        row: list[object] = [label]
        for unit, digits in (("px", 2), ("m", 3)):
            b = getattr(before, f"{key}_{unit}")
            a = getattr(after, f"{key}_{unit}") if after is not None else float("nan")
            row += [(b, digits), (a, digits), (a - b, digits)]
        rows.append(row)
    return rows


def _errors(rec: RefineRecord) -> tuple[Block, ...]:
    """The RMS held-out errors before and after (pixels decide, the ground is shown), then one row per point."""
    rms = table(["RMS held-out error", "before (px)", "after (px)", "change (px)", "before (m)", "after (m)",
                 "change (m)"], _rms_rows(rec.before, rec.after),
                caption="held-out error at the user's GCPs, original (before) and refined (after) camera; the "
                        "verdict goes by the pixels, where every click's noise weighs the same (on the ground a "
                        "click's noise grows with its distance along the view)")
    rows, classes = [], []
    for p in rec.before.points:
        q = rec.after.point(p.id) if rec.after is not None else None
        ga = q.ground_error_m if q is not None else float("nan")
        pa = q.pixel_error_px if q is not None else float("nan")
        rows.append([p.id, p.role, (p.ground_error_m, 3), (ga, 3), (ga - p.ground_error_m, 3),
                     (p.pixel_error_px, 2), (pa, 2)])
        classes.append("check" if p.role == "check" else "")
    per_point = table(["id", "role", "ground error before (m)", "after (m)", "change (m)", "pixel error before (px)",
                       "after (px)"], rows, row_classes=classes, caption="per user's point")
    note = Text("A control point's error is its leave-one-out error (the camera fitted without it); a check point "
                "was never fitted. Both include the clicks' own noise. '-': not known (no re-fit, or the ray "
                "misses the ground).", "note")
    return rms, per_point, note


def _correspondences(rec: RefineRecord) -> tuple[Block, ...]:
    rejected = rec.matches_found - rec.matches_kept
    text = Text(f"{rec.matches_found} automatic correspondences (orthophoto patch -> frame) found on the last pass, "
                f"{rec.matches_kept} kept by the re-fit, {rejected} rejected as outliers.")
    if not rec.passes:
        return text, Text("No pass was completed.", "note")
    rows = [[k + 1, (p.search_px, 1), p.tried, p.matched, p.kept, (p.rmse_px, 2), (p.moved_px, 2)]
            for k, p in enumerate(rec.passes)]
    passes = table(["pass", "search (px)", "tried", "matched", "kept", "RMSE (px)", "moved (px)"], rows,
                   caption="each match + re-fit pass: search radius, patches tried, matched and kept, the kept "
                   "matches' RMS reprojection error, and how far the re-fit moved the matched points (RMS)")
    return text, passes


def _model(rec: RefineRecord, b: ReportContext) -> tuple[Block, ...]:
    if rec.model is None or rec.refined is None:
        return (Text("No re-fit: the original camera is the only one.", "note"),)
    words = list(dict.fromkeys(PARAMETER_WORDS.get(n, n) for n in rec.model))
    text = Text(f"Free parameters of the refined model: {', '.join(rec.model)} ({', '.join(words)}).")
    o, r = rec.original, rec.refined
    free = set(rec.model)
    unit = b.axes.unit
    rows: list[list[object]] = [["focal length fx", *_pair(o.fx_px, r.fx_px, 1), "px", bool({"f", "fx"} & free)]]
    if abs(o.fy_px - o.fx_px) > 1e-9 or abs(r.fy_px - r.fx_px) > 1e-9:
        rows.append(["focal length fy", *_pair(o.fy_px, r.fy_px, 1), "px", bool({"f", "fy"} & free)])
    rows += [["principal point cx", *_pair(o.cx_px, r.cx_px, 1), "px", "cx" in free],
             ["principal point cy", *_pair(o.cy_px, r.cy_px, 1), "px", "cy" in free]]
    for k, name in enumerate(DIST_NAMES):
        if name in free or o.dist[k] != 0.0 or r.dist[k] != 0.0:
            rows.append([f"distortion {name}", *_pair(o.dist[k], r.dist[k], 4), "", name in free])
    for k, axis in enumerate(("easting", "northing", "height")):
        rows.append([f"position {axis}", *_pair(o.position[k], r.position[k], 2), unit, True])
    for name in ("heading_deg", "tilt_deg", "roll_deg"):
        rows.append([name.removesuffix("_deg"), *_pair(getattr(o, name), getattr(r, name), 3), "deg", True])
    return text, table(["quantity", "original", "refined", "change", "unit", "free in the re-fit"], rows,
                       caption="the original and the refined camera")


def _pair(a: float, b: float, nd: int) -> list[object]:
    return [(a, nd), (b, nd), (b - a, nd)]


def _figure(rec: RefineRecord, b: ReportContext) -> Part:
    """The matches on the frame (the picture when the frame file is there and fits the camera; said otherwise)."""
    if rec.matches_found == 0:
        return (Text("No automatic correspondences to draw.", "note"),)
    size = rec.original.image_size
    image, missing = _frame(rec.frame, size)
    blocks: list[Block] = []
    if missing:
        b.skip("frame behind the orthophoto matches", missing)
        blocks.append(Text(f"The matches are drawn without the picture: {missing}.", "note"))
    fig = matches_on_frame(rec.pixels, rec.predicted, rec.kept, size, image)
    caption = (f"The automatic correspondences of the last pass in the frame: green kept by the re-fit, red "
               f"rejected as outliers; each line runs from where the camera predicted the point to where it was "
               f"found, the offset magnified x{SHIFT_FACTOR:g}.")
    return (figure(fig, caption, b.dpi), *blocks)


def _frame(path: Path | None, size: tuple[int, int]) -> tuple[np.ndarray | None, str]:
    """The frame the matches were made on, RGB and decimated to at most MAX_FRAME_PX, or None and why not."""
    import cv2

    if path is None:
        return None, "the refinement report names no frame image"
    if not path.is_file():
        return None, f"its frame image {path} is missing (it is written beside the report)"
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        return None, f"{path} is not an image OpenCV can read"
    h, w = img.shape[:2]
    if abs(w / h - size[0] / size[1]) > 0.01:
        return None, f"{path} is {w}x{h} px but the camera's image is {size[0]}x{size[1]} px"
    k = max(w, h) / MAX_FRAME_PX
    if k > 1:
        img = cv2.resize(img, (round(w / k), round(h / k)), interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(img[:, :, ::-1]), ""
