"""`uav-ground-station run` and ports it cannot have, as real subprocesses (INFO logging).

* A second station on a running station's UDP port, or a busy dashboard port, must fail with
  one line naming the port and the option that moves it (with SO_REUSEADDR the second
  station started, bound the same UDP port and silently took the fleet's datagrams).
* The "dashboard:" login link is printed only once the HTTP site listens, with the port it
  got: it was printed before binding, so a busy port handed a login code to whatever held
  it, and ``--http-port 0`` printed ``:0``.
"""

from __future__ import annotations

import socket
import subprocess
import sys
import urllib.request
from pathlib import Path

from tests.integration.test_ground_station_cli import free_port
from tests.keys import write_test_keys
from tests.processes import interrupt

STATION = Path(sys.executable).parent / "uav-ground-station"


def _station(tmp_path: Path, name: str, *, udp_port: int, http_port: int) -> list[str]:
    data = tmp_path / name
    write_test_keys(data / "keys")
    return [str(STATION), "run", "--data-dir", str(data), "--udp-port", str(udp_port),
            "--http-port", str(http_port)]


def _dashboard_line(proc: subprocess.Popen[str]) -> str:
    assert proc.stdout is not None
    for line in proc.stdout:
        if line.startswith("dashboard:"):
            return line
    raise AssertionError(f"no dashboard line; exit {proc.wait(timeout=20)}")


def test_a_second_station_on_the_same_udp_port_fails(tmp_path: Path) -> None:
    udp_port = free_port(socket.SOCK_DGRAM)
    first = subprocess.Popen(_station(tmp_path, "a", udp_port=udp_port, http_port=0),
                             stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        _dashboard_line(first)  # listening on both ports now
        second = subprocess.run(_station(tmp_path, "b", udp_port=udp_port, http_port=0),
                                capture_output=True, text=True, timeout=60, check=False)
        assert second.returncode == 1, second.stderr
        assert "Traceback" not in second.stderr
        errors = [x for x in second.stderr.splitlines() if x.startswith("uav-ground-station")]
        assert errors == [f"uav-ground-station: UDP 127.0.0.1:{udp_port} is already in use "
                          "(another ground station?): stop it, or pick another --udp-port"
                          ], second.stderr
        assert "dashboard:" not in second.stdout
        assert first.poll() is None
    finally:
        interrupt(first)


def test_no_login_link_for_a_busy_http_port(tmp_path: Path) -> None:
    with socket.socket() as squatter:
        squatter.bind(("127.0.0.1", 0))
        squatter.listen()
        port = squatter.getsockname()[1]
        result = subprocess.run(_station(tmp_path, "a", udp_port=0, http_port=port),
                                capture_output=True, text=True, timeout=60, check=False)
    assert result.returncode == 1, result.stderr
    assert "Traceback" not in result.stderr
    # one line naming the dashboard's address and the flag that moves it (aiohttp's words,
    # "error while attempting to bind on address ('127.0.0.1', N)", named neither)
    errors = [x for x in result.stderr.splitlines() if x.startswith("uav-ground-station")]
    assert errors == [f"uav-ground-station: dashboard 127.0.0.1:{port} is already in use "
                      "(another program listens there): stop it, or pick another --http-port"
                      ], result.stderr
    assert "login=" not in result.stdout and "dashboard:" not in result.stdout


def test_http_port_0_shows_the_port_it_got(tmp_path: Path) -> None:
    station = subprocess.Popen(_station(tmp_path, "a", udp_port=0, http_port=0),
                               stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        url = _dashboard_line(station).split()[1]
        assert not url.startswith("http://127.0.0.1:0/")
        with urllib.request.urlopen(url, timeout=10) as resp:  # the one-time login works
            assert resp.status == 200
    finally:
        interrupt(station)


def test_a_host_that_does_not_resolve_is_named(tmp_path: Path) -> None:
    """`cannot serve: [Errno -2] Name or service not known` named neither the host nor the
    option."""
    result = subprocess.run([*_station(tmp_path, "a", udp_port=0, http_port=0), "--http-host",
                             "no.such.host.invalid"], capture_output=True, text=True,
                            timeout=60, check=False)
    assert result.returncode == 1, result.stderr
    assert "Traceback" not in result.stderr
    errors = [x for x in result.stderr.splitlines() if x.startswith("uav-ground-station")]
    assert len(errors) == 1, result.stderr
    assert errors[0].startswith("uav-ground-station: http_host (--http-host) "
                                "'no.such.host.invalid' does not resolve (")  # the resolver's
    assert errors[0].endswith("): give an address or a name of this computer")  # own words
    assert "dashboard:" not in result.stdout
