"""A companion whose sockets cannot open says which setting and what to change, in one line.

Seen on a netns fleet (docs/peers.md, by hand): ``peers.medium`` with a multicast interface
address that is not the drone's, or a multicast group without the interface on a host with
no route for it, or a ``listen_port`` another program holds, ended ``uav-companion run`` with
an ExceptionGroup traceback in its log and ``companion failed: OSError(99, 'Cannot assign
requested address')``, naming neither the setting nor the fix.
"""

from __future__ import annotations

import errno
import json
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from companion.medium import medium_problem, parse_medium
from companion.protocol import Decoder, Encoder
from companion.transport import TransportStartError, UdpTransport
from tests.keys import TEST_FLEET_KEY, write_test_keys

NOT_OURS = "192.0.2.1"
"""TEST-NET-1: never an address of the machine running the tests."""


def _transport(*, medium: str | None = None, local: tuple[str, int] = ("127.0.0.1", 0)
               ) -> UdpTransport:
    return UdpTransport(encoder=Encoder(1, "d1", TEST_FLEET_KEY),
                        decoder=Decoder(1, TEST_FLEET_KEY, local_id="d1"),
                        remote_addr=("127.0.0.1", 9), local_addr=local,
                        medium=parse_medium(medium) if medium else None)


async def test_a_multicast_interface_not_ours_names_the_setting() -> None:
    t = _transport(medium=f"multicast:239.255.42.99:14799:{NOT_OURS}")
    with pytest.raises(TransportStartError) as info:
        await t.run()
    text = str(info.value)
    assert text.startswith(f"peers.medium multicast:239.255.42.99:14799:{NOT_OURS}: cannot "
                           "open the shared medium (")
    assert f"{NOT_OURS} is not an address of this computer" in text
    assert t._transport is None  # the unicast socket opened before it is closed again


async def test_a_listen_port_in_use_names_the_setting() -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as busy:
        busy.bind(("127.0.0.1", 0))
        port = busy.getsockname()[1]
        with pytest.raises(TransportStartError, match=rf"ground_station.listen_host/"
                           rf"listen_port 127.0.0.1:{port}: cannot bind \("):
            await _transport(local=("127.0.0.1", port)).run()


def test_medium_problems_say_what_to_change() -> None:
    group = parse_medium("multicast:239.255.42.99:14700")
    no_dev = medium_problem(OSError(errno.ENODEV, "No such device"), group, "shared_medium")
    assert no_dev.startswith("shared_medium multicast:239.255.42.99:14700: cannot open")
    assert 'shared_medium = "multicast:239.255.42.99:14700:IFACE_ADDR"' in no_dev
    busy = medium_problem(OSError(errno.EADDRINUSE, "Address already in use"),
                          parse_medium("broadcast:10.0.0.255:14600"), "peers.medium")
    assert "port 14600 is held by a program that does not share it" in busy


def test_run_prints_one_line_and_no_traceback(tmp_path: Path) -> None:
    write_test_keys(tmp_path / "keys")
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:  # a port nobody sends to
        s.bind(("127.0.0.1", 0))
        mavlink_port = s.getsockname()[1]
    config = tmp_path / "companion.toml"
    config.write_text(
        '[drone]\nid = "d1"\n[camera]\nenabled = false\n'
        f'[mavlink]\nurl = "udpin:127.0.0.1:{mavlink_port}"\n'
        '[ground_station]\nfleet_key_file = "keys/fleet.key"\n'
        'command_public_key_file = "keys/command.pub"\n'
        f'[peers]\nmedium = "multicast:239.255.42.99:14799:{NOT_OURS}"\n')
    bin_dir = Path(sys.executable).parent
    if not (bin_dir / "uav-companion").exists():
        pytest.skip("uav-companion is not installed in this environment (pip install -e .)")
    result = subprocess.run([str(bin_dir / "uav-companion"), "run", "--config", str(config)],
                            capture_output=True, text=True, timeout=120, check=False)
    assert result.returncode == 1, result.stderr[-2000:]
    assert "Traceback" not in result.stderr, result.stderr[-3000:]
    lines = result.stderr.strip().splitlines()
    assert lines[-1].startswith("cannot start: peers.medium multicast:239.255.42.99:14799:"), \
        lines[-1]
    records = [json.loads(line) for line in lines if line.startswith("{")]
    errors = [r for r in records if r["level"] == "error"]
    assert len(errors) == 1 and "exc" not in errors[0], errors


def test_check_opens_the_medium(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`uav-companion check` said `check: ok` for a medium `run` could not open (seen: a
    multicast interface address not the drone's; `run` then stopped at once)."""
    from companion.cli import main

    write_test_keys(tmp_path / "keys")
    base = ('[drone]\nid = "d1"\n[camera]\nenabled = false\n'
            '[ground_station]\nfleet_key_file = "keys/fleet.key"\n'
            'command_public_key_file = "keys/command.pub"\n')
    bad = tmp_path / "bad.toml"
    bad.write_text(base + f'[peers]\nmedium = "multicast:239.255.42.99:14799:{NOT_OURS}"\n')
    assert main(["check", "--config", str(bad), "--skip-mavlink"]) == 1
    out = capsys.readouterr().out.splitlines()
    assert out[-1] == "check: 1 problem(s)"
    assert any(line.startswith("peers: peers.medium multicast:239.255.42.99:14799:") and
               f"{NOT_OURS} is not an address of this computer" in line for line in out), out
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    good = tmp_path / "good.toml"
    good.write_text(base + f'[peers]\nmedium = "broadcast:127.255.255.255:{port}"\n')
    assert main(["check", "--config", str(good), "--skip-mavlink"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert f"peers: shared medium broadcast:127.255.255.255:{port} opened" in out
    assert out[-1] == "check: ok"
