"""Camera intrinsics in OpenCV FileStorage files (YAML, also XML/JSON), as OpenCV's calibration tools write.

Reading accepts the key names in common use (first found wins):

    camera matrix   camera_matrix, cameraMatrix, K, M, M1
    distortion      distortion_coefficients, dist_coeffs, distCoeffs, dist, D, D1  (optional; missing -> zeros)
    image size      image_width + image_height, or image_size / imageSize / resolution = [W, H]   (optional)
    reprojection    avg_reprojection_error, rms, reprojection_error                                (optional)

Matrices may be ``!!opencv-matrix`` nodes, ROS-style ``{rows, cols, data}`` maps or plain (nested) sequences.
Distortion is the OpenCV 5-term model ``[k1, k2, p1, p2, k3]``; 4 values get ``k3 = 0``; 8/12/14 values
(rational, thin-prism, tilted models) and fisheye/equidistant files are refused.

Writing produces the layout of OpenCV's ``calibration`` sample (``image_width``, ``image_height``,
``camera_matrix``, ``distortion_coefficients`` as 5x1, ``avg_reprojection_error``), atomically. FileStorage
prints doubles with 17 significant digits, so a write/read round trip is exact to the bit.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from trafficgeo.errors import InputError

CAMERA_MATRIX_KEYS = ("camera_matrix", "cameraMatrix", "K", "M", "M1")
DISTORTION_KEYS = ("distortion_coefficients", "dist_coeffs", "distCoeffs", "dist", "D", "D1")
IMAGE_SIZE_KEYS = ("image_size", "imageSize", "resolution")
RMS_KEYS = ("avg_reprojection_error", "rms", "reprojection_error")
# distortion_model values (ROS camera_info) that mean the OpenCV 5-term model
_PLUMB_BOB = {"plumb_bob", "radtan", "radial-tangential", "pinhole", "opencv", "brown", "brown_conrady"}
_WRITE_SUFFIXES = (".yml", ".yaml", ".xml", ".json")
_FIX_HINT = "fix the file or recalibrate the camera with a chessboard"


def _check_K(K: np.ndarray, where: str) -> None:
    """Raise InputError unless K is a finite 3x3 pinhole matrix [[fx, s, cx], [0, fy, cy], [0, 0, 1]]."""
    if K.shape != (3, 3):
        raise InputError(
            f"{where}: the camera matrix has shape {K.shape}, expected 3x3 [[fx, s, cx], [0, fy, cy], "
            f"[0, 0, 1]]; {_FIX_HINT}"
        )
    if not np.all(np.isfinite(K)):
        raise InputError(f"{where}: the camera matrix has non-finite values (NaN or inf); {_FIX_HINT}")
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        raise InputError(
            f"{where}: focal lengths must be positive, got fx={K[0, 0]:g}, fy={K[1, 1]:g}; {_FIX_HINT}"
        )
    bottom = np.array([K[1, 0], K[2, 0], K[2, 1], K[2, 2] - 1.0])
    if np.max(np.abs(bottom)) > 1e-9:
        raise InputError(
            f"{where}: the camera matrix must have the form [[fx, s, cx], [0, fy, cy], [0, 0, 1]], "
            f"got rows 2-3 = {K[1].tolist()}, {K[2].tolist()}; {_FIX_HINT}"
        )


def _as_dist(d: np.ndarray, where: str) -> np.ndarray:
    """Distortion as exactly 5 float64 values; 4 -> padded with k3 = 0."""
    if d.ndim > 2 or (d.ndim == 2 and min(d.shape) != 1):
        raise InputError(
            f"{where}: distortion coefficients have shape {d.shape}, expected a vector "
            f"[k1, k2, p1, p2, k3]; {_FIX_HINT}"
        )
    d = d.reshape(-1)
    if d.size > 5:
        raise InputError(
            f"{where}: {d.size} distortion coefficients, but only the 5-term OpenCV model "
            f"[k1, k2, p1, p2, k3] is supported; recalibrate without CALIB_RATIONAL_MODEL / "
            f"thin-prism / tilted flags"
        )
    if d.size < 4:
        raise InputError(
            f"{where}: {d.size} distortion coefficients, expected 4 or 5 [k1, k2, p1, p2(, k3)]; {_FIX_HINT}"
        )
    if not np.all(np.isfinite(d)):
        raise InputError(f"{where}: distortion coefficients have non-finite values (NaN or inf); {_FIX_HINT}")
    if d.size == 4:
        d = np.concatenate([d, [0.0]])
    return d


@dataclass(frozen=True, eq=False)
class Intrinsics:
    """Pinhole intrinsics with OpenCV 5-term distortion.

    Attributes:
        K: (3, 3) float64 ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` in pixels; pixel (0, 0) is the centre of
            the top-left pixel.
        dist: (5,) float64 ``[k1, k2, p1, p2, k3]`` (4 values are accepted and padded with ``k3 = 0``).
        image_size: ``(width, height)`` of the images the intrinsics belong to, if known.
        rms_px: reprojection RMS [px] of the calibration that produced them, if known.

    The arrays are float64 copies of what was given. ``eq=False`` (arrays have no single truth value): compare
    the fields with ``np.array_equal``.
    """

    K: np.ndarray
    dist: np.ndarray
    image_size: tuple[int, int] | None
    rms_px: float | None = None

    def __post_init__(self) -> None:
        where = "Intrinsics"
        try:
            K = np.array(self.K, dtype=np.float64)
            dist = np.array(self.dist, dtype=np.float64)
        except (TypeError, ValueError):
            raise InputError(f"{where}: K and dist must be numeric arrays") from None
        _check_K(K, f"{where}.K")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "dist", _as_dist(dist, f"{where}.dist"))
        if self.image_size is not None:
            size = tuple(self.image_size)
            if len(size) != 2 or not all(_is_positive_int(v) for v in size):
                raise InputError(
                    f"{where}: image_size must be (width, height) as two positive integers, "
                    f"got {self.image_size!r}"
                )
            object.__setattr__(self, "image_size", (int(size[0]), int(size[1])))
        if self.rms_px is not None:
            rms = float(self.rms_px)
            if not (math.isfinite(rms) and rms >= 0):
                raise InputError(f"{where}: rms_px must be a finite number >= 0 or None, got {self.rms_px!r}")
            object.__setattr__(self, "rms_px", rms)

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])


def _is_positive_int(v: Any) -> bool:
    if isinstance(v, bool | np.bool_):
        return False
    try:
        f = float(v)
    except (TypeError, ValueError):
        return False
    return math.isfinite(f) and f > 0 and f == int(f)


# ---------------------------------------------------------------------------------------------- reading
def node_scalar(node: Any) -> float | None:
    """The number in a scalar node, or None if the node is not a number."""
    if node.isInt() or node.isReal():
        return float(node.real())
    return None


def _seq_values(node: Any, where: str) -> np.ndarray:
    """A (nested) sequence of numbers as a 1-D or 2-D float64 array."""
    rows: list[Any] = []
    for i in range(node.size()):
        item = node.at(i)
        if item.isSeq():
            rows.append(_seq_values(item, where))
        else:
            v = node_scalar(item)
            if v is None:
                raise InputError(f"{where}: element {i} is not a number; {_FIX_HINT}")
            rows.append(v)
    if rows and all(isinstance(r, np.ndarray) for r in rows):
        if any(r.ndim != 1 or r.size != rows[0].size for r in rows):
            raise InputError(f"{where}: the rows of the matrix have different lengths; {_FIX_HINT}")
        return np.array(rows, dtype=np.float64)
    if any(isinstance(r, np.ndarray) for r in rows):
        raise InputError(f"{where}: mixes numbers and lists; {_FIX_HINT}")
    return np.array(rows, dtype=np.float64)


def node_array(node: Any, where: str) -> np.ndarray:
    """The array in a matrix node: ``!!opencv-matrix``, ``{rows, cols, data}`` map or a (nested) sequence."""
    if node.isMap():
        keys = set(node.keys())
        if "dt" in keys:
            try:
                mat = node.mat()
            except cv2.error:
                mat = None
            if mat is None:
                raise InputError(
                    f"{where}: unreadable matrix (check rows, cols, dt and the number of data "
                    f"values); {_FIX_HINT}"
                )
            return np.asarray(mat, dtype=np.float64)
        if "data" in keys:
            data = node.getNode("data")
            if not data.isSeq():
                raise InputError(f"{where}: 'data' must be a list of numbers; {_FIX_HINT}")
            arr = _seq_values(data, where).reshape(-1)
            rows, cols = node_scalar(node.getNode("rows")), node_scalar(node.getNode("cols"))
            if rows is not None and cols is not None:
                if rows * cols != arr.size:
                    raise InputError(
                        f"{where}: rows x cols = {rows:g} x {cols:g} but data has {arr.size} values; "
                        f"{_FIX_HINT}"
                    )
                arr = arr.reshape(int(rows), int(cols))
            return arr
        raise InputError(f"{where}: a map without 'data'; expected a matrix; {_FIX_HINT}")
    if node.isSeq():
        return _seq_values(node, where)
    raise InputError(f"{where}: expected a matrix, found a single value or text; {_FIX_HINT}")


def first_key(fs: Any, keys: tuple[str, ...]) -> tuple[str, Any] | None:
    for key in keys:
        node = fs.getNode(key)
        if not node.empty() and not node.isNone():
            return key, node
    return None


def _positive_int(node: Any, where: str) -> int:
    v = node_scalar(node)
    if v is None or not _is_positive_int(v):
        raise InputError(f"{where}: must be a positive integer number of pixels; {_FIX_HINT}")
    return int(v)


def _read_image_size(fs: Any, src: str) -> tuple[int, int] | None:
    w_node, h_node = fs.getNode("image_width"), fs.getNode("image_height")
    has_w, has_h = not w_node.empty(), not h_node.empty()
    if has_w or has_h:
        if not (has_w and has_h):
            missing = "image_height" if has_w else "image_width"
            raise InputError(
                f"{src}: key '{missing}' is missing (the file has only one of image_width / "
                f"image_height); add it or remove both"
            )
        return (
            _positive_int(w_node, f"{src}, key 'image_width'"),
            _positive_int(h_node, f"{src}, key 'image_height'"),
        )
    found = first_key(fs, IMAGE_SIZE_KEYS)
    if found is None:
        return None
    key, node = found
    where = f"{src}, key '{key}'"
    arr = node_array(node, where).reshape(-1) if (node.isSeq() or node.isMap()) else np.array([])
    if arr.size != 2 or not all(_is_positive_int(v) for v in arr):
        raise InputError(f"{where}: expected [width, height] as two positive integers; {_FIX_HINT}")
    return int(arr[0]), int(arr[1])


def cv_error_detail(exc: BaseException) -> str:
    """The useful part of an OpenCV error, on one line ("file(line): what is wrong" for parse errors)."""
    cause = exc.__cause__ or exc.__context__ or exc
    text = " ".join(str(cause).split())
    m = re.search(r"in function '(.+)'$", text)
    if (
        m and "(-212:" in text
    ):  # cv::Error::StsParseError: OpenCV puts "file(line): message" in the function slot
        return m.group(1)
    m = re.search(r"error: (.+)$", text)
    return (m.group(1) if m else text)[:200]


MAX_STORAGE_BYTES = 16 << 20  # a camera file is a few kB
MAX_NESTING = 64  # levels of [ ], { } or XML elements; a camera file needs 3


def check_storage_file(path: Path) -> None:
    """Refuse a FileStorage file that OpenCV's parser cannot take safely: larger than :data:`MAX_STORAGE_BYTES`,
    or nested deeper than :data:`MAX_NESTING` (OpenCV's recursive parser overflows its stack and the process dies
    at about 100,000 levels), by brackets, XML elements or YAML indentation (2 columns a level)."""
    if path.stat().st_size > MAX_STORAGE_BYTES:
        raise InputError(f"{path}: {path.stat().st_size / 1e6:.0f} MB is too large for a camera file; give an OpenCV "
                         ".yml with camera_matrix")
    text = path.read_bytes()
    depth = deepest = 0
    for ch in text.translate(None, _NOT_NESTING):
        depth += 1 if ch in b"[{" else -1
        deepest = max(deepest, depth)
    indent = max((len(line) - len(line.lstrip(b" ")) for line in text.splitlines()), default=0)
    if max(deepest, _xml_depth(text) if b"<" in text else 0, indent // 2) > MAX_NESTING:
        raise InputError(f"{path}: nested more than {MAX_NESTING} levels deep, which no camera file is; give an "
                         "OpenCV .yml with camera_matrix")


_NOT_NESTING = bytes(b for b in range(256) if b not in b"[]{}")


def _xml_depth(text: bytes) -> int:
    """The deepest nesting of XML elements in ``text`` (0 for a file without tags)."""
    import re

    depth = deepest = 0
    for m in re.finditer(rb"<(/?)[A-Za-z_][^>]*?(/?)>", text):
        if m.group(1):
            depth -= 1
        elif not m.group(2):
            depth += 1
            deepest = max(deepest, depth)
    return deepest


def read_intrinsics_yaml(path: str | os.PathLike[str]) -> Intrinsics:
    """Read camera intrinsics from an OpenCV FileStorage file (``.yml``/``.yaml``, also ``.xml``/``.json``).

    Raises:
        InputError: missing or unparsable file, no camera matrix, wrong shapes, non-finite values,
            fx or fy <= 0, more than 5 distortion coefficients or a fisheye model. The message names the file
            and the key.
    """
    p = Path(path)
    src = str(p)
    if not p.exists():
        raise InputError(
            f"{src}: intrinsics file not found; check the path (an OpenCV .yml with camera_matrix)"
        )
    if not p.is_file():
        raise InputError(f"{src}: is not a file; give an OpenCV .yml with camera_matrix")
    check_storage_file(p)
    try:
        fs = cv2.FileStorage(src, cv2.FILE_STORAGE_READ)
        opened = fs.isOpened()
        root = fs.root() if opened else None
        is_map = root is not None and root.isMap()
    except (cv2.error, SystemError) as exc:  # a parse error surfaces as SystemError in the OpenCV 5 bindings
        detail = cv_error_detail(exc)
        raise InputError(
            f"{src}: not a readable OpenCV FileStorage YAML/XML/JSON file ({detail}); give an OpenCV "
            f".yml with camera_matrix"
        ) from None
    if not opened:
        raise InputError(
            f"{src}: cannot be opened by OpenCV FileStorage (permissions or format); give an OpenCV "
            f".yml with camera_matrix"
        )
    try:
        if not is_map:
            raise InputError(f"{src}: empty or not a key/value file; give an OpenCV .yml with camera_matrix")
        found = first_key(fs, CAMERA_MATRIX_KEYS)
        if found is None:
            raise InputError(
                f"{src}: no camera matrix (looked for keys {', '.join(CAMERA_MATRIX_KEYS)}); "
                f"give an OpenCV calibration .yml with camera_matrix"
            )
        key, node = found
        where = f"{src}, key '{key}'"
        K = node_array(node, where)
        if K.size == 9 and K.ndim == 1:  # a flat list of 9 values, row-major
            K = K.reshape(3, 3)
        _check_K(K, where)

        model_node = fs.getNode("distortion_model")
        if model_node.isString():
            model = model_node.string().strip()
            if model.lower() not in _PLUMB_BOB:
                raise InputError(
                    f"{src}, key 'distortion_model': '{model}' is not supported, only the OpenCV "
                    f"5-term model (plumb_bob) [k1, k2, p1, p2, k3]; recalibrate with it"
                )
        found = first_key(fs, DISTORTION_KEYS)
        if found is None:
            dist = np.zeros(5)
        else:
            dkey, dnode = found
            dwhere = f"{src}, key '{dkey}'"
            dist = _as_dist(node_array(dnode, dwhere), dwhere)

        image_size = _read_image_size(fs, src)

        rms: float | None = None
        found = first_key(fs, RMS_KEYS)
        if found is not None:
            rkey, rnode = found
            rms = node_scalar(rnode)
            if rms is None or not (math.isfinite(rms) and rms >= 0):
                raise InputError(f"{src}, key '{rkey}': must be a finite number >= 0 (pixels); {_FIX_HINT}")
    finally:
        fs.release()
    return Intrinsics(K=K, dist=dist, image_size=image_size, rms_px=rms)


# ---------------------------------------------------------------------------------------------- writing
def write_intrinsics_yaml(path: str | os.PathLike[str], intr: Intrinsics) -> None:
    """Write ``intr`` to an OpenCV FileStorage file atomically (temporary file beside it, then os.replace).

    The format follows the suffix: ``.yml``/``.yaml`` (YAML), ``.xml`` or ``.json``. Keys: ``image_width``,
    ``image_height`` (if known), ``camera_matrix`` (3x3), ``distortion_coefficients`` (5x1),
    ``avg_reprojection_error`` (if known). Values are written with 17 significant digits: reading back is
    exact.
    """
    p = Path(path)
    if p.suffix.lower() not in _WRITE_SUFFIXES:
        raise InputError(
            f"{p}: unsupported intrinsics file suffix '{p.suffix}'; use .yml (or .yaml, .xml, .json)"
        )
    if p.is_dir():
        raise InputError(f"{p}: is a directory; give a file name such as camera_intrinsics.yml")
    if not isinstance(intr, Intrinsics):
        raise TypeError(f"write_intrinsics_yaml expects an Intrinsics, got {type(intr).__name__}")
    def write(fs: cv2.FileStorage) -> None:
        if p.suffix.lower() != ".json":  # OpenCV would write a // comment, which is not JSON
            fs.writeComment("camera intrinsics (OpenCV pinhole + [k1, k2, p1, p2, k3]), written by trafficgeo")
        if intr.image_size is not None:
            fs.write("image_width", int(intr.image_size[0]))
            fs.write("image_height", int(intr.image_size[1]))
        fs.write("camera_matrix", np.ascontiguousarray(intr.K, dtype=np.float64))
        fs.write("distortion_coefficients", np.ascontiguousarray(intr.dist, dtype=np.float64).reshape(5, 1))
        if intr.rms_px is not None:
            fs.write("avg_reprojection_error", float(intr.rms_px))

    write_storage(p, write)


def write_storage(path: Path, write: Callable[[cv2.FileStorage], None]) -> None:
    """Write an OpenCV FileStorage file (its format from ``path``'s suffix) atomically: ``write(fs)`` fills it in
    memory and Python writes the text, so that a disk that refuses it (full) raises
    :class:`~trafficgeo.errors.OutputError` (OpenCV's own file writer ignores failed writes: a truncated file
    looked written)."""
    from trafficgeo.io.atomic import write_text_atomic

    fs = cv2.FileStorage(f"storage{path.suffix.lower()}", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
    try:
        write(fs)
    finally:
        text = fs.releaseAndGetString()
    try:
        write_text_atomic(path, text)
    except OSError as exc:
        raise InputError(f"{path}: cannot be written ({exc.strerror or exc}); check that the folder exists and is "
                         "writable") from None
