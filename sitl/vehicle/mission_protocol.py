"""The mission microservice of the simulated vehicle (a mixin): upload, download, clear,
set-current, with the retries and results of the MAVLink mission protocol."""

from __future__ import annotations

from collections import Counter
from collections.abc import Hashable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sitl.vehicle.autopilot import FlightController
from sitl.vehicle.fields import mission_item_error
from sitl.vehicle.flavour import Flavour
from sitl.vehicle.mission import MissionItem
from sitl.vehicle.telemetry import Telemetry

if TYPE_CHECKING:
    from sitl.vehicle.core import VehicleConfig

# MAV_MISSION_RESULT
MISSION_ACCEPTED = 0
MISSION_NO_SPACE = 4
MISSION_INVALID_SEQUENCE = 13
MISSION_CANCELLED = 15
MAX_MISSION_ITEMS = 1000


@dataclass(slots=True, kw_only=True)
class _Upload:
    mission_type: int
    count: int
    peer: tuple[int, int]
    items: list[MissionItem] = field(default_factory=list)
    deadline: float = 0.0
    retries: int = 0
    link: Hashable = None
    """The link the upload came on: its requests are retried there."""


class MissionProtocol:
    """MISSION_* handlers; mixed into VehicleCore, which owns ``_stored`` and ``_upload``."""

    config: VehicleConfig
    fc: FlightController
    flavour: Flavour
    counters: Counter[str]
    telemetry: Telemetry
    _stored: dict[int, list[MissionItem]]
    _upload: _Upload | None
    _current: Hashable | None

    if TYPE_CHECKING:  # provided by VehicleCore
        def _send(self, msg: Any) -> None:
            raise NotImplementedError

        def statustext(self, severity: int, text: str) -> None:
            raise NotImplementedError

    def _on_mission_count(self, msg: Any, now: float) -> None:
        mtype = getattr(msg, "mission_type", 0)
        peer = (msg.get_srcSystem(), msg.get_srcComponent())
        if mtype not in self._stored:
            self._send(mavlink.MAVLink_mission_ack_message(*peer, 3, mtype))
            return
        if msg.count > MAX_MISSION_ITEMS:
            self._send(mavlink.MAVLink_mission_ack_message(*peer, MISSION_NO_SPACE, mtype))
            return
        if msg.count == 0:
            self._upload = None
            self._store(mtype, [])
            self._send(mavlink.MAVLink_mission_ack_message(*peer, MISSION_ACCEPTED, mtype))
            return
        self._upload = _Upload(mission_type=mtype, count=msg.count, peer=peer,
                               link=self._current)
        self._request_item(self._upload, now)

    def _request_item(self, up: _Upload, now: float) -> None:
        up.deadline = now + self.config.protocol_timeout_s * self.config.speedup
        self._send(mavlink.MAVLink_mission_request_int_message(
            up.peer[0], up.peer[1], len(up.items), up.mission_type))

    def _on_mission_item(self, msg: Any, now: float) -> None:
        up = self._upload
        mtype = getattr(msg, "mission_type", 0)
        if up is None or mtype != up.mission_type:
            self.counters["mission_item_unexpected"] += 1
            return
        if msg.seq != len(up.items):
            self.counters["mission_item_out_of_sequence"] += 1
            self._request_item(up, now)
            return
        is_int = msg.get_type() == "MISSION_ITEM_INT"
        scale = 1e-7 if is_int else 1.0
        item_error = mission_item_error(msg, scale)
        if item_error is not None:
            self.counters["mission_item_invalid"] += 1
            self._upload = None
            self._send(mavlink.MAVLink_mission_ack_message(*up.peer, item_error, mtype))
            return
        up.items.append(MissionItem(
            seq=msg.seq, frame=msg.frame, command=msg.command, current=msg.current,
            autocontinue=msg.autocontinue, param1=msg.param1, param2=msg.param2,
            param3=msg.param3, param4=msg.param4, lat_deg=msg.x * scale, lon_deg=msg.y * scale,
            z_m=msg.z, mission_type=mtype))
        up.retries = 0
        if len(up.items) < up.count:
            self._request_item(up, now)
            return
        self._upload = None
        self._store(mtype, up.items)
        self._send(mavlink.MAVLink_mission_ack_message(*up.peer, MISSION_ACCEPTED, mtype))

    def _store(self, mission_type: int, items: list[MissionItem]) -> None:
        self._stored[mission_type] = list(items)
        if mission_type == 0:
            self.fc.set_mission(list(items))

    def _download_item(self, mission_type: int, seq: int) -> MissionItem | None:
        items = self._stored.get(mission_type, [])
        if not 0 <= seq < len(items):
            return None
        if mission_type == 0 and seq == 0 and self.flavour.mission_item0_is_home:
            home = self.config.home
            return MissionItem(seq=0, frame=0, command=16, lat_deg=home.lat_deg,
                               lon_deg=home.lon_deg, z_m=home.alt_m)
        return items[seq]

    def _on_mission_request_list(self, msg: Any, now: float) -> None:
        mtype = getattr(msg, "mission_type", 0)
        count = len(self._stored.get(mtype, []))
        self._send(mavlink.MAVLink_mission_count_message(
            msg.get_srcSystem(), msg.get_srcComponent(), count, mtype))

    def _on_mission_request(self, msg: Any, now: float) -> None:
        mtype = getattr(msg, "mission_type", 0)
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        item = self._download_item(mtype, msg.seq)
        if item is None:
            self._send(mavlink.MAVLink_mission_ack_message(*src, MISSION_INVALID_SEQUENCE,
                                                           mtype))
            return
        current = int(item.seq == self.fc.mission_current and mtype == 0)
        if msg.get_type() == "MISSION_REQUEST_INT":
            self._send(mavlink.MAVLink_mission_item_int_message(
                *src, item.seq, item.frame, item.command, current, item.autocontinue,
                item.param1, item.param2, item.param3, item.param4,
                round(item.lat_deg * 1e7), round(item.lon_deg * 1e7), item.z_m,
                mtype))
        else:
            self._send(mavlink.MAVLink_mission_item_message(
                *src, item.seq, item.frame, item.command, current, item.autocontinue,
                item.param1, item.param2, item.param3, item.param4, item.lat_deg,
                item.lon_deg, item.z_m, mtype))

    def _on_mission_ack(self, msg: Any, now: float) -> None:
        if self._upload is not None and msg.type != MISSION_ACCEPTED:
            self.counters["mission_upload_cancelled"] += 1
            self._upload = None

    def _on_mission_clear_all(self, msg: Any, now: float) -> None:
        mtype = getattr(msg, "mission_type", 0)
        self._upload = None
        if mtype == 255:  # MAV_MISSION_TYPE_ALL
            for key in self._stored:
                self._store(key, [])
        elif mtype in self._stored:
            self._store(mtype, [])
        self._send(mavlink.MAVLink_mission_ack_message(
            msg.get_srcSystem(), msg.get_srcComponent(), MISSION_ACCEPTED, mtype))

    def _on_mission_set_current(self, msg: Any, now: float) -> None:
        res = self.fc.set_current_item(msg.seq)
        if not res.ok:
            self.statustext(4, res.text or "Mission: bad item")
        self._send(self.telemetry.mission_current(now))
