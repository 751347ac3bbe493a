"""Video commands: frame (a thin wrapper over :mod:`trafficgeo.video.reader`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from trafficgeo.cli.app import app, console
from trafficgeo.errors import InputError

FRAME_SUFFIXES = {".png": ".png", ".jpg": ".jpg", ".jpeg": ".jpg"}


@app.command()
def frame(
    video: Annotated[Path, typer.Argument(help="video file (MP4, MOV, MKV, AVI, ...)")],
    at: Annotated[float, typer.Option("--at", help="time of the frame (s from the start of the video); the "
                                      "frame shown at that time is written")] = 0.0,
    output: Annotated[Path | None, typer.Option("--output", "-o", help="image to write (.png or .jpg)")] = None,
    info: Annotated[bool, typer.Option("--info", help="only print the video's properties")] = False,
) -> None:
    """Write the frame shown at a time as an image (upright, as a player shows it) to pick GCPs on.

    Also prints the video's size, frame rate (and whether it varies), duration and rotation, and the frame's
    exact time.
    """
    import math

    from trafficgeo.video.reader import read_frame_at, video_info

    if not info:
        if output is None:
            raise InputError("frame: give the image to write with -o frame.png (or --info to only print the "
                             "video's properties)")
        if output.suffix.lower() not in FRAME_SUFFIXES:
            raise InputError(f"-o {output}: unknown image format '{output.suffix}'; use .png (lossless, best for "
                             "picking GCPs) or .jpg")
        if not math.isfinite(at) or at < 0:
            raise InputError(f"--at {at:g} must be a time in seconds from the start of the video, >= 0")
    meta = video_info(video)
    picked = None if info else read_frame_at(video, at)
    console.print(f"video {video}", markup=False, highlight=False)
    console.print(f"  {meta.describe()}", markup=False, highlight=False)
    if picked is None or output is None:
        return
    _write_image(output, picked.image)
    console.print(f"frame {picked.index} at {picked.time_s:.6f} s (asked {at:g} s)", highlight=False)
    console.print(f"wrote {output}", markup=False, highlight=False)


def _write_image(path: Path, image) -> None:
    """PNG or JPEG (quality 95) by suffix, written atomically."""
    import cv2

    from trafficgeo.io.atomic import atomic_path

    ext = FRAME_SUFFIXES[path.suffix.lower()]
    params = [cv2.IMWRITE_JPEG_QUALITY, 95] if ext == ".jpg" else [cv2.IMWRITE_PNG_COMPRESSION, 3]
    ok, buf = cv2.imencode(ext, image, params)
    if not ok:
        raise InputError(f"-o {path}: OpenCV could not encode the frame as {ext}")
    with atomic_path(path) as tmp:
        tmp.write_bytes(buf.tobytes())
