"""A small MAVLink vehicle on loopback UDP for the companion's tests (until sitl.vehicle exists).

It plays the two autopilot families the companion must handle:

* ``ardupilot``: sends only HEARTBEAT until streams are requested (SET_MESSAGE_INTERVAL or
  REQUEST_DATA_STREAM); integer parameters are sent as their float value; refuses to arm in
  RTL/LAND.
* ``px4``: streams unasked; integer parameters are byte-encoded in PARAM_VALUE's float.

Run as a script (``python companion_fake_vehicle.py --port N``) to be killed and restarted by
the integration tests, or as a thread with :class:`FakeVehicle`.
"""

from __future__ import annotations

import argparse
import math
import os
import select
import socket
import struct
import sys
import threading
import time

os.environ.setdefault("MAVLINK20", "1")

import contextlib

from pymavlink.dialects.v20 import ardupilotmega as mav

ARDUCOPTER_MODES = {"STABILIZE": 0, "GUIDED": 4, "LOITER": 5, "RTL": 6, "LAND": 9, "AUTO": 3}
PX4_POSCTL = (mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 3 << 16)
STREAM_IDS = {
    mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: "position",
    mav.MAVLINK_MSG_ID_ATTITUDE: "attitude",
    mav.MAVLINK_MSG_ID_SYS_STATUS: "sys_status",
    mav.MAVLINK_MSG_ID_BATTERY_STATUS: "battery_status",
    mav.MAVLINK_MSG_ID_GPS_RAW_INT: "gps",
    mav.MAVLINK_MSG_ID_SYSTEM_TIME: "system_time",
    mav.MAVLINK_MSG_ID_EKF_STATUS_REPORT: "ekf",
}
EKF_READY = (mav.EKF_ATTITUDE | mav.EKF_VELOCITY_HORIZ | mav.EKF_VELOCITY_VERT
             | mav.EKF_POS_HORIZ_REL | mav.EKF_POS_HORIZ_ABS | mav.EKF_POS_VERT_ABS)
EKF_NO_ORIGIN = mav.EKF_ATTITUDE | mav.EKF_VELOCITY_VERT | mav.EKF_CONST_POS_MODE


