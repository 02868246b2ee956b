"""DNS rebinding: the station answers only to IP literals, ``localhost`` and the names it is
given (``--allowed-host``, ``allowed_hosts``); state changes from another Origin are refused.

A page on ``evil.example`` re-resolved to the station's address sends ``Host: evil.example``
(to the browser it is still that site), so the Host check is what stops it."""

from __future__ import annotations

import asyncio
import signal
import socket
import subprocess
import sys
from pathlib import Path
from typing import Any

import aiohttp
import pytest
from aiohttp.test_utils import TestClient
from hypothesis import given
from hypothesis import strategies as st

from ground_station.cli import _config, _parser
from ground_station.config import ConfigError, GroundConfig, config_from_mapping
from ground_station.host_guard import allowed_names, host_name, host_refusal
from tests.ground_station.conftest import TOKEN, auth
from tests.keys import write_test_keys

ALLOWED = allowed_names(["gs.example.org"])


@pytest.mark.parametrize("host", [
    "127.0.0.1", "127.0.0.1:8080", "10.1.2.3:80", "[::1]", "[::1]:8080", "::1",
    "[fe80::1%eth0]:8080", "localhost", "localhost:8080", "LOCALHOST.", "gs.example.org",
    "GS.Example.Org.:8443",
])
def test_ip_literals_localhost_and_allowed_names_are_served(host: str) -> None:
    assert host_refusal(host, ALLOWED) is None


@pytest.mark.parametrize("host", [
    "evil.example", "evil.example:8080", "gs.example.org.evil.example", "example.org",
    "127.0.0.1.nip.io", "localhost.evil.example", "", "[::1", "1.2.3.4:80:80",
])
def test_other_names_are_refused_with_the_option_that_would_allow_them(host: str) -> None:
    reason = host_refusal(host, ALLOWED)
    assert reason is not None and "DNS rebinding" in reason and "\n" not in reason
    assert reason.endswith(f"--allowed-host {host_name(host)}")


def test_a_request_without_host_is_served() -> None:
    assert host_refusal(None, ALLOWED) is None  # no browser omits it


@given(st.ip_addresses(), st.one_of(st.none(), st.integers(1, 65535)))
def test_every_ip_literal_is_served(address: Any, port: int | None) -> None:
    text = f"[{address}]" if address.version == 6 else str(address)
    assert host_refusal(text if port is None else f"{text}:{port}", frozenset()) is None


def test_host_name_strips_ports_and_brackets() -> None:
    assert [host_name(h) for h in ("gs.lan:8080", "[::1]:80", "::1", "10.0.0.1:1", "x")] == [
        "gs.lan", "::1", "::1", "10.0.0.1", "x"]


def test_allowed_hosts_come_from_the_config_file_and_the_command_line(tmp_path: Path) -> None:
    config = config_from_mapping({"ground_station": {"allowed_hosts": ["gs.lan"]}})
    assert config.allowed_hosts == ("gs.lan",)
    for bad in (["http://gs.lan"], ["gs.lan:8080"], ["*.lan"], [3], "gs.lan"):
        with pytest.raises(ConfigError, match="allowed_hosts"):
            config_from_mapping({"ground_station": {"allowed_hosts": bad}})
    toml = tmp_path / "gs.toml"
    toml.write_text('[ground_station]\nallowed_hosts = ["gs.lan"]\n')
    args = _parser().parse_args(["run", "--config", str(toml), "--allowed-host", "gs.example.org",
                                 "--allowed-host", "uav-gs"])
    assert _config(args).allowed_hosts == ("gs.lan", "gs.example.org", "uav-gs")


async def test_the_app_refuses_a_rebound_host_and_serves_its_own(
        aiohttp_client: Any, gs_config: GroundConfig) -> None:
    from ground_station.app import create_app

    config = gs_config.with_overrides(allowed_hosts=("gs.example.org",))
    client: TestClient[Any, Any] = await aiohttp_client(create_app(config, token=TOKEN))
    for path in ("/", "/api/stats", "/static/app.js"):
        resp = await client.get(path, headers={**auth(), "Host": "evil.example"})
        assert resp.status == 421, path
        assert (await resp.text()).count("\n") == 1
    resp = await client.post("/api/mission/start", json={"delay_s": 5},
                             headers={**auth(), "Host": "evil.example:80"})
    assert resp.status == 421
    assert not (await (await client.get("/api/mission", headers=auth())).json()).get("commands")
    for host in ("gs.example.org", f"localhost:{client.port}", f"127.0.0.1:{client.port}"):
        assert (await client.get("/api/stats", headers={**auth(), "Host": host})).status == 200


