"""The scripts in examples/ run as a user runs them, and their figures agree with the truth of the world."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


@pytest.mark.slow
def test_api_example_runs_the_whole_chain_on_a_short_demo_world(tmp_path: Path, capsys) -> None:
    spec = importlib.util.spec_from_file_location("api_demo_world", EXAMPLES / "api_demo_world.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    figures = module.main(["--seconds", "8", "--out", str(tmp_path)])
    printed = capsys.readouterr().out
    for step in ("calibrated:", "pixels to the ground:", "video:", "against the simulation:", "vehicles.csv:"):
        assert step in printed, step
    assert figures["count_accuracy"] >= 0.85  # per-lane counts against the world's true crossings
    assert figures["ground_median_error_m"] < 1.0  # true pixels mapped back through the calibrated camera
    assert 0.0 <= figures["share_geh_below_5"] <= 1.0
    # the calibration's knowledge reached the speeds (a bare camera would have dropped it: "none")
    assert figures["speed_scale_knowledge"] == "covariance+gcps"
