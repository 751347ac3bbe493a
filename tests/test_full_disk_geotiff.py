"""A full disk while a GeoTIFF is written (issue 43): libtiff reports a refused write only as a message, so
``ortho-from-image``, ``accuracy`` and ``dem`` said "wrote ..." with exit 0 and left a truncated GeoTIFF at the final
path. Each now stops with one line and exit code 1 (the README's code for an output the disk would not take) and
leaves no file behind. The full disk is a file-size limit (RLIMIT_FSIZE, SIGXFSZ ignored: writes past it fail with
EFBIG, as writes to a full disk fail with ENOSPC) in the command's own process."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from trafficgeo.camera.io import write_camera_json
from trafficgeo.camera.model import Camera

DATA = Path(__file__).parent / "data" / "autzen"
SRC = Path(__file__).resolve().parents[1] / "src"
LIMIT = 16 * 1024  # bytes: below every GeoTIFF written here

LIMITED = """
    import resource, signal, sys
    limit = int(sys.argv[1])
    if limit:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    from trafficgeo.cli import main
    main(sys.argv[2:])
"""


def _run(limit: int, *args: object) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(SRC), "PYTHONDONTWRITEBYTECODE": "1"}
    return subprocess.run([sys.executable, "-c", textwrap.dedent(LIMITED), str(limit), *map(str, args)], env=env,
                          capture_output=True, text=True, timeout=600)


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
    done = _run(0, *COMMANDS[command](tmp_path, room))
    assert done.returncode == 0, done.stderr
    assert room.stat().st_size > LIMIT  # the limit does cut this file
    full = tmp_path / "full"
    full.mkdir()
    cut = _run(LIMIT, *COMMANDS[command](tmp_path, full / "out.tif"))
    assert cut.returncode == 1, (cut.stdout, cut.stderr)
    lines = [ln for ln in cut.stderr.splitlines() if ln.startswith("trafficgeo")]
    assert len(lines) == 1 and "could not write" in lines[0] and "out.tif" in lines[0], cut.stderr
    assert "Traceback" not in cut.stderr and "wrote" not in cut.stdout
    assert list(full.iterdir()) == []  # neither the GeoTIFF nor a temporary file
