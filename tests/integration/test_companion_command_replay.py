"""A captured command is not executed again after the companion restarts (issue 13 item 4),
and a drone holding the fleet key cannot command a companion (item 5): real ``uav-companion``
processes, real UDP, effects read from the STATUS replies and the companion's mission log.
A companion given the wrong command key says so at WARNING, not only at DEBUG."""

from __future__ import annotations

import asyncio
import base64
import json
import secrets
import socket
import time
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from companion.protocol import EPOCH_STATUS, Command, Decoder, Encoder, StatusReceived
from tests.companion_process import ground_station_toml, start_companion, stop_companion, until
from tests.keys import TEST_COMMAND_KEY

KEY = b"command-replay-test-fleet-key"
FLEET = 12
STATION_AHEAD_S = 25.0
"""How fast the captured command's sender clock runs (the decoder accepts ±30 s)."""


class Station(asyncio.DatagramProtocol):
    """The ground station's command side: signs with the station key, records statuses."""

    def __init__(self) -> None:
        self.decoder = Decoder(FLEET, KEY, local_id="gs")
        self.encoder = Encoder(FLEET, "gs", KEY, command_key=TEST_COMMAND_KEY)
        self.statuses: list[tuple[float, StatusReceived]] = []
        self.transport: asyncio.DatagramTransport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        now = time.time()
        self.decoder.receive_datagram(data, addr, now)
        while (event := self.decoder.next_event()) is not None:
            if isinstance(event, StatusReceived):
                self.statuses.append((now, event))

    def epochs(self, after: float = 0.0) -> list[tuple[int, tuple[str, int]]]:
        return [(int(e.status.info["epoch"]), (str(e.addr[0]), int(e.addr[1])))
                for t, e in self.statuses if e.status.state == EPOCH_STATUS and t > after]

    def states(self, command_id: int, after: float = 0.0) -> list[str]:
        return [e.status.state for t, e in self.statuses
                if e.status.command_id == command_id and t > after]

    def send(self, datagram: bytes, addr: tuple[str, int]) -> None:
        assert self.transport is not None
        self.transport.sendto(datagram, addr)


@pytest.fixture
async def station() -> AsyncIterator[tuple[Station, int]]:
    loop = asyncio.get_running_loop()
    transport, proto = await loop.create_datagram_endpoint(Station, local_addr=("127.0.0.1", 0))
    yield proto, transport.get_extra_info("sockname")[1]
    transport.close()


def _config(path: Path, gs_port: int, *, public_key: bytes | None = None) -> Path:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:  # nobody answers MAVLink here
        s.bind(("127.0.0.1", 0))
        mavlink_port = s.getsockname()[1]
    path.write_text(f"""
[drone]
id = "d1"
[mavlink]
url = "udpout:127.0.0.1:{mavlink_port}"
[camera]
enabled = false
[mission]
spec = "builtin:image_streaming"
log = "{path.parent / 'd1.jsonl'}"
wait_for_start = true
{ground_station_toml(gs_port, fleet_id=FLEET, fleet_key=KEY)}
[budgets]
mcts_iterations = 20
""")
    if public_key is not None:  # instead of the station's (the line ground_station_toml wrote)
        lines = [f'command_public_key = "{base64.b64encode(public_key).decode()}"'
                 if line.startswith("command_public_key =") else line
                 for line in path.read_text().splitlines()]
        path.write_text("\n".join(lines) + "\n")
    return path


def _commands_logged(log: Path, after: float) -> list[str]:
    names = []
    for line in log.read_text().splitlines():
        state = json.loads(line).get("state", {})
        if "command" in state and state["t"] > after:
            names.append(state["command"])
    return names


