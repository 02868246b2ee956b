"""The fleet side of the ground station, on aiohttp's event loop (aioquic-style shell).

The link is protocol logic over a transport (:mod:`ground_station.transport`, UDP by
default): datagrams arrive through :meth:`GroundLink.datagrams_received` and leave through
``transport.send``; addresses are the transport's own, opaque here.

Every entry point does the same three steps: call the sans-I/O cores with ``now=clock()``
(decoder, report scheduler, mission manager), process their events, transmit what they
want sent, and keep exactly one timer armed for the earliest deadline any of them has.
Nothing here awaits: storage and dashboard pushes are handed off without blocking.
"""

from __future__ import annotations

import asyncio
import logging
import threading
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from companion.protocol import (
    EPOCH_STATUS,
    Address,
    Decoder,
    DecoderLimits,
    Encoder,
    MessageExpired,
    MessageReassembled,
    PacketDropped,
    StatusReceived,
)
from ground_station.broadcast import Broadcaster
from ground_station.config import GroundConfig
from ground_station.fleet import Alert, FleetView
from ground_station.link_output import (
    MAX_TILE_PUSHES_PER_S,
    TILE_INTERVAL_S,
    LinkOutput,
    tile_interval,
)
from ground_station.mission_state import MissionStateKeeper
from ground_station.missions import MissionManager
from ground_station.replay_state import read_replay_state, save_replay_state
from ground_station.reports import ReportScheduler
from ground_station.storage import StoreItem
from ground_station.store_service import StorageService
from ground_station.transport import GroundTransport, udp_transport
from ground_station.utility import ImageUtility

__all__ = ["MAX_TILE_PUSHES_PER_S", "TILE_INTERVAL_S", "GroundLink", "tile_interval"]

log = logging.getLogger(__name__)

MAX_EPOCHS = 1024
"""Drones whose boot epoch is kept; a forgotten one is sent epoch 0 and announces again."""

TICK_S = 1.0  # the link charts are sampled and link loss checked once a second
LATE_TIMER_S = 1.0  # a timer this late means the station itself did not run


