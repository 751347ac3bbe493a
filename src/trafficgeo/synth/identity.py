"""Identity metrics of tracks against a generated world's truth: IDF1, identity switches and fragmentations
(``motmetrics``) and HOTA with its detection and association parts (``trackeval``), both maintained packages of
the MOT community; this module only hands them the boxes.

A truth box and a track box match at IoU >= ``iou`` (0.5, as in MOTChallenge). Truth is the world's rendered boxes
(``truth_tracks.csv``: ``frame, vehicle, x1, y1, x2, y2``) on the frames the tracks were made on; hypotheses are
track boxes (``frame, track_id, x1, y1, x2, y2``) under any ids: the tracker's, or the vehicles the journeys stage
made of them (:func:`vehicle_ids`). Boxes are image pixels.

The two packages are test and benchmark tools, not dependencies of the library (``pip install trafficgeo[test]``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from trafficgeo.video.detections import box_iou

__all__ = ["IdentityScores", "identity_scores", "vehicle_ids"]

BOX = ["x1", "y1", "x2", "y2"]


@dataclass(frozen=True)
class IdentityScores:
    """IDF1 (identity F1: the share of boxes given the right identity), IDP / IDR (its precision and recall),
    ``id_switches`` (a truth vehicle's matched track id changes), ``fragmentations`` (a truth vehicle's track is
    interrupted), MOTA, HOTA with DetA and AssA (at IoU thresholds 0.05-0.95, averaged), and the numbers of truth
    vehicles and of hypothesis ids."""

    idf1: float
    idp: float
    idr: float
    id_switches: int
    fragmentations: int
    mota: float
    hota: float
    deta: float
    assa: float
    truth_ids: int
    hypothesis_ids: int


def _missing(package: str) -> ImportError:
    return ImportError(f"{package} is needed for identity metrics; pip install 'trafficgeo[test]' (or pip install "
                       f"{package})")


def _frames(truth: pd.DataFrame, hyp: pd.DataFrame):
    """Per frame: truth ids, hypothesis ids and their IoU matrix."""
    tg = truth.groupby("frame").indices
    hg = hyp.groupby("frame").indices
    tid, hid = truth["id"].to_numpy(), hyp["id"].to_numpy()
    tbox, hbox = truth[BOX].to_numpy(dtype=np.float64), hyp[BOX].to_numpy(dtype=np.float64)
    for f in sorted(set(tg) | set(hg)):
        ti = tg.get(f, np.zeros(0, dtype=int))
        hi = hg.get(f, np.zeros(0, dtype=int))
        iou = box_iou(tbox[ti][:, None], hbox[hi][None, :]) if ti.size and hi.size else np.zeros((ti.size, hi.size))
        yield f, tid[ti], hid[hi], np.asarray(iou, dtype=np.float64).reshape(ti.size, hi.size)


def identity_scores(truth: pd.DataFrame, hypotheses: pd.DataFrame, *, iou: float = 0.5) -> IdentityScores:
    """The identity metrics (:class:`IdentityScores`) of ``hypotheses`` (``frame, id, x1, y1, x2, y2``) against
    ``truth`` (same columns), frame by frame."""
    try:
        import motmetrics as mm
    except ImportError:
        raise _missing("motmetrics") from None
    try:
        from trackeval.metrics import HOTA
    except ImportError:
        raise _missing("trackeval") from None
    truth = truth.assign(id=truth["id"].astype(str))
    hyp = hypotheses.assign(id=hypotheses["id"].astype(str))
    acc = mm.MOTAccumulator(auto_id=False)
    t_index = {v: k for k, v in enumerate(pd.unique(truth["id"]))}
    h_index = {v: k for k, v in enumerate(pd.unique(hyp["id"]))}
    data: dict = {"gt_ids": [], "tracker_ids": [], "similarity_scores": []}
    for f, tids, hids, sim in _frames(truth, hyp):
        dist = np.where(sim >= iou, 1.0 - sim, np.nan)
        gt = np.array([t_index[t] for t in tids], dtype=int)  # numbers: motmetrics keeps ids as floats
        tr = np.array([h_index[h] for h in hids], dtype=int)
        acc.update(list(gt), list(tr), dist, frameid=int(f))
        data["gt_ids"].append(gt)
        data["tracker_ids"].append(tr)
        data["similarity_scores"].append(sim)
    data.update(num_gt_ids=len(t_index), num_tracker_ids=len(h_index), num_gt_dets=len(truth),
                num_tracker_dets=len(hyp), num_timesteps=len(data["gt_ids"]))
    summary = mm.metrics.create().compute(acc, metrics=["idf1", "idp", "idr", "num_switches", "num_fragmentations",
                                                        "mota"], name="all")
    row = summary.loc["all"]
    hota = HOTA().eval_sequence(data)
    return IdentityScores(idf1=float(row["idf1"]), idp=float(row["idp"]), idr=float(row["idr"]),
                          id_switches=int(row["num_switches"]), fragmentations=int(row["num_fragmentations"]),
                          mota=float(row["mota"]), hota=float(np.mean(hota["HOTA"])),
                          deta=float(np.mean(hota["DetA"])), assa=float(np.mean(hota["AssA"])),
                          truth_ids=len(t_index), hypothesis_ids=len(h_index))


def vehicle_ids(tracks: pd.DataFrame, points: pd.DataFrame) -> pd.DataFrame:
    """The track boxes ``tracks`` (``tracks.csv``: ``frame, time, track_id, x1, y1, x2, y2``) with ``id`` the vehicle
    each box became in ``points`` (``trajectories.csv``: ``track_id`` the vehicle, ``source_track`` the tracker's
    id, ``frame``, ``time``). A box ``analyze`` did not use (too far, cut off by the frame's edge) takes the vehicle
    of the nearest box in time of its tracker id that was used; a tracker id none of whose boxes was used keeps its
    own id (``"t<id>"``)."""
    key = points[["source_track", "frame", "track_id"]].astype({"source_track": str}).drop_duplicates(
        ["source_track", "frame"])
    out = tracks.assign(source_track=tracks["track_id"].astype(str)).merge(key.rename(columns={"track_id": "id"}),
                                                                           how="left", on=["source_track", "frame"])
    ids = out["id"].to_numpy(dtype=object)
    for _src, rows in out.groupby("source_track").indices.items():
        have = rows[pd.notna(ids[rows])]
        lost = rows[pd.isna(ids[rows])]
        if not have.size or not lost.size:
            continue
        f_have = out["frame"].to_numpy()[have]
        order = np.argsort(f_have)
        f_sorted = f_have[order]
        f_lost = out["frame"].to_numpy()[lost]
        k = np.clip(np.searchsorted(f_sorted, f_lost), 1, max(f_sorted.size - 1, 1))
        left = np.clip(k - 1, 0, f_sorted.size - 1)
        right = np.clip(k, 0, f_sorted.size - 1)
        pick = np.where(np.abs(f_sorted[left] - f_lost) <= np.abs(f_sorted[right] - f_lost), left, right)
        ids[lost] = ids[have[order[pick]]]
    out["id"] = np.where(pd.isna(ids), "t" + out["source_track"].astype(str), ids)
    return out.drop(columns=["source_track"])
