"""The drone-side UDP shell around the sans-I/O codec (companion.protocol).

It owns the socket, the clock and one timer; the codec owns every decision. Each entry point
does the aioquic three steps: call the core with ``now=clock()``, hand its events out, re-arm
the single ``loop.call_later`` for ``decoder.get_timer()``. Sending is the socket's
non-blocking ``sendto``: an error (ENOBUFS, unreachable...) or a full write buffer is counted
and the message is lost, like any other loss on the air; nothing here retries or blocks.

After :meth:`UdpTransport.pace` (the app's: at the configured link rate) the datagrams of a
message do not leave in one burst: they go through a :class:`~companion.protocol.pacer.Pacer`,
driven by a second timer; a message the pacer cannot take whole is dropped whole and counted
(``send_dropped_pacer_full``).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable, Sequence
from typing import Any

from companion.drop_warnings import DropWarnings
from companion.medium import (
    SharedMedium,
    medium_problem,
    open_medium_socket,
    parse_medium,
    prepare_medium_sender,
    sender_id,
)
from companion.medium_watch import MediumWatch
from companion.protocol import (
    Address,
    Decoder,
    Encoder,
    Event,
    LocalProtocolError,
    PacketDropped,
    Report,
    Status,
)
from companion.protocol.pacer import Pacer
from companion.protocol.records import EPOCH_STATUS
from companion.remote_lookup import RemoteLookup
from utility_specs.message import Message

__all__ = ["Clock", "SharedMedium", "TransportStartError", "UdpTransport", "open_medium_socket",
           "parse_medium"]

log = logging.getLogger(__name__)

Clock = Callable[[], float]
"""Fleet clock: Unix seconds (``time.time`` in production)."""

SEND_COUNTERS = (
    "datagrams_sent", "bytes_sent", "messages_sent", "send_errors", "send_dropped_buffer_full",
    "send_not_ready", "events_dropped", "medium_sent", "medium_received", "medium_own_echo",
    "medium_reports_sent", "send_dropped_pacer_full",
)


class TransportStartError(RuntimeError):
    """A socket cannot open; the text names the setting and the fix (one line in ``run``)."""


class _MediumProtocol(asyncio.DatagramProtocol):
    """The medium listener: everything but our own echo goes to the same decoder."""

    def __init__(self, owner: UdpTransport) -> None:
        self._owner = owner

    def datagram_received(self, data: bytes, addr: Address) -> None:
        owner = self._owner
        if sender_id(data) == owner.encoder.sender:  # our own datagram, looped back
            owner.counters["medium_own_echo"] += 1
            if owner.medium_watch is not None and owner._transport is not None:  # or a twin's
                owner.medium_watch.own_id_heard(addr, owner.local_address[1])
            return
        owner.counters["medium_received"] += 1
        owner._on_datagram(data, addr)


class _Protocol(asyncio.DatagramProtocol):
    def __init__(self, owner: UdpTransport) -> None:
        self._owner = owner

    def datagram_received(self, data: bytes, addr: Address) -> None:
        self._owner._on_datagram(data, addr)

    def error_received(self, exc: Exception) -> None:
        self._owner._on_send_error(exc)


class UdpTransport:
    """One UDP socket speaking the fleet protocol.

    Received events (reports, commands, statuses, reassembled messages, drops) go to
    ``on_event`` when given, else into the bounded ``events`` queue (oldest dropped and
    counted when full). ``remote_addr`` is where ``send_*`` go by default (the ground
    station); a hostname is resolved once at start, never on the send path.
    """

    def __init__(
        self,
        *,
        encoder: Encoder,
        decoder: Decoder,
        remote_addr: tuple[str, int] | None = None,
        local_addr: tuple[str, int] = ("0.0.0.0", 0),
        clock: Clock = time.time,
        on_event: Callable[[Event], None] | None = None,
        max_queued_events: int = 1000,
        max_write_buffer_bytes: int = 256 * 1024,
        epoch: int | None = None,
        medium: SharedMedium | None = None,
        remote_name: str = "remote host",
    ) -> None:
        """``epoch``: this boot's epoch (the decoder's); announced to ``remote_addr`` at start
        and whenever a command for another boot is refused, at most twice a second.
        ``medium``: the fleet's shared medium; ``send_message(..., shared=True)`` goes there
        and peers' datagrams heard on it reach ``on_event`` like the ground's."""
        self.medium = medium
        self._medium_transport: asyncio.DatagramTransport | None = None
        self.encoder = encoder
        self.epoch = epoch
        self._epoch_sent_at = -1.0
        self.decoder = decoder
        self.remote_addr = remote_addr
        self.remote_name = remote_name
        """What a WARNING calls ``remote_addr``'s host (the app: ``ground_station.host``)."""
        self._lookup: RemoteLookup | None = None
        """Set while ``remote_addr`` is a name that has not resolved yet."""
        self.local_addr = local_addr
        self._clock = clock
        self._on_event = on_event
        self.events: asyncio.Queue[Event] = asyncio.Queue(maxsize=max_queued_events)
        self.max_write_buffer_bytes = max_write_buffer_bytes
        self.counters: dict[str, int] = dict.fromkeys(SEND_COUNTERS, 0)
        self._transport: asyncio.DatagramTransport | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._timer: asyncio.TimerHandle | None = None
        self._timer_deadline: float | None = None
        self._stopped = asyncio.Event()
        self._started = asyncio.Event()
        self.pacer: Pacer[Address] | None = None
        """Set by :meth:`pace`; None: each message's datagrams go to the socket at once."""
        self._pace_timer: asyncio.TimerHandle | None = None
        self._pace_deadline: float | None = None
        self._drop_warnings = DropWarnings(log)
        """A wrong key or fleet id is told at WARNING (rate-limited), not only at DEBUG."""
        self.medium_watch = MediumWatch(medium, log) if medium is not None else None
        self._sending_to: Address | None = None
        self._watch_timer: asyncio.TimerHandle | None = None

    # -- lifecycle -----------------------------------------------------------------------

    @property
    def local_address(self) -> tuple[str, int]:
        """The bound (host, port); only valid once started."""
        if self._transport is None:
            raise RuntimeError("transport not started")
        sockname = self._transport.get_extra_info("sockname")
        return (sockname[0], sockname[1])

    async def start(self) -> None:
        """Bind the socket and resolve the remote address (idempotent)."""
        if self._transport is not None:
            return
        self._loop = asyncio.get_running_loop()
        if self.remote_addr is not None:
            lookup = RemoteLookup(self.remote_addr, self.remote_name, self._resolved)
            resolved = await lookup.first()
            if resolved is None:
                self._lookup = lookup  # retrying in the background; nothing is sent meanwhile
            else:
                self.remote_addr = resolved
        try:
            transport, _ = await self._loop.create_datagram_endpoint(
                lambda: _Protocol(self), local_addr=self.local_addr)
        except OSError as exc:
            host, port = self.local_addr
            raise TransportStartError(
                f"ground_station.listen_host/listen_port {host}:{port}: cannot bind "
                f"({exc.strerror or exc}): another program holds it, or it is not an address "
                "of this computer (listen_port = 0 takes any free port)") from None
        self._transport = transport
        if self.medium is not None:
            try:
                prepare_medium_sender(transport.get_extra_info("socket"), self.medium)
                medium_sock = open_medium_socket(self.medium)
            except OSError as exc:
                raise TransportStartError(medium_problem(exc, self.medium, "peers.medium")
                                          ) from None
            self._medium_transport, _ = await self._loop.create_datagram_endpoint(
                lambda: _MediumProtocol(self), sock=medium_sock)
            log.info("shared medium: %s %s:%d", self.medium.kind, self.medium.address,
                     self.medium.port)
            self._watch_medium()
        self._started.set()
        log.info("protocol transport bound to %s", self.local_address)
        self._announce_epoch()

    def _watch_medium(self) -> None:
        if self.medium_watch is None or self._loop is None or self._transport is None:
            return
        self.medium_watch.check(self.counters)
        self._watch_timer = self._loop.call_later(self.medium_watch.period_s,
                                                  self._watch_medium)

    def _resolved(self, addr: tuple[str, int]) -> None:
        self.remote_addr = addr
        self._lookup = None
        self._announce_epoch()

    def _announce_epoch(self) -> None:
        if self.epoch is None or self.remote_addr is None or self._lookup is not None:
            return
        now = self._clock()
        if 0 <= now - self._epoch_sent_at < 0.5:
            return
        self._epoch_sent_at = now
        self.send_status(Status(state=EPOCH_STATUS, info={"epoch": self.epoch}), now)

    async def wait_started(self) -> None:
        await self._started.wait()

    async def run(self) -> None:
        """Serve until ``stop()``; the socket and the timer are released on the way out."""
        try:
            await self.start()
            await self._stopped.wait()
        finally:
            self._close()

    def stop(self) -> None:
        self._stopped.set()

    def _close(self) -> None:
        if self._lookup is not None:
            self._lookup.cancel()
            self._lookup = None
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        if self._pace_timer is not None:
            self._pace_timer.cancel()
            self._pace_timer = None
        if self._watch_timer is not None:
            self._watch_timer.cancel()
            self._watch_timer = None
        if self._transport is not None:
            self._transport.close()
            self._transport = None
        if self._medium_transport is not None:
            self._medium_transport.close()
            self._medium_transport = None

    # -- sending -------------------------------------------------------------------------

    def send_message(self, message: Message, payload: bytes, now: float | None = None, *,
                     shared: bool = False) -> int:
        """Fragment and send one message; returns the datagrams sent (0 if it was dropped).

        ``shared``: to the shared medium (every peer and the ground station hear it) when
        one is configured, else to ``remote_addr`` as usual.
        ``LocalProtocolError`` (a message the wire cannot carry) propagates: it is the
        caller's bug, not bad luck on the link.
        """
        now = self._clock() if now is None else now
        datagrams = self.encoder.fragment(message, payload, now)
        if shared and self.medium is not None:
            sent = self.send_datagrams(datagrams, self.medium.target)
            if sent:
                self.counters["medium_sent"] += 1
        else:
            sent = self.send_datagrams(datagrams)
        if sent:
            self.counters["messages_sent"] += 1
        return sent

    def send_status(self, status: Status, now: float | None = None) -> int:
        now = self._clock() if now is None else now
        return self.send_datagrams([self.encoder.encode_status(status, now)])

    def send_report_shared(self, report: Report, now: float | None = None) -> int:
        """This drone's receiver report of what it heard from peers, on the shared medium
        (every peer learns what this drone holds, issue 15); 0 without a medium."""
        if self.medium is None:
            return 0
        now = self._clock() if now is None else now
        sent = self.send_datagrams(self.encoder.encode_report(report, now), self.medium.target)
        if sent:
            self.counters["medium_reports_sent"] += 1
        return sent

    def send_report(self, report: Report, addr: Address, now: float | None = None) -> int:
        """Ground-side helper, handy in tests and tools."""
        now = self._clock() if now is None else now
        return self.send_datagrams(self.encoder.encode_report(report, now), addr)

    def send_datagrams(self, datagrams: Sequence[bytes], addr: Address | None = None) -> int:
        """Send all datagrams of one unit (a message is lost whole, never half-queued):
        at once, or through the pacer when a pacing rate is set."""
        target = addr if addr is not None else self.remote_addr
        if target is None:
            raise LocalProtocolError("no remote address to send to")
        transport = self._transport
        if transport is None or (addr is None and self._lookup is not None):
            # not bound yet, closed, or the remote's name not resolved: lost like on the air
            self.counters["send_not_ready"] += 1
            return 0
        total = sum(len(d) for d in datagrams)
        if _write_buffer_size(transport) + total > self.max_write_buffer_bytes:
            self.counters["send_dropped_buffer_full"] += 1
            return 0
        if self.pacer is None:
            for data in datagrams:
                self._sendto(transport, data, target)
        else:
            now = self._clock()
            if not self.pacer.offer(datagrams, target, now):
                self.counters["send_dropped_pacer_full"] += 1
                return 0
            self._release_paced(now)
        self.counters["datagrams_sent"] += len(datagrams)
        self.counters["bytes_sent"] += total
        return len(datagrams)

    def pace(self, rate_bytes_per_s: float) -> None:
        """From now on every message's datagrams leave at ``rate_bytes_per_s`` (the radio's
        rate), not in one burst; call it before sending."""
        self.pacer = Pacer(rate_bytes_per_s=rate_bytes_per_s,
                           max_backlog_bytes=self.max_write_buffer_bytes)

    def _release_paced(self, now: float) -> None:
        """Hand the pacer's due datagrams to the socket; re-arm its one timer."""
        pacer = self.pacer
        transport = self._transport
        if pacer is None:
            return
        for data, target in pacer.pop_due(now):
            if transport is not None:
                self._sendto(transport, data, target)
        deadline = pacer.next_due()
        if deadline == self._pace_deadline and self._pace_timer is not None:
            return
        if self._pace_timer is not None:
            self._pace_timer.cancel()
            self._pace_timer = None
        self._pace_deadline = deadline
        if deadline is not None and self._loop is not None and transport is not None:
            self._pace_timer = self._loop.call_later(max(0.0, deadline - self._clock()),
                                                     self._on_pace_timer)

    def _on_pace_timer(self) -> None:
        self._pace_timer = None
        deadline = self._pace_deadline
        self._pace_deadline = None
        now = self._clock()
        # as _on_timer: the loop's clock and the fleet clock differ slightly; never early
        self._release_paced(max(now, deadline) if deadline is not None else now)

    def _sendto(self, transport: asyncio.DatagramTransport, data: bytes, target: Address
                ) -> None:
        self._sending_to = target  # asyncio reports a failed sendto before it returns
        try:
            transport.sendto(data, target)
        finally:
            self._sending_to = None

    def _on_send_error(self, exc: Exception) -> None:
        self.counters["send_errors"] += 1
        log.debug("UDP error: %s", exc)
        if self.medium_watch is not None and isinstance(exc, OSError) \
                and self.medium is not None and self._sending_to == self.medium.target:
            self.medium_watch.send_failed(exc, self._clock())

    # -- receiving -----------------------------------------------------------------------

    def _on_datagram(self, data: bytes, addr: Address) -> None:
        self.decoder.receive_datagram(data, addr, self._clock())
        self._process_events()
        self._arm_timer()

    def _on_timer(self) -> None:
        self._timer = None
        deadline = self._timer_deadline
        self._timer_deadline = None
        now = self._clock()
        # The loop's monotonic clock and the fleet clock drift apart slightly; never fire
        # "early" and re-arm in a tight loop for the difference.
        self.decoder.handle_timer(max(now, deadline) if deadline is not None else now)
        self._process_events()
        self._arm_timer()

    def _arm_timer(self) -> None:
        deadline = self.decoder.get_timer()
        if deadline == self._timer_deadline and (deadline is None or self._timer is not None):
            return
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        self._timer_deadline = deadline
        if deadline is not None and self._loop is not None:
            delay = max(0.0, deadline - self._clock())
            self._timer = self._loop.call_later(delay, self._on_timer)

    def _process_events(self) -> None:
        while (event := self.decoder.next_event()) is not None:
            if isinstance(event, PacketDropped):
                log.debug(
                    "dropped datagram from %s: %s (%s)", event.addr, event.reason, event.detail
                )
                self._drop_warnings.on_drop(event.reason, event.addr, event.detail)
                if event.reason == "wrong_epoch":
                    self._announce_epoch()
            if self._on_event is not None:
                self._on_event(event)
                continue
            if self.events.full():
                with contextlib.suppress(asyncio.QueueEmpty):
                    self.events.get_nowait()
                self.counters["events_dropped"] += 1
            self.events.put_nowait(event)

    def stats(self) -> dict[str, Any]:
        """Send counters and the decoder's receive counters, for logs and status reports."""
        stats: dict[str, Any] = {"send": dict(self.counters),
                                 "receive": dict(self.decoder.counters)}
        if self.pacer is not None:
            pacer = self.pacer
            stats["pacer"] = {**pacer.counters, "rate_bytes_per_s": pacer.rate_bytes_per_s,
                              "max_backlog_bytes": pacer.max_backlog_seen_bytes}
        return stats


def _write_buffer_size(transport: asyncio.DatagramTransport) -> int:
    """Bytes asyncio holds because the socket would block (typeshed omits the method)."""
    size = getattr(transport, "get_write_buffer_size", None)
    return int(size()) if callable(size) else 0
