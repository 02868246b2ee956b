"""What this drone knows about every other drone of the fleet, for its autopilot and its logic.

A companion on the shared medium (docs/peers.md) hears its peers' telemetry messages
(``position``, ``battery``, ``status``). :class:`PeerTable` keeps the latest state of each
peer with the time it was observed, and hands it out three ways:

- :meth:`PeerTable.snapshot` — JSON for the drone's own mission logic, served read-only by
  :class:`PeerHttp` at ``GET /peers`` (and ``GET /peers/<drone>``) on a local address;
- :meth:`PeerTable.adsb_reports` — one ADSB_VEHICLE per peer with a position, for the
  autopilot's traffic avoidance (ArduPilot AP_ADSB/AP_Avoidance, PX4 navigator), sent by
  :class:`AdsbInjector` at a configured rate (off by default);
- :attr:`PeerTable.peers` for tests and the status line.

**Identities on the ADS-B side.** ``icao_address`` is ``crc32(drone_id) & 0xFFFFFF`` (24
bits, never 0: 0 becomes 1); the callsign is the drone id upper-cased with anything but
A-Z and 0-9 removed, cut to 8 characters (the ADS-B callsign alphabet). ``tslc`` is the
position's age in whole seconds (0..255), so an autopilot drops a peer that stopped
reporting: ArduPilot after 5 s (VEHICLE_TIMEOUT_MS), as it would a silent transponder.

**Ages.** A peer's position is observed at its message's ``t_gen`` minus its ``pose_age_s``
(the fleet's clocks are chrony-synchronised; an observation "in the future" counts as age 0).
Velocity comes from the message (``vn_m_s``, ``ve_m_s``, ``vd_m_s``) when present, else
from the last two positions.

The table is sans-I/O (every call takes ``now``); the two shells are thin.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
import re
import zlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

from companion.protocol import MessageReassembled
from companion.protocol.records import ClockEcho, Report, ReportEntry, entry_from_message
from utility_specs.message import Message

__all__ = [
    "AdsbInjector",
    "AdsbReport",
    "PeerHttp",
    "PeerReporter",
    "PeerServices",
    "PeerState",
    "PeerTable",
    "PeersSettings",
    "callsign_for",
    "icao_for",
    "parse_peers_settings",
    "peer_types_of",
]

log = logging.getLogger(__name__)

ADSB_FLAGS_VALID_COORDS = 1
ADSB_FLAGS_VALID_ALTITUDE = 2
ADSB_FLAGS_VALID_HEADING = 4
ADSB_FLAGS_VALID_VELOCITY = 8
ADSB_FLAGS_VALID_CALLSIGN = 16
ADSB_ALTITUDE_TYPE_GEOMETRIC = 1
"""The altitude is from GNSS (AMSL), not a pressure altitude."""
ADSB_EMITTER_TYPE_UAV = 14
MAX_PEERS = 256
"""Peers kept; a new one beyond this evicts the least recently heard."""
MAX_STATUS_PEERS = 32
"""Peers whose ages a status message carries at most (the most recently heard)."""
_CALLSIGN_DROP = re.compile(r"[^A-Z0-9]")


def icao_for(drone_id: str) -> int:
    """24-bit ICAO address of a drone (module docstring)."""
    return (zlib.crc32(drone_id.encode()) & 0xFFFFFF) or 1


def callsign_for(drone_id: str) -> str:
    """ADS-B callsign of a drone: A-Z, 0-9, at most 8 characters."""
    return _CALLSIGN_DROP.sub("", drone_id.upper())[:8] or "UAV"


def _num(data: Mapping[str, Any], *keys: str) -> float | None:
    for key in keys:
        value = data.get(key)
        if isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(
                value):
            return float(value)
    return None


@dataclass(frozen=True, slots=True, kw_only=True)
class PeerState:
    """The latest of one peer; ``t_*`` are fleet-clock observation times (None: never)."""

    drone: str
    t_heard: float
    lat_deg: float | None = None
    lon_deg: float | None = None
    alt_rel_m: float | None = None
    alt_amsl_m: float | None = None
    heading_deg: float | None = None
    velocity_ned_m_s: tuple[float, float, float] | None = None
    t_position: float | None = None
    battery: float | None = None
    t_battery: float | None = None
    status: Mapping[str, Any] = field(default_factory=dict)
    t_status: float | None = None

    def age(self, t: float | None, now: float) -> float | None:
        return None if t is None else max(0.0, now - t)

    def to_json(self, now: float) -> dict[str, Any]:
        return {
            "drone": self.drone,
            "heard_age_s": round(max(0.0, now - self.t_heard), 3),
            "position": None if self.t_position is None else {
                "lat_deg": self.lat_deg, "lon_deg": self.lon_deg, "alt_rel_m": self.alt_rel_m,
                "alt_amsl_m": self.alt_amsl_m, "heading_deg": self.heading_deg,
                "velocity_ned_m_s": (list(self.velocity_ned_m_s)
                                     if self.velocity_ned_m_s is not None else None),
                "age_s": round(max(0.0, now - self.t_position), 3)},
            "battery": None if self.t_battery is None else {
                "level": self.battery, "age_s": round(max(0.0, now - self.t_battery), 3)},
            "status": None if self.t_status is None else {
                **dict(self.status), "age_s": round(max(0.0, now - self.t_status), 3)},
        }


@dataclass(frozen=True, slots=True, kw_only=True)
class AdsbReport:
    """ADSB_VEHICLE fields in MAVLink's units, ready for ``MAVLink_adsb_vehicle_message``."""

    icao_address: int
    lat: int
    lon: int
    altitude_type: int
    altitude: int
    heading: int
    hor_velocity: int
    ver_velocity: int
    callsign: bytes
    emitter_type: int
    tslc: int
    flags: int
    squawk: int = 0

    def args(self) -> tuple[Any, ...]:
        """Positional arguments of pymavlink's ``MAVLink_adsb_vehicle_message``."""
        return (self.icao_address, self.lat, self.lon, self.altitude_type, self.altitude,
                self.heading, self.hor_velocity, self.ver_velocity, self.callsign,
                self.emitter_type, self.tslc, self.flags, self.squawk)