class FakeVehicle:
    def __init__(self, *, port: int = 0, autopilot: str = "ardupilot",
                 accept_message_interval: bool = True, system_id: int = 1,
                 lat_deg: float = 50.0615, lon_deg: float = 19.9373,
                 fix_after_s: float = 0.0) -> None:
        self.autopilot = autopilot
        self.accept_message_interval = accept_message_interval
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.sock.bind(("127.0.0.1", port))
        self.port = self.sock.getsockname()[1]
        self.mav = mav.MAVLink(None, srcSystem=system_id, srcComponent=1)
        self.mav.robust_parsing = True
        self.peer: tuple[str, int] | None = None
        self.rates_hz: dict[int, float] = {}
        if autopilot == "px4":
            self.rates_hz = {i: 5.0 for i, kind in STREAM_IDS.items() if kind != "ekf"}
        self.next_due: dict[int, float] = {}
        self.custom_mode = ARDUCOPTER_MODES["STABILIZE"] if autopilot == "ardupilot" else 0
        self.base_mode = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        self.armed = False
        self.system_status = mav.MAV_STATE_ACTIVE  # MAV_STATE_CRITICAL: a failsafe
        self.lat_deg, self.lon_deg = lat_deg, lon_deg
        self.t0 = time.time()
        self.fix_after_s = fix_after_s
        """Like ArduPilot after boot: no fix, 0/0 and an EKF without origin for this long
        after the first client spoke (the vehicle 'boots' when someone listens)."""
        self.t_first_peer: float | None = None
        self.silent_until = 0.0
        """An autopilot outage: nothing is sent (or answered) before this time.time()."""
        self.received: list[str] = []
        self.data_stream_requests = 0
        self.params: dict[str, tuple[float, int]] = {
            "SYSID_THISMAV": (float(system_id), mav.MAV_PARAM_TYPE_INT32),
            "WPNAV_SPEED": (500.0, mav.MAV_PARAM_TYPE_REAL32),
            "MAV_SYS_ID": (float(system_id), mav.MAV_PARAM_TYPE_INT32),
        }
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # -- life cycle
    def start(self) -> FakeVehicle:
        self._thread = threading.Thread(target=self.serve, daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5)
        self.sock.close()

    def serve(self) -> None:
        next_hb = 0.0
        while not self._stop.is_set():
            ready, _, _ = select.select([self.sock], [], [], 0.01)
            if ready:
                try:
                    data, addr = self.sock.recvfrom(4096)
                except OSError:
                    continue
                self.peer = addr
                if self.t_first_peer is None:
                    self.t_first_peer = time.time()
                for msg in self.mav.parse_buffer(data) or []:
                    self.handle(msg)
            now = time.time()
            if self.peer is None or now < self.silent_until:
                continue
            if now >= next_hb:
                self.send(self.heartbeat())
                next_hb = now + 1.0
            for msg_id, rate in self.rates_hz.items():
                if rate <= 0:
                    continue
                if now >= self.next_due.get(msg_id, 0.0):
                    self.next_due[msg_id] = now + 1.0 / rate
                    self.send(self.telemetry(msg_id, now))

    def send(self, msg: mav.MAVLink_message) -> None:
        if self.peer is None:
            return
        with contextlib.suppress(OSError):
            self.sock.sendto(msg.pack(self.mav), self.peer)

    # -- behaviour
    def heartbeat(self) -> mav.MAVLink_message:
        base = self.base_mode | (mav.MAV_MODE_FLAG_SAFETY_ARMED if self.armed else 0)
        autopilot = mav.MAV_AUTOPILOT_PX4 if self.autopilot == "px4" else \
            mav.MAV_AUTOPILOT_ARDUPILOTMEGA
        return mav.MAVLink_heartbeat_message(mav.MAV_TYPE_QUADROTOR, autopilot, base,
                                             self.custom_mode, self.system_status, 3)

    def telemetry(self, msg_id: int, now: float) -> mav.MAVLink_message:
        t = now - self.t0
        boot_ms = int(t * 1000) & 0xFFFFFFFF
        fixed = self.t_first_peer is not None and now - self.t_first_peer >= self.fix_after_s
        lat = self.lat_deg + 1e-4 * math.sin(0.2 * t) if fixed else 0.0
        lon = self.lon_deg + 1e-4 * math.cos(0.2 * t) if fixed else 0.0
        kind = STREAM_IDS[msg_id]
        if kind == "ekf":
            return mav.MAVLink_ekf_status_report_message(
                EKF_READY if fixed else EKF_NO_ORIGIN, 0.1, 0.1, 0.1, 0.1, 0.1)
        if kind == "position":
            return mav.MAVLink_global_position_int_message(
                boot_ms, int(lat * 1e7), int(lon * 1e7), 250_000, 30_000, 100, -50, 0, 9000)
        if kind == "attitude":
            return mav.MAVLink_attitude_message(boot_ms, 0.1, -0.05, 1.5, 0.0, 0.0, 0.01)
        if kind == "sys_status":
            return mav.MAVLink_sys_status_message(0, 0, 0, 500, 12_300, 1_500, 87, 0, 0, 0, 0,
                                                  0, 0)
        if kind == "battery_status":
            cells = [4100, 4100, 4100] + [65535] * 7
            return mav.MAVLink_battery_status_message(0, 0, 0, 2500, cells, 1500, -1, -1, 87)
        if kind == "gps":
            return mav.MAVLink_gps_raw_int_message(int(t * 1e6), 3 if fixed else 1,
                                                   int(lat * 1e7),
                                                   int(lon * 1e7), 250_000, 80, 65535, 0,
                                                   65535, 12)
        return mav.MAVLink_system_time_message(int(now * 1e6), boot_ms)

    def outage(self, seconds: float) -> None:
        """The autopilot goes quiet for ``seconds`` (a reboot, a cable pulled)."""
        self.silent_until = time.time() + seconds

    def handle(self, msg: mav.MAVLink_message) -> None:
        if time.time() < self.silent_until:
            return
        kind = msg.get_type()
        self.received.append(kind)
        if kind == "COMMAND_LONG":
            self.command(msg)
        elif kind == "REQUEST_DATA_STREAM":
            self.data_stream_requests += 1
            if msg.start_stop:
                self.rates_hz = {i: float(msg.req_message_rate) for i in STREAM_IDS}
        elif kind == "PARAM_REQUEST_READ":
            name = msg.param_id
            if name not in self.params:  # ArduCopter 4.5 SITL answers an unknown name with
                return  # nothing (measured), as does PX4 since v1.14
            value, ptype = self.params[name]
            if self.autopilot == "px4" and ptype == mav.MAV_PARAM_TYPE_INT32:
                value = struct.unpack("<f", struct.pack("<i", int(value)))[0]
            self.send(mav.MAVLink_param_value_message(name.encode(), value, ptype,
                                                      len(self.params), 0))

    def ack(self, command: int, result: int) -> None:
        self.send(mav.MAVLink_command_ack_message(command, result))

    def command(self, msg: mav.MAVLink_message) -> None:
        cmd = msg.command
        if cmd == mav.MAV_CMD_SET_MESSAGE_INTERVAL:
            if not self.accept_message_interval:
                self.ack(cmd, mav.MAV_RESULT_UNSUPPORTED)
                return
            msg_id = int(msg.param1)
            if self.autopilot == "ardupilot" and msg_id == mav.MAVLINK_MSG_ID_ESTIMATOR_STATUS:
                # ArduCopter 4.5 (measured on its SITL): a message it has no ap_message for
                self.send(mav.MAVLink_statustext_message(
                    mav.MAV_SEVERITY_INFO, f"No ap_message for mavlink id ({msg_id})".encode()))
                self.ack(cmd, mav.MAV_RESULT_DENIED)
                return
            if self.autopilot == "px4" and msg_id in (mav.MAVLINK_MSG_ID_HEARTBEAT,
                                                      mav.MAVLINK_MSG_ID_EKF_STATUS_REPORT):
                # PX4 SIH (measured, docs/sitl.md): HEARTBEAT or a message it lacks
                self.ack(cmd, mav.MAV_RESULT_FAILED)
                return
            if msg_id in STREAM_IDS:
                interval_us = msg.param2
                self.rates_hz[msg_id] = 1e6 / interval_us if interval_us > 0 else 0.0
            self.ack(cmd, mav.MAV_RESULT_ACCEPTED)
        elif cmd == mav.MAV_CMD_DO_SET_MODE:
            self.custom_mode = int(msg.param2)
            self.ack(cmd, mav.MAV_RESULT_ACCEPTED)
            self.send(self.heartbeat())
        elif cmd == mav.MAV_CMD_COMPONENT_ARM_DISARM:
            refused = self.autopilot == "ardupilot" and self.custom_mode in (
                ARDUCOPTER_MODES["RTL"], ARDUCOPTER_MODES["LAND"])
            if refused:
                self.ack(cmd, mav.MAV_RESULT_DENIED)
                return
            self.armed = msg.param1 == 1
            self.ack(cmd, mav.MAV_RESULT_ACCEPTED)
            self.send(self.heartbeat())
        else:
            self.ack(cmd, mav.MAV_RESULT_UNSUPPORTED)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--port", type=int, default=0)
    parser.add_argument("--autopilot", choices=["ardupilot", "px4"], default="ardupilot")
    parser.add_argument("--fix-after", type=float, default=0.0,
                        help="seconds without a GPS fix (0/0, EKF without origin) after start")
    args = parser.parse_args(argv)
    vehicle = FakeVehicle(port=args.port, autopilot=args.autopilot, fix_after_s=args.fix_after)
    print(f"PORT {vehicle.port}", flush=True)
    with contextlib.suppress(KeyboardInterrupt):
        vehicle.serve()
    return 0


if __name__ == "__main__":
    sys.exit(main())
