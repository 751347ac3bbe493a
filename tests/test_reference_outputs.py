"""The commands' outputs on the small world equal those of the release before the Python API.

tests/data/api-reference/pipeline holds what ``process`` (whole video, and two overlapping parts), ``stitch`` and
``compare-sumo`` wrote at commit be710d4 (see its SOURCE.txt). The same command lines run here through the CLI
(:func:`trafficgeo.cli.main`, i.e. through the library entry points they now call) must write the same tables and
summaries, value for value.

Compared by what they mean, never by their bytes (see tests/reference_values.py). The world is rebuilt here on this
machine and its files are checked by their content (``input_meaning``). The commands then run on that world with the
reference's own video instead of the one rendered here (pipeline/video.mp4: H.264 decodes to the same pixels
on any CPU), because the detector cannot promise the same counts from other pixels: re-encoding the video with +-1
grey level on 2 % of its pixels cost the background detector one of its 3 crossings (measured 2026-12-04). From the
same pixels every number must agree to reference_values.TRAFFIC (measured: within 4e-9 under another SIMD dispatch).
"""

from __future__ import annotations

import importlib.util
import json
import shutil
from pathlib import Path

import pandas as pd
import pytest

from reference_values import TRAFFIC, assert_csv_close, assert_json_close

pytestmark = [pytest.mark.slow, pytest.mark.reference]
REF = Path(__file__).parent / "data" / "api-reference"


def _maker():
    spec = importlib.util.spec_from_file_location("make_pipeline_reference", REF / "make_pipeline_reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_process_stitch_and_compare_write_what_the_release_before_the_api_wrote(small_world: Path,
                                                                                tmp_path: Path) -> None:
    maker = _maker()
    recorded = json.loads((REF / "pipeline" / "inputs.json").read_text(encoding="utf-8"))
    differ = maker.inputs_differ(maker.input_meaning(small_world), recorded, video=False)
    assert not differ, (f"the small world's inputs changed ({', '.join(differ)}: synth or SMALL_WORLD): write the "
                        "reference again as its SOURCE.txt says")
    world = tmp_path / "world"  # the small world, with the reference's video
    world.mkdir()
    for item in small_world.iterdir():
        (world / item.name).symlink_to(item)
    (world / "video.mp4").unlink()
    shutil.copyfile(REF / "pipeline" / "video.mp4", world / "video.mp4")
    assert not maker.inputs_differ(maker.input_meaning(world), recorded)  # the video decodes to the same pixels
    maker.run_all(world, tmp_path)
    compared = 0
    for run, names in maker.KEEP.items():
        for name in names:
            new_path, old_path = tmp_path / run / name, REF / "pipeline" / run / name
            if name.endswith(".csv"):
                # a frame's tracked boxes in any order: the tracker's (before) or by track id (ImageTracks)
                assert_csv_close(new_path, old_path, f"{run}/{name}", TRAFFIC,
                                 sort_by=("frame", "track_id") if name == "tracks.csv" else ())
            else:
                assert_json_close(json.loads(new_path.read_text()), json.loads(old_path.read_text()),
                                  f"{run}/{name}", TRAFFIC)
            compared += 1
    assert compared == sum(len(v) for v in maker.KEEP.values()) == 16
    # the reference is not empty: vehicles were counted in every run and the comparison found them
    for run in ("process", "stitch"):
        assert len(pd.read_csv(REF / "pipeline" / run / "crossings.csv")) >= 3
    # two overlapping parts processed apart and stitched count like the one run of the whole video
    whole, stitched = (len(pd.read_csv(tmp_path / run / "crossings.csv")) for run in ("process", "stitch"))
    assert abs(stitched - whole) <= 1, (stitched, whole)
    assert len(pd.read_csv(REF / "pipeline" / "compare" / "compare_counts.csv")) >= 2