class PeerTable:
    """Latest state of every peer (sans-I/O; module docstring)."""

    def __init__(self, own_id: str, *, forget_after_s: float = 60.0,
                 max_peers: int = MAX_PEERS) -> None:
        self.own_id = own_id
        self.forget_after_s = forget_after_s
        self.max_peers = max_peers
        self.peers: dict[str, PeerState] = {}
        self.counters: dict[str, int] = {}

    def _count(self, key: str) -> None:
        self.counters[key] = self.counters.get(key, 0) + 1

    def on_message(self, message: Message, *, now: float) -> None:
        """One reassembled message from the medium; our own and unknown types are ignored."""
        if message.sender == self.own_id:
            self._count("own")
            return
        data = message.data
        peer = self.peers.pop(message.sender, None)
        if peer is None:
            if len(self.peers) >= self.max_peers:
                del self.peers[next(iter(self.peers))]
                self._count("evicted")
            peer = PeerState(drone=message.sender, t_heard=now)
            log.info("peer %s heard", message.sender)
        peer = replace(peer, t_heard=max(peer.t_heard, now))
        t_obs = message.t_gen
        if message.type == "position" or _num(data, "lat_deg") is not None:
            peer = self._position(peer, data, t_obs - max(0.0, _num(data, "pose_age_s") or 0.0))
        if message.type == "battery":
            level = _num(data, "level")
            if level is not None and (peer.t_battery is None or t_obs >= peer.t_battery):
                peer = replace(peer, battery=level, t_battery=t_obs)
        if message.type == "status" and (peer.t_status is None or t_obs >= peer.t_status):
            keep = ("mode", "armed", "failsafe", "mission", "autopilot", "connected",
                    "fix_type")
            peer = replace(peer, status={k: data[k] for k in keep if k in data},
                           t_status=t_obs)
        self.peers[message.sender] = peer  # most recently heard last
        self._count(message.type if message.type in ("position", "battery", "status")
                    else "other")

    def _position(self, peer: PeerState, data: Mapping[str, Any], t_obs: float) -> PeerState:
        lat, lon = _num(data, "lat_deg"), _num(data, "lon_deg")
        if lat is None or lon is None or not (abs(lat) <= 90 and abs(lon) <= 180):
            self._count("no_position")
            return peer
        if peer.t_position is not None and t_obs <= peer.t_position:
            self._count("older_position")
            return peer
        velocity: tuple[float, float, float] | None = None
        vn, ve, vd = (_num(data, k) for k in ("vn_m_s", "ve_m_s", "vd_m_s"))
        alt_rel = _num(data, "alt_rel_m", "alt_m")
        if vn is not None and ve is not None:
            velocity = (vn, ve, vd or 0.0)
        elif (peer.t_position is not None and peer.lat_deg is not None
              and peer.lon_deg is not None and 0.0 < t_obs - peer.t_position <= 10.0):
            dt = t_obs - peer.t_position
            r = 6_371_000.0
            dn = math.radians(lat - peer.lat_deg) * r
            de = math.radians(lon - peer.lon_deg) * r * math.cos(math.radians(lat))
            dd = 0.0
            if alt_rel is not None and peer.alt_rel_m is not None:
                dd = -(alt_rel - peer.alt_rel_m)
            velocity = (dn / dt, de / dt, dd / dt)
        return replace(peer, lat_deg=lat, lon_deg=lon, alt_rel_m=alt_rel,
                       alt_amsl_m=_num(data, "alt_amsl_m"),
                       heading_deg=_num(data, "heading_deg"), velocity_ned_m_s=velocity,
                       t_position=t_obs)

    def forget_silent(self, now: float) -> list[str]:
        gone = [d for d, p in self.peers.items() if now - p.t_heard > self.forget_after_s]
        for drone in gone:
            del self.peers[drone]
            self._count("forgotten")
        return gone

    def snapshot(self, now: float) -> dict[str, Any]:
        """What ``GET /peers`` returns."""
        return {"drone": self.own_id, "t": now,
                "peers": [self.peers[d].to_json(now) for d in sorted(self.peers)]}

    def ages(self, now: float, *, limit: int = MAX_STATUS_PEERS) -> dict[str, float]:
        """Per peer, the age of its position (of its last word when it sent none), 0.1 s
        resolution: the compact map a status message carries to the dashboard. At most
        ``limit``, the most recently heard."""
        out: dict[str, float] = {}
        for drone, peer in list(self.peers.items())[-limit:]:
            age = peer.age(peer.t_position, now)
            if age is None:
                age = max(0.0, now - peer.t_heard)
            out[drone] = round(age, 1)
        return out

    def adsb_reports(self, now: float) -> list[AdsbReport]:
        """One ADSB_VEHICLE per peer with a position (module docstring)."""
        reports = []
        for drone in sorted(self.peers):
            p = self.peers[drone]
            if p.t_position is None or p.lat_deg is None or p.lon_deg is None:
                continue
            flags = ADSB_FLAGS_VALID_COORDS | ADSB_FLAGS_VALID_CALLSIGN
            altitude = 0
            amsl = p.alt_amsl_m
            if amsl is not None:
                flags |= ADSB_FLAGS_VALID_ALTITUDE
                altitude = round(amsl * 1000)
            heading = p.heading_deg
            hor = ver = 0
            if p.velocity_ned_m_s is not None:
                vn, ve, vd = p.velocity_ned_m_s
                flags |= ADSB_FLAGS_VALID_VELOCITY
                hor = min(65535, round(math.hypot(vn, ve) * 100))
                ver = max(-32768, min(32767, round(-vd * 100)))
                if math.hypot(vn, ve) > 0.5:  # course over ground when moving
                    heading = math.degrees(math.atan2(ve, vn)) % 360
            if heading is not None:
                flags |= ADSB_FLAGS_VALID_HEADING
            reports.append(AdsbReport(
                icao_address=icao_for(drone), lat=round(p.lat_deg * 1e7),
                lon=round(p.lon_deg * 1e7), altitude_type=ADSB_ALTITUDE_TYPE_GEOMETRIC,
                altitude=altitude,
                heading=0 if heading is None else round(heading * 100) % 36000,
                hor_velocity=hor, ver_velocity=ver, callsign=callsign_for(drone).encode(),
                emitter_type=ADSB_EMITTER_TYPE_UAV,
                tslc=min(255, int(max(0.0, now - p.t_position))), flags=flags))
        return reports


