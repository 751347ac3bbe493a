"""Runtimes for ONNX detectors: which library runs the network, chosen per machine and model by a timed probe.

A :class:`Backend` runs the network on prepared inputs (``run(feeds) -> list[np.ndarray]``, the outputs in the order
asked for); the pre- and post-processing stay in :class:`~trafficgeo.video.detectors.onnx.OnnxDetector`. Candidates:
onnxruntime on the CPU (always, the reference), onnxruntime's OpenVINO and CUDA execution providers when
``onnxruntime.get_available_providers()`` lists them, and the OpenVINO runtime (``pip install trafficgeo[openvino]``)
when it imports; for a model with an INT8 version (the built-in NanoDet's Conv nodes in INT8, built by
``tools/nanodet/quantize_int8.py`` and kept only within 0.01 F1 of the float model on the hand-labelled real
frames), that version on onnxruntime CPU and on OpenVINO too.

:func:`choose_backend` times each on a fixed synthetic input (:data:`PROBE_WARMUP` runs, then :data:`PROBE_PASSES`;
the median), refuses one whose outputs differ from onnxruntime CPU's by more than :data:`PROBE_ATOL` +
:data:`PROBE_RTOL` x the largest reference value of that output (e.g. a reduced precision gone wrong), and picks the
fastest left. The choice is cached as JSON in :func:`cache_dir` (``TRAFFICGEO_CACHE_DIR``, else
``$XDG_CACHE_HOME/trafficgeo``, else ``~/.cache/trafficgeo``), one file per key (model sha256, library versions,
CPU model and flags, threads, candidates); a damaged file is probed again and rewritten.
"""

from __future__ import annotations

import hashlib
import json
import os
import stat
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np

from trafficgeo.errors import InputError, OutputError
from trafficgeo.io.atomic import write_json_atomic
from trafficgeo.io.json_text import loads_json

BACKENDS = ("auto", "onnxruntime", "onnxruntime-int8", "openvino")  # what a user may ask for (``backend``)
ORT_CPU, ORT_OPENVINO, ORT_CUDA, OPENVINO = "onnxruntime", "onnxruntime-openvino-ep", "onnxruntime-cuda", "openvino"
ORT_INT8, OPENVINO_INT8 = "onnxruntime-int8", "openvino-int8"  # the model's INT8 version on these runtimes
PROBE_WARMUP = 1  # runs before timing (graph compilation, caches)
PROBE_PASSES = 5  # timed runs per backend (the median is kept)
PROBE_ATOL = 0.02  # agreement with onnxruntime CPU on the probe input: |diff| <= ATOL + RTOL * max|reference|
PROBE_RTOL = 0.02
INT8_ATOL = 0.05  # an INT8 version against the float model (NanoDet, real frame: up to 0.07 + 0.15 x max)
INT8_RTOL = 0.25
CACHE_VERSION = 1
OPENVINO_HINT = "pip install trafficgeo[openvino]"


class Backend(Protocol):
    """Runs a network: ``run(feeds)`` (input name -> array) -> its outputs in the order it was built with."""

    name: str

    def run(self, feeds: Mapping[str, np.ndarray]) -> list[np.ndarray]: ...


class OrtBackend:
    """onnxruntime ``session`` (any providers), outputs ``out_names`` in that order."""

    def __init__(self, session: object, out_names: Sequence[str], name: str = ORT_CPU) -> None:
        self.session, self.out_names, self.name = session, list(out_names), name

    def run(self, feeds: Mapping[str, np.ndarray]) -> list[np.ndarray]:
        return self.session.run(self.out_names, dict(feeds))


