"""The web server of ``trafficgeo gcp-ui``: a FastAPI app over one :class:`~trafficgeo.ui.session.Session`.

Endpoints (JSON unless said otherwise; every error is a 4xx answer ``{"detail": "<one-line message>"}``):

* ``GET /`` the page; ``GET /static/...`` its scripts, styles and the vendored Leaflet;
* ``GET /api/info`` sizes, sources, CRS, files; ``GET /api/frame.png``, ``GET /api/ortho.png`` the two images;
* ``GET /api/state`` the pairs; ``POST /api/pairs`` make one from ``{u, v, col, row[, id, role, z, sigma_px]}``
  (frame pixel, orthophoto position); ``PATCH /api/pairs/{id}`` move/rename/re-role it or set its ``z`` or
  ``z_auto``; ``DELETE /api/pairs/{id}``;
* ``GET /api/calibration`` the live calibration (a failure is a normal answer with ``status`` "failed");
* ``POST /api/gcps/save`` ``{name}``, ``POST /api/gcps/load`` ``{name}``, ``POST /api/camera/save`` ``{name}``:
  files in the working folder;
* ``POST /api/refine`` ``{}`` "Refine from orthophoto": the live calibration refined by registering the orthophoto
  to the frame (1-10 s, run off the event loop; see :mod:`trafficgeo.ui.refine`); ``POST /api/refine/save``
  ``{[name]}`` writes the accepted refined camera, its report and frame into the working folder.

Request bodies are limited to ``MAX_BODY_BYTES`` (counted as they arrive, chunked or not) and validated strictly
(no type coercion, no unknown keys, no NaN); changing requests must be JSON (``Content-Type: application/json``)
and same-origin, so other web sites cannot drive the app through the browser.
Frame pixels ``(u, v)``: ``(0, 0)`` = centre of the top-left pixel; orthophoto positions ``(col, row)``: ``(0, 0)``
= top-left corner of the full-resolution raster; world coordinates are computed here in float64.
"""

from __future__ import annotations

import logging
import socket
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Annotated, Any, Literal
from urllib.parse import urlsplit

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, JSONResponse, Response
from fastapi.staticfiles import StaticFiles
from pydantic import BaseModel, ConfigDict, Field
from starlette.concurrency import run_in_threadpool
from starlette.exceptions import HTTPException as StarletteHTTPException

from trafficgeo.errors import InputError
from trafficgeo.ui.refine import CAMERA_NAME as REFINED_CAMERA_NAME
from trafficgeo.ui.refine import SessionRefiner
from trafficgeo.ui.session import Session, SessionError

log = logging.getLogger(__name__)

STATIC_DIR = Path(__file__).parent / "static"
MAX_BODY_BYTES = 64 * 1024
_UNSAFE = {"POST", "PUT", "PATCH", "DELETE"}

Finite = Annotated[float, Field(allow_inf_nan=False)]
Sigma = Annotated[float, Field(gt=0, le=1000, allow_inf_nan=False)]
Name = Annotated[str, Field(min_length=1, max_length=255)]
PairId = Annotated[str, Field(min_length=1, max_length=40)]


class _Body(BaseModel):
    model_config = ConfigDict(strict=True, extra="forbid", allow_inf_nan=False)


class NewPair(_Body):
    """A new pair: frame pixel (u, v) [px, (0, 0) = centre of the top-left pixel] and orthophoto position
    (col, row) [full-resolution raster pixels, (0, 0) = top-left corner]; optional id, role, typed z, sigma."""

    u: Finite
    v: Finite
    col: Finite
    row: Finite
    id: PairId | None = None
    role: Literal["control", "check"] = "control"
    z: Finite | None = None
    sigma_px: Sigma = 1.0


class PairChange(_Body):
    """Changes to a pair; absent fields stay. ``z`` types the elevation, ``z_auto: true`` takes it from the ground."""

    u: Finite | None = None
    v: Finite | None = None
    col: Finite | None = None
    row: Finite | None = None
    id: PairId | None = None
    role: Literal["control", "check"] | None = None
    z: Finite | None = None
    z_auto: bool | None = None
    sigma_px: Sigma | None = None


class FileName(_Body):
    """A file in the working folder (relative name, no ``..``)."""

    name: Name


class OptionalFileName(_Body):
    name: Name | None = None


class RefineRequest(_Body):
    """``POST /api/refine`` takes an empty JSON object (a JSON body keeps plain cross-site form posts out)."""


def _error(status: int, message: str) -> JSONResponse:
    return JSONResponse({"detail": message}, status_code=status)


def _validation_message(exc: RequestValidationError) -> str:
    parts = []
    for err in exc.errors()[:5]:
        if err.get("type") == "json_invalid":
            reason = (err.get("ctx") or {}).get("error", "")
            return f"the request body is not valid JSON ({reason}); send a JSON object"
        loc = [str(p) for p in err.get("loc", ()) if p != "body"]
        where = ".".join(loc) or "body"
        msg = err.get("msg", "invalid")
        if err.get("type") == "extra_forbidden":
            msg = "unknown field"
        elif err.get("type") == "missing":
            msg = "missing"
        elif err.get("type") == "model_attributes_type":
            msg = "the body must be a JSON object (Content-Type: application/json)"
        parts.append(f"{where}: {msg}")
    return "invalid request: " + "; ".join(parts)


