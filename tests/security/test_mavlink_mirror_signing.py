"""MAVLink 2 signing on the station's fleet mirror (``mavlink_signing_key_file``, 2026-11-25).

Without a key, anyone who reaches ``mavlink_listen`` and sends a HEARTBEAT gets every drone's
positions (row 29 and "Known limits" of docs/security.md). With one, the mirror signs every
frame (a GCS with the key can tell the station's frames from a spoofer's) and answers only a
client whose frames are signed with it, fresh, and newer than that stream's last: an
unsigned or wrongly signed HEARTBEAT, a captured one replayed from elsewhere and a stale one
add nobody and get no answer. pymavlink's own check records a stream's timestamp before it
compares the signature; one forged far-future frame would then lock the real GCS out, and
here does not.
"""

from __future__ import annotations

import hashlib
import os
import socket
import time
from pathlib import Path
from typing import Any

import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mav

from ground_station.config import ConfigError, config_from_mapping
from ground_station.mavlink_mirror import MavlinkMirror
from ground_station.mavlink_signing import signing_timestamp

PASSPHRASE = b"fleet mirror passphrase"
KEY = hashlib.sha256(PASSPHRASE).digest()  # what MAVProxy's `signing setup` makes of it
NOW = time.time()
GCS, STRANGER = ("127.0.0.1", 14550), ("127.0.0.9", 14550)


def _client(key: bytes | None, *, stamp: int | None = None, link_id: int = 1) -> Any:
    client = mav.MAVLink(None, srcSystem=255, srcComponent=190)
    if key is not None:
        client.signing.secret_key = key
        client.signing.sign_outgoing = True
        client.signing.link_id = link_id
        client.signing.timestamp = signing_timestamp(NOW) if stamp is None else stamp
    return client


def _heartbeat(client: Any) -> bytes:
    return bytes(client.heartbeat_encode(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0,
                                         mav.MAV_STATE_ACTIVE).pack(client))


def _arm(client: Any) -> bytes:
    return bytes(client.command_long_encode(3, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0).pack(client))


def _mirror() -> MavlinkMirror:
    mirror = MavlinkMirror(now=NOW, signing_key=KEY)
    mirror.on_data("drone3", {"lat_deg": 47.0, "lon_deg": 8.0}, now=NOW)
    mirror.datagrams_to_send()
    return mirror


def test_a_signed_gcs_is_served_and_every_frame_out_is_signed() -> None:
    mirror = _mirror()
    gcs = _client(KEY)
    mirror.receive_datagram(_heartbeat(gcs) + _arm(gcs), GCS, NOW)
    assert mirror.live_clients(NOW) == [GCS]
    mirror.handle_timer(NOW + 1.0)
    out = mirror.datagrams_to_send()
    checker = mav.MAVLink(None)
    checker.signing.secret_key = KEY  # and no unsigned frame allowed
    checker.signing.timestamp = signing_timestamp(NOW)
    kinds = []
    for frame, _ in out:
        for msg in checker.parse_buffer(frame) or []:
            assert msg.get_type() != "BAD_DATA" and msg._signed, msg
            kinds.append(msg.get_type())
    assert {"COMMAND_ACK", "HEARTBEAT", "GLOBAL_POSITION_INT"} <= set(kinds)
    assert checker.signing.badsig_count == 0 and checker.signing.goodsig_count == len(kinds)


@pytest.mark.parametrize(("client", "counter"), [
    (_client(None), "unsigned"),
    (_client(hashlib.sha256(b"another passphrase").digest()), "bad_signature"),
    (_client(KEY, stamp=signing_timestamp(NOW - 120)), "stale_signature"),
])
def test_strangers_add_nobody_and_get_no_answer(client: Any, counter: str) -> None:
    mirror = _mirror()
    mirror.receive_datagram(_heartbeat(client) + _arm(client), STRANGER, NOW)
    assert mirror.live_clients(NOW) == []
    assert mirror.datagrams_to_send() == []  # not even the COMMAND_ACK DENIED
    assert mirror.counters[counter] == 2


def test_a_replayed_heartbeat_adds_nobody() -> None:
    mirror = _mirror()
    heartbeat = _heartbeat(_client(KEY))
    mirror.receive_datagram(heartbeat, GCS, NOW)
    mirror.receive_datagram(heartbeat, STRANGER, NOW + 0.5)  # captured, sent from elsewhere
    assert mirror.live_clients(NOW + 0.5) == [GCS]
    assert mirror.counters["replayed_signature"] == 1


