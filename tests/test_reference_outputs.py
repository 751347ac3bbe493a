"""The commands' outputs on the small world equal those of the release before the Python API.

tests/data/api-reference/pipeline holds what ``process`` (whole video, and two overlapping parts), ``stitch`` and
``compare-sumo`` wrote at commit be710d4 (see its SOURCE.txt). The same command lines run here through the CLI
(:func:`trafficgeo.cli.main`, i.e. through the library entry points they now call) must write the same tables and
summaries, value for value.
"""

from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path

import pandas as pd
import pytest

pytestmark = pytest.mark.slow

REF = Path(__file__).parent / "data" / "api-reference"


def _maker():
    spec = importlib.util.spec_from_file_location("make_pipeline_reference", REF / "make_pipeline_reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _same_json(new: object, old: object, where: str) -> None:
    if isinstance(old, dict):
        assert isinstance(new, dict) and set(new) == set(old), f"{where}: keys {sorted(new)} != {sorted(old)}"
        for k in old:
            _same_json(new[k], old[k], f"{where}.{k}")
    elif isinstance(old, list):
        assert isinstance(new, list) and len(new) == len(old), where
        for i, (a, b) in enumerate(zip(new, old, strict=True)):
            _same_json(a, b, f"{where}[{i}]")
    elif isinstance(old, float) and not isinstance(new, bool):
        assert isinstance(new, int | float) and math.isclose(new, old, rel_tol=1e-9, abs_tol=1e-9), \
            f"{where}: {new} != {old}"
    else:
        assert new == old, f"{where}: {new!r} != {old!r}"


def test_process_stitch_and_compare_write_what_the_release_before_the_api_wrote(small_world: Path,
                                                                                tmp_path: Path) -> None:
    maker = _maker()
    recorded = json.loads((REF / "pipeline" / "inputs.json").read_text(encoding="utf-8"))
    assert maker.input_digests(small_world) == recorded, (
        "the small world's inputs changed (synth or SMALL_WORLD): write the reference again as its SOURCE.txt says")
    maker.run_all(small_world, tmp_path)
    compared = 0
    for run, names in maker.KEEP.items():
        for name in names:
            new_path, old_path = tmp_path / run / name, REF / "pipeline" / run / name
            if new_path.read_bytes() == old_path.read_bytes():
                compared += 1
                continue
            if name.endswith(".csv"):  # not the same bytes: the same values?
                pd.testing.assert_frame_equal(pd.read_csv(new_path), pd.read_csv(old_path), check_exact=False,
                                              rtol=1e-9, atol=1e-9, obj=f"{run}/{name}")
            else:
                _same_json(json.loads(new_path.read_text()), json.loads(old_path.read_text()), f"{run}/{name}")
            compared += 1
    assert compared == sum(len(v) for v in maker.KEEP.values()) == 16
    # the reference is not empty: vehicles were counted in every run and the comparison found them
    for run in ("process", "stitch"):
        assert len(pd.read_csv(REF / "pipeline" / run / "crossings.csv")) >= 3
    # two overlapping parts processed apart and stitched count like the one run of the whole video
    whole, stitched = (len(pd.read_csv(tmp_path / run / "crossings.csv")) for run in ("process", "stitch"))
    assert abs(stitched - whole) <= 1, (stitched, whole)
    assert len(pd.read_csv(REF / "pipeline" / "compare" / "compare_counts.csv")) >= 2
