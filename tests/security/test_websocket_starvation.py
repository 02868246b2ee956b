"""WebSocket clients that connect and never read, against the real ``uav-ground-station run``.

* Idle WebSockets held every HTTP connection the station serves (``http_max_connections``):
  the dashboard's next request was closed on accept for as long as they stayed open. Now one
  client address holds at most ``ws_max_per_client`` WebSockets and all of them together at
  most half the connections; the rest get a 429/503 and their connection is closed.
* A client that keeps the feed busy and never reads (its receive window full) held its
  connection forever: the writer waited on the socket, and aiohttp's heartbeat "closes" a
  transport with unsent data by waiting for it to drain. Now an update that cannot be sent
  within ``ws_send_timeout_s`` drops the client (the connection is aborted, its descriptor
  freed); a client that does not answer pings within ``ws_heartbeat_s`` * 1.5 is closed.
"""

from __future__ import annotations

import os
import socket
import struct
import time
import urllib.request
from pathlib import Path

from tests.processes import interrupt
from tests.station_process import Station, running_station

ATTACKER = "127.0.0.2"  # another host on the LAN: loopback answers for all of 127/8


def _upgrade(station: Station) -> bytes:
    return (f"GET /ws HTTP/1.1\r\nHost: 127.0.0.1:{station.port}\r\nUpgrade: websocket\r\n"
            f"Connection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
            f"Sec-WebSocket-Version: 13\r\nAuthorization: Bearer {station.token}\r\n\r\n"
            ).encode()


def _open_ws(station: Station, source: str, *, rcvbuf: int | None = None) -> tuple[
        socket.socket, bytes]:
    """A WebSocket handshake; returns the socket and the reply's status line."""
    conn = socket.socket()
    if rcvbuf is not None:  # before connecting: the window the server sees stays small
        conn.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
    conn.settimeout(10)
    conn.bind((source, 0))
    conn.connect(("127.0.0.1", station.port))
    conn.sendall(_upgrade(station))
    head = b""
    while b"\r\n\r\n" not in head:
        chunk = conn.recv(1)  # the reply's head only: nothing after it is read
        if not chunk:
            break
        head += chunk
    return conn, head.split(b"\r\n")[0]


def _frame(text: bytes) -> bytes:
    """A masked client text frame."""
    mask = os.urandom(4)
    size = (bytes([0x80 | len(text)]) if len(text) < 126
            else bytes([0x80 | 127]) + struct.pack("!Q", len(text)))
    return bytes([0x81]) + size + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(text))


def _server_frames(data: bytes) -> list[tuple[int, bytes]]:
    """(opcode, payload) of the unmasked server frames in ``data``."""
    frames = []
    while len(data) >= 2:
        opcode, size, at = data[0] & 0x0F, data[1] & 0x7F, 2
        if size == 126:
            size, at = struct.unpack("!H", data[2:4])[0], 4
        elif size == 127:
            size, at = struct.unpack("!Q", data[2:10])[0], 10
        frames.append((opcode, data[at:at + size]))
        data = data[at + size:]
    return frames


def _stats(station: Station) -> int:
    req = urllib.request.Request(f"http://127.0.0.1:{station.port}/api/stats",
                                 headers={"Authorization": f"Bearer {station.token}"})
    with urllib.request.urlopen(req, timeout=5) as resp:
        return int(resp.status)


def test_idle_websockets_cannot_starve_the_dashboard(tmp_path: Path) -> None:
    with running_station(tmp_path, "http_max_connections = 20\n") as station:
        held = [_open_ws(station, ATTACKER) for _ in range(20)]
        try:
            assert _stats(station) == 200  # the dashboard still answers...
            mine, status = _open_ws(station, "127.0.0.1")  # ...and gets its live feed
            assert b" 101 " in status, status
            mine.close()
            statuses = [status for _, status in held]
            assert statuses.count(b"HTTP/1.1 101 Switching Protocols") == 8, statuses
            assert statuses.count(b"HTTP/1.1 429 Too Many Requests") == 12, statuses
            for conn, status in held:  # a refused upgrade's connection is closed
                if b" 429 " in status:
                    conn.settimeout(2)
                    while conn.recv(65536):
                        pass
        finally:
            for conn, _ in held:
                conn.close()
        text = station.log_text()
    assert "Traceback" not in text
    refusals = [x for x in text.splitlines() if "WebSocket refused" in x]
    assert refusals and all(" WARNING " in x and ATTACKER in x for x in refusals), refusals


def test_a_websocket_that_stops_reading_is_dropped(tmp_path: Path) -> None:
    with running_station(tmp_path, "ws_send_timeout_s = 1\n") as station:
        conn, status = _open_ws(station, "127.0.0.1", rcvbuf=4096)
        assert b" 101 " in status, status
        # each ping asks for a pong; the station fills its ~3 MB send buffer in ~3 s
        pings = _frame(b"ping") * 50
        t0 = time.monotonic()
        dropped_after = None
        with conn:
            while time.monotonic() - t0 < 15:
                try:
                    conn.sendall(pings)
                except OSError:  # reset by the station
                    dropped_after = time.monotonic() - t0
                    break
                time.sleep(0.002)
        assert dropped_after is not None, "the station kept a client that does not read"
        assert _stats(station) == 200
        text = station.log_text()
    assert dropped_after < 10, dropped_after
    dropped = [x for x in text.splitlines() if "WebSocket client 127.0.0.1 dropped" in x]
    assert len(dropped) == 1 and " WARNING " in dropped[0], text[-2000:]


def test_a_websocket_that_never_answers_pings_is_closed(tmp_path: Path) -> None:
    heartbeat = 1
    with running_station(tmp_path, f"ws_heartbeat_s = {heartbeat}\n") as station:
        conn, status = _open_ws(station, "127.0.0.1")
        assert b" 101 " in status, status
        t0 = time.monotonic()
        with conn:
            while conn.recv(65536):  # the snapshot, pings: never a pong from us
                pass
        assert time.monotonic() - t0 < heartbeat * 1.5 + 2


def test_ctrl_c_does_not_wait_for_a_websocket_that_does_not_read(tmp_path: Path) -> None:
    """The shutdown's close frame cannot be sent to a client whose window is full: the
    station waited for it forever (SIGINT did nothing while the client stayed)."""
    with running_station(tmp_path, "ws_send_timeout_s = 60\n") as station:
        conn, status = _open_ws(station, "127.0.0.1", rcvbuf=4096)
        assert b" 101 " in status, status
        pings = _frame(b"ping") * 50
        t0 = time.monotonic()
        with conn:
            while time.monotonic() - t0 < 4:  # the station's send buffer fills up
                conn.sendall(pings)
                time.sleep(0.002)
            t1 = time.monotonic()
            assert interrupt(station.proc, timeout_s=20) == 0
            stopped_after = time.monotonic() - t1
    assert stopped_after < 5, stopped_after


def test_a_big_websocket_message_closes_the_feed(tmp_path: Path) -> None:
    """The feed expects only "ping" from a client: a message over 4 KiB (aiohttp's default
    allowed 4 MiB, decompressed, per message) closes it with 1009."""
    with running_station(tmp_path) as station:
        conn, status = _open_ws(station, "127.0.0.1")
        assert b" 101 " in status, status
        with conn:
            conn.sendall(_frame(b"p" * 8192))  # read whole: no reset for unread bytes
            data = b""
            while chunk := conn.recv(65536):
                data += chunk
        closes = [p for op, p in _server_frames(data) if op == 0x8]
        assert closes and struct.unpack("!H", closes[0][:2])[0] == 1009, closes
