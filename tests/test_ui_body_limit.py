"""gcp-ui's request body limit holds for chunked uploads too (no Content-Length): the server answers 413 while the
body streams in and never reads (or holds) the rest. Real server on 127.0.0.1, raw socket, bounded upload."""

from __future__ import annotations

import json
import select
import shutil
import socket
import time

import pytest

from trafficgeo.ui.server import MAX_BODY_BYTES, BackgroundServer, create_app
from trafficgeo.ui.startup import open_session
from ui_support import shared_scene

CHUNK = 64 * 1024
CAP_BYTES = 32 * 1024 * 1024  # never send more than this


@pytest.fixture()
def server(tmp_path_factory, tmp_path):
    scene = shared_scene(tmp_path_factory)
    for p in (scene.frame, scene.ortho):
        shutil.copy(p, tmp_path / p.name)
    session, _ = open_session(frame=tmp_path / "frame.png", ortho=tmp_path / "ortho.tif", gcps=tmp_path / "g.csv")
    with BackgroundServer(create_app(session)) as url:
        host, port = url.split("//")[1].rstrip("/").split(":")
        yield host, int(port), session


def _head(host: str, port: int) -> bytes:
    return (f"POST /api/pairs HTTP/1.1\r\nHost: {host}:{port}\r\nContent-Type: application/json\r\n"
            "Transfer-Encoding: chunked\r\n\r\n").encode()


def _chunk(data: bytes) -> bytes:
    return f"{len(data):x}\r\n".encode() + data + b"\r\n"


def _response(sock: socket.socket, timeout_s: float = 10.0) -> tuple[int, dict]:
    sock.settimeout(timeout_s)
    data = b""
    while b"\r\n\r\n" not in data or len(data.split(b"\r\n\r\n", 1)[1]) < _length(data):
        part = sock.recv(65536)
        if not part:
            break
        data += part
    head, body = data.split(b"\r\n\r\n", 1)
    return int(head.split()[1]), json.loads(body[:_length(data)])


def _length(data: bytes) -> int:
    for line in data.split(b"\r\n\r\n", 1)[0].split(b"\r\n")[1:]:
        k, _, v = line.partition(b":")
        if k.strip().lower() == b"content-length":
            return int(v)
    return 0


@pytest.mark.slow
def test_a_chunked_upload_over_the_limit_is_refused_while_it_streams(server):
    host, port, session = server
    sent = 0
    answered = False
    with socket.create_connection((host, port), timeout=5) as sock:
        sock.sendall(_head(host, port) + _chunk(b'{"u": ' + b"1" * (CHUNK - 6)))
        sent = CHUNK
        deadline = time.monotonic() + 20
        while sent < CAP_BYTES and time.monotonic() < deadline:
            if select.select([sock], [], [], 0)[0]:
                answered = True
                break
            try:
                sock.sendall(_chunk(b"1" * CHUNK))
            except (TimeoutError, BrokenPipeError, ConnectionResetError):
                answered = True  # the server stopped reading: its answer is waiting
                break
            sent += CHUNK
        if not answered:
            sock.sendall(_chunk(b"}") + b"0\r\n\r\n")
        status, body = _response(sock)
    assert status == 413 and body["detail"] == f"the request body is larger than {MAX_BODY_BYTES} bytes"
    assert answered and sent < CAP_BYTES // 2, f"the server read {sent} bytes before answering"
    assert session.revision == 0


@pytest.mark.slow
def test_a_chunked_upload_within_the_limit_is_served(server):
    host, port, session = server
    body = json.dumps({"u": 10.0, "v": 20.0, "col": 30.0, "row": 40.0}).encode()
    with socket.create_connection((host, port), timeout=5) as sock:
        sock.sendall(_head(host, port) + _chunk(body[:10]) + _chunk(body[10:]) + b"0\r\n\r\n")
        status, answer = _response(sock)
    assert status == 201 and answer["id"] == "P1" and session.revision == 1
