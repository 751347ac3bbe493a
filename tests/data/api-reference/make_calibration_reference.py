"""Write the reference outputs of ``calibrate`` (report.json, camera.json and the terminal report) on fixed GCPs.

Run from a trafficgeo checkout:  python tests/data/api-reference/make_calibration_reference.py [OUT]
(default: the ``calibration`` folder beside this script). Three inputs, each written or read as a GCP CSV so the
reference depends on the file only (its
messages name the file without its folder):

* ``blunders``: a generated road scene (``make_gcp_scene(7, ...)``, EPSG:2949, 1920x1080) with 14 control points,
  5 check points and 3 planted blunders (elevation and click errors): outliers with reasons, check-point blocks;
* ``local``: a generated scene in local coordinates (no CRS), 7 control points and no check points;
* ``paper``: the GCPs of the paper's table 2 (``tests/data/paper_table2_gcps.csv``, 848x464): warnings of a bad fit.

For each: ``<name>_gcps.csv`` (the input; not written for ``paper``), ``<name>_report.json``,
``<name>_camera.json`` and ``<name>_terminal.txt`` (``print_calibration_report`` on a 140-column plain console).
It uses only functions that existed at commit 157ed9b (before the typed calibration report), so a reference
written there can be compared byte for byte with the outputs of newer code (tests/test_calibration_report.py).
"""

from __future__ import annotations

import io
import sys
from dataclasses import replace
from pathlib import Path

HERE = Path(__file__).resolve().parent
DATA = HERE.parent

#: name -> (image size, CRS, make_gcp_scene arguments or None for the paper's table)
SCENES = {
    "blunders": ((1920, 1080), "EPSG:2949", dict(seed=7, n_control=14, n_check=5, n_outliers=3, survey_sigma=0.02,
                                                 grade=0.025, crossfall=0.02)),
    "local": ((1280, 720), None, dict(seed=12, image_size=(1280, 720), n_control=7, crs=None)),
    "paper": ((848, 464), "EPSG:2949", None),
}


def gcp_csv(name: str, folder: Path) -> Path:
    """The GCP CSV of scene ``name`` (written into ``folder`` for the generated scenes)."""
    args = SCENES[name][2]
    if args is None:
        return DATA / "paper_table2_gcps.csv"
    path = folder / f"{name}_gcps.csv"
    if not path.is_file():
        from trafficgeo.synth import make_gcp_scene

        args = dict(args)
        make_gcp_scene(args.pop("seed"), **args).gcps.to_csv(path)
    return path


def terminal_text(report: object) -> str:
    """``print_calibration_report`` on a plain 140-column console."""
    from rich.console import Console

    from trafficgeo.report.terminal import print_calibration_report

    buf = io.StringIO()
    print_calibration_report(report, Console(file=buf, width=140, force_terminal=False, color_system=None))
    return buf.getvalue()


def main(out: Path) -> None:
    from trafficgeo.calibration import read_gcps, run_calibration

    out.mkdir(parents=True, exist_ok=True)
    for name, (size, crs, _args) in SCENES.items():
        path = gcp_csv(name, out)
        gcps = replace(read_gcps(path, crs=crs), source=path.name)  # messages name the file, not its folder
        run = run_calibration(gcps, size, camera_path=out / f"{name}_camera.json",
                              report_path=out / f"{name}_report.json")
        (out / f"{name}_terminal.txt").write_text(terminal_text(run.report), encoding="utf-8")
        print(f"wrote {name}: {gcps.n} GCPs")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else HERE / "calibration")
