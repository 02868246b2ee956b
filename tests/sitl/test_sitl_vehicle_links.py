"""A flight controller with two links (``uav-sitl vehicle --serial --gcs-port``): the
companion's UART and a GCS's UDP port, each with its own streams, as ArduPilot keeps them
per channel and PX4 per MAVLink instance (sitl/vehicle/links.py)."""

from __future__ import annotations

import asyncio
import contextlib
import os
import socket
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sitl.vehicle.core import VehicleConfig
from sitl.vehicle.flavour import FLAVOURS
from sitl.vehicle.serial_pty import start_serial_and_udp_vehicle

ATTITUDE, GLOBAL_POSITION_INT = 30, 33


def _seen(parser: mavlink.MAVLink, data: bytes, into: Counter[tuple[str, int, int]]) -> None:
    for msg in parser.parse_buffer(data) or []:
        into[(msg.get_type(), msg.get_srcSystem(), msg.get_srcComponent())] += 1


async def test_a_gcs_on_its_link_never_changes_the_companions_streams(tmp_path: Path) -> None:
    config = VehicleConfig(system_id=1, flavour=FLAVOURS["ardupilot"], first_fix_s=0.0)
    serial, udp = await start_serial_and_udp_vehicle(config, baud=115200,
                                                     link=tmp_path / "tty", port=0)
    fd = os.open(str(tmp_path / "tty"), os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setblocking(False)
    comp = mavlink.MAVLink(None, srcSystem=1, srcComponent=191)
    gcs = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    on_line: Counter[tuple[str, int, int]] = Counter()
    on_udp: Counter[tuple[str, int, int]] = Counter()
    line_parser, udp_parser = mavlink.MAVLink(None), mavlink.MAVLink(None)
    for p in (line_parser, udp_parser):
        p.robust_parsing = True
    try:
        os.write(fd, comp.heartbeat_encode(18, 8, 0, 0, 4).pack(comp))
        os.write(fd, comp.command_long_encode(1, 1, 511, 0, ATTITUDE, 100_000, 0, 0, 0, 0,
                                              0).pack(comp))  # ATTITUDE at 10 Hz
        for msg in (gcs.heartbeat_encode(6, 8, 0, 0, 4),
                    gcs.request_data_stream_encode(1, 1, 0, 2, 1),  # ALL at 2 Hz (QGC-like)
                    gcs.command_long_encode(1, 1, 511, 0, ATTITUDE, -1, 0, 0, 0, 0, 0)):
            sock.sendto(msg.pack(gcs), udp.address)
            await asyncio.sleep(0.05)

        def drain() -> None:
            with contextlib.suppress(BlockingIOError):
                _seen(line_parser, os.read(fd, 65536), on_line)
            while True:
                try:
                    _seen(udp_parser, sock.recv(65536), on_udp)
                except BlockingIOError:
                    break

        await asyncio.sleep(0.5)  # what was asked takes effect
        drain()
        # an answer goes to the link that asked: each its own ACK, not the other's
        assert on_line[("COMMAND_ACK", 1, 1)] == on_udp[("COMMAND_ACK", 1, 1)] == 1
        for counter in (on_line, on_udp):
            counter.clear()
        t0 = time.monotonic()
        beats = 0
        while time.monotonic() - t0 < 2.0:
            if time.monotonic() - t0 > 0.5 * beats:  # both clients beat, as they do
                beats += 1
                os.write(fd, comp.heartbeat_encode(18, 8, 0, 0, 4).pack(comp))
                sock.sendto(gcs.heartbeat_encode(6, 8, 0, 0, 4).pack(gcs), udp.address)
            await asyncio.sleep(0.05)
            drain()
    finally:
        os.close(fd)
        sock.close()
        serial.close()
        udp.close()
    ap = ("ATTITUDE", 1, 1)
    assert 15 <= on_line[ap] <= 22, on_line  # 10 Hz for 2 s: the GCS turned it off elsewhere
    assert on_udp[ap] == 0, on_udp  # the GCS's own link: off, as it asked
    assert 3 <= on_udp[("GLOBAL_POSITION_INT", 1, 1)] <= 5, on_udp  # its ALL at 2 Hz
    assert on_line[("GLOBAL_POSITION_INT", 1, 1)] == 0, on_line  # never asked on the line
    assert on_line[("HEARTBEAT", 1, 1)] >= 1 and on_udp[("HEARTBEAT", 1, 1)] >= 1
    # each client's HEARTBEAT is routed to the other link, never echoed to its sender
    assert on_line[("HEARTBEAT", 255, 190)] >= 3 and on_udp[("HEARTBEAT", 1, 191)] >= 3
    assert on_line[("HEARTBEAT", 1, 191)] == 0 and on_udp[("HEARTBEAT", 255, 190)] == 0
    assert on_line[("COMMAND_ACK", 1, 1)] == on_udp[("COMMAND_ACK", 1, 1)] == 0


def test_the_cli_serves_both_links(tmp_path: Path) -> None:
    sitl = Path(sys.executable).parent / "uav-sitl"
    proc = subprocess.Popen([str(sitl), "vehicle", "--serial", "--serial-link",
                             str(tmp_path / "fc"), "--gcs-port", "0", "--duration", "5"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        assert line.startswith("READY ") and '"serial": ' in line and '"port": ' in line, line
    finally:
        proc.terminate()
        proc.communicate(timeout=10)
    bad = subprocess.run([str(sitl), "vehicle", "--gcs-port", "1"], capture_output=True,
                         text=True, timeout=30, check=False)
    assert bad.returncode == 2 and "--gcs-port needs --serial" in bad.stderr
