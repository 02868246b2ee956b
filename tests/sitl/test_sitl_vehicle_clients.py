"""Acceptance: stock clients (pymavlink over UDP, MAVSDK) against ``uav-sitl vehicle`` run as
a real subprocess on a free port, faster than real time."""

from __future__ import annotations

import asyncio
import json
import math
import os
import socket
import time

import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil

HOME_LAT, HOME_LON, HOME_ALT = 47.397742, 8.545594, 488.0


def _connect(port: int):
    conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255,
                                      source_component=190, dialect="common")
    conn.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID,
                            0, 0, 0)
    hb = conn.wait_heartbeat(timeout=10)
    assert hb is not None, "no heartbeat from the vehicle"
    return conn, hb


def _wait(conn, kind: str, timeout: float = 10.0, cond=lambda m: True):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        msg = conn.recv_match(type=kind, blocking=True, timeout=0.5)
        if msg is not None and cond(msg):
            return msg
    raise AssertionError(f"no {kind} within {timeout} s")


def _command(conn, command: int, *params: float) -> int:
    p = list(params) + [0.0] * (7 - len(params))
    conn.mav.command_long_send(conn.target_system, conn.target_component, command, 0, *p)
    return _wait(conn, "COMMAND_ACK", cond=lambda m: m.command == command).result


def _mission(m, ardupilot: bool):
    d = 25.0 / 111_200.0
    rows = [  # frame, command, p1, p2, lat, lon, alt
        (6, m.MAV_CMD_NAV_TAKEOFF, 0, 0, 0.0, 0.0, 10.0),
        (3, m.MAV_CMD_DO_CHANGE_SPEED, 1, 8.0, 0.0, 0.0, 0.0),
        (6, m.MAV_CMD_NAV_WAYPOINT, 0, 0, HOME_LAT + d, HOME_LON, 10.0),
        (6, m.MAV_CMD_NAV_WAYPOINT, 0, 0, HOME_LAT + d, HOME_LON + d, 10.0),
        (6, m.MAV_CMD_NAV_LAND, 0, 0, HOME_LAT, HOME_LON + d, 0.0),
    ]
    if ardupilot:
        rows.insert(0, (0, m.MAV_CMD_NAV_WAYPOINT, 0, 0, HOME_LAT, HOME_LON, HOME_ALT))
    return rows


@pytest.mark.timeout(90)
@pytest.mark.parametrize("flavour", ["px4", "ardupilot"])
def test_pymavlink_uploads_a_mission_that_is_flown_and_read_back(vehicle_process, flavour):
    vehicle = vehicle_process("--flavour", flavour, "--speedup", "20")
    conn, hb = _connect(vehicle.port)
    m = mavutil.mavlink
    ap = flavour == "ardupilot"
    assert hb.autopilot == (m.MAV_AUTOPILOT_ARDUPILOTMEGA if ap else m.MAV_AUTOPILOT_PX4)
    if ap:  # ArduPilot streams nothing until asked
        conn.mav.request_data_stream_send(1, 1, m.MAV_DATA_STREAM_ALL, 10, 1)
    _wait(conn, "GLOBAL_POSITION_INT")
    rows = _mission(m, ap)
    # Upload: MISSION_COUNT -> MISSION_REQUEST_INT(seq) -> MISSION_ITEM_INT ... -> MISSION_ACK
    conn.mav.mission_count_send(1, 1, len(rows), 0)
    for _ in rows:
        req = _wait(conn, "MISSION_REQUEST_INT")
        frame, cmd, p1, p2, lat, lon, alt = rows[req.seq]
        conn.mav.mission_item_int_send(1, 1, req.seq, frame, cmd, 0, 1, p1, p2, 0, 0,
                                       round(lat * 1e7), round(lon * 1e7), alt, 0)
    assert _wait(conn, "MISSION_ACK").type == m.MAV_MISSION_ACCEPTED
    # Fly it.
    if ap:
        assert _command(conn, m.MAV_CMD_DO_SET_MODE, 1, 5) == 0  # LOITER
        assert _command(conn, m.MAV_CMD_COMPONENT_ARM_DISARM, 1) == 0
        assert _command(conn, m.MAV_CMD_DO_SET_MODE, 1, 3) == 0  # AUTO
    else:
        assert _command(conn, m.MAV_CMD_COMPONENT_ARM_DISARM, 1) == 0
        assert _command(conn, m.MAV_CMD_DO_SET_MODE, 1, 4, 4) == 0  # AUTO.MISSION
    first = 1 if ap else 0
    # DO_CHANGE_SPEED is not a NAV command: it is executed but not "reached".
    nav = [i for i, r in enumerate(rows) if i >= first and r[1] < 95]
    reached = []
    deadline = time.monotonic() + 30
    while len(reached) < len(nav) and time.monotonic() < deadline:
        msg = conn.recv_match(type="MISSION_ITEM_REACHED", blocking=True, timeout=0.5)
        if msg is not None and msg.seq not in reached:
            reached.append(msg.seq)
    assert reached == nav
    _wait(conn, "HEARTBEAT", timeout=15,
          cond=lambda h: not h.base_mode & m.MAV_MODE_FLAG_SAFETY_ARMED)
    pos = _wait(conn, "GLOBAL_POSITION_INT")
    assert abs(pos.relative_alt) < 200  # mm: on the ground
    assert abs(pos.lat / 1e7 - HOME_LAT) < 2e-6  # landed at the last item's position
    # Download: MISSION_REQUEST_LIST -> COUNT -> REQUEST_INT(seq) -> ITEM_INT ... -> ACK
    conn.mav.mission_request_list_send(1, 1, 0)
    assert _wait(conn, "MISSION_COUNT").count == len(rows)
    for seq, row in enumerate(rows):
        conn.mav.mission_request_int_send(1, 1, seq, 0)
        item = _wait(conn, "MISSION_ITEM_INT", cond=lambda x, s=seq: x.seq == s)
        assert (item.command, item.x, item.y) == (row[1], round(row[4] * 1e7),
                                                   round(row[5] * 1e7))
    conn.mav.mission_ack_send(1, 1, 0, 0)
    conn.close()