class BodyLimit:
    """ASGI middleware: a request body over ``max_bytes`` gets a 413, counted while it streams in (a chunked upload
    has no Content-Length), so no more than ``max_bytes`` of one is ever held; the app gets the body buffered."""

    def __init__(self, app: Any, max_bytes: int) -> None:
        self.app = app
        self.max_bytes = max_bytes

    async def __call__(self, scope: dict[str, Any], receive: Any, send: Any) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        chunks: list[bytes] = []
        size = 0
        while True:
            message = await receive()
            if message["type"] == "http.disconnect":
                return  # the client went away mid-body: nothing to answer
            body = message.get("body", b"")
            size += len(body)
            if size > self.max_bytes:
                response = _error(413, f"the request body is larger than {self.max_bytes} bytes")
                response.headers["Connection"] = "close"
                await response(scope, receive, send)
                return
            chunks.append(body)
            if not message.get("more_body", False):
                break
        replayed = False

        async def replay() -> dict[str, Any]:
            nonlocal replayed
            if not replayed:
                replayed = True
                return {"type": "http.request", "body": b"".join(chunks), "more_body": False}
            return await receive()

        await self.app(scope, replay, send)


def create_app(session: Session, *, allowed_hosts: Sequence[str] | None = None) -> FastAPI:
    """The web app over ``session`` (no global state: everything it serves comes from ``session``).

    ``allowed_hosts``: host names the ``Host`` header may carry (e.g. ``["127.0.0.1", "localhost"]``, which
    stops DNS-rebinding attacks on a local server); None accepts any.
    """
    app = FastAPI(title="trafficgeo gcp-ui", docs_url=None, redoc_url=None, openapi_url=None)
    app.state.session = session
    refiner = app.state.refiner = SessionRefiner(session)
    hosts = None if allowed_hosts is None else {h.lower() for h in allowed_hosts}
    app.add_middleware(BodyLimit, max_bytes=MAX_BODY_BYTES)  # inside the guard below: refused hosts send nothing

    @app.middleware("http")
    async def guard(request: Request, call_next: Any) -> Response:
        host = (request.headers.get("host") or "").lower()
        if hosts is not None and urlsplit(f"//{host}").hostname not in hosts:
            return _error(400, f"host {host!r} is not served here; open the address gcp-ui printed")
        if request.method in _UNSAFE:
            origin = request.headers.get("origin")
            if origin and origin != "null" and urlsplit(origin).netloc.lower() != host:
                return _error(403, "cross-origin requests are refused; use the page gcp-ui serves")
            if origin == "null":
                return _error(403, "requests from opaque origins are refused; use the page gcp-ui serves")
            length = request.headers.get("content-length")
            if length is not None and (not length.isdigit() or int(length) > MAX_BODY_BYTES):
                return _error(413, f"the request body is larger than {MAX_BODY_BYTES} bytes")
        return await call_next(request)

    @app.exception_handler(SessionError)
    async def session_error(_: Request, exc: SessionError) -> JSONResponse:
        return _error(exc.status_code, str(exc))

    @app.exception_handler(InputError)
    async def input_error(_: Request, exc: InputError) -> JSONResponse:
        return _error(400, str(exc))

    @app.exception_handler(RequestValidationError)
    async def validation_error(_: Request, exc: RequestValidationError) -> JSONResponse:
        return _error(422, _validation_message(exc))

    @app.exception_handler(StarletteHTTPException)
    async def http_error(_: Request, exc: StarletteHTTPException) -> JSONResponse:
        detail = exc.detail if isinstance(exc.detail, str) else str(exc.detail)
        if exc.status_code == 404 and detail == "Not Found":
            detail = "no such address; open / for the page"
        if exc.status_code == 405:
            detail = "this method is not allowed here"
        return _error(exc.status_code, detail)

    @app.exception_handler(Exception)
    async def unexpected(_: Request, exc: Exception) -> JSONResponse:
        log.exception("unexpected error")
        return _error(500, f"internal error ({type(exc).__name__}); the session and its autosave are intact")

    app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")

    @app.get("/", include_in_schema=False)
    def index() -> FileResponse:
        return FileResponse(STATIC_DIR / "index.html", headers={"Cache-Control": "no-cache"})

    @app.get("/api/info")
    def info() -> dict[str, Any]:
        return {**session.info(), "refined_camera_name": REFINED_CAMERA_NAME}

    @app.get("/api/frame.png")
    def frame_png() -> Response:
        return Response(session.frame.png, media_type="image/png")

    @app.get("/api/ortho.png")
    def ortho_png() -> Response:
        return Response(session.ortho.png, media_type="image/png")

    @app.get("/api/state")
    def state() -> dict[str, Any]:
        return session.state()

    @app.post("/api/pairs", status_code=201)
    def add_pair(body: NewPair) -> dict[str, Any]:
        return session.add_pair(body.u, body.v, body.col, body.row, pair_id=body.id, role=body.role, z=body.z,
                                sigma_px=body.sigma_px)

    @app.patch("/api/pairs/{pair_id:path}")
    def change_pair(pair_id: str, body: PairChange) -> dict[str, Any]:
        if not body.model_fields_set:
            raise SessionError("nothing to change: give at least one of u, v, col, row, id, role, z, z_auto, "
                               "sigma_px")
        if None in {getattr(body, k) for k in body.model_fields_set}:
            nulls = sorted(k for k in body.model_fields_set if getattr(body, k) is None)
            raise SessionError(f"{', '.join(nulls)}: null is not a value; leave the field out to keep it")
        return session.update_pair(pair_id, u=body.u, v=body.v, col=body.col, row=body.row, new_id=body.id,
                                   role=body.role, z=body.z, z_auto=body.z_auto, sigma_px=body.sigma_px)

    @app.delete("/api/pairs/{pair_id:path}")
    def delete_pair(pair_id: str) -> dict[str, Any]:
        session.delete_pair(pair_id)
        return {"deleted": pair_id, "revision": session.revision}

    @app.get("/api/calibration")
    def calibration() -> dict[str, Any]:
        return session.calibration()

    @app.post("/api/gcps/save")
    def save_gcps(body: OptionalFileName) -> dict[str, Any]:
        return session.save_csv(body.name)

    @app.post("/api/gcps/load")
    def load_gcps(body: FileName) -> dict[str, Any]:
        return session.load_csv(body.name)

    @app.post("/api/camera/save")
    def save_camera(body: FileName) -> dict[str, Any]:
        return session.save_camera(body.name)

    @app.post("/api/refine")
    async def refine(_: RefineRequest) -> dict[str, Any]:
        return await run_in_threadpool(refiner.refine)  # seconds of work: the other requests go on meanwhile

    @app.post("/api/refine/save")
    def save_refined(body: OptionalFileName) -> dict[str, Any]:
        return refiner.save(body.name)

    return app