# -- settings -------------------------------------------------------------------------------

@dataclass(frozen=True, slots=True, kw_only=True)
class PeersSettings:
    """The companion's ``[peers]`` table (docs/peers.md); everything off by default."""

    medium: str | None = None
    """``broadcast:ADDR:PORT`` or ``multicast:GROUP:PORT``: send peer-bound types there and
    listen to it (companion.transport.SharedMedium). None: unicast to the ground only."""
    adsb_rate_hz: float = 0.0
    """ADSB_VEHICLE injections per second per peer into the autopilot; 0 = off."""
    http: str | None = None
    """``HOST:PORT`` of the read-only JSON endpoint (``GET /peers``); None = off."""
    forget_after_s: float = 60.0


def parse_peers_settings(raw: Mapping[str, Any]) -> PeersSettings:
    """Validate the ``[peers]`` table; ValueError names the key and what was expected."""
    from companion.transport import parse_medium

    known = {"medium", "adsb_rate_hz", "http", "forget_after_s"}
    unknown = sorted(set(raw) - known)
    if unknown:
        raise ValueError(f"peers.{unknown[0]}: unknown key (expected one of {sorted(known)})")
    medium = raw.get("medium")
    if medium is not None:
        if not isinstance(medium, str):
            raise ValueError("peers.medium: expected broadcast:ADDR:PORT or "
                             "multicast:GROUP:PORT")
        parse_medium(medium)
    rate = raw.get("adsb_rate_hz", 0.0)
    if isinstance(rate, bool) or not isinstance(rate, int | float) or not 0 <= rate <= 50:
        raise ValueError(f"peers.adsb_rate_hz: expected a number 0..50, got {rate!r}")
    http = raw.get("http")
    if http is not None and (not isinstance(http, str) or not _is_host_port(http)):
        raise ValueError(f"peers.http: expected HOST:PORT, got {http!r}")
    forget = raw.get("forget_after_s", 60.0)
    if isinstance(forget, bool) or not isinstance(forget, int | float) or not forget > 0:
        raise ValueError(f"peers.forget_after_s: expected a number > 0, got {forget!r}")
    return PeersSettings(medium=medium, adsb_rate_hz=float(rate), http=http,
                         forget_after_s=float(forget))


