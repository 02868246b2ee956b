"""Requests the HTTP parser refuses get a short fixed 400, never a page quoting them.

aiohttp's 400 page for a request it cannot parse echoes the offending bytes: the request
line, a header line (a cookie among them), 100 bytes of an over-long line, a chunk-size
line. Against the real ``uav-ground-station run`` each request below carries a marker; the
reply must be exactly the fixed body with the security headers, and the log one WARNING
line per request without the marker.
"""

from __future__ import annotations

import socket
from pathlib import Path

from tests.station_process import raw_reply, running_station

MARK = b"<script>alert(7)</script>"
FIXED_BODY = b"400 Bad Request: malformed HTTP request\n"
HOST = b"Host: 127.0.0.1\r\n"
BAD = {
    "header name": b"GET / HTTP/1.1\r\n" + HOST + b"Bad" + MARK + b": x\r\n\r\n",
    "header value": b"GET / HTTP/1.1\r\n" + HOST + b"X: " + MARK + b"\x01\r\n\r\n",
    "version": b"GET /" + MARK + b" HTTP/9.9\r\n" + HOST + b"\r\n",
    "method": b"FOO" + MARK + b" / HTTP/1.1\r\n" + HOST + b"\r\n",
    "long url": b"GET /" + MARK + b"a" * 9000 + b" HTTP/1.1\r\n" + HOST + b"\r\n",
    "long header": b"GET / HTTP/1.1\r\n" + HOST + b"Cookie: " + MARK + b"x" * 9000
    + b"\r\n\r\n",
    "content-length": b"GET / HTTP/1.1\r\n" + HOST + b"Content-Length: " + MARK
    + b"\r\n\r\n",
    "chunk size": b"POST /api/login HTTP/1.1\r\n" + HOST
    + b"Transfer-Encoding: chunked\r\n\r\nZZ" + MARK + b"\r\n",
    "nul in name": b"GET / HTTP/1.1\r\n" + HOST + b"\x00" + MARK + b": y\r\n\r\n",
}


def _check(name: str, reply: bytes) -> None:
    head, _, body = reply.partition(b"\r\n\r\n")
    lines = head.split(b"\r\n")
    assert b" 400 " in lines[0], (name, reply[:300])
    assert body == FIXED_BODY, (name, reply[:600])
    assert MARK not in reply and b"<script" not in reply.lower(), name
    headers = {k.strip().lower(): v.strip() for k, _, v in (x.partition(b":") for x in lines[1:])}
    assert headers[b"content-type"].startswith(b"text/plain"), name
    assert headers[b"x-content-type-options"] == b"nosniff", name
    assert b"content-security-policy" in headers, name


def test_malformed_requests_get_a_fixed_400_and_one_warning(tmp_path: Path) -> None:
    with running_station(tmp_path) as station:
        for name, request in BAD.items():
            _check(name, raw_reply(station.port, request, kept_alive=True))
        for name in ("method", "header name"):  # a fresh connection too
            _check(name, raw_reply(station.port, BAD[name], kept_alive=False))
        text = station.log_text()
    assert "Traceback" not in text and "alert(7)" not in text, text[-3000:]
    refused = [x for x in text.splitlines() if "HTTP request refused (400 " in x]
    assert len(refused) == len(BAD) + 1, text[-3000:]  # a fresh bad method: DEBUG only
    assert all(" WARNING " in x and x.endswith("from 127.0.0.1") for x in refused), refused


def test_a_bad_websocket_handshake_quotes_nothing(tmp_path: Path) -> None:
    """aiohttp's handshake errors quote the Upgrade/Connection header or the key."""
    with running_station(tmp_path) as station:
        auth = f"Authorization: Bearer {station.token}\r\n".encode()
        base = b"GET /ws HTTP/1.1\r\n" + HOST + auth
        for headers in (
            b"Upgrade: websocket" + MARK + b"\r\nConnection: Upgrade\r\n",
            b"Upgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Version: 13\r\n"
            b"Sec-WebSocket-Key: " + MARK + b"\r\n",
            b"Upgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Version: "
            + MARK + b"\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n",
        ):
            with socket.create_connection(("127.0.0.1", station.port), timeout=10) as conn:
                conn.sendall(base + headers + b"\r\n")
                reply = conn.recv(65536)
            head, _, body = reply.partition(b"\r\n\r\n")
            assert head.startswith(b"HTTP/1.1 400 "), reply[:300]
            assert body == b"400 Bad Request: not a WebSocket handshake\n", reply[:600]