class GroundLink(LinkOutput):
    """Receives the fleet's datagrams, reports back, and sends mission commands."""

    def __init__(
        self,
        *,
        config: GroundConfig,
        clock: Callable[[], float],
        fleet: FleetView,
        missions: MissionManager,
        storage: StorageService,
        broadcaster: Broadcaster,
        image_utility: ImageUtility,
        latest_jpeg: dict[str, bytes],
        transport: GroundTransport[Address] | None = None,
    ) -> None:
        """``transport``: where datagrams come from and go to (default: UDP on the
        config's ``udp_host``/``udp_port``)."""
        self.config = config
        self.clock = clock
        self.fleet = fleet
        self.missions = missions
        self.storage = storage
        self.broadcaster = broadcaster
        self.image_utility = image_utility
        self.latest_jpeg = latest_jpeg
        limits = DecoderLimits(
            reassembly_timeout_s=config.reassembly_timeout_s,
            max_partials=config.max_pending_messages,
            max_buffered_bytes=max(8 << 20, config.max_pending_messages * 64 * 1024),
            max_clock_skew_s=config.clock_tolerance_s,
        )
        if config.fleet_key is None or config.command_key is None:
            raise ValueError("the ground station needs a fleet key and a command key")
        self.decoder = Decoder(
            config.fleet_id, config.fleet_key, local_id=config.station_id, limits=limits
        )
        now = clock()
        self.encoder = Encoder(
            config.fleet_id, config.station_id, config.fleet_key, command_key=config.command_key
        )
        self.command_epochs: dict[str, int] = {}
        """Boot epoch each drone announced; its commands must carry it (docs/protocol.md)."""
        self.replay_path = config.data_dir / "replay_state.json"
        self._replay_saving = False
        self._replay_lock = threading.Lock()
        self._replay_closed = False
        self.reports = ReportScheduler(interval_s=config.report_interval_s, now=now)
        self.transport: GroundTransport[Address] = (
            transport if transport is not None else udp_transport(config)
        )
        self._open = False
        self.counters: Counter[str] = Counter()
        self.mission_state = MissionStateKeeper(
            missions, config.mission, config.data_dir / "mission_state.json", self.counters)
        self._timer: asyncio.TimerHandle | None = None
        self._timer_at: float | None = None
        self._deferred = False  # the late timer waited for one read of the socket
        self._next_tick = now + TICK_S
        self._last_storage_alert = 0.0
        self._tile_pushed: dict[str, float] = {}
        """Drone -> when its tile was last pushed to the dashboard."""
        self._tiles_due: dict[str, float] = {}
        """Drones whose tile changed since its last push -> when the next push is due."""
        self.data_listeners: list[Callable[[str, Mapping[str, Any]], None]] = []
        """Called with (drone, data) for every message and status (MAVLink out)."""

    # -- lifecycle ------------------------------------------------------------------------
    async def open(self) -> Address:
        """Open the transport and start receiving from it.

        First the previous run's replay state is restored: whatever the previous run may have
        accepted is refused, so datagrams captured earlier cannot be replayed into this run.
        """
        saved = await asyncio.to_thread(read_replay_state, self.replay_path)
        restored = self.decoder.restore_replay_state(saved.senders, self.clock(),
                                                     closed=saved.closed)
        if restored:
            log.info("replay protection restored for %d sender(s)", restored)
        if await self.mission_state.restore():
            log.info("mission state restored: phase %s, %d command(s)",
                     self.missions.phase(now=self.clock()), len(self.missions.commands))
        await self._reopen_mission()
        addr = await self.transport.open(self)
        self._open = True
        self._arm()
        return addr

    @property
    def local_addr(self) -> Address:
        return self.transport.local_addr

    def save_replay_state(self) -> None:
        """Write the replay state now, as the last one (blocking: at shutdown, once nothing
        more is received)."""
        self._write_replay_state(self.decoder.replay_state(self.clock()), closed=True)

    def _write_replay_state(self, state: dict[str, list[float]], closed: bool = False) -> None:
        try:
            with self._replay_lock:
                if self._replay_closed:  # a periodic save finishing late: not over the last
                    return
                save_replay_state(self.replay_path, state, closed=closed)
                self._replay_closed = closed
        except OSError as exc:
            self.counters["replay_state_errors"] += 1
            if self.counters["replay_state_errors"] % 60 == 1:  # once a minute, not a flood
                log.warning("replay state not saved (%d times): %s",
                            self.counters["replay_state_errors"], exc)

    def _save_replay_state_soon(self) -> None:
        """Once a second, off the event loop; one write at a time."""
        if self._replay_saving:
            return
        self._replay_saving = True
        state = self.decoder.replay_state(self.clock())

        def done(_: asyncio.Future[None]) -> None:
            self._replay_saving = False

        future = asyncio.get_running_loop().run_in_executor(None, self._write_replay_state,
                                                            state)
        future.add_done_callback(done)

    async def _reopen_mission(self) -> None:
        """A mission not ended goes on in the mission log (``Storage.reopen_mission``): the
        restored start command's, or the one the station opened with its first message."""
        t_start, mission = self.missions.t_start, self.config.mission
        if t_start is not None and self.missions.phase(now=self.clock()) == "ended":
            return
        try:
            await self.storage.call_writer(
                lambda s: s.reopen_mission(mission, now=self.clock(), t_start=t_start))
        except Exception as exc:  # full disk, SQLite: shown, the station still runs
            log.warning("mission %s not reopened in its log: %s", mission, exc)

    async def save_mission_state(self) -> None:
        """Write the mission state now (an accepted command is on disk before the API
        answers)."""
        await self.mission_state.save_now()

    def close(self) -> None:
        if self._open:
            self.save_replay_state()
            self.mission_state.save_blocking()
            self._open = False
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        self.transport.close()

    # -- input --------------------------------------------------------------------------
    def datagrams_received(self, datagrams: Sequence[tuple[bytes, Address]]) -> None:
        """A burst from the transport: decoded together, then events handled once."""
        now = self.clock()
        self.decoder.receive_datagrams(datagrams, now)
        self._process_events(now)
        self._arm()

    def datagram_received(self, data: bytes, addr: Address) -> None:
        """One datagram (tests feed the link through this, bypassing the transport)."""
        self.datagrams_received(((data, addr),))

    def _process_events(self, now: float) -> None:
        while (event := self.decoder.next_event()) is not None:
            if isinstance(event, MessageReassembled):
                self._on_message(event, now)
            elif isinstance(event, StatusReceived):
                self._on_status(event, now)
            elif isinstance(event, MessageExpired):
                reason = "evicted" if event.evicted else "incomplete"
                self.fleet.on_drop(reason, now=now, drone=event.sender)
            elif isinstance(event, PacketDropped):
                if event.reason not in ("duplicate_fragment",):
                    self.fleet.on_drop(event.reason, now=now, drone=event.sender,
                                       skew_s=event.skew_s)
            else:
                # REPORT/COMMAND packets are for drones; a ground station ignores them.
                self.counters["ignored_" + type(event).__name__] += 1
        self._catch_up(now)
        self._flush_alerts()

    def _on_message(self, event: MessageReassembled, now: float) -> None:
        message = event.message
        addr = event.addr
        image = bool(event.payload)  # JPEG bytes; telemetry travels in the metadata
        utility = (
            self.image_utility.weight(message)
            if image
            else None
        )
        self._joined(message.sender, now)
        self.fleet.on_message(message, now=now, addr=addr, utility=utility)
        for listener in self.data_listeners:
            listener(message.sender, message.data)
        report = message.data.get("report")
        if isinstance(report, str) and report:
            self.missions.on_report(message.sender, report, now=now)
        window = message.data.get("mission")
        if message.type == "status" and window in ("idle", "running", "ended") \
                and self.missions.on_mission_state(message.sender, str(window),
                                                   t_gen=message.t_gen, now=now):
            log.info("%s says its mission is %s: sending it the mission's commands again",
                     message.sender, window)
            self.send_commands(now)
        if message.t_sent is not None:
            self.reports.on_datagram(message.sender, t_sent=message.t_sent, t_rcv=event.t_rcv)
        # Reported delivered only once durable: the report entry is added by
        # on_storage_batch when the storage says the item is stored.
        accepted = self.storage.submit(
            StoreItem(
                mission=self.config.mission,
                message=message,
                payload=event.payload if image else None,
                utility=utility,
                t_rcv=event.t_rcv,
            )
        )
        if not accepted:
            self._storage_alert(now, "storage backlog full: a message was not stored")
        self.counters["messages"] += 1
        if image:
            self.counters["images"] += 1
            self.latest_jpeg[message.sender] = event.payload
        if self.broadcaster.clients:  # the tile costs ~20 us; build it only for a watcher
            interval = tile_interval(len(self.fleet.drones))
            due = self._tile_pushed.get(message.sender, -interval) + interval
            if now >= due:
                self._push_tile(message.sender, now)
            else:
                self._tiles_due.setdefault(message.sender, due)

    def _on_status(self, event: StatusReceived, now: float) -> None:
        status = event.status
        addr = event.addr
        if status.state == EPOCH_STATUS:
            self._on_epoch(event, addr, now)
            return
        self._joined(event.sender, now)
        state = self.fleet.heard(event.sender, now=now, addr=addr)
        self.fleet.apply_data(state, status.info, now=now)
        for listener in self.data_listeners:
            listener(event.sender, status.info)
        self.reports.on_datagram(event.sender, t_sent=event.t_sent, t_rcv=event.t_rcv)
        self.missions.on_status(
            event.sender,
            state=status.state,
            command_id=status.command_id,
            now=now,
            info=status.info,
        )
        self.counters["statuses"] += 1
        if status.state == "error":
            text = str(status.info.get("error", status.info.get("text", "command failed")))
            self.fleet.alert(
                Alert(t=now, level="error", kind="mission", drone=event.sender, text=text)
            )
        self.broadcaster.publish(
            "status",
            {
                "drone": self.fleet.drone_json(state, now=now),
                "status": {
                    "state": status.state,
                    "command_id": status.command_id,
                    "info": dict(status.info),
                },
                "mission": self.missions.state(now=now),
            },
        )

    def _joined(self, drone: str, now: float) -> None:
        """A drone new to the mission (not heard by this run nor, per the mission state, by
        an earlier one: a restart re-raised "drone joined" for the whole fleet) is shown."""
        if self.missions.on_drone_heard(drone, now=now):
            self.fleet.alert(Alert(t=now, level="info", kind="fleet", drone=drone,
                                   text="drone joined"))

    def _catch_up(self, now: float) -> None:
        """Drones heard again after a link loss (or for the first time since a restart) get
        the mission's commands they have not answered."""
        back = [d for d in self.fleet.take_back() if self.missions.catch_up(d, now=now)]
        for drone in back:
            log.info("%s is back: sending it the mission's commands it has not answered",
                     drone)
        if back:
            self.send_commands(now)

    def _on_epoch(self, event: StatusReceived, addr: Address, now: float) -> None:
        """A drone (re)started: remember its epoch, resend its unacknowledged commands."""
        epoch = event.status.info.get("epoch")
        if isinstance(epoch, bool) or not isinstance(epoch, int) or not 0 < epoch < 2**64:
            self.counters["bad_epoch_status"] += 1
            return
        self._joined(event.sender, now)
        self.fleet.heard(event.sender, now=now, addr=addr)
        previous = self.command_epochs.get(event.sender)
        if previous != epoch:
            self.command_epochs.pop(event.sender, None)
            self.command_epochs[event.sender] = epoch
            while len(self.command_epochs) > MAX_EPOCHS:  # oldest announcement first
                del self.command_epochs[next(iter(self.command_epochs))]
            self.missions.resend_to(event.sender)
            if previous is not None and self.missions.rejoin(event.sender, now=now):
                log.info("%s restarted: sending it the mission's commands again", event.sender)
            self.send_commands(now)

    # -- timer ---------------------------------------------------------------------------
    def _deadline(self) -> float:
        candidates = [self.reports.get_timer(), self._next_tick]
        if self._tiles_due:
            candidates.append(min(self._tiles_due.values()))
        for timer in (self.decoder.get_timer(), self.missions.get_timer()):
            if timer is not None:
                candidates.append(timer)
        return min(candidates)

    def _arm(self) -> None:
        deadline = self._deadline()
        if self._timer is not None and self._timer_at == deadline:
            return
        if self._timer is not None:
            self._timer.cancel()
        loop = asyncio.get_running_loop()
        self._timer_at = deadline
        self._timer = loop.call_later(max(0.0, deadline - self.clock()), self._on_timer)

    def _on_timer(self) -> None:
        due, self._timer, self._timer_at = self._timer_at, None, None
        now = self.clock()
        if due is not None and now - due > LATE_TIMER_S and not self._deferred:
            # the station did not run (its wait timed out meanwhile): read what waited in the
            # socket before expiring images or judging links lost; once
            log.warning("the station did not run for %.1f s (this computer was busy or "
                        "suspended): reading what its drones sent meanwhile first", now - due)
            self._deferred, self._timer_at = True, due
            self._timer = asyncio.get_running_loop().call_later(0.01, self._on_timer)
            return
        self._deferred = False
        self.decoder.handle_timer(now)
        self._process_events(now)
        self._push_due_tiles(now)
        self._send_report(now)
        self.send_commands(now)
        if now >= self._next_tick:
            self._next_tick = now + TICK_S
            self._save_replay_state_soon()
            self.mission_state.save_soon()
            point = self.fleet.tick(now=now)
            for drone in self.fleet.take_forgotten():
                self.missions.forget(drone)
                if drone not in self.fleet.drones:  # not heard again since
                    self.latest_jpeg.pop(drone, None)
                    self._tile_pushed.pop(drone, None)
                    self._tiles_due.pop(drone, None)
            self._flush_alerts()
            self.broadcaster.publish(
                "tick",  # with the mission: phases and command results change with time
                {
                    "point": point,
                    "stats": self.stats(now=now),
                    "mission": self.missions.state(now=now, last_commands=5),  # as drawn
                },
            )
        self._arm()

    def kick(self) -> None:
        """Re-evaluate timers now (after a mission command was issued from the API)."""
        now = self.clock()
        self.send_commands(now)
        self._arm()

    def stats(self, *, now: float) -> dict[str, Any]:
        return {
            "t": now,
            "decoder": dict(self.decoder.counters),
            **self.transport.stats(),
            "decoder_partials": self.decoder.partial_count,
            "decoder_buffered_bytes": self.decoder.buffered_bytes,
            "drops": dict(self.fleet.drops),
            "link": dict(self.counters + self.transport.counters),
            "storage": self.storage.stats(),
            "websocket": {
                "clients": len(self.broadcaster.clients),
                "published": self.broadcaster.published,
                "dropped": self.broadcaster.dropped,
            },
        }
