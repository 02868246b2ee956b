"""The companion's ``GET /peers`` endpoint cannot be held: a client that stops reading is
dropped after ``peers.http_send_timeout_s``, and connections are capped per address and in
all (``peers.http_max_per_address``, ``peers.http_max_connections``)."""

from __future__ import annotations

import asyncio
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from companion.peer_http import PeerHttp
from companion.peer_table import PeerTable
from companion.peers import PeersSettings, parse_peers_settings
from tests.companion_process import stop_companion
from tests.keys import write_test_keys

SCRIPT = Path(sys.executable).parent / "uav-companion"


class HugeTable(PeerTable):
    """A table whose snapshot is ~12 MB of JSON: more than the kernel's socket buffers and
    the transport's high-water mark together, so a client that does not read blocks it."""

    def snapshot(self, now: float) -> dict[str, Any]:
        return {"drone": "d1", "t": now, "peers": ["x" * 1000] * 12_000}


def _recv_all(sock: socket.socket) -> bytes:
    chunks = []
    sock.settimeout(10)
    try:
        while chunk := sock.recv(1 << 20):
            chunks.append(chunk)
    except ConnectionResetError:
        pass
    return b"".join(chunks)


async def test_a_client_that_stops_reading_is_dropped() -> None:
    http = PeerHttp(HugeTable("d1"), clock=time.time, host="127.0.0.1", port=0,
                    send_timeout_s=0.5)
    _, port = await http.start()
    client = socket.socket()
    client.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    try:
        client.connect(("127.0.0.1", port))
        client.sendall(b"GET /peers HTTP/1.0\r\nHost: 127.0.0.1\r\n\r\n")
        await asyncio.sleep(2.0)  # 4 x the send timeout, not reading
        raw = await asyncio.to_thread(_recv_all, client)  # now read: the rest never comes
        head, _, body = raw.partition(b"\r\n\r\n")
        length = int(head.split(b"Content-Length: ")[1].split(b"\r\n")[0])
        assert length > 10_000_000 and len(body) < length
        assert http.gate.open == 0 and http.counters["dropped"] == 1
    finally:
        client.close()
        http.close()


async def test_a_client_that_reads_gets_all_of_a_large_reply() -> None:
    http = PeerHttp(HugeTable("d1"), clock=time.time, host="127.0.0.1", port=0,
                    send_timeout_s=30.0)
    _, port = await http.start()
    try:
        reader, writer = await asyncio.open_connection("127.0.0.1", port)
        writer.write(b"GET /peers HTTP/1.0\r\n\r\n")
        raw = await asyncio.wait_for(reader.read(), 30)
        writer.close()
        head, _, body = raw.partition(b"\r\n\r\n")
        assert head.startswith(b"HTTP/1.0 200") and len(body) > 10_000_000
        assert f"Content-Length: {len(body)}".encode() in head
        assert http.counters == {"refused": 0, "dropped": 0}
    finally:
        http.close()


def test_limits_are_settings_with_safe_defaults() -> None:
    s = parse_peers_settings({})
    assert (s.http_max_connections, s.http_max_per_address, s.http_send_timeout_s) == \
        (32, 8, 5.0)
    s = parse_peers_settings({"http_max_connections": 3, "http_max_per_address": 2,
                              "http_send_timeout_s": 0.5})
    assert s == PeersSettings(http_max_connections=3, http_max_per_address=2,
                              http_send_timeout_s=0.5)
    for bad in ({"http_max_connections": 0}, {"http_max_per_address": 2.5},
                {"http_max_per_address": True}, {"http_send_timeout_s": 0},
                {"http_send_timeout_s": float("inf")}, {"http_send_timeout_s": "5"}):
        with pytest.raises(ValueError, match=f"peers.{next(iter(bad))}"):
            parse_peers_settings(bad)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _idle(source: str, port: int) -> socket.socket:
    """A connection from ``source`` (any 127/8 address is this host) that sends nothing."""
    s = socket.create_connection(("127.0.0.1", port), timeout=5, source_address=(source, 0))
    return s


def _get(source: str, port: int) -> bytes:
    """One ``GET /peers``: the reply, or b"" when the connection is closed on accept."""
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=5,
                                      source_address=(source, 0)) as s:
            s.sendall(b"GET /peers HTTP/1.0\r\nHost: 127.0.0.1\r\n\r\n")
            return _recv_all(s)
    except (ConnectionResetError, BrokenPipeError):
        return b""


def _until(predicate: Any, timeout_s: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.1)
    return True


def test_connections_are_capped_per_address_and_in_all(tmp_path: Path) -> None:
    """A real ``uav-companion run``: 2 idle connections from 127.0.0.1 use up its share, a
    third address's request still works until the total (3) is held too; closing one
    idle connection lets requests in again. The old code served every one."""
    port = _free_port()
    write_test_keys(tmp_path / "keys")
    config = tmp_path / "companion.toml"
    config.write_text(f"""[drone]
id = "d1"
[mavlink]
url = "udpin:127.0.0.1:{_free_port()}"
[camera]
enabled = false
[constraint]
name = "constant"
params = {{ limit_bytes_per_s = 20000.0 }}
[peers]
http = "127.0.0.1:{port}"
http_max_connections = 3
http_max_per_address = 2
[ground_station]
fleet_key_file = "keys/fleet.key"
command_public_key_file = "keys/command.pub"
""")
    log = tmp_path / "companion.log"
    with open(log, "w") as stderr:
        proc = subprocess.Popen([str(SCRIPT), "--log-format", "text", "run", "--config",
                                 str(config)], stdout=subprocess.DEVNULL, stderr=stderr)
    held: list[socket.socket] = []
    try:
        assert _until(lambda: "peer state on http" in log.read_text()
                      or proc.poll() is not None, 60)
        assert proc.poll() is None, log.read_text()
        assert _get("127.0.0.1", port).startswith(b"HTTP/1.0 200")
        held += [_idle("127.0.0.1", port), _idle("127.0.0.1", port)]
        assert _until(lambda: _get("127.0.0.1", port) == b""), "no per-address cap"
        assert _get("127.0.0.2", port).startswith(b"HTTP/1.0 200")  # another address: room
        held.append(_idle("127.0.0.2", port))
        assert _until(lambda: _get("127.0.0.3", port) == b""), "no total cap"
        held.pop(0).close()  # the server reads EOF, answers 400, frees the slot
        assert _until(lambda: _get("127.0.0.3", port).startswith(b"HTTP/1.0 200"))
        assert proc.poll() is None
    finally:
        for s in held:
            s.close()
        code, _ = stop_companion(proc)  # type: ignore[arg-type]
    text = log.read_text()
    assert code == 0, text[-3000:]
    assert "Traceback" not in text
    refusals = [line for line in text.splitlines() if "connection from" in line]
    assert len(refusals) == 1 and "WARNING" in refusals[0], refusals  # once, not per probe
    assert "at most 2 per address and 3 in all" in refusals[0]
