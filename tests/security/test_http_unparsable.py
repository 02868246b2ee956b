"""Requests the HTTP parser refuses, against a real ``uav-ground-station run`` (default INFO
logging), each on a kept-alive connection: an unknown method, an 8 kB header holding a session
cookie, a NUL in the URL, an over-long URL, a bad HTTP version, TLS bytes. Each gets a 400,
the station keeps serving, and its log has one WARNING line per request: it had an ERROR
with a traceback for each, quoting the raw bytes (the cookie's value among them)."""

from __future__ import annotations

import subprocess
import sys
import time
import urllib.request
from pathlib import Path

from tests.keys import write_test_keys
from tests.processes import interrupt
from tests.station_process import raw_reply

STATION = Path(sys.executable).parent / "uav-ground-station"
SECRET = "cookie-secret-0123456789abcdef"
BAD = [
    b"FOO /api/stats HTTP/1.1\r\n\r\n",
    b"GET /api/stats HTTP/1.1\r\nHost: 127.0.0.1\r\nCookie: gs_session=" + SECRET.encode()
    + b"x" * 9000 + b"\r\n\r\n",
    b"GET /api/images/\x00.jpg HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n",
    b"GET /" + b"a" * 9000 + b" HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n",
    b"GET / HTTP/9.9\r\nHost: 127.0.0.1\r\n\r\n",
    b"\x16\x03\x01\x02\x00\x01\x00\x01\xfc\x03\x03" + bytes(32) + b"\r\n\r\n",
]


def test_unparsable_requests_are_one_warning_line_each(tmp_path: Path) -> None:
    data = tmp_path / "data"
    write_test_keys(data / "keys")
    log = tmp_path / "station.log"
    with open(log, "w") as stderr:
        station = subprocess.Popen([str(STATION), "run", "--data-dir", str(data),
                                    "--udp-port", "0", "--http-port", "0"],
                                   stdout=subprocess.PIPE, stderr=stderr, text=True)
    try:
        assert station.stdout is not None
        line = next(x for x in station.stdout if x.startswith("dashboard:"))
        port = int(line.split("/")[2].split(":")[1])
        for request in BAD:
            assert b" 400 " in raw_reply(port, request).split(b"\r\n")[0], request[:40]
        token = (data / "token").read_text().strip()
        req = urllib.request.Request(f"http://127.0.0.1:{port}/api/stats",
                                     headers={"Authorization": f"Bearer {token}"})
        with urllib.request.urlopen(req, timeout=10) as resp:
            assert resp.status == 200
        time.sleep(0.2)  # the last log lines reach the file
    finally:
        interrupt(station, timeout_s=20)
    text = log.read_text()
    assert "Traceback" not in text and SECRET not in text, text[-3000:]
    refused = [x for x in text.splitlines() if "HTTP request refused (400 " in x]
    assert len(refused) == len(BAD), text[-3000:]
    assert all(" WARNING aiohttp.server: " in x and x.endswith("from 127.0.0.1")
               for x in refused), refused