def _is_host_port(text: str) -> bool:
    host, sep, port = text.rpartition(":")
    return bool(sep and host and port.isdigit() and 0 <= int(port) < 65536)


# -- shells ---------------------------------------------------------------------------------

class AdsbInjector:
    """Sends each peer to the autopilot as ADSB_VEHICLE every ``1/rate_hz`` seconds.

    ``send`` takes a pymavlink message object (the companion's MAVLink link writes it); a
    failing send is counted, never raised into the loop.
    """

    def __init__(self, table: PeerTable, *, rate_hz: float, clock: Callable[[], float],
                 send: Callable[[Any], None]) -> None:
        self.table = table
        self.period_s = 1.0 / rate_hz if rate_hz > 0 else math.inf
        self.clock = clock
        self.send = send
        self.counters: dict[str, int] = {"sent": 0, "send_errors": 0}
        self._stop = asyncio.Event()

    def inject(self, now: float) -> int:
        from pymavlink.dialects.v20 import ardupilotmega as mavlink

        sent = 0
        for report in self.table.adsb_reports(now):
            try:
                self.send(mavlink.MAVLink_adsb_vehicle_message(*report.args()))
            except Exception as exc:  # the link may be down; the next round tries again
                self.counters["send_errors"] += 1
                log.debug("ADSB_VEHICLE not sent: %s", exc)
                continue
            sent += 1
        self.counters["sent"] += sent
        return sent

    async def run(self) -> None:
        if not math.isfinite(self.period_s):
            return
        while not self._stop.is_set():
            now = self.clock()
            self.table.forget_silent(now)
            self.inject(now)
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._stop.wait(), self.period_s)

    def stop(self) -> None:
        self._stop.set()


