"""Counts on a hand-counted real clip (issue 38): the background detector on the Intel parking-lot clip.

Truth: tests/data/intel-sample-video-counts (4 cars cross the image's middle row, 2 up and 2 down, counted by eye).
The clip has no calibration; the camera here is a nominal one from the image's scale (a ~4.5 m car spans ~300 px
of the 432 rows, seen from above: 8.5 m over the pavement, looking 75 deg down, 600 px focal length). Counting is
topological, so any camera that keeps the image's order of points would do; this one also keeps the cuboid fit's
sizes realistic. The cars are so large in the frame that the ones driving down (towards the camera) are cut off
by the bottom of the frame before their centre reaches the line, and the two that pass side by side merge into
one blob for half a second: the down-going ones are counted only because boxes cut off at the bottom are fitted
by their top edge (TrajectoryOptions.top_edge_clipped).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from trafficgeo.camera.model import Camera
from trafficgeo.pipeline.run import process_video
from trafficgeo.site.site import Site
from trafficgeo.traffic.analyze import analyze_tracks
from trafficgeo.traffic.trajectories import TrajectoryOptions
from trafficgeo.video.pipeline import ProcessOptions

DATA = Path(__file__).parent / "data"
INTEL = DATA / "intel-sample-video" / "car-detection.mp4"
TRUTH = DATA / "intel-sample-video-counts" / "crossings.csv"
UP, DOWN = -1, 1  # the line runs left to right (west to east for this camera): +1 is crossing it southwards (down)


def nominal_camera() -> Camera:
    return Camera.from_orientation((768, 432), 600.0, [500000.0, 5000000.0, 108.5], 0.0, 75.0, crs="EPSG:32633")


@pytest.fixture(scope="module")
def intel_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``trafficgeo process`` on the clip with the background detector, as a new user would run it."""
    out = tmp_path_factory.mktemp("intel")
    line = out / "line.csv"
    line.write_text("line,u,v\nmid,0,215.5\nmid,767,215.5\n")  # the truth's row, across the whole frame
    site = Site.load(nominal_camera(), 100.0, lines=line)
    with pytest.warns(UserWarning, match="loaded from a bare Camera"):  # a nominal camera: said, not silent
        process_video(INTEL, site, out / "run", options=ProcessOptions(detector="background"))
    return out


def test_background_detector_counts_the_hand_counted_clip(intel_run: Path) -> None:
    truth = pd.read_csv(TRUTH)
    got = pd.read_csv(intel_run / "run" / "crossings.csv")
    for name, sign in (("up", UP), ("down", DOWN)):
        want = np.sort(truth[truth.direction == name].time_s.to_numpy())
        seen = np.sort(got[got.direction == sign].time.to_numpy())
        assert seen.size == want.size, (name, seen, want)
        # each at the time it was counted by eye (frames 0.24 s apart; +-0.25 s) within half a second
        assert np.all(np.abs(seen - want) < 0.5), (name, seen, want)
    vehicles = pd.read_csv(intel_run / "run" / "vehicles.csv")
    assert got.track_id.astype(str).isin(vehicles.track_id.astype(str)).all()


def test_without_top_edges_the_down_going_cars_are_lost(intel_run: Path) -> None:
    """The fix above is what counts them: without it the cars cut off by the frame's bottom are not counted."""
    got = analyze_tracks(nominal_camera(), 100.0, intel_run / "run" / "tracks.csv", lines=intel_run / "line.csv",
                         options=TrajectoryOptions(top_edge_clipped=False)).crossings
    assert (got.direction == DOWN).sum() < 2


def test_a_detector_object_of_ones_own_runs_the_clip(tmp_path: Path) -> None:
    """A detector is any object with ``detect(image, time_s)`` (issue 41: a new backend meant editing the names in
    three files): passed as ``ProcessOptions(detector=...)`` it runs on every detection frame, and the run records
    it by its ``name``. This one wraps the library's background subtraction and counts what it does."""
    from trafficgeo.errors import InputError
    from trafficgeo.geo.surface import ConstantSurface
    from trafficgeo.run.folder import RunFolder
    from trafficgeo.video.detectors.factory import make_detector

    camera = nominal_camera()

    class Counting:
        name = "counting-background"
        learns_background = True  # learns from every frame: process then detects on every frame

        def __init__(self) -> None:
            self.inner = make_detector("background", camera=camera, surface=ConstantSurface(100.0))
            self.frames = 0

        def detect(self, image, time_s):
            self.frames += 1
            return self.inner.detect(image, time_s)

    mine = Counting()
    line = tmp_path / "line.csv"
    line.write_text("line,u,v\nmid,0,215.5\nmid,767,215.5\n")
    with pytest.warns(UserWarning, match="loaded from a bare Camera"):
        run = process_video(INTEL, Site.load(camera, 100.0, lines=line), tmp_path / "run",
                            options=ProcessOptions(detector=mine))
    assert mine.frames == run.read["frames"] == 377  # every frame of the clip, with the object given
    assert RunFolder(tmp_path / "run").process().options.detector == "counting-background"
    truth = pd.read_csv(TRUTH)
    got = pd.read_csv(tmp_path / "run" / "crossings.csv")
    for name, sign in (("up", UP), ("down", DOWN)):
        assert (got.direction == sign).sum() == (truth.direction == name).sum(), got
    with pytest.raises(InputError, match="not a detector"):
        ProcessOptions(detector=object())


def test_a_detector_object_that_learns_gets_an_untrained_copy_per_segment(tmp_path: Path) -> None:
    """A detector object that can give an untrained copy of itself (``fresh()``, as background subtraction does)
    learns anew for each segment of a run, as the named detector does (so a resumed run detects as an uninterrupted
    one): the same tracks as ``detector="background"``, with a copy per segment and one per segment learning ahead.
    """
    from trafficgeo.geo.surface import ConstantSurface
    from trafficgeo.video.detectors.factory import make_detector

    camera = nominal_camera()
    made: list[object] = []

    class Learning:
        name = "learning-background"
        learns_background = True

        def __init__(self, inner) -> None:
            self.inner, self.warmup_s = inner, inner.warmup_s
            made.append(self)

        def detect(self, image, time_s):
            return self.inner.detect(image, time_s)

        def fresh(self) -> Learning:
            return Learning(self.inner.fresh())

    site = Site.load(camera, 100.0)
    window = {"end_s": 6.0, "checkpoint_s": 2.0}  # three segments
    with pytest.warns(UserWarning, match="loaded from a bare Camera"):
        named = process_video(INTEL, site, tmp_path / "named", options=ProcessOptions(detector="background", **window))
        mine = process_video(INTEL, site, tmp_path / "mine", options=ProcessOptions(
            detector=Learning(make_detector("background", camera=camera, surface=ConstantSurface(100.0))), **window))
    assert len(made) >= 1 + 3  # the one given, then one per segment (and those learning the next ahead)
    assert len(mine.tracks) > 0
    pd.testing.assert_frame_equal(mine.tracks.to_table(), named.tracks.to_table())
