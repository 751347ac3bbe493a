"""A small generated video for the video tests: two cars (40 x 20 px) crossing a 320 x 180 frame at 90 px/s on a
noisy grey road, encoded as H.264."""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import av
import numpy as np

W, H = 320, 180


def road(rng: np.random.Generator, *, green: float = 0.0) -> np.ndarray:
    """The empty scene (float32 BGR): grey 110 with per-pixel noise, ``green`` added to the green band."""
    bg = np.full((H, W, 3), 110, np.float32) + rng.normal(0, 6, (H, W, 1))
    bg[:, :, 1] += green
    return bg


def two_cars(bg: np.ndarray, t: float, rng: np.random.Generator, rows: tuple[int, int]) -> np.ndarray:
    """The frame at ``t`` s: a red and a yellow car at image rows ``rows`` driving right at 90 px/s (wrapping
    round), plus 1.5 grey levels of noise (uint8 BGR)."""
    img = bg.copy()
    for x0, y0, colour in ((20.0, rows[0], (40, 40, 200)), (200.0, rows[1], (220, 200, 40))):
        x = round((x0 + 90.0 * t) % (W + 60) - 60)
        a, b = max(x, 0), min(x + 40, W)
        if b > a:
            img[y0:y0 + 20, a:b] = colour
    img += rng.normal(0, 1.5, (H, W, 1))
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def write_two_car_video(path: Path, fps: int, seconds: float, *, rows: tuple[int, int], seed: int,
                        green: float = 0.0, faststart: bool = False) -> Path:
    """Encode ``seconds`` of :func:`two_cars` at ``fps`` to ``path`` (MP4; ``faststart`` puts the index first)."""
    rng = np.random.default_rng(seed)
    bg = road(rng, green=green)
    kw = {"format": "mp4", "options": {"movflags": "faststart"}} if faststart else {}
    with av.open(str(path), "w", **kw) as c:
        s = c.add_stream("libx264", rate=Fraction(fps))
        s.width, s.height, s.pix_fmt = W, H, "yuv420p"
        s.options = {"preset": "veryfast", "crf": "18"}
        for k in range(round(fps * seconds)):
            for p in s.encode(av.VideoFrame.from_ndarray(two_cars(bg, k / fps, rng, rows), format="bgr24")):
                c.mux(p)
        for p in s.encode():
            c.mux(p)
    return path