class PeerHttp:
    """Read-only local JSON: ``GET /peers`` and ``GET /peers/<drone>``; nothing else.

    A deliberately small HTTP/1.0 responder on asyncio streams (no framework on the drone's
    hot path): one request per connection, bounded request size and read time, and only
    GET. Bind it to 127.0.0.1 (the default in docs/peers.md): it has no authentication.
    """

    MAX_REQUEST_BYTES = 4096
    READ_TIMEOUT_S = 5.0

    def __init__(self, table: PeerTable, *, clock: Callable[[], float], host: str,
                 port: int) -> None:
        self.table = table
        self.clock = clock
        self.host = host
        self.port = port
        self.server: asyncio.Server | None = None

    async def start(self) -> tuple[str, int]:
        self.server = await asyncio.start_server(self._serve, self.host, self.port,
                                                 limit=self.MAX_REQUEST_BYTES)
        sock = self.server.sockets[0].getsockname()
        log.info("peer state on http://%s:%d/peers", sock[0], sock[1])
        return str(sock[0]), int(sock[1])

    def close(self) -> None:
        if self.server is not None:
            self.server.close()
            self.server = None

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            async with asyncio.timeout(self.READ_TIMEOUT_S):
                head = await reader.readuntil(b"\r\n\r\n")
            status, body = self.respond(head.split(b"\r\n", 1)[0])
        except (asyncio.IncompleteReadError, asyncio.LimitOverrunError, TimeoutError,
                ConnectionError):
            status, body = 400, {"error": "bad request"}
        payload = json.dumps(body).encode()
        reason = {200: "OK", 400: "Bad Request", 404: "Not Found",
                  405: "Method Not Allowed"}[status]
        try:
            writer.write(f"HTTP/1.0 {status} {reason}\r\nContent-Type: application/json\r\n"
                         f"Content-Length: {len(payload)}\r\nCache-Control: no-store\r\n"
                         "Connection: close\r\n\r\n".encode() + payload)
            await writer.drain()
        except ConnectionError:
            pass
        finally:
            writer.close()

    def respond(self, request_line: bytes) -> tuple[int, dict[str, Any]]:
        """Status and JSON body for one request line (sans-I/O, tested directly)."""
        parts = request_line.decode("latin-1").split(" ")
        if len(parts) != 3 or not parts[2].startswith("HTTP/"):
            return 400, {"error": "bad request"}
        method, path = parts[0], parts[1].split("?", 1)[0]
        if method != "GET":
            return 405, {"error": "read-only: GET only"}
        now = self.clock()
        if path in ("/peers", "/peers/"):
            return 200, self.table.snapshot(now)
        if path.startswith("/peers/"):
            peer = self.table.peers.get(path[len("/peers/"):])
            if peer is not None:
                return 200, peer.to_json(now)
        return 404, {"error": "not found"}


REPORT_INTERVAL_S = 0.25
"""A companion reports what it heard from peers this often (the ground station's default)."""
MAX_REPORT_ENTRIES = 256
"""Entries held between two reports; beyond, the oldest are dropped (counted)."""


class PeerReporter:
    """This drone as a receiver on the shared medium (issue 15): what it heard from peers.

    Sans-I/O. :meth:`on_message` collects each peer message heard (an entry, and the
    sender's clock pair as the ground station keeps it); :meth:`take` returns the report of
    everything since the previous one, in the ground station's format, so every sender
    learns what this drone holds (its optimiser plans with it, its goodput constraint
    learns the medium's latency from it) and this drone's own optimiser learns the same
    deliveries locally (``receiver`` = this drone).
    """

    def __init__(self, own_id: str, *, max_entries: int = MAX_REPORT_ENTRIES) -> None:
        self.own_id = own_id
        self.max_entries = max_entries
        self._entries: list[ReportEntry] = []
        self._echoes: dict[str, ClockEcho] = {}
        self.counters: dict[str, int] = {"heard": 0, "reports": 0, "entries_dropped": 0}

    def on_message(self, message: Message, *, t_rcv: float) -> None:
        if message.sender == self.own_id:
            return
        try:
            entry = entry_from_message(message, t_rcv=t_rcv)
        except ValueError:  # a message the report format cannot carry: not reported
            return
        self.counters["heard"] += 1
        self._entries.append(entry)
        if len(self._entries) > self.max_entries:
            del self._entries[0]
            self.counters["entries_dropped"] += 1
        if message.t_sent is not None:
            self._echoes[message.sender] = ClockEcho(sender=message.sender,
                                                     t_sent=message.t_sent, t_rcv=t_rcv)

    def take(self) -> Report | None:
        """The report since the previous one; None when nothing was heard."""
        if not self._entries and not self._echoes:
            return None
        report = Report(entries=tuple(self._entries), echoes=tuple(self._echoes.values()))
        self._entries = []
        self._echoes = {}
        self.counters["reports"] += 1
        return report


