"""The built-in vehicle routes its clients' HEARTBEATs to its other clients, as ArduCopter 4.5
SITL was seen to (a GCS on serial 0 received the companion's HEARTBEAT, system 1 component 191,
from serial 1). A client that takes every message of system 1 for the autopilot's is wrong
against a real autopilot; it is now wrong here too."""

from __future__ import annotations

import os
import time
from collections import Counter

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as M


def _link(port: int, system: int, component: int):
    return mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=system,
                                      source_component=component, dialect="ardupilotmega")


def test_a_clients_heartbeat_reaches_the_other_clients_not_itself(vehicle_process) -> None:
    vehicle = vehicle_process("--flavour", "ardupilot")
    companion = _link(vehicle.port, 1, M.MAV_COMP_ID_ONBOARD_COMPUTER)
    gcs = _link(vehicle.port, 255, 190)
    heard: dict[str, Counter[tuple[int, int]]] = {"companion": Counter(), "gcs": Counter()}
    deadline = time.monotonic() + 2.0
    next_beat = 0.0
    while time.monotonic() < deadline:
        if time.monotonic() >= next_beat:
            companion.mav.heartbeat_send(M.MAV_TYPE_ONBOARD_CONTROLLER,
                                         M.MAV_AUTOPILOT_INVALID, 0, 0, M.MAV_STATE_ACTIVE)
            gcs.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            next_beat = time.monotonic() + 0.25
        for name, link in (("companion", companion), ("gcs", gcs)):
            msg = link.recv_match(type="HEARTBEAT", blocking=True, timeout=0.02)
            if msg is not None:
                heard[name][(msg.get_srcSystem(), msg.get_srcComponent())] += 1
    companion.close()
    gcs.close()
    assert heard["gcs"][(1, 1)] >= 1 and heard["companion"][(1, 1)] >= 1  # the autopilot
    assert heard["gcs"][(1, M.MAV_COMP_ID_ONBOARD_COMPUTER)] >= 3  # routed
    assert heard["companion"][(255, 190)] >= 3
    assert heard["companion"][(1, M.MAV_COMP_ID_ONBOARD_COMPUTER)] == 0  # never echoed
    assert heard["gcs"][(255, 190)] == 0