@pytest.mark.timeout(240)
async def test_a_captured_command_is_not_executed_after_a_restart(
    station: tuple[Station, int], tmp_path: Path
) -> None:
    gs, gs_port = station
    config = _config(tmp_path / "d1.toml", gs_port)
    log = tmp_path / "d1.jsonl"

    first = start_companion(config)
    try:
        await until(lambda: gs.epochs(), 60, first, poll_s=0.05)
        epoch1, addr1 = gs.epochs()[-1]
        # a drone with the fleet key (and its own Ed25519 key) tries first: not obeyed
        forger = Encoder(FLEET, "drone9", KEY, command_key=secrets.token_bytes(32))
        forged = Command(command_id=40, name="start", t_exec=time.time())
        gs.send(forger.encode_command(forged, time.time(), epoch=epoch1), addr1)
        start = Command(command_id=41, name="start", t_exec=time.time())
        # The station's clock runs STATION_AHEAD_S fast, within the decoder's ±30 s: the
        # captured command stays fresh by the clock for 55 s, however slow the restart on a
        # loaded machine (12-25 s measured), so only the epoch can refuse the replay.
        captured_at = time.time()
        captured = gs.encoder.encode_command(start, captured_at + STATION_AHEAD_S, epoch=epoch1)
        gs.send(captured, addr1)
        # (generous: on a cold numba cache the optimiser compiles meanwhile, holding the GIL)
        await until(lambda: "done" in gs.states(41), 30, first, poll_s=0.05)
        assert gs.states(40) == []
    finally:
        code, err = stop_companion(first)
    assert code == 0, err[-2000:]
    assert _commands_logged(log, after=0.0) == ["start"]

    restarted = time.time()
    second = start_companion(config)
    try:
        await until(lambda: gs.epochs(after=restarted), 60, second, poll_s=0.05)
        epoch2, addr2 = gs.epochs(after=restarted)[-1]
        assert epoch2 != epoch1
        await asyncio.sleep(0.6)  # past the companion's epoch announcement rate limit
        replayed_at = time.time()
        # refused by the epoch only while the clock still finds it fresh (±30 s skew)
        assert replayed_at - captured_at < STATION_AHEAD_S + 28.0, "restart too slow to test"
        gs.send(captured, addr2)  # fresh by the clock, a replay by the epoch
        print(f"replayed {replayed_at - captured_at:.1f} s after the capture")
        # the companion refuses it and tells the station its epoch again
        await until(lambda: gs.epochs(after=replayed_at), 15, second, poll_s=0.05)
        await asyncio.sleep(1.0)
        assert gs.states(41, after=restarted) == []
        assert _commands_logged(log, after=restarted) == []
        # the same companion obeys a fresh command for its new epoch (the check can fail)
        again = Command(command_id=42, name="start", t_exec=time.time())
        gs.send(gs.encoder.encode_command(again, time.time(), epoch=epoch2), addr2)
        await until(lambda: "done" in gs.states(42), 30, second, poll_s=0.05)
    finally:
        code, err = stop_companion(second)
    assert code == 0, err[-2000:]
    assert _commands_logged(log, after=restarted) == ["start"]
    assert "Traceback" not in err


@pytest.mark.timeout(120)
async def test_commands_refused_for_their_signature_are_told_at_warning(
    station: tuple[Station, int], tmp_path: Path
) -> None:
    """The station's private key as the drone's public key (an untagged copy of command.key,
    which no reader can tell from command.pub): every command was dropped, the shell said "no
    reply" and the companion logged nothing above DEBUG."""
    gs, gs_port = station
    config = _config(tmp_path / "d1.toml", gs_port, public_key=TEST_COMMAND_KEY)
    proc = start_companion(config)
    try:
        await until(lambda: gs.epochs(), 60, proc, poll_s=0.05)
        epoch, addr = gs.epochs()[-1]
        for command_id in (51, 52, 53):
            start = Command(command_id=command_id, name="start", t_exec=time.time())
            gs.send(gs.encoder.encode_command(start, time.time(), epoch=epoch), addr)
        await asyncio.sleep(1.0)
        assert gs.states(51) == []
    finally:
        code, err = stop_companion(proc)
    assert code == 0, err[-2000:]
    warned = [line for line in err.splitlines() if "refused bad_signature" in line]
    assert len(warned) == 1, err[-3000:]  # the first; the others at most once a minute
    assert '"level": "warning"' in warned[0]
    assert "ground_station.command_public_key_file" in warned[0]
    assert "the station's command.pub" in warned[0]
    assert "Traceback" not in err