class OpenVinoBackend:
    """The OpenVINO runtime on the CPU (``INFERENCE_NUM_THREADS`` = ``threads``; ``config``: more of its properties,
    e.g. ``{"INFERENCE_PRECISION_HINT": "f32"}``), outputs ``out_names`` in that order (an InputError when the
    compiled model lacks one of them)."""

    name = OPENVINO

    def __init__(self, model_path: str | Path, out_names: Sequence[str], threads: int,
                 config: Mapping[str, str] | None = None) -> None:
        import openvino as ov

        self.compiled = ov.Core().compile_model(str(model_path), "CPU",
                                                {"INFERENCE_NUM_THREADS": int(threads), **dict(config or {})})
        have = {n for port in self.compiled.outputs for n in port.get_names()}
        missing = [n for n in out_names if n not in have]
        if missing:
            raise InputError(f"{model_path}: OpenVINO's compiled model has no output {', '.join(missing)} (it has "
                             f"{', '.join(sorted(have))}); use backend onnxruntime", parameters=("backend",))
        self.ports = [self.compiled.output(n) for n in out_names]
        self.request = self.compiled.create_infer_request()

    def run(self, feeds: Mapping[str, np.ndarray]) -> list[np.ndarray]:
        result = self.request.infer(dict(feeds))
        return [np.array(result[p]) for p in self.ports]


def openvino_version() -> str | None:
    """The installed OpenVINO runtime's version, or None when it does not import."""
    try:
        import openvino as ov
    except ImportError:
        return None
    return str(getattr(ov, "__version__", None) or ov.get_version())


def check_backend(backend: str) -> str:
    """``backend`` checked: one of :data:`BACKENDS` (lower case), and importable; a one-line InputError naming
    ``backend`` otherwise."""
    key = str(backend).strip().lower()
    if key not in BACKENDS:
        raise InputError(f"backend {backend!r}: use one of {', '.join(BACKENDS)}", parameters=("backend",))
    if key == OPENVINO and openvino_version() is None:
        raise InputError(f"backend openvino: the OpenVINO runtime is not installed; {OPENVINO_HINT}, or use backend "
                         "auto or onnxruntime", parameters=("backend",))
    return key


# ---------------------------------------------------------------------------------------------------- probe
@dataclass(frozen=True)
class BackendChoice:
    """What runs the network: ``backend`` (a name such as ``"openvino"``), its median ``ms_per_pass`` on the probe
    input of ``probe_input_hw`` (h, w px), the others' (``times_ms``), those refused and why (``refused``), and
    whether it came from the cache (``cached``)."""

    backend: str
    ms_per_pass: float
    times_ms: dict[str, float]
    refused: dict[str, str] = field(default_factory=dict)
    probe_input_hw: tuple[int, int] = (0, 0)
    cached: bool = False

    def to_dict(self) -> dict[str, object]:
        doc = asdict(self)
        doc["probe_input_hw"] = list(self.probe_input_hw)
        return doc

    def summary(self) -> str:
        """One line for the terminal."""
        others = ", ".join(f"{k} {v:.1f} ms" for k, v in self.times_ms.items() if k != self.backend)
        refused = "; ".join(f"{k} refused: {v}" for k, v in self.refused.items())
        how = "cached probe" if self.cached else "probed"
        return (f"backend: {self.backend}, {self.ms_per_pass:.1f} ms per pass at {self.probe_input_hw[1]}x"
                f"{self.probe_input_hw[0]} ({how}{'; ' + others if others else ''}{'; ' + refused if refused else ''})")


def _time_ms(backend: Backend, feeds: Mapping[str, np.ndarray]) -> tuple[float, list[np.ndarray]]:
    out: list[np.ndarray] = []
    for _ in range(PROBE_WARMUP):
        out = backend.run(feeds)
    times = []
    for _ in range(PROBE_PASSES):
        t0 = time.perf_counter()
        out = backend.run(feeds)
        times.append(1e3 * (time.perf_counter() - t0))
    return float(np.median(times)), [np.asarray(o, dtype=np.float32) for o in out]