async def test_a_token_does_not_let_another_origin_change_state(
        gs_client: TestClient[Any, Any]) -> None:
    body = {"delay_s": 5}
    resp = await gs_client.post("/api/mission/start", json=body,
                                headers={**auth(), "Origin": "http://evil.example"})
    assert resp.status == 403 and "Origin http://evil.example is not this station" in \
        await resp.text()
    here = f"http://{gs_client.host}:{gs_client.port}"
    assert (await gs_client.post("/api/mission/start", json=body,
                                 headers={**auth(), "Origin": here})).status == 200
    assert (await gs_client.post("/api/mission/end", json={},
                                 headers=auth())).status == 200  # no Origin: not a browser
    with pytest.raises(aiohttp.WSServerHandshakeError) as info:
        await gs_client.ws_connect("/ws", headers={**auth(), "Origin": "http://evil.example"})
    assert info.value.status == 403


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


async def _raw_get(port: int, host: str, path: str = "/") -> tuple[int, bytes]:
    """A request as a rebinding page's browser sends it: to the station's address, with
    the attacker's name in Host (a real socket, nothing in between)."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    writer.write(f"GET {path} HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n\r\n".encode())
    await writer.drain()
    data = await reader.read()
    writer.close()
    status = int(data.split(b" ", 2)[1])
    return status, data.split(b"\r\n\r\n", 1)[1]


async def test_the_shipped_station_refuses_a_rebound_host(tmp_path: Path) -> None:
    """``uav-ground-station run`` as shipped (INFO logging, real sockets; ~3 s)."""
    keys = write_test_keys(tmp_path / "keys")
    port = _free_port()
    config = tmp_path / "gs.toml"
    config.write_text(
        f'[ground_station]\ndata_dir = "data"\nudp_port = 0\nhttp_port = {port}\n'
        f'fleet_key_file = "{keys / "fleet.key"}"\n'
        f'command_key_file = "{keys / "command.key"}"\n'
        'public_read = true\nallowed_hosts = ["gs.lan"]\n')
    gs = Path(sys.executable).parent / "uav-ground-station"
    station = subprocess.Popen([str(gs), "run", "--config", str(config), "--allowed-host",
                                "uav-gs.example.org"], cwd=tmp_path,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        async with asyncio.timeout(30):
            while True:
                try:
                    status, _ = await _raw_get(port, f"127.0.0.1:{port}", "/api/stats")
                    break
                except OSError:
                    assert station.poll() is None, station.communicate()
                    await asyncio.sleep(0.1)
        assert status == 200
        status, body = await _raw_get(port, f"evil.example:{port}", "/api/fleet")
        assert status == 421 and b"not a name of this ground station" in body
        assert b"drones" not in body  # nothing of the fleet's data
        status, _ = await _raw_get(port, "evil.example", "/")
        assert status == 421
        for host in (f"127.0.0.1:{port}", f"localhost:{port}", "uav-gs.example.org",
                     f"gs.lan:{port}"):
            status, body = await _raw_get(port, host, "/")
            assert status == 200 and b"<html" in body.lower(), host  # the dashboard
            status, body = await _raw_get(port, host, "/api/fleet")
            assert status == 200 and body.startswith(b"{"), host
    finally:
        station.send_signal(signal.SIGINT)
        _, err = station.communicate(timeout=20)
    assert station.returncode == 0, err
    refusals = [line for line in err.splitlines() if "HTTP request refused" in line]
    assert len(refusals) == 1, err  # one line per refused name, not per request
    assert "Host 'evil.example' is not a name of this ground station" in refusals[0]
    assert "Traceback" not in err
