"""The simulated vehicle's serial line (a pty) carries what a UART of that baud rate would."""

from __future__ import annotations

import asyncio
import itertools
import os
import time
from pathlib import Path

from pymavlink.dialects.v20 import common as mavlink

from sitl.vehicle.core import VehicleConfig
from sitl.vehicle.flavour import FLAVOURS
from sitl.vehicle.serial_pty import start_serial_vehicle


def _read_all(fd: int) -> bytes:
    out = b""
    while True:
        try:
            chunk = os.read(fd, 65536)
        except BlockingIOError:
            return out
        if not chunk:
            return out
        out += chunk


async def test_a_slow_line_drops_frames_instead_of_queueing(tmp_path: Path) -> None:
    config = VehicleConfig(system_id=1, flavour=FLAVOURS["px4"])
    link = start_serial_vehicle(config, baud=1200, link=tmp_path / "tty",  # 120 B/s
                                tx_buffer_bytes=256)
    fd = os.open(str(tmp_path / "tty"), os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        t0 = time.monotonic()
        received = b""
        while time.monotonic() - t0 < 2.0:
            await asyncio.sleep(0.05)
            received += _read_all(fd)
        elapsed = time.monotonic() - t0
    finally:
        os.close(fd)
        link.close()
    # One full transmit buffer at start, then at most the line rate.
    assert len(received) <= 256 + 120 * (elapsed + 0.2)
    assert link.counters["tx_dropped_frames"] > 0
    assert link.counters["tx_bytes"] == len(received)
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    kinds = {m.get_type() for m in parser.parse_buffer(received) or []}
    assert "HEARTBEAT" in kinds and "BAD_DATA" not in kinds
    assert not (tmp_path / "tty").exists()


async def test_frames_split_across_writes_reach_the_vehicle(tmp_path: Path) -> None:
    """A UART delivers bytes, not datagrams: a command arriving in pieces still counts."""
    config = VehicleConfig(system_id=1, flavour=FLAVOURS["ardupilot"])
    link = start_serial_vehicle(config, baud=921600, link=tmp_path / "tty")
    fd = os.open(str(tmp_path / "tty"), os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        sender = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
        frame = sender.param_request_read_encode(1, 1, b"SYSID_THISMAV", -1).pack(sender)
        for i in range(0, len(frame), 5):
            os.write(fd, frame[i:i + 5])
            await asyncio.sleep(0.01)
        parser = mavlink.MAVLink(None)
        names: list[str] = []
        for _ in range(40):
            await asyncio.sleep(0.05)
            for msg in parser.parse_buffer(_read_all(fd)) or []:
                if msg.get_type() == "PARAM_VALUE":
                    names.append(msg.param_id)
            if names:
                break
    finally:
        os.close(fd)
        link.close()
    assert names == ["SYSID_THISMAV"]
    assert link.counters["rx_bytes"] == len(frame)


async def test_a_parameter_download_on_a_full_line_is_paced_not_lost(tmp_path: Path) -> None:
    """A GCS downloads all parameters over a 57600-baud line (~16 kB for ArduPilot's 440):
    ArduPilot sends them with at most 30 % of the line as the UART frees, and the HEARTBEAT
    and the streams keep coming; the fake dropped what did not fit its buffer at once, most
    of the list and the HEARTBEAT behind it."""
    config = VehicleConfig(system_id=1, flavour=FLAVOURS["ardupilot"])
    link = start_serial_vehicle(config, baud=57600, link=tmp_path / "tty")
    fd = os.open(str(tmp_path / "tty"), os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    gcs = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    names: set[str] = set()
    beats: list[float] = []
    attitudes = 0
    count = 0
    try:
        # streams too, as a GCS asks for them: they fill the line the parameters share
        os.write(fd, gcs.request_data_stream_encode(1, 1, 0, 10, 1).pack(gcs))
        os.write(fd, gcs.param_request_list_encode(1, 1).pack(gcs))
        t0 = time.monotonic()
        while time.monotonic() - t0 < 20.0 and not (count and len(names) >= count):
            await asyncio.sleep(0.05)
            for msg in parser.parse_buffer(_read_all(fd)) or []:
                if msg.get_type() == "PARAM_VALUE":
                    names.add(msg.param_id)
                    count = msg.param_count
                elif msg.get_type() == "HEARTBEAT":
                    beats.append(time.monotonic())
                elif msg.get_type() == "ATTITUDE":
                    attitudes += 1
        elapsed = time.monotonic() - t0
    finally:
        os.close(fd)
        link.close()
    assert count > 400 and len(names) == count, (len(names), count)
    assert 6.0 < elapsed < 20.0  # 30 % of the line's 5760 B/s: ~9 s, not all at once
    assert attitudes > 5 * elapsed  # the streams went on (10 Hz asked, the line is full)
    gaps = [b - a for a, b in itertools.pairwise(beats)]
    assert beats and max(gaps, default=0.0) < 1.6, gaps  # the HEARTBEAT went on meanwhile
