"""Client-side checks of a MAVLink autopilot, written against what real ArduCopter 4.5 and PX4
SIH do, so the same checks run against ``uav-sitl vehicle`` (both flavours) in the suite and
against a real SITL when one is configured (``UAV_TEST_MAVLINK_URL``).

Only pymavlink, only what a stock client relies on: heartbeat, streams on request, the first
fix and home, parameters, mission upload/download, mode change confirmed by HEARTBEAT, arming,
takeoff, climb and mission progress, landing. Time limits are generous for a real stack at
real time; the simulated vehicle runs faster than real time.
"""

from __future__ import annotations

import math
import os
import struct
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as m

# pymavlink's dialect is process-wide: other tests switch it to "common", which cannot decode
# ArduPilot's EKF_STATUS_REPORT or WIND, so every connection here names its dialect.
DIALECT = "ardupilotmega"

__all__ = ["Autopilot", "run_all_checks"]

PX4_HOLD = (4, 3)
PX4_TAKEOFF = (4, 2)
PX4_MISSION = (4, 4)
PX4_LAND = (4, 6)
AP_GUIDED, AP_AUTO, AP_LAND = 4, 3, 9


@dataclass
class Autopilot:
    """One pymavlink connection to an autopilot and what was learned about it."""

    conn: Any
    sysid: int
    ardupilot: bool
    home: tuple[float, float, float] | None = None
    compid: int = 1
    """The autopilot's component: the companion shares its system id (``source_system`` 1,
    component 191) and ArduPilot forwards the companion's HEARTBEAT to every other link."""

    @classmethod
    def connect(cls, url: str, timeout_s: float = 30.0) -> Autopilot:
        # autoreconnect: a TCP link (ArduPilot SITL's serial ports) closes when the autopilot
        # reboots; like MAVProxy, the test's link connects again.
        conn = mavutil.mavlink_connection(url, source_system=255, source_component=190,
                                          dialect=DIALECT, autoreconnect=True)
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            conn.mav.heartbeat_send(m.MAV_TYPE_GCS, m.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            hb = conn.recv_match(type="HEARTBEAT", blocking=True, timeout=1.0)
            if hb is not None and hb.autopilot in (m.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                                   m.MAV_AUTOPILOT_PX4):
                conn.target_system = hb.get_srcSystem()
                conn.target_component = hb.get_srcComponent()
                return cls(conn=conn, sysid=hb.get_srcSystem(), compid=hb.get_srcComponent(),
                           ardupilot=hb.autopilot == m.MAV_AUTOPILOT_ARDUPILOTMEGA)
        raise AssertionError(f"no autopilot HEARTBEAT on {url} within {timeout_s} s")

    def close(self) -> None:
        """Close the link. ArduPilot SITL's TCP ports take one client at a time: a link left
        to the garbage collector (pymavlink's objects form a cycle) kept port 5760 taken, and
        the next client's connection waited unaccepted, without a byte, until it gave up."""
        self.conn.close()

    def __enter__(self) -> Autopilot:
        return self

    def __exit__(self, *_: object) -> None:
        self.close()

    # ------------------------------------------------------------------------ primitives

    def sent_it(self, msg: Any) -> bool:
        """From the autopilot itself, not another component of its system (the companion)."""
        return bool(msg.get_srcSystem() == self.sysid and msg.get_srcComponent() == self.compid)

    def beat(self) -> None:
        self.conn.mav.heartbeat_send(m.MAV_TYPE_GCS, m.MAV_AUTOPILOT_INVALID, 0, 0, 0)

    def wait(self, kind: str | list[str], timeout_s: float = 10.0,
             cond: Callable[[Any], bool] = lambda msg: True) -> Any:
        deadline = time.monotonic() + timeout_s
        next_beat = 0.0
        while time.monotonic() < deadline:
            if time.monotonic() >= next_beat:  # stay a known GCS (ArduPilot FS_GCS, PX4 DL loss)
                self.beat()
                next_beat = time.monotonic() + 1.0
            msg = self.conn.recv_match(type=kind, blocking=True, timeout=0.3)
            if msg is not None and self.sent_it(msg) and cond(msg):
                return msg
        raise AssertionError(f"no {kind} within {timeout_s} s")

    def collect(self, seconds: float) -> Counter[str]:
        """Message types (and counts) from the autopilot over ``seconds``."""
        seen: Counter[str] = Counter()
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            msg = self.conn.recv_match(blocking=True, timeout=0.2)
            if msg is not None and self.sent_it(msg):
                seen[msg.get_type()] += 1
        return seen

    def command(self, command: int, *params: float, timeout_s: float = 5.0) -> int:
        p = list(params) + [0.0] * (7 - len(params))
        for _ in range(3):  # COMMAND_LONG is retried by every GCS; UDP may lose one
            self.conn.mav.command_long_send(self.sysid, 1, command, 0, *p)
            try:
                ack = self.wait("COMMAND_ACK", timeout_s,
                                cond=lambda a: a.command == command and a.result != 5)
            except AssertionError:
                continue
            return int(ack.result)
        raise AssertionError(f"no COMMAND_ACK for command {command}")

    def heartbeat(self, cond: Callable[[Any], bool], timeout_s: float, what: str) -> Any:
        try:
            return self.wait("HEARTBEAT", timeout_s, cond)
        except AssertionError:
            raise AssertionError(f"HEARTBEAT never showed {what} within {timeout_s} s") from None

    def set_mode(self, mode: int | tuple[int, int], timeout_s: float = 10.0) -> None:
        """Ask for a mode and return once HEARTBEAT shows it (an ACK alone proves nothing)."""
        if isinstance(mode, tuple):
            main, sub = mode
            custom = (main << 16) | (sub << 24)
            result = self.command(m.MAV_CMD_DO_SET_MODE, 1, main, sub)
        else:
            custom = mode
            result = self.command(m.MAV_CMD_DO_SET_MODE, 1, mode)
        assert result == m.MAV_RESULT_ACCEPTED, f"mode {mode} refused: {result}"
        self.heartbeat(lambda hb: hb.custom_mode == custom, timeout_s, f"mode {mode}")

    def armed(self, hb: Any) -> bool:
        return bool(hb.base_mode & m.MAV_MODE_FLAG_SAFETY_ARMED)

    def param(self, name: str, timeout_s: float = 5.0) -> float:
        for _ in range(3):
            self.conn.mav.param_request_read_send(self.sysid, 1, name.encode(), -1)
            try:
                msg = self.wait("PARAM_VALUE", timeout_s / 3,
                                cond=lambda p: p.param_id == name)
            except AssertionError:
                continue
            return param_value(msg, px4=not self.ardupilot)
        raise AssertionError(f"no PARAM_VALUE for {name}")

    def set_param(self, name: str, value: float, param_type: int) -> float:
        raw = value
        if not self.ardupilot and param_type != m.MAV_PARAM_TYPE_REAL32:
            raw = struct.unpack("<f", struct.pack("<i", int(value)))[0]
        self.conn.mav.param_set_send(self.sysid, 1, name.encode(), raw, param_type)
        msg = self.wait("PARAM_VALUE", 5.0, cond=lambda p: p.param_id == name)
        return param_value(msg, px4=not self.ardupilot)

    def request_streams(self, rate_hz: float = 4.0) -> None:
        """What the companion asks for; ArduPilot streams nothing on a new link until asked."""
        for msg_id in (m.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, m.MAVLINK_MSG_ID_ATTITUDE,
                       m.MAVLINK_MSG_ID_SYS_STATUS, m.MAVLINK_MSG_ID_GPS_RAW_INT,
                       m.MAVLINK_MSG_ID_EXTENDED_SYS_STATE):
            self.command(m.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, 1e6 / rate_hz)
        if self.ardupilot:
            self.conn.mav.request_data_stream_send(self.sysid, 1, m.MAV_DATA_STREAM_ALL,
                                                   int(rate_hz), 1)

    def home_alt_amsl_m(self, timeout_s: float = 10.0) -> float:
        """Home's altitude now. PX4 sets home again when it arms (PX4 SIH: 0.8 m higher than
        the home read 1 s after the fix, as its height estimate settled), and a NAV_TAKEOFF
        altitude (AMSL) must be counted from that home, as its relative_alt is."""
        deadline = time.monotonic() + timeout_s
        while True:
            self.command(m.MAV_CMD_REQUEST_MESSAGE, m.MAVLINK_MSG_ID_HOME_POSITION)
            try:
                return float(self.wait("HOME_POSITION", 2.0).altitude) / 1000.0
            except AssertionError:
                assert time.monotonic() < deadline, "no HOME_POSITION"

    def relative_alt_m(self) -> float:
        return self.wait("GLOBAL_POSITION_INT", 5.0).relative_alt / 1000.0


def param_value(msg: Any, *, px4: bool) -> float:
    """PX4 sends integer parameters byte-encoded in the float; ArduPilot casts them."""
    if px4 and msg.param_type != m.MAV_PARAM_TYPE_REAL32:
        return float(struct.unpack("<i", struct.pack("<f", msg.param_value))[0])
    return float(msg.param_value)


# ------------------------------------------------------------------------------ the checks


def check_heartbeat(ap: Autopilot) -> None:
    hbs = [ap.wait("HEARTBEAT", 3.0) for _ in range(3)]
    assert {hb.type for hb in hbs} == {m.MAV_TYPE_QUADROTOR}
    assert all(hb.base_mode & m.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED for hb in hbs)


def check_streams(ap: Autopilot) -> Counter[str]:
    ap.request_streams(4.0)
    ap.conn.mav.timesync_send(0, 123456789)
    sync = ap.wait("TIMESYNC", 5.0, cond=lambda t: t.ts1 == 123456789)
    assert sync.tc1 != 0
    seen = ap.collect(3.0)
    for kind in ("HEARTBEAT", "SYS_STATUS", "GPS_RAW_INT", "ATTITUDE"):
        assert seen[kind] >= 1, f"{kind} not streamed: {dict(seen)}"
    assert 6 <= seen["ATTITUDE"] <= 40, f"ATTITUDE at 4 Hz: {seen['ATTITUDE']} in 3 s"
    if ap.ardupilot:  # REQUEST_DATA_STREAM(ALL): ArduCopter's stream groups
        # (not WIND: ArduCopter sends it only with an airspeed estimate, none on the ground)
        for kind in ("EKF_STATUS_REPORT", "NAV_CONTROLLER_OUTPUT", "RC_CHANNELS", "AHRS",
                     "VIBRATION", "SERVO_OUTPUT_RAW", "VFR_HUD", "SYSTEM_TIME",
                     "BATTERY_STATUS"):
            assert seen[kind] >= 1, f"{kind} not in ArduPilot's streams: {sorted(seen)}"
    return seen


def check_first_fix_and_home(ap: Autopilot, timeout_s: float = 90.0) -> None:
    """Wait for a 3D fix and home, as a client must after boot; then positions are real."""
    ap.wait("GPS_RAW_INT", timeout_s, cond=lambda g: g.fix_type >= 3 and g.lat != 0)
    deadline = time.monotonic() + timeout_s
    home = None
    while home is None:  # before home is set the request fails or goes unanswered
        assert time.monotonic() < deadline, "home never set"
        ap.command(m.MAV_CMD_REQUEST_MESSAGE, m.MAVLINK_MSG_ID_HOME_POSITION)
        try:
            home = ap.wait("HOME_POSITION", 2.0)
        except AssertionError:
            continue
    assert home.latitude != 0 and home.longitude != 0
    ap.home = (home.latitude / 1e7, home.longitude / 1e7, home.altitude / 1000.0)
    gps = m.MAV_SYS_STATUS_SENSOR_GPS
    ap.wait("SYS_STATUS", 10.0, cond=lambda st: st.onboard_control_sensors_present & gps
            and st.onboard_control_sensors_health & gps)
    pos = ap.wait("GLOBAL_POSITION_INT", 10.0, cond=lambda p: p.lat != 0)
    assert abs(pos.lat / 1e7 - ap.home[0]) < 0.001 and abs(pos.lon / 1e7 - ap.home[1]) < 0.001
    if ap.ardupilot:
        # The EKF uses the GPS well after home is set (ArduCopter 4.5 SITL: home ~10 s after
        # the fix, EKF_POS_HORIZ_ABS without CONST_POS_MODE ~23 s after home).
        ekf = ap.wait("EKF_STATUS_REPORT", max(10.0, deadline - time.monotonic()),
                      cond=lambda e: e.flags & m.EKF_POS_HORIZ_ABS
                      and not e.flags & m.EKF_CONST_POS_MODE)
        assert ekf.flags & m.EKF_POS_HORIZ_ABS and not ekf.flags & m.EKF_CONST_POS_MODE


def check_parameters(ap: Autopilot) -> None:
    name = "SYSID_THISMAV" if ap.ardupilot else "MAV_SYS_ID"
    assert ap.param(name) == ap.sysid
    ap.conn.mav.param_request_read_send(ap.sysid, 1, b"", 0)
    first = ap.wait("PARAM_VALUE", 5.0, cond=lambda p: p.param_index == 0)
    assert first.param_count >= 200, f"only {first.param_count} parameters"
    # An unknown name: no PARAM_VALUE for it (both stacks drop the read).
    ap.conn.mav.param_request_read_send(ap.sysid, 1, b"NO_SUCH_PARAM", -1)
    try:
        ap.wait("PARAM_VALUE", 2.0, cond=lambda p: p.param_id == "NO_SUCH_PARAM")
    except AssertionError:
        pass
    else:
        raise AssertionError("a PARAM_VALUE for a parameter that does not exist")
    speed, scale = ("WPNAV_SPEED", 1.0) if ap.ardupilot else ("MPC_XY_CRUISE", 0.01)
    old = ap.param(speed)
    new = old - 100.0 * scale
    assert math.isclose(ap.set_param(speed, new, m.MAV_PARAM_TYPE_REAL32), new, rel_tol=1e-5)
    assert math.isclose(ap.param(speed), new, rel_tol=1e-5)
    ap.set_param(speed, old, m.MAV_PARAM_TYPE_REAL32)


def _mission(ap: Autopilot, north_m: float, alt_m: float) -> list[tuple]:
    assert ap.home is not None
    lat, lon, alt_amsl = ap.home
    dlat = north_m / 111_195.0
    rows: list[tuple] = [  # frame, command, p1..p4, lat, lon, alt
        (6, m.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, lat, lon, alt_m),
        (6, m.MAV_CMD_NAV_WAYPOINT, 0, 0, 0, 0, lat + dlat, lon, alt_m),
        (6, m.MAV_CMD_NAV_WAYPOINT, 0, 0, 0, 0, lat + dlat / 2, lon, alt_m),
    ]
    if ap.ardupilot:  # item 0 is home on ArduPilot
        rows.insert(0, (0, m.MAV_CMD_NAV_WAYPOINT, 0, 0, 0, 0, lat, lon, alt_amsl))
    return rows


def check_mission_upload_download(ap: Autopilot, north_m: float, alt_m: float) -> int:
    """Upload a takeoff and two waypoints, read them back; returns the first waypoint's seq."""
    rows = _mission(ap, north_m, alt_m)
    ap.conn.mav.mission_count_send(ap.sysid, 1, len(rows), 0)
    sent: set[int] = set()
    while True:
        req = ap.wait(["MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK"], 10.0)
        if req.get_type() == "MISSION_ACK":
            assert req.type == m.MAV_MISSION_ACCEPTED, f"upload refused: {req.type}"
            break
        frame, cmd, p1, p2, p3, p4, lat, lon, alt = rows[req.seq]
        ap.conn.mav.mission_item_int_send(ap.sysid, 1, req.seq, frame, cmd, 0, 1, p1, p2, p3,
                                          p4, round(lat * 1e7), round(lon * 1e7), alt, 0)
        sent.add(req.seq)
    assert sent == set(range(len(rows)))
    ap.conn.mav.mission_request_list_send(ap.sysid, 1, 0)
    count = ap.wait("MISSION_COUNT", 5.0).count
    assert count == len(rows)
    first = 1 if ap.ardupilot else 0
    for seq in range(first, count):
        ap.conn.mav.mission_request_int_send(ap.sysid, 1, seq, 0)
        item = ap.wait("MISSION_ITEM_INT", 5.0, cond=lambda i, s=seq: i.seq == s)
        assert item.command == rows[seq][1]
        assert abs(item.x - round(rows[seq][6] * 1e7)) <= 1
        assert abs(item.y - round(rows[seq][7] * 1e7)) <= 1
        assert math.isclose(item.z, rows[seq][8], abs_tol=0.01)
    ap.conn.mav.mission_ack_send(ap.sysid, 1, m.MAV_MISSION_ACCEPTED, 0)
    return first + 1


def check_arm_and_takeoff(ap: Autopilot, alt_m: float) -> None:
    """Mode confirmed by HEARTBEAT, armed, taken off and climbed to ``alt_m``."""
    assert ap.home is not None
    if ap.ardupilot:
        ap.set_mode(AP_GUIDED)
        assert ap.command(m.MAV_CMD_COMPONENT_ARM_DISARM, 1) == m.MAV_RESULT_ACCEPTED
        ap.heartbeat(ap.armed, 5.0, "armed")
        assert ap.command(m.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, alt_m) == 0
    else:
        ap.set_mode(PX4_HOLD)
        assert ap.command(m.MAV_CMD_COMPONENT_ARM_DISARM, 1) == m.MAV_RESULT_ACCEPTED
        ap.heartbeat(ap.armed, 5.0, "armed")
        # PX4: NAV_TAKEOFF param7 is AMSL (from the home set at arming); lat/lon NaN keep
        # the current position.
        result = ap.command(m.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan,
                            ap.home_alt_amsl_m() + alt_m)
        assert result == m.MAV_RESULT_ACCEPTED
    deadline = time.monotonic() + 60.0
    while ap.relative_alt_m() < 0.9 * alt_m:
        assert time.monotonic() < deadline, f"did not climb to {alt_m} m"
    hb = ap.wait("HEARTBEAT", 3.0)
    assert ap.armed(hb)
    ap.wait("EXTENDED_SYS_STATE", 5.0,
            cond=lambda e: e.landed_state == m.MAV_LANDED_STATE_IN_AIR)


def check_mission_progress(ap: Autopilot, first_wp: int) -> None:
    """AUTO/Mission from the air: MISSION_CURRENT advances, MISSION_ITEM_REACHED arrives."""
    if ap.ardupilot:
        ap.set_mode(AP_AUTO)
    else:
        ap.set_mode(PX4_MISSION)
    reached = ap.wait("MISSION_ITEM_REACHED", 90.0, cond=lambda r: r.seq >= first_wp)
    assert reached.seq >= first_wp
    current = ap.wait("MISSION_CURRENT", 10.0)
    assert current.seq >= first_wp


def check_land(ap: Autopilot) -> None:
    ap.set_mode(AP_LAND if ap.ardupilot else PX4_LAND)
    ap.heartbeat(lambda hb: not ap.armed(hb), 120.0, "disarmed after landing")
    assert ap.relative_alt_m() < 1.0


def run_all_checks(url: str, *, alt_m: float = 10.0, north_m: float = 30.0) -> Autopilot:
    """Every check in flight order, against the autopilot at ``url``."""
    with Autopilot.connect(url) as ap:  # closed after: what was learnt stays readable
        check_heartbeat(ap)
        check_streams(ap)
        check_first_fix_and_home(ap)
        check_parameters(ap)
        first_wp = check_mission_upload_download(ap, north_m, alt_m)
        check_arm_and_takeoff(ap, alt_m)
        check_mission_progress(ap, first_wp)
        check_land(ap)
    return ap