# ---------------------------------------------------------------------------------------------------- serving
def bind_socket(host: str, port: int) -> socket.socket:
    """A listening TCP socket on ``host:port`` (port 0 = any free port).

    Raises:
        InputError: the port is out of range or in use, or the host is unknown.
    """
    if not 0 <= port <= 65535:
        raise InputError(f"port {port} is not a TCP port; give 1 to 65535 (or 0 for any free port)",
                         parameters=("port",))
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except socket.gaierror as exc:
        raise InputError(f"host {host!r} is not a known address ({exc.strerror}); use 127.0.0.1",
                         parameters=("host",)) from None
    family, _, _, _, addr = infos[0]
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind(addr)
        sock.listen(128)
    except OSError as exc:
        sock.close()
        if port and exc.errno in (98, 48, 10048):  # EADDRINUSE on Linux, macOS, Windows
            raise InputError(f"port {port} on {host} is in use (another gcp-ui?); give another `port`, "
                             "or `port` 0 for any free port", parameters=("port",)) from None
        raise InputError(f"cannot listen on {host}:{port} ({exc.strerror or exc}); give another `host` or "
                         "`port`", parameters=("host", "port")) from None
    sock.set_inheritable(True)
    return sock


def url_of(sock: socket.socket) -> str:
    """The http:// address of a bound socket (IPv6 hosts in brackets)."""
    host, port = sock.getsockname()[:2]
    shown = f"[{host}]" if ":" in host else host
    return f"http://{shown}:{port}/"


def make_server(app: FastAPI) -> Any:
    """A uvicorn server for ``app`` (quiet logs; call ``.run(sockets=[sock])``)."""
    import uvicorn

    config = uvicorn.Config(app, log_level="warning", lifespan="off", access_log=False)
    return uvicorn.Server(config)


class BackgroundServer:
    """Serve an app from a background thread (tests, notebooks): ``with BackgroundServer(app) as url: ...``."""

    def __init__(self, app: FastAPI, host: str = "127.0.0.1", port: int = 0, timeout_s: float = 10.0) -> None:
        self.sock = bind_socket(host, port)
        self.url = url_of(self.sock)
        self.server = make_server(app)
        self.thread = threading.Thread(target=self.server.run, kwargs={"sockets": [self.sock]}, daemon=True,
                                       name="gcp-ui-server")
        self.timeout_s = timeout_s

    def __enter__(self) -> str:
        self.thread.start()
        deadline = time.monotonic() + self.timeout_s
        while not self.server.started:
            if not self.thread.is_alive() or time.monotonic() > deadline:
                raise RuntimeError("the gcp-ui server did not start")
            time.sleep(0.01)
        return self.url

    def __exit__(self, *exc: object) -> None:
        self.server.should_exit = True
        self.thread.join(self.timeout_s)
        self.sock.close()