def test_a_forged_far_future_frame_does_not_lock_the_gcs_out() -> None:
    mirror = _mirror()
    forger = _client(b"\x00" * 32, stamp=2**47)  # the GCS's stream, a wrong signature
    mirror.receive_datagram(_heartbeat(forger), STRANGER, NOW)
    assert mirror.counters["bad_signature"] == 1
    mirror.receive_datagram(_heartbeat(_client(KEY)), GCS, NOW + 0.1)
    assert mirror.live_clients(NOW + 0.1) == [GCS]
    # pymavlink's own check, for comparison, now refuses the genuine frame
    parser = mav.MAVLink(None)
    parser.signing.secret_key = KEY
    parser.signing.timestamp = signing_timestamp(NOW)
    parser.robust_parsing = True
    parser.parse_buffer(_heartbeat(forger))
    genuine = parser.parse_buffer(_heartbeat(_client(KEY))) or []
    assert [m.get_type() for m in genuine] == ["BAD_DATA"]


def test_the_key_file_is_a_private_passphrase(tmp_path: Path) -> None:
    key_file = tmp_path / "mavlink.key"
    key_file.write_bytes(PASSPHRASE + b"\n")
    key_file.chmod(0o600)
    table = {"fleet_key": "k" * 16, "mavlink_listen": "127.0.0.1:14551",
             "mavlink_signing_key_file": str(key_file)}
    assert config_from_mapping(table).mavlink_signing_key == KEY
    key_file.chmod(0o644)
    with pytest.raises(ConfigError, match="chmod 600"):
        config_from_mapping(table)
    key_file.write_bytes(b"short\n")
    key_file.chmod(0o600)
    with pytest.raises(ConfigError, match="at least 8 bytes") as refused:
        config_from_mapping(table)
    assert "short" not in str(refused.value)


def test_a_signed_wildcard_listen_address_is_not_warned_about(
        caplog: pytest.LogCaptureFixture) -> None:
    from ground_station.cli import _warn_every_interface
    from ground_station.config import GroundConfig

    _warn_every_interface(GroundConfig(fleet_key=b"k" * 16, mavlink_listen="0.0.0.0:14551",
                                       mavlink_signing_key=KEY))
    assert caplog.records == []


async def test_a_signed_pymavlink_client_sees_the_drone_over_udp(tmp_path: Path,
                                                                 aiohttp_client: Any) -> None:
    import asyncio

    from ground_station.app import create_app
    from ground_station.config import GroundConfig
    from ground_station.fake_drone import FakeDrone
    from ground_station.keys import LINK
    from tests.integration.test_ground_station_cli import free_port
    from tests.keys import TEST_COMMAND_KEY

    port = free_port(socket.SOCK_DGRAM)
    config = GroundConfig(fleet_id=5, fleet_key=b"s" * 24, command_key=TEST_COMMAND_KEY,
                          data_dir=tmp_path / "gs", udp_port=0, link_lost_s=5.0, fsync=False,
                          mavlink_listen=f"127.0.0.1:{port}", mavlink_signing_key=KEY)
    client = await aiohttp_client(create_app(config, token="t" * 24))
    drone = FakeDrone("drone3", fleet_id=5, key=b"s" * 24,
                      ground=client.server.app[LINK].local_addr)
    await drone.open()
    socks = {}
    for name, key in (("gcs", KEY), ("stranger", None)):
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.bind(("127.0.0.1", 0))
        sock.setblocking(False)
        socks[name] = (sock, _client(key, stamp=signing_timestamp(time.time())))
    got: dict[str, list[Any]] = {"gcs": [], "stranger": []}
    try:
        async with asyncio.timeout(15):
            while not any(m.get_type() == "GLOBAL_POSITION_INT" for m in got["gcs"]):
                drone.send_telemetry("position", {"lat_deg": 47.0, "lon_deg": 8.0})
                for sock, mav_client in socks.values():
                    sock.sendto(_heartbeat(mav_client), ("127.0.0.1", port))
                await asyncio.sleep(0.3)
                for name, (sock, _) in socks.items():
                    while True:
                        try:
                            data = sock.recv(4096)
                        except BlockingIOError:
                            break
                        got[name] += mav.MAVLink(None).parse_buffer(data) or []
        assert got["stranger"] == []
        assert all(m._header.incompat_flags & 1 for m in got["gcs"])  # signed
    finally:
        drone.close()
        for sock, _ in socks.values():
            sock.close()
