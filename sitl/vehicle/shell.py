"""The asyncio shell around :class:`~sitl.vehicle.core.VehicleCore`: one UDP socket per vehicle.

aioquic-shaped: every entry point calls the core with ``now`` from a :class:`SimClock`, then
``transmit()`` sends what the core produced and re-arms exactly one timer. The vehicle sends
to every peer it has heard (the ``max_peers`` most recent) and to a fixed ``out`` address if
configured. A peer that went quiet keeps its stream, as on ArduPilot, where each link streams
whatever its client does, and a listener that only listens (MAVProxy's ``--out``, a logger)
must not be starved because another client talks.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Hashable, Sequence
from dataclasses import dataclass, replace
from typing import cast

from sitl.vehicle.core import VehicleConfig, VehicleCore
from sitl.vehicle.links import DEFAULT_LINK

__all__ = ["SimClock", "VehicleEndpoint", "VehicleProtocol", "start_vehicles"]

Addr = tuple[str, int]


class SimClock:
    """Vehicle time in simulated seconds since boot: loop time scaled by ``speedup``."""

    def __init__(self, loop: asyncio.AbstractEventLoop, speedup: float = 1.0) -> None:
        if not speedup > 0.0:
            raise ValueError(f"speedup must be > 0, got {speedup}")
        self._loop = loop
        self.speedup = speedup
        self._t0 = loop.time()

    @property
    def loop(self) -> asyncio.AbstractEventLoop:
        return self._loop

    def __call__(self) -> float:
        return (self._loop.time() - self._t0) * self.speedup

    def wall_delay(self, sim_deadline: float) -> float:
        """Wall seconds until the simulated deadline (never negative)."""
        return max(0.0, (sim_deadline - self()) / self.speedup)


class CoreTimer:
    """The core's next deadline as one ``call_later``, re-armed after every output
    (aioquic's transmit/timer pattern); shared by the UDP and the serial endpoints."""

    def __init__(self, core: VehicleCore, clock: SimClock, on_fire: Callable[[], None]) -> None:
        self.core = core
        self.clock = clock
        self._on_fire = on_fire
        self._handle: asyncio.TimerHandle | None = None

    def rearm(self) -> None:
        self.cancel()
        delay = self.clock.wall_delay(self.core.get_timer())
        self._handle = self.clock.loop.call_later(delay, self._fire)

    def cancel(self) -> None:
        if self._handle is not None:
            self._handle.cancel()
            self._handle = None

    def _fire(self) -> None:
        self._handle = None
        self.core.handle_timer(self.clock())
        self._on_fire()


class LinkGroup:
    """One core served on several links (a flight controller's TELEM ports, each its own
    streams: sitl.vehicle.links) with one timer: after any input or deadline every link
    sends what the core produced for it."""

    def __init__(self, core: VehicleCore, clock: SimClock) -> None:
        self.core = core
        self.clock = clock
        self.members: list[Callable[[], None]] = []
        """Each link's ``send_pending``."""
        self._timer = CoreTimer(core, clock, self.transmit)

    def transmit(self) -> None:
        for send_pending in self.members:
            send_pending()
        self._timer.rearm()

    def cancel(self) -> None:
        self._timer.cancel()


class VehicleProtocol(asyncio.DatagramProtocol):
    """Feeds datagrams and timers into one core and sends its output."""

    def __init__(self, core: VehicleCore, clock: SimClock, *, out: Addr | None = None,
                 max_peers: int = 8, link: Hashable = DEFAULT_LINK,
                 group: LinkGroup | None = None) -> None:
        self.core = core
        self.clock = clock
        self.out = out
        self.max_peers = max_peers
        self.peers: dict[Addr, float] = {}
        self.transport: asyncio.DatagramTransport | None = None
        self.link = link
        self.group = group
        self._timer = CoreTimer(core, clock, self.transmit) if group is None else None
        if group is not None:
            group.members.append(self.send_pending)
        self.send_errors = 0

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = cast(asyncio.DatagramTransport, transport)
        self.transmit()

    def datagram_received(self, data: bytes, addr: tuple[str | int, ...]) -> None:
        peer = (str(addr[0]), int(addr[1]))
        now_wall = self.clock.loop.time()
        self.peers.pop(peer, None)
        self.peers[peer] = now_wall  # most recent last
        while len(self.peers) > self.max_peers:
            self.peers.pop(next(iter(self.peers)))
        self.core.receive_datagram(data, peer, self.clock(), self.link)
        self.transmit()

    def error_received(self, exc: Exception) -> None:
        # ICMP port unreachable from a client that went away: count, keep serving.
        self.send_errors += 1

    def connection_lost(self, exc: Exception | None) -> None:
        if self._timer is not None:
            self._timer.cancel()
        if self.group is not None:
            self.group.cancel()

    def destinations(self) -> list[Addr]:
        dests = list(self.peers)
        if self.out is not None and self.out not in dests:
            dests.append(self.out)
        return dests

    def transmit(self) -> None:
        if self.group is not None:
            self.group.transmit()
            return
        if self.transport is None or self.transport.is_closing():
            return
        self.send_pending()
        if self._timer is not None:
            self._timer.rearm()

    def send_pending(self) -> None:
        """Send this link's frames and the HEARTBEATs routed to it (never echoed)."""
        if self.transport is None or self.transport.is_closing():
            return
        frames = self.core.datagrams_to_send(self.link)
        if frames:
            dests = self.destinations()
            for frame in frames:
                for dest in dests:
                    self.transport.sendto(frame, dest)
        for sender, frame in self.core.forwards_to_send(self.link):
            for dest in self.destinations():
                if dest != sender:
                    self.transport.sendto(frame, dest)


@dataclass(slots=True)
class VehicleEndpoint:
    """A running vehicle: its core, protocol and bound address."""

    core: VehicleCore
    protocol: VehicleProtocol
    transport: asyncio.DatagramTransport
    address: Addr

    def close(self) -> None:
        self.transport.close()


async def start_vehicles(
    configs: Sequence[VehicleConfig],
    *,
    host: str = "127.0.0.1",
    ports: Sequence[int],
    speedup: float = 1.0,
    outs: Sequence[Addr | None] | None = None,
) -> list[VehicleEndpoint]:
    """Bind one UDP endpoint per config (port 0 picks a free port) on the running loop.

    All vehicles share one :class:`SimClock`, so they fly in the same simulated time.
    """
    if len(ports) != len(configs):
        raise ValueError("one port per vehicle config is needed")
    loop = asyncio.get_running_loop()
    clock = SimClock(loop, speedup)
    endpoints: list[VehicleEndpoint] = []
    try:
        for i, (config, port) in enumerate(zip(configs, ports, strict=True)):
            core = VehicleCore(replace(config, speedup=speedup), now=clock())
            out = outs[i] if outs is not None else None
            protocol = VehicleProtocol(core, clock, out=out)
            transport, _ = await loop.create_datagram_endpoint(
                lambda p=protocol: p, local_addr=(host, port))  # type: ignore[misc]
            sock_addr = transport.get_extra_info("sockname")
            endpoints.append(VehicleEndpoint(core=core, protocol=protocol, transport=transport,
                                             address=(str(sock_addr[0]), int(sock_addr[1]))))
    except BaseException:
        for ep in endpoints:
            ep.close()
        raise
    return endpoints
