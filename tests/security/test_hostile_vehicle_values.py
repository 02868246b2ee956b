"""The shipped ``uav-companion run`` fed absurd values by its autopilot link (2026-11-25):
NaN, infinities and float32 extremes in ATTITUDE, EKF_STATUS_REPORT and PARAM_VALUE (the
ADS-B and avoidance parameters the peer injector reads), every integer field of
GLOBAL_POSITION_INT, GPS_RAW_INT, SYS_STATUS, BATTERY_STATUS, SYSTEM_TIME and HEARTBEAT at
its limits, a STATUSTEXT of NULs and invalid UTF-8 with severity 255. Twenty rounds, with
HEARTBEATs. Held: the companion keeps running and reporting (a non-finite number would make
the fleet codec refuse the status), nothing non-finite reaches the station, no traceback,
exit 0. ``slow``: a companion starts (its optimiser compiles on a cold cache).
"""

from __future__ import annotations

import math
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from companion.protocol import Decoder, MessageReassembled
from tests.integration.test_peers_e2e import FLEET, KEY, SPEC, companion_config, free_port
from tests.processes import interrupt

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mav

BIN = Path(sys.executable).parent
I32, U32, U64 = 2**31 - 1, 2**32 - 1, 2**64 - 1


def _absurd(ours: Any) -> list[bytes]:
    frames = []
    for v in (math.nan, math.inf, -math.inf, 3.4e38, -3.4e38):
        frames.append(ours.attitude_encode(1, v, v, v, v, v, v).pack(ours))
        frames.append(ours.ekf_status_report_encode(65535, v, v, v, v, v).pack(ours))
        for index, name in enumerate((b"ADSB_TYPE", b"AVD_ENABLE", b"AVD_F_DIST_XY")):
            frames.append(ours.param_value_encode(name, v, 9, 10, index).pack(ours))
    frames += [
        ours.global_position_int_encode(U32, I32, I32, I32, I32, 32767, -32768, 32767,
                                        65534).pack(ours),
        ours.global_position_int_encode(1, 471234567, 85000000, -I32 - 1, -I32 - 1, -32768,
                                        -32768, -32768, 36000).pack(ours),
        ours.gps_raw_int_encode(U64, 255, I32, -I32 - 1, I32, 65534, 65534, 65534, 65534,
                                254).pack(ours),
        ours.sys_status_encode(U32, U32, U32, 65535, 65534, 32767, 127, 65535, 65535, 65535,
                               65535, 65535, 65535).pack(ours),
        ours.battery_status_encode(255, 255, 255, 32767, [65534] * 10, 32767, I32, I32,
                                   -128).pack(ours),
        ours.system_time_encode(U64, U32).pack(ours),
        ours.system_time_encode(1, 0).pack(ours),
        ours.command_ack_encode(65535, 255).pack(ours),
        ours.heartbeat_encode(2, 3, 255, U32, 255).pack(ours),
        ours.statustext_encode(255, b"\x00\xff\xfe" * 16 + b"\xe2\x80\xae").pack(ours),
    ]
    return frames


def _finite(value: Any) -> bool:
    if isinstance(value, float):
        return math.isfinite(value)
    if isinstance(value, dict):
        return all(_finite(v) for v in value.values())
    if isinstance(value, list):
        return all(_finite(v) for v in value)
    return True


@pytest.mark.slow
@pytest.mark.timeout(240)
def test_absurd_autopilot_values_neither_stop_nor_poison_the_reports(tmp_path: Path) -> None:
    vehicle = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    vehicle.bind(("127.0.0.1", 0))
    vehicle.settimeout(60)
    station = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    station.bind(("127.0.0.1", 0))
    station.settimeout(0.2)
    config = companion_config(tmp_path / "drone1.toml", drone="drone1",
                              vehicle_port=vehicle.getsockname()[1],
                              gs_port=station.getsockname()[1],
                              medium=f"broadcast:127.255.255.255:{free_port()}", spec=SPEC)
    err = tmp_path / "drone1.err"
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "MAVLINK20": "1"}
    with err.open("w") as stderr:
        companion = subprocess.Popen([str(BIN / "uav-companion"), "run", "--config",
                                      str(config)], stdout=subprocess.DEVNULL, stderr=stderr,
                                     env=env)
    decoder = Decoder(FLEET, KEY, local_id="gs")
    received: list[tuple[float, str, dict[str, Any]]] = []

    def drain(until: float) -> None:
        while time.monotonic() < until:
            try:
                data, addr = station.recvfrom(65536)
            except TimeoutError:
                continue
            decoder.receive_datagrams([(data, addr)], time.time())
            while (event := decoder.next_event()) is not None:
                if isinstance(event, MessageReassembled):
                    received.append((time.monotonic(), event.message.type,
                                     dict(event.message.data)))

    ours = mav.MAVLink(None, srcSystem=1, srcComponent=1)
    heartbeat = ours.heartbeat_encode(mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                      mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 5,
                                      mav.MAV_STATE_STANDBY).pack(ours)
    try:
        _, companion_addr = vehicle.recvfrom(4096)
        vehicle.sendto(heartbeat, companion_addr)
        deadline = time.monotonic() + 150
        while not any(d.get("autopilot") == "ardupilot" and d.get("optimiser_ready")
                      for _, _, d in received):
            assert time.monotonic() < deadline and companion.poll() is None, \
                err.read_text()[-3000:]
            drain(time.monotonic() + 0.5)
            vehicle.sendto(heartbeat, companion_addr)
        start = time.monotonic()
        frames = _absurd(ours)
        for _ in range(20):
            for frame in frames:
                vehicle.sendto(frame, companion_addr)
            vehicle.sendto(heartbeat, companion_addr)
            drain(time.monotonic() + 0.1)
        for _ in range(10):  # then a sane link again for a second
            vehicle.sendto(heartbeat, companion_addr)
            drain(time.monotonic() + 0.1)
        after = [(t, kind, d) for t, kind, d in received if t >= start]
        assert companion.poll() is None, err.read_text()[-3000:]
        connected = [d for _, kind, d in after if kind == "status" and d.get("connected")]
        assert len(connected) >= 2, after  # it kept reporting, the link up, all along
        assert all(_finite(d) for _, _, d in received)
    finally:
        vehicle.close()
        station.close()
        interrupt(companion, timeout_s=30, sig=signal.SIGTERM)
    assert companion.returncode == 0, err.read_text()[-3000:]
    assert "Traceback" not in err.read_text()
