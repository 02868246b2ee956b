"""One client address cannot take every HTTP connection (real ``uav-ground-station run``).

Any host that can reach the port, without a token, opened ``http_max_connections`` idle
TCP connections (reopening them every ``http_idle_timeout_s``): every other client,
the operator's dashboard among them, was closed on accept. Now one address holds at most
``http_max_per_client`` (64 by default, half the connections); beyond that its
connections are closed at once.
"""

from __future__ import annotations

import select
import socket
import time
import urllib.request
from pathlib import Path

from tests.station_process import running_station

ATTACKER = "127.0.0.2"  # another host on the LAN: loopback answers for all of 127/8


def _closed(conns: list[socket.socket]) -> list[bool]:
    """Which connections the station has closed (EOF or reset waiting)."""
    readable, _, _ = select.select(conns, [], [], 0)
    return [c in readable for c in conns]


def test_one_address_cannot_hold_every_connection(tmp_path: Path) -> None:
    with running_station(tmp_path) as station:  # defaults: 128 connections, 64 a client
        held = []
        try:
            for _ in range(128):
                conn = socket.socket()
                conn.bind((ATTACKER, 0))
                conn.connect(("127.0.0.1", station.port))
                held.append(conn)
            time.sleep(1.0)  # all accepted (the station accepts in bursts)
            closed = _closed(held)
            req = urllib.request.Request(f"http://127.0.0.1:{station.port}/api/stats",
                                         headers={"Authorization": f"Bearer {station.token}"})
            with urllib.request.urlopen(req, timeout=5) as resp:  # the operator still gets in
                assert resp.status == 200
        finally:
            for conn in held:
                conn.close()
        text = station.log_text()
    assert closed.count(False) == 64 and closed[:64] == [False] * 64, closed
    refusals = [x for x in text.splitlines() if "HTTP connection from 127.0.0.2 refused" in x]
    assert 1 <= len(refusals) <= 3 and all(" WARNING " in x for x in refusals), refusals
