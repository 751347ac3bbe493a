"""The typed calibration report (``CalibrationReport``): report.json, camera.json and the terminal report written
as before it existed (value for value, to the fit's tolerance: tests/reference_values.py), the file read back (and
refused with one line when it is not a report)."""

from __future__ import annotations

import dataclasses
import importlib.util
import io
import json
import math
from pathlib import Path

import numpy as np
import pytest

from cli_support import invoke
from reference_values import FIT, assert_json_close, assert_text_close
from trafficgeo.calibration import (
    CalibrationReport,
    build_report,
    calibrate,
    read_calibration_report,
    read_gcps,
    run_calibration,
)
from trafficgeo.calibration.report import REPORT_FORMAT, CheckStats, DistanceRatios, PoseConsistency, gcp_row
from trafficgeo.camera.calibrated import CameraGCP
from trafficgeo.camera.orientation import Orientation
from trafficgeo.errors import InputError
from trafficgeo.io.atomic import to_json_safe
from trafficgeo.report.inputs import find_inputs

API_REF = Path(__file__).parent / "data" / "api-reference"
REF = API_REF / "calibration"


def _reference_module():
    spec = importlib.util.spec_from_file_location("make_calibration_reference",
                                                  API_REF / "make_calibration_reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


MAKE = _reference_module()


def _json_text(doc: object) -> str:
    """The text write_json_atomic writes."""
    return json.dumps(to_json_safe(doc), indent=2, allow_nan=False) + "\n"


def _gcps(name: str):
    size, crs, _args = MAKE.SCENES[name]
    path = MAKE.gcp_csv(name, REF)  # the stored CSV (generated once at 157ed9b; nothing is generated here)
    return dataclasses.replace(read_gcps(path, crs=crs), source=path.name), size


@pytest.mark.reference
@pytest.mark.parametrize("name", sorted(MAKE.SCENES))
def test_outputs_are_those_written_before_the_typed_report(name: str, tmp_path: Path) -> None:
    # tests/data/api-reference/calibration: written by commit 157ed9b, when the report was a dict (SOURCE.txt).
    # By value, not bytes: the fit's numbers to reference_values.FIT, the covariance scaled by its own standard
    # deviations, the terminal text with each number within one unit of its last printed digit.
    gcps, size = _gcps(name)
    run = run_calibration(gcps, size, camera_path=tmp_path / "camera.json", report_path=tmp_path / "report.json")
    assert isinstance(run.report, CalibrationReport)
    for what in ("report.json", "camera.json"):
        new, old = (json.loads(p.read_text(encoding="utf-8")) for p in (tmp_path / what, REF / f"{name}_{what}"))
        assert_json_close(new, old, f"{name}_{what}", FIT, covariances=(".covariance.matrix",))
    assert_text_close(MAKE.terminal_text(run.report), (REF / f"{name}_terminal.txt").read_text(encoding="utf-8"),
                      f"{name}_terminal.txt")


@pytest.mark.parametrize("name", sorted(MAKE.SCENES))
def test_a_report_file_reads_back_typed_and_writes_the_same_bytes(name: str) -> None:
    path = REF / f"{name}_report.json"
    rep = read_calibration_report(path)
    assert _json_text(rep.to_dict()) == path.read_text(encoding="utf-8")
    assert CalibrationReport.from_dict(rep.to_dict()) == rep
    doc = json.loads(path.read_text(encoding="utf-8"))
    assert rep.summary == doc["summary"] and rep.image_size == tuple(doc["image_size"]) and rep.crs == doc["crs"]
    assert all(isinstance(r, CameraGCP) for r in rep.gcps) and isinstance(rep.camera.orientation, Orientation)
    assert [(r.du, r.dv, r.status) for r in rep.gcps] == [(r["du"], r["dv"], r["status"]) for r in doc["gcps"]]
    assert [r.id for r in rep.gcps] == [r["id"] for r in doc["gcps"]]
    assert rep.stats.rmse_px == doc["stats"]["rmse_px"] and rep.check.n == doc["check"]["n"]
    assert rep.uncertainty.orientation_std_deg.tilt == doc["uncertainty"]["orientation_std_deg"]["tilt"]


def test_the_typed_report_holds_what_the_scene_planted() -> None:
    rep = read_calibration_report(REF / "blunders_report.json")
    gcps, _size = _gcps("blunders")
    assert len(rep.gcps) == gcps.n == 19
    assert (rep.stats.n_control, rep.stats.n_check, rep.stats.n_outliers) == (14, 5, 3)
    assert rep.check.n == 5 and rep.check.ground_rmse_m < 0.1
    assert {o.id for o in rep.outliers} == {r.id for r in rep.gcps if r.status == "outlier"}
    assert [r.id for r in rep.gcps if r.role == "check"] == [gcps.ids[i] for i in np.nonzero(gcps.is_check)[0]]
    np.testing.assert_array_equal([[r.u, r.v] for r in rep.gcps], gcps.pixels)
    local = read_calibration_report(REF / "local_report.json")
    assert local.crs is None and local.check == CheckStats(0) and local.distance_ratios_check == DistanceRatios(0)
    assert math.isnan(local.check.rmse_px) and local.check.to_dict() == {"n": 0}


def test_round_trip_in_memory_and_through_json(tmp_path: Path) -> None:
    gcps, size = _gcps("blunders")
    rep = build_report(calibrate(gcps, size))
    assert CalibrationReport.from_dict(rep.to_dict()) == rep
    assert CalibrationReport.from_dict(json.loads(_json_text(rep.to_dict()))) == rep
    assert rep.check.ground_rmse_m <= rep.check.ground_max_m < 1.0
    unknown = dataclasses.replace(rep, check=dataclasses.replace(rep.check, ground_max_m=math.nan))
    assert json.loads(_json_text(unknown.to_dict()))["check"]["ground_max_m"] is None
    assert CalibrationReport.from_dict(json.loads(_json_text(unknown.to_dict()))) == unknown  # NaN back from null
    assert dataclasses.replace(rep, summary=rep.summary + " ") != rep  # equality can fail
    moved = dataclasses.replace(rep.gcps[0], u=rep.gcps[0].u + 1e-9)
    assert dataclasses.replace(rep, gcps=(moved, *rep.gcps[1:])) != rep
    # A pose consistency without enough refits writes only its count, and reads back equal.
    few = dataclasses.replace(rep, pose_consistency=PoseConsistency("leave-one-out refits", 2, False))
    doc = json.loads(_json_text(few.to_dict()))
    assert doc["pose_consistency"] == {"method": "leave-one-out refits", "n_fits": 2, "available": False}
    assert CalibrationReport.from_dict(doc) == few


def _broken(tmp_path: Path, change) -> Path:
    doc = json.loads((REF / "local_report.json").read_text(encoding="utf-8"))
    change(doc)
    path = tmp_path / "broken.json"
    path.write_text(json.dumps(doc), encoding="utf-8")
    return path


@pytest.mark.parametrize("case, expect", [
    ("camera_json", "not a calibration report (format 'trafficgeo.camera/1', expected " + REPORT_FORMAT),
    ("no_format", "not a calibration report (no 'format' key"),
    ("other_format", "not a calibration report (format 'trafficgeo.calibration-report/9'"),
    ("missing_key", "key 'stats.rmse_px' is missing"),
    ("missing_block", "key 'uncertainty' is missing"),
    ("wrong_type", "'gcps' is not a list"),
    ("wrong_row", "'gcps[2].u' is not a number"),
    ("text_angle", "'camera.orientation.tilt_deg' is not a number"),
    ("flag_count", "'stats.n_control' is not a whole number"),
    ("short_position", "key 'camera.position[2]' is missing"),
    ("not_json", "not readable JSON"),
    ("missing_file", "file not found"),
])
def test_a_file_that_is_not_a_report_is_refused_in_one_line(case: str, expect: str, tmp_path: Path) -> None:
    changes = {
        "no_format": lambda d: d.pop("format"),
        "other_format": lambda d: d.update(format="trafficgeo.calibration-report/9"),
        "missing_key": lambda d: d["stats"].pop("rmse_px"),
        "missing_block": lambda d: d.pop("uncertainty"),
        "wrong_type": lambda d: d.update(gcps="G01"),
        "wrong_row": lambda d: d["gcps"][2].update(u="12"),
        "text_angle": lambda d: d["camera"]["orientation"].update(tilt_deg="12"),
        "flag_count": lambda d: d["stats"].update(n_control=True),
        "short_position": lambda d: d["camera"].update(position=d["camera"]["position"][:2]),
    }
    if case == "camera_json":
        path = REF / "local_camera.json"
    elif case == "not_json":
        path = tmp_path / "report.json"
        path.write_text("{'format': ", encoding="utf-8")
    elif case == "missing_file":
        path = tmp_path / "nothing.json"
    else:
        path = _broken(tmp_path, changes[case])
    with pytest.raises(InputError) as err:
        read_calibration_report(path)
    msg = str(err.value)
    assert msg.startswith(f"{path}: ") and expect in msg and "\n" not in msg


def test_html_report_refuses_a_wrong_report_file_and_a_wrong_dict(tmp_path: Path) -> None:
    code, _out, err = invoke("report", REF, "--calibration-report", REF / "local_camera.json", "-o",
                             tmp_path / "r.html")
    assert code == 2 and f"--calibration-report {REF / 'local_camera.json'}: not a calibration report" in err
    assert not (tmp_path / "r.html").exists()
    doc = json.loads((REF / "local_report.json").read_text(encoding="utf-8"))
    inputs = find_inputs(tmp_path, calibration_report=doc)
    assert inputs.calibration_report == read_calibration_report(REF / "local_report.json")
    with pytest.raises(InputError, match=r"^calibration_report: not a complete calibration report \(key 'summary'"):
        find_inputs(tmp_path, calibration_report={"format": REPORT_FORMAT})


def test_the_terminal_report_prints_the_typed_report() -> None:
    from rich.console import Console

    from trafficgeo.report.terminal import print_calibration_report

    rep = read_calibration_report(REF / "blunders_report.json")
    buf = io.StringIO()
    print_calibration_report(rep, Console(file=buf, width=140, force_terminal=False, color_system=None))
    text = buf.getvalue()
    assert text == (REF / "blunders_terminal.txt").read_text(encoding="utf-8")  # the report read from disk, too
    assert [line.split(":")[0] for line in text.splitlines() if line.startswith("outlier ")] == \
        [f"outlier {o.id}" for o in rep.outliers] == ["outlier G04", "outlier G09", "outlier G11"]


def test_the_camera_json_keeps_what_the_report_knows_of_each_gcp(tmp_path: Path) -> None:
    """One GCP record (CameraGCP) in the report and the camera JSON: the sigma_px a GCP file gave reaches the camera
    JSON, which ``refine`` reads the user's points from (it was dropped: refine judged with 1 px); the report's
    records are the camera's."""
    from trafficgeo.camera.calibrated import CalibratedCamera
    from trafficgeo.registration.run import user_gcps

    gcps, size = _gcps("local")
    sigma = np.linspace(0.5, 3.0, gcps.n)
    cal = calibrate(dataclasses.replace(gcps, sigma_px=sigma), size)
    rep = build_report(cal)
    camera = cal.calibrated_camera()
    assert _json_text([gcp_row(g) for g in camera.gcps]) == _json_text([gcp_row(g) for g in rep.gcps])
    np.testing.assert_allclose([g.sigma_px for g in rep.gcps], sigma)
    camera.write(tmp_path / "camera.json")
    table, _ = user_gcps(CalibratedCamera.read(tmp_path / "camera.json"))
    np.testing.assert_allclose(table.sigma_px, sigma)
    assert all(np.isfinite(g.ground_error_m) for g in rep.gcps)
    assert [g.status for g in rep.gcps] == ["inlier" if g.inlier else "outlier" for g in rep.gcps]
