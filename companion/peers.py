"""Peer services of a companion: the ``[peers]`` settings and the thin shells around
:class:`~companion.peer_table.PeerTable` (ADSB_VEHICLE injection, the read-only ``/peers``
endpoint of :mod:`companion.peer_http`) wired together by :class:`PeerServices`
(docs/peers.md).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from companion.middleware.constraints.adaptive import LinkStatsConstraint
from companion.middleware.constraints.base import GoodputConstraint
from companion.peer_airtime import CountingReports, ReportTraffic, report_wire_bytes
from companion.peer_http import MAX_CONNECTIONS, MAX_PER_ADDRESS, SEND_TIMEOUT_S, PeerHttp
from companion.peer_reports import REPORT_INTERVAL_S, PeerReporter
from companion.peer_table import (
    AdsbReport,
    PeerState,
    PeerTable,
    callsign_for,
    icao_for,
)
from companion.protocol import MessageReassembled, ReportReceived
from companion.protocol.records import Report

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
    "peers_setup_problem",
]

log = logging.getLogger(__name__)

FORGET_INTERVAL_S = 1.0
"""How often silent peers are looked for (``forget_after_s``), with or without ADSB."""


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
    http_max_connections: int = MAX_CONNECTIONS
    http_max_per_address: int = MAX_PER_ADDRESS
    http_send_timeout_s: float = SEND_TIMEOUT_S
    """The endpoint's limits (companion/peer_http.py): no client holds it forever."""


def parse_peers_settings(raw: Mapping[str, Any]) -> PeersSettings:
    """Validate the ``[peers]`` table; ValueError names the key and what was expected."""
    from companion.medium import parse_medium

    known = {"medium", "adsb_rate_hz", "http", "forget_after_s", "http_max_connections",
             "http_max_per_address", "http_send_timeout_s"}
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
    limits = {key: raw.get(key, default) for key, default in (
        ("http_max_connections", MAX_CONNECTIONS), ("http_max_per_address", MAX_PER_ADDRESS))}
    for key, value in limits.items():
        if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= 10000:
            raise ValueError(f"peers.{key}: expected a whole number 1..10000, got {value!r}")
    send = raw.get("http_send_timeout_s", SEND_TIMEOUT_S)
    if isinstance(send, bool) or not isinstance(send, int | float) or not 0 < send <= 3600:
        raise ValueError(f"peers.http_send_timeout_s: expected seconds in (0, 3600], "
                         f"got {send!r}")
    return PeersSettings(medium=medium, adsb_rate_hz=float(rate), http=http,
                         forget_after_s=float(forget), http_send_timeout_s=float(send), **limits)


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
            self.inject(self.clock())  # PeerServices forgets the silent peers
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._stop.wait(), self.period_s)

    def stop(self) -> None:
        self._stop.set()


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
                 report_interval_s: float = REPORT_INTERVAL_S,
                 forget_interval_s: float = FORGET_INTERVAL_S) -> None:
        """``send_report(report, now)`` puts this drone's receiver report on the medium;
        ``learn(report, now)`` hands each delivery heard to its own optimiser as it arrives
        (a one-entry report). Without ``send_report`` (no medium) nothing is reported."""
        self.settings = settings
        self.own_id = own_id
        self.reporter = PeerReporter(own_id)
        self.report_traffic = ReportTraffic()
        """Receiver reports on the medium, sent and heard: air time the budget counts."""
        self._send_report = send_report
        self._learn = learn
        self.report_interval_s = report_interval_s
        self.forget_interval_s = forget_interval_s
        self.clock = clock
        self.peer_types = peer_types
        self.table = PeerTable(own_id, forget_after_s=settings.forget_after_s)
        self.http: PeerHttp | None = None
        if settings.http is not None:
            host, _, port = settings.http.rpartition(":")
            self.http = PeerHttp(self.table, clock=clock, host=host, port=int(port),
                                 max_connections=settings.http_max_connections,
                                 max_per_address=settings.http_max_per_address,
                                 send_timeout_s=settings.http_send_timeout_s)
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
                entry = self.reporter.on_message(event.message, t_rcv=event.message.t_rcv or now)
                if entry is not None and self._learn is not None:
                    # at once: a peer's send unknown for a report period (0.25 s) is neither
                    # in the optimiser's window nor in its in-flight estimate (which spans
                    # only the link's latency), so the fleet would overfill the window
                    self._learn(Report(entries=(entry,)), now)
        elif isinstance(event, ReportReceived) and self._send_report is not None \
                and self.is_peer(event.reporter):
            self.report_traffic.add(event.t_sent, report_wire_bytes(event.report,
                                                                    sender=event.reporter))

    def count_reports_in(self, decider: Any) -> bool:
        """On a medium, the decider's goodput budget leaves room for the receiver reports
        (companion/peer_airtime.py). True if its constraint now counts them.

        A constraint that learns ξ from the link (adaptive, AIMD) already sees the reports as
        load on the medium: taking them off its budget again would count them twice."""
        constraint = getattr(decider, "constraint", None)
        if self._send_report is None or not isinstance(constraint, GoodputConstraint) \
                or isinstance(constraint, CountingReports | LinkStatsConstraint):
            return False
        decider.constraint = CountingReports(constraint, self.report_traffic)
        return True

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
        if self._send_report(report, now):
            self.report_traffic.add(now, report_wire_bytes(report, sender=self.own_id))
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

    def forget_silent(self) -> list[str]:
        """Drop the peers silent for ``forget_after_s`` (from the table, ``/peers``, the
        status's ``peers`` map and the ADSB injection); each is logged once."""
        gone = self.table.forget_silent(self.clock())
        for drone in gone:
            log.info("peer %s forgotten: nothing heard from it for %.0f s (peers.forget_after_s)",
                     drone, self.settings.forget_after_s)
        return gone

    async def _forget_loop(self) -> None:
        # Not in the ADSB injector only: with adsb_rate_hz = 0 (the default) a stopped peer
        # stayed in /peers and on the dashboard for ever, whatever forget_after_s said.
        while not self._stop.is_set():
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._stop.wait(), self.forget_interval_s)
            self.forget_silent()

    async def _serve(self) -> None:
        forgetting = asyncio.ensure_future(self._forget_loop())
        try:
            await self._serve_endpoints()
        finally:
            self._stop.set()
            await forgetting

    async def _serve_endpoints(self) -> None:
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


def peers_setup_problem(settings: PeersSettings, peer_types: frozenset[str]) -> str | None:
    """What a ``[peers]`` table without ``medium`` will not do that the config asks for
    (a spec sharing types with peers, ``http``, ``adsb_rate_hz``); None when nothing is lost.
    Such a drone ran without a word: its shared types went to the ground only, its ``/peers``
    stayed empty and it injected no ADSB_VEHICLE."""
    if settings.medium is not None:
        return None
    asked = []
    if peer_types:
        asked.append(f"the mission spec shares {', '.join(sorted(peer_types))} with peers "
                     "(receivers), so they go to the ground station only")
    if settings.http is not None:
        asked.append(f"GET /peers on {settings.http} will list no peer")
    if settings.adsb_rate_hz > 0:
        asked.append("no peer goes to the autopilot as ADSB_VEHICLE")
    if not asked:
        return None
    return (f"peers.medium is not set: {'; '.join(asked)}; set peers.medium to the fleet's "
            "shared medium (docs/peers.md)")


def peer_types_of(spec: Any) -> frozenset[str]:
    """The spec's types whose receivers include ``peers``."""
    return frozenset(name for name, info in spec.types.items()
                     if "peers" in getattr(info, "receivers", ("ground",)))