def disagreement(reference: Sequence[np.ndarray], other: Sequence[np.ndarray], atol: float = PROBE_ATOL,
                 rtol: float = PROBE_RTOL) -> str | None:
    """Why ``other``'s outputs do not agree with ``reference``'s (shapes, or a difference beyond ``atol`` + ``rtol``
    x max|reference| of that output), or None when they agree."""
    if len(reference) != len(other):
        return f"{len(other)} outputs, not {len(reference)}"
    for k, (a, b) in enumerate(zip(reference, other, strict=True)):
        if a.shape != b.shape:
            return f"output {k} has shape {list(b.shape)}, not {list(a.shape)}"
        diff = float(np.max(np.abs(a - b))) if a.size else 0.0
        bound = atol + rtol * (float(np.max(np.abs(a))) if a.size else 0.0)
        if not diff <= bound:
            return f"output {k} differs by up to {diff:.3g} from onnxruntime CPU's (tolerance {bound:.3g})"
    return None


def probe(candidates: Mapping[str, Callable[[], Backend]], feeds: Mapping[str, np.ndarray],
          input_hw: tuple[int, int]) -> tuple[BackendChoice, dict[str, Backend]]:
    """Time each of ``candidates`` (name -> a function building it; the first is the reference, onnxruntime CPU)
    on ``feeds``; the fastest that builds and agrees with the reference (:func:`disagreement`; names ending in
    ``-int8`` within :data:`INT8_ATOL` + :data:`INT8_RTOL`) wins. Returns the choice and the backends built (name ->
    backend)."""
    built: dict[str, Backend] = {}
    times: dict[str, float] = {}
    refused: dict[str, str] = {}
    reference: list[np.ndarray] | None = None
    for name, make in candidates.items():
        try:
            backend = make()
            ms, out = _time_ms(backend, feeds)
        except Exception as exc:  # a runtime that fails to build or run is refused, with its reason
            if reference is None:
                raise
            refused[name] = " ".join(str(exc).split())[:160]
            continue
        times[name] = round(ms, 3)
        if reference is None:
            reference = out
        else:
            why = (disagreement(reference, out, INT8_ATOL, INT8_RTOL) if name.endswith("-int8")
                   else disagreement(reference, out))
            if why is not None:
                refused[name] = why
                continue
        built[name] = backend
    best = min(built, key=lambda n: times[n])
    return BackendChoice(best, times[best], times, refused, (int(input_hw[0]), int(input_hw[1]))), built


# ---------------------------------------------------------------------------------------------------- cache
def cache_dir() -> Path:
    """The user cache folder of trafficgeo: ``TRAFFICGEO_CACHE_DIR``, else ``$XDG_CACHE_HOME/trafficgeo``, else
    ``~/.cache/trafficgeo``."""
    own = os.environ.get("TRAFFICGEO_CACHE_DIR")
    if own:
        return Path(own)
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "trafficgeo"


def _cpuinfo() -> tuple[str, frozenset[str]] | None:
    """The CPU's model name and feature flags from /proc/cpuinfo; None where it cannot be read."""
    try:
        text = Path("/proc/cpuinfo").read_text(encoding="utf-8", errors="replace")
    except OSError:
        return None
    lines = text.splitlines()
    model = next((ln.split(":", 1)[1].strip() for ln in lines if ln.startswith("model name")), "")
    flags = next((ln.split(":", 1)[1].split() for ln in lines if ln.startswith(("flags", "Features")) and ":" in ln),
                 [])
    return model, frozenset(flags)


def cpu_signature() -> str:
    """The CPU's model name and SIMD flags (from /proc/cpuinfo; the platform's processor name elsewhere)."""
    info = _cpuinfo()
    if info is None:
        import platform

        return platform.processor() or platform.machine()
    model, flags = info
    simd = sorted(f for f in flags if f.startswith(("avx", "amx", "sse4", "fma", "f16c", "asimd", "sve")))
    return f"{model} [{' '.join(simd)}]"


VNNI_FLAGS = frozenset({"avx512_vnni", "avx_vnni", "amx_int8"})  # x86 8-bit dot products that do not saturate


def cpu_flags() -> frozenset[str]:
    """This CPU's feature flags (from /proc/cpuinfo; empty where it cannot be read)."""
    info = _cpuinfo()
    return info[1] if info is not None else frozenset()