class PeerServices:
    """What the companion runs for peer sharing: the table, the endpoint, the injector.

    companion/app.py builds it, runs it in its task group, stops it, hands it every transport
    event, and asks :meth:`shared` whether a message type goes on the shared medium.
    """

    def __init__(self, settings: PeersSettings, *, own_id: str, clock: Callable[[], float],
                 peer_types: frozenset[str] = frozenset(),
                 send_mavlink: Callable[[Any], None] | None = None,
                 send_report: Callable[[Report, float], object] | None = None,
                 learn: Callable[[Report, float], object] | None = None,
                 report_interval_s: float = REPORT_INTERVAL_S) -> None:
        """``send_report(report, now)`` puts this drone's receiver report on the medium;
        ``learn(report, now)`` hands the same deliveries to its own optimiser. Without
        ``send_report`` (no medium) nothing is reported."""
        self.settings = settings
        self.own_id = own_id
        self.reporter = PeerReporter(own_id)
        self._send_report = send_report
        self._learn = learn
        self.report_interval_s = report_interval_s
        self.clock = clock
        self.peer_types = peer_types
        self.table = PeerTable(own_id, forget_after_s=settings.forget_after_s)
        self.http: PeerHttp | None = None
        if settings.http is not None:
            host, _, port = settings.http.rpartition(":")
            self.http = PeerHttp(self.table, clock=clock, host=host, port=int(port))
        self.injector: AdsbInjector | None = None
        if settings.adsb_rate_hz > 0 and send_mavlink is not None:
            self.injector = AdsbInjector(self.table, rate_hz=settings.adsb_rate_hz, clock=clock,
                                         send=send_mavlink)
        self._stop = asyncio.Event()

    def shared(self, type_name: str) -> bool:
        """Does a message of this type go on the shared medium (spec ``receivers``)?"""
        return self.settings.medium is not None and type_name in self.peer_types

    def on_event(self, event: Any) -> None:
        if isinstance(event, MessageReassembled):
            now = self.clock()
            self.table.on_message(event.message, now=now)
            if self._send_report is not None:
                self.reporter.on_message(event.message, t_rcv=event.message.t_rcv or now)

    def status_fields(self) -> dict[str, Any]:
        """``peers``: {peer: age of its position, s} for this drone's status messages (the
        dashboard shows who each drone knows); nothing without a medium."""
        if self.settings.medium is None:
            return {}
        return {"peers": self.table.ages(self.clock())}

    def is_peer(self, sender: str) -> bool:
        """Is ``sender`` (of a report) a drone heard on the medium, not the ground station?"""
        return sender != self.own_id and sender in self.table.peers

    def report_now(self) -> bool:
        """Send the receiver report of what was heard since the last one (if anything)."""
        report = self.reporter.take()
        if report is None or self._send_report is None:
            return False
        now = self.clock()
        self._send_report(report, now)
        if self._learn is not None:
            self._learn(report, now)
        return True

    async def _report_loop(self) -> None:
        while not self._stop.is_set():
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._stop.wait(), self.report_interval_s)
            try:
                self.report_now()
            except Exception:  # a report lost must never stop the drone
                log.exception("peers: receiver report not sent")

    async def run(self) -> None:
        reporting = (asyncio.ensure_future(self._report_loop())
                     if self._send_report is not None else None)
        try:
            await self._serve()
        finally:
            if reporting is not None:
                self._stop.set()
                await reporting
                c = self.reporter.counters
                log.info("peers: %d messages heard from %d peers, %d receiver reports sent",
                         c["heard"], len(self.table.peers), c["reports"],
                         extra={"event": "peers", "counters": dict(c)})

    async def _serve(self) -> None:
        if self.http is not None:
            try:
                await self.http.start()
            except OSError as exc:  # the drone flies on without its local endpoint
                log.error("peers.http: cannot serve on %s: %s", self.settings.http,
                          exc.strerror or exc)
                self.http = None
        try:
            if self.injector is not None:
                injector = asyncio.ensure_future(self.injector.run())
                await self._stop.wait()
                self.injector.stop()
                await injector
            else:
                await self._stop.wait()
        finally:
            if self.http is not None:
                self.http.close()

    def stop(self) -> None:
        self._stop.set()


def peer_types_of(spec: Any) -> frozenset[str]:
    """The spec's types whose receivers include ``peers``."""
    return frozenset(name for name, info in spec.types.items()
                     if "peers" in getattr(info, "receivers", ("ground",)))