@pytest.mark.timeout(60)
def test_count_gives_independent_vehicles_on_their_own_ports(vehicle_process):
    vehicle = vehicle_process("--speedup", "5", count=2)
    sysids = [r["sysid"] for r in vehicle.records]
    ports = [r["port"] for r in vehicle.records]
    assert sysids == [1, 2] and len(set(ports)) == 2
    for sysid, port in zip(sysids, ports, strict=True):
        conn, _hb = _connect(port)
        assert conn.target_system == sysid
        conn.close()


@pytest.mark.timeout(30)
def test_vehicle_sends_to_the_out_address_before_hearing_anyone(vehicle_process):
    listener = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    listener.bind(("127.0.0.1", 0))
    listener.settimeout(5)
    try:
        out_port = listener.getsockname()[1]
        vehicle_process("--out", f"127.0.0.1:{out_port}")
        data, _ = listener.recvfrom(2048)
        assert data[0] == 0xFD  # a MAVLink 2 frame, unrequested
    finally:
        listener.close()


mavsdk = pytest.importorskip("mavsdk")


@pytest.mark.timeout(90)
@pytest.mark.parametrize("flavour", ["px4", "ardupilot"])
async def test_mavsdk_reads_telemetry_arms_takes_off_to_10m_and_lands(vehicle_process,
                                                                      flavour):
    from mavsdk.asyncio import Configuration, Mavsdk
    from mavsdk.asyncio.plugins.action import ActionAsync
    from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

    vehicle = vehicle_process("--flavour", flavour, "--speedup", "10")
    # A GCS that heartbeats from the start, so the vehicle learns where to answer.
    config = Configuration.create_manual(245, 190, True)
    async with asyncio.timeout(60), Mavsdk(config) as drone:
        await drone.add_any_connection(f"udpout://127.0.0.1:{vehicle.port}")
        system = await drone.first_autopilot(timeout_s=10.0)
        assert system is not None
        telemetry, action = TelemetryAsync(system), ActionAsync(system)
        if flavour == "ardupilot":  # no streams until requested
            await telemetry.set_rate_position(10.0)
            await telemetry.set_rate_battery(2.0)
            await telemetry.set_rate_in_air(2.0)
            await telemetry.set_rate_landed_state(2.0)
        async for position in telemetry.subscribe_position():
            assert position.latitude_deg == pytest.approx(HOME_LAT, abs=1e-5)
            assert position.relative_altitude_m == pytest.approx(0.0, abs=0.1)
            break
        async for battery in telemetry.subscribe_battery():
            assert 99.0 <= battery.remaining_percent <= 100.0
            assert 16.0 < battery.voltage_v < 17.0
            break
        await action.set_takeoff_altitude(10.0)
        await action.arm()
        await action.takeoff()
        top = 0.0
        async for position in telemetry.subscribe_position():
            top = max(top, position.relative_altitude_m)
            if position.relative_altitude_m > 9.7:
                break
        await asyncio.sleep(0.3)  # 3 simulated seconds of hover: no overshoot
        top = max(top, (await _next(telemetry.subscribe_position())).relative_altitude_m)
        assert 9.7 < top < 10.5
        async for battery in telemetry.subscribe_battery():
            assert battery.remaining_percent < 100.0  # flying costs energy
            break
        await action.land()
        async for in_air in telemetry.subscribe_in_air():
            if not in_air:
                break
        async for armed in telemetry.subscribe_armed():
            if not armed:
                break
        position = await _next(telemetry.subscribe_position())
        assert position.relative_altitude_m == pytest.approx(0.0, abs=0.2)


