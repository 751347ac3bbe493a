"""A full disk while a GeoTIFF is written (issue 43): libtiff reports a refused write only as a message, so
``ortho-from-image``, ``accuracy`` and ``dem`` said "wrote ..." with exit 0 and left a truncated GeoTIFF at the final
path. Each now stops with one line and exit code 1 (the README's code for an output the disk would not take) and
leaves no file behind. The full disk is a file-size limit (RLIMIT_FSIZE, SIGXFSZ ignored: writes past it fail with
EFBIG, as writes to a full disk fail with ENOSPC) in the command's own process."""

from __future__ import annotations

from pathlib import Path

import pytest

from cli_support import invoke, invoke_on_a_full_disk
from trafficgeo.camera.io import write_camera_json
from trafficgeo.camera.model import Camera

DATA = Path(__file__).parent / "data" / "autzen"
LIMIT = 16 * 1024  # bytes: below every GeoTIFF written here


def _camera(tmp: Path) -> Path:
    cam = Camera.from_orientation((1280, 720), 1000.0, [500000.0, 5000000.0, 10.0], 0.0, 15.0, crs="EPSG:32633")
    write_camera_json(tmp / "camera.json", cam)
    return tmp / "camera.json"


COMMANDS = {
    "dem": lambda tmp, out: ["dem", DATA / "autzen_trim.laz", "--crs", "EPSG:2994", "--resolution", "1", "-o", out],
    "ortho-from-image": lambda tmp, out: ["ortho-from-image", DATA / "autzen_crop.jpg", "--crs", "EPSG:2994",
                                          "-o", out],
    "accuracy": lambda tmp, out: ["accuracy", _camera(tmp), "--surface", "0", "--cell", "0.5", "--max-distance",
                                  "60", "-o", out],
}


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_a_full_disk_while_writing_a_geotiff_is_one_line_exit_1(command: str, tmp_path: Path) -> None:
    room = tmp_path / "room" / "out.tif"
    code, _stdout, stderr = invoke(*COMMANDS[command](tmp_path, room))
    assert code == 0, stderr
    assert room.stat().st_size > LIMIT  # the limit does cut this file
    full = tmp_path / "full"
    full.mkdir()
    cut = invoke_on_a_full_disk(LIMIT, *COMMANDS[command](tmp_path, full / "out.tif"))
    assert cut.returncode == 1, (cut.stdout, cut.stderr)
    lines = [ln for ln in cut.stderr.splitlines() if ln.startswith("trafficgeo")]
    assert len(lines) == 1 and "could not write" in lines[0] and "out.tif" in lines[0], cut.stderr
    assert "Traceback" not in cut.stderr and "wrote" not in cut.stdout
    assert list(full.iterdir()) == []  # neither the GeoTIFF nor a temporary file
