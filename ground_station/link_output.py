"""What the ground link sends: commands and receiver reports to the drones, alerts and
drone tiles to the dashboard, and the storage's feedback that makes an item reportable.

A mixin of :class:`~ground_station.receiver.GroundLink` (which owns the state declared
below), split from it by issue 14 so the receiver reads as input, lifecycle and timer.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Callable, Sequence

from companion.protocol import Address, Command, Encoder, LocalProtocolError
from ground_station.broadcast import Broadcaster
from ground_station.config import GroundConfig
from ground_station.fleet import Alert, FleetView
from ground_station.missions import MissionManager
from ground_station.reports import ReportScheduler
from ground_station.storage_records import BatchResult, StoreItem
from ground_station.store_service import StorageService
from ground_station.transport import GroundTransport

__all__ = ["MAX_TILE_PUSHES_PER_S", "TILE_INTERVAL_S", "LinkOutput", "tile_interval"]

log = logging.getLogger("ground_station.receiver")  # the link's log, as before the split

TILE_INTERVAL_S = 0.25
"""Least time between two dashboard tile pushes of one drone. A drone's first image shows
at once; later ones within the interval show as one push of the latest tile at its end.
A browser cannot draw 500 tiles a second, and building and sending one (JSON, a WebSocket
frame, a syscall per watcher) costs the UDP path as much as decoding half the image."""

MAX_TILE_PUSHES_PER_S = 50.0
"""Fleet-wide bound on tile pushes: past 12 drones each drone's interval grows with the fleet
(50 drones: one push a second each). A push costs ~0.4 ms on the loop (the tile, its JSON);
at 50 drones x 10 images/s the 0.25 s interval alone spent ~0.2 ms of every image on it."""


def tile_interval(drones: int) -> float:
    """Least time between two tile pushes of one drone in a fleet of ``drones``."""
    return max(TILE_INTERVAL_S, drones / MAX_TILE_PUSHES_PER_S)


class LinkOutput:
    """The sending half of ``GroundLink``; the attributes are set by its ``__init__``."""

    config: GroundConfig
    clock: Callable[[], float]
    fleet: FleetView
    missions: MissionManager
    storage: StorageService
    broadcaster: Broadcaster
    encoder: Encoder
    reports: ReportScheduler
    transport: GroundTransport[Address]
    command_epochs: dict[str, int]
    counters: Counter[str]
    _last_storage_alert: float
    _tile_pushed: dict[str, float]
    _tiles_due: dict[str, float]

    # -- dashboard tiles -----------------------------------------------------------------
    def _push_tile(self, drone: str, now: float) -> None:
        self._tiles_due.pop(drone, None)
        state = self.fleet.drones.get(drone)
        if state is None:  # forgotten since
            self._tile_pushed.pop(drone, None)
            return
        self._tile_pushed[drone] = now
        self.broadcaster.publish("drone", {"drone": self.fleet.drone_json(state, now=now)})

    def _push_due_tiles(self, now: float) -> None:
        for drone in [d for d, due in self._tiles_due.items() if due <= now]:
            self._push_tile(drone, now)

    # -- storage feedback ----------------------------------------------------------------
    def on_storage_batch(self, items: Sequence[StoreItem], result: BatchResult) -> None:
        """Called by the storage service after each batch (on the event loop): what is now
        durable goes into the receiver reports; failures are counted and alerted."""
        stored = result.stored if len(result.stored) == len(items) else [False] * len(items)
        for item, durable in zip(items, stored, strict=True):
            if durable:
                t_rcv = item.t_rcv if item.t_rcv is not None else item.message.t_rcv
                self.reports.on_message(item.message, t_rcv=t_rcv if t_rcv is not None else 0.0)
            else:
                self.counters["not_stored"] += 1
        if not result.errors:
            return
        self.counters["storage_errors"] += len(result.errors)
        more = f" (+{len(result.errors) - 1} more)" if len(result.errors) > 1 else ""
        self._storage_alert(self.clock(), result.errors[0] + more)

    def _storage_alert(self, now: float, text: str) -> None:
        # One alert per few seconds: a full disk must be visible but not flood the list.
        if now - self._last_storage_alert >= 5.0:
            self._last_storage_alert = now
            self.fleet.alert(Alert(t=now, level="error", kind="storage", text=text))
            self._flush_alerts()

    # -- output -------------------------------------------------------------------------
    def _send(self, datagram: bytes, addr: Address) -> None:
        """Through the transport, best effort: what it cannot send it counts and drops."""
        self.transport.send(datagram, addr)

    def _drone_addrs(self) -> list[tuple[str, Address]]:
        return [(d, s.addr) for d, s in self.fleet.drones.items() if s.addr is not None]

    def send_commands(self, now: float) -> None:
        pending: list[tuple[str, Command]] = self.missions.due(now=now)
        addrs = dict(self._drone_addrs())
        for drone, command in pending:
            addr = addrs.get(drone)
            if addr is None:
                continue
            try:
                datagram = self.encoder.encode_command(
                    command, now, epoch=self.command_epochs.get(drone, 0)
                )
            except LocalProtocolError as exc:
                self.fleet.alert(
                    Alert(t=now, level="error", kind="mission", text=f"command not sent: {exc}")
                )
                continue
            self._send(datagram, addr)
            self.counters["commands_sent"] += 1

    def _send_report(self, now: float) -> None:
        report = self.reports.due(now=now)
        if report is None:
            return
        targets = self._drone_addrs()
        if not targets:
            return
        try:
            datagrams = self.encoder.encode_report(report, now)
        except LocalProtocolError as exc:  # a bug in our entries, not bad input
            log.error("report not encodable: %s", exc)
            return
        for _drone, addr in targets:
            for datagram in datagrams:
                self._send(datagram, addr)
        self.counters["reports_sent"] += 1

    def _flush_alerts(self) -> None:
        for alert in self.fleet.take_new_alerts():
            self.broadcaster.publish(
                "alert",
                {
                    "alert": {
                        "t": alert.t,
                        "level": alert.level,
                        "kind": alert.kind,
                        "drone": alert.drone,
                        "text": alert.text,
                    }
                },
            )
            self.storage.submit_alert(self.config.mission, alert)