def int8_saturation(flags: frozenset[str] | None = None) -> str | None:
    """Why an INT8 model should not run on this CPU, or None. An x86 CPU without VNNI (``flags``: its feature flags,
    default this one's) multiplies 8-bit values with instructions whose 16-bit intermediate sums saturate, so a
    quantized network loses accuracy there (OpenVINO's documentation: the saturation issue; none on VNNI CPUs).
    Measured: the built-in detector's INT8 version on the NGSIM frames with 2 x 2 tiles, F1 0.741 -> 0.717 on an
    AVX2 CPU without VNNI, within 0.01 on AVX-512 VNNI."""
    flags = cpu_flags() if flags is None else flags
    if "sse2" not in flags or flags & VNNI_FLAGS:  # not x86 (or unknown), or VNNI
        return None
    return ("this CPU has no VNNI (avx512_vnni, avx_vnni): its 8-bit dot products saturate and the INT8 model "
            "finds fewer vehicles; the float model runs")


def probe_key(model_sha256: str, candidates: Sequence[str], threads: int, input_hw: tuple[int, int]) -> dict:
    """What a cached choice holds for: the model, the libraries' versions, the CPU, the threads, the candidates."""
    import onnxruntime as ort

    return {"version": CACHE_VERSION, "model_sha256": model_sha256, "onnxruntime": ort.__version__,
            "openvino": openvino_version(), "cpu": cpu_signature(), "threads": int(threads),
            "candidates": list(candidates), "input_hw": [int(input_hw[0]), int(input_hw[1])]}


def _cache_file(key: dict) -> Path:
    name = hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:20]
    return cache_dir() / f"backend-{name}.json"


MAX_CACHE_BYTES = 1 << 20  # a cached choice is a few hundred bytes


def load_choice(key: dict) -> BackendChoice | None:
    """The cached choice for ``key``, or None (no file, or a damaged or foreign one)."""
    path = _cache_file(key)
    try:
        # a regular file of a sane size only: a FIFO (or a device) put there would block the read for ever
        if not stat.S_ISREG(path.stat().st_mode) or path.stat().st_size > MAX_CACHE_BYTES:
            return None
        doc = loads_json(path.read_text(encoding="utf-8"))
        if doc.get("key") != key:
            return None
        c = doc["choice"]
        return BackendChoice(str(c["backend"]), float(c["ms_per_pass"]),
                             {str(k): float(v) for k, v in c["times_ms"].items()},
                             {str(k): str(v) for k, v in c.get("refused", {}).items()},
                             (int(c["probe_input_hw"][0]), int(c["probe_input_hw"][1])), cached=True)
    except (OSError, ValueError, KeyError, TypeError, IndexError, AttributeError):
        return None


def save_choice(key: dict, choice: BackendChoice) -> None:
    """Cache ``choice`` for ``key`` (atomically); a cache folder that cannot be written is left alone."""
    try:
        cache_dir().mkdir(parents=True, exist_ok=True)
        write_json_atomic(_cache_file(key), {"key": key, "choice": {**choice.to_dict(), "cached": False}})
    except (OSError, OutputError):  # OutputError: the disk full or read-only while writing
        pass


def choose_backend(candidates: Mapping[str, Callable[[], Backend]], feeds: Mapping[str, np.ndarray], *,
                   model_sha256: str, threads: int, input_hw: tuple[int, int]) -> tuple[BackendChoice, Backend]:
    """The backend to run with: the cached choice for this model, machine and candidates when there is one (only
    that backend is built), else :func:`probe` (and cache) them. Returns the choice and the built backend."""
    key = probe_key(model_sha256, list(candidates), threads, input_hw)
    cached = load_choice(key)
    if cached is not None and cached.backend in candidates:
        try:
            return cached, candidates[cached.backend]()
        except Exception:  # the cached runtime no longer builds: probe again
            pass
    choice, built = probe(candidates, feeds, input_hw)
    save_choice(key, choice)
    return choice, built[choice.backend]


__all__ = ["BACKENDS", "Backend", "BackendChoice", "OpenVinoBackend", "OrtBackend", "cache_dir", "check_backend",
           "choose_backend", "disagreement", "probe"]
