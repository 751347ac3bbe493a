"""The commands' outputs on the small world equal those of the release before the Python API.

tests/data/api-reference/pipeline holds what ``process`` (whole video, and two overlapping parts), ``stitch`` and
``compare-sumo`` wrote at commit be710d4 (see its SOURCE.txt). The same command lines run here through the CLI
(:func:`trafficgeo.cli.main`, i.e. through the library entry points they now call) must write the same tables and
summaries, value for value.

Compared by what they mean, never by their bytes (see tests/reference_values.py): the world is rebuilt here on this
machine, and its files are checked by their content (``input_meaning``). When the video decodes to the very pixels
of the reference, every number must agree to :data:`SAME_PIXELS` (measured: 4e-9 under another SIMD dispatch);
when its pixels differ a little (a renderer on another CPU), a detection may come or go and only what a user reads
must agree (``assert_what_a_user_reads``).
"""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pandas as pd
import pytest

from reference_values import TRAFFIC, assert_csv_close, assert_json_close, assert_what_a_user_reads

pytestmark = [pytest.mark.slow, pytest.mark.reference]

#: Tables and summaries from the same pixels (reference_values.TRAFFIC)
SAME_PIXELS = TRAFFIC

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
    here = maker.input_meaning(small_world)
    assert not maker.inputs_differ(here, recorded), (
        f"the small world's inputs changed ({', '.join(maker.inputs_differ(here, recorded))}: synth or SMALL_WORLD): "
        "write the reference again as its SOURCE.txt says")
    same_pixels = here["video.mp4"]["decoded_pixels_sha1"] == recorded["video.mp4"]["decoded_pixels_sha1"]
    maker.run_all(small_world, tmp_path)
    compared = 0
    for run, names in maker.KEEP.items():
        for name in names:
            new_path, old_path = tmp_path / run / name, REF / "pipeline" / run / name
            if not same_pixels:
                assert_what_a_user_reads(new_path, old_path, f"{run}/{name}")
            elif name.endswith(".csv"):
                assert_csv_close(new_path, old_path, f"{run}/{name}", SAME_PIXELS)
            else:
                assert_json_close(json.loads(new_path.read_text()), json.loads(old_path.read_text()),
                                  f"{run}/{name}", SAME_PIXELS)
            compared += 1
    assert compared == sum(len(v) for v in maker.KEEP.values()) == 16
    # the reference is not empty: vehicles were counted in every run and the comparison found them
    for run in ("process", "stitch"):
        assert len(pd.read_csv(REF / "pipeline" / run / "crossings.csv")) >= 3
    # two overlapping parts processed apart and stitched count like the one run of the whole video
    whole, stitched = (len(pd.read_csv(tmp_path / run / "crossings.csv")) for run in ("process", "stitch"))
    assert abs(stitched - whole) <= 1, (stitched, whole)
    assert len(pd.read_csv(REF / "pipeline" / "compare" / "compare_counts.csv")) >= 2