@pytest.mark.timeout(90)
async def test_mavsdk_mission_raw_upload_download_and_progress(vehicle_process):
    from mavsdk.asyncio import Configuration, Mavsdk
    from mavsdk.asyncio.plugins.action import ActionAsync
    from mavsdk.asyncio.plugins.mission_raw import MissionRawAsync
    from mavsdk.asyncio.plugins.telemetry import TelemetryAsync
    from mavsdk.plugins.mission_raw import MissionItem

    vehicle = vehicle_process("--speedup", "10")
    d = 25 / 111_200
    lat, lon = round((HOME_LAT + d) * 1e7), round(HOME_LON * 1e7)
    lon2 = round((HOME_LON + d) * 1e7)
    nan = float("nan")
    items = [  # seq, frame, command, current, autocontinue, p1-p4, x, y, z, mission_type
        MissionItem(0, 6, 22, 1, 1, 0, 0, 0, nan, 0, 0, 10.0, 0),
        MissionItem(1, 6, 16, 0, 1, 0, 0, 0, nan, lat, lon, 10.0, 0),
        MissionItem(2, 6, 16, 0, 1, 0, 0, 0, nan, lat, lon2, 10.0, 0),
        MissionItem(3, 2, 20, 0, 1, 0, 0, 0, 0, 0, 0, 0, 0),
    ]
    config = Configuration.create_manual(245, 190, True)
    async with asyncio.timeout(60), Mavsdk(config) as drone:
        await drone.add_any_connection(f"udpout://127.0.0.1:{vehicle.port}")
        system = await drone.first_autopilot(timeout_s=10.0)
        mission, action = MissionRawAsync(system), ActionAsync(system)
        telemetry = TelemetryAsync(system)
        await mission.upload_mission(items)
        back = await mission.download_mission()
        assert [(i.seq, i.command, i.x, i.y) for i in back] == [
            (i.seq, i.command, i.x, i.y) for i in items]
        await action.arm()
        await mission.start_mission()
        progress = []
        async for p in mission.subscribe_mission_progress():
            progress.append(p.current)
            if p.current == p.total == len(items):
                break
        assert progress == sorted(progress)
        async for armed in telemetry.subscribe_armed():
            if not armed:  # RTL landed at home and disarmed
                break
        position = await _next(telemetry.subscribe_position())
        assert position.latitude_deg == pytest.approx(HOME_LAT, abs=1e-5)
        assert position.longitude_deg == pytest.approx(HOME_LON, abs=1e-5)


async def _next(gen):
    try:
        return await gen.__anext__()
    finally:
        await gen.aclose()


def test_ready_line_is_json_with_the_bound_port(vehicle_process):
    vehicle = vehicle_process("--pattern", "orbit", "--flavour", "ardupilot")
    rec = vehicle.records[0]
    assert rec["port"] > 0 and rec["flavour"] == "ardupilot"
    assert rec["mission_items"] > 3
    assert json.loads(json.dumps(rec)) == rec
    assert math.isclose(rec["home"][0], HOME_LAT)
