"""The counts the calibration's texts give say which set of control points they mean (issue 29, part 4): the lens
model is chosen on the points the consensus kept (before snooping and readmission), the "Fit" line counts the
points of the final fit."""

from __future__ import annotations

import io

import numpy as np
from rich.console import Console

from trafficgeo.calibration import Calibration, build_report, calibrate
from trafficgeo.calibration.pipeline import CalibrationOptions, _base_model, _choose_model
from trafficgeo.calibration.refine import fit_camera
from trafficgeo.report.terminal import print_calibration_report
from trafficgeo.synth import make_gcp_scene


def _terminal(report: object) -> str:
    buf = io.StringIO()
    print_calibration_report(report, Console(file=buf, width=400, force_terminal=False, color_system=None))
    return buf.getvalue()


def test_seven_control_points_are_named_control_points_in_both_texts() -> None:
    scene = make_gcp_scene(12, image_size=(1280, 720), n_control=7, crs=None)
    cal = calibrate(scene.gcps, (1280, 720))
    reasons = cal.fit.model.reasons
    assert "k1 not estimated: 7 control points (needs 8)" in reasons
    text = _terminal(build_report(cal))
    assert "Fit: 7 of 7 control points kept in the final fit;" in text
    assert "inlier GCPs" not in text


def test_a_count_taken_before_readmission_says_so() -> None:
    # 7 of 8 control points reach the model choice (the consensus set one aside; the pipeline may readmit it).
    scene = make_gcp_scene(12, image_size=(1280, 720), n_control=8, crs=None)
    gcps = scene.gcps
    ctrl = np.nonzero(gcps.is_control)[0][:7]
    loc = gcps.world[ctrl] - gcps.world[ctrl].mean(axis=0)
    pix, sig = gcps.pixels[ctrl], gcps.sigma_px[ctrl]
    options = CalibrationOptions()
    cal = calibrate(gcps, (1280, 720))  # a good start for the fit on the seven
    base = _base_model(options)
    start = fit_camera(loc, pix, sig, _start_for(cal, gcps.world[ctrl].mean(axis=0)), base)
    _fit, model = _choose_model(base, start, loc, pix, sig, (1280, 720), options, n_control=8)
    why = [r for r in model.reasons if r.startswith("k1 not estimated")]
    assert why == ["k1 not estimated: only 7 of the 8 control points agreed on one camera when the lens model was "
                   "chosen (needs 8); points readmitted after that count in the final fit, not here"]


def _start_for(cal: Calibration, origin: np.ndarray) -> np.ndarray:
    """The calibration's parameter vector with its pose moved to the origin ``origin``."""
    full = cal.fit.full.copy()
    R = cal.camera.R
    full[3:6] = -R @ (cal.camera.position - origin)
    return full
