"""The fleet in any MAVLink ground station: the asyncio UDP endpoint (:class:`MavlinkOut`).

What is sent and answered, and the system ids, are the sans-I/O
:class:`~ground_station.mavlink_mirror.MavlinkMirror`'s (see that module); this shell owns the
socket and the one timer. Enabled by the ground-station config keys ``mavlink_out`` and/or
``mavlink_listen``; off when neither is set. See docs/peers.md.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Mapping
from typing import Any

from ground_station.mavlink_mirror import (
    PERIOD_S,
    Addr,
    MavlinkMirror,
    parse_endpoint,
    system_id_for,
)

__all__ = [
    "MavlinkMirror",
    "MavlinkOut",
    "open_mavlink_out",
    "parse_endpoint",
    "system_id_for",
]

log = logging.getLogger(__name__)


class _Protocol(asyncio.DatagramProtocol):
    def __init__(self, owner: MavlinkOut) -> None:
        self.owner = owner

    def datagram_received(self, data: bytes, addr: tuple[str | Any, int]) -> None:
        self.owner._on_datagram(data, (str(addr[0]), int(addr[1])))

    def error_received(self, exc: Exception) -> None:
        self.owner.mirror.counters["socket_errors"] += 1


class MavlinkOut:
    """The UDP shell: one socket, one timer, the mirror's frames to every destination."""

    def __init__(self, *, clock: Any, out: Addr | None, listen: Addr | None,
                 link_lost_s: float = 3.0, signing_key: bytes | None = None) -> None:
        self.clock = clock
        self.out = out
        self.listen = listen
        self.mirror = MavlinkMirror(now=clock(), link_lost_s=link_lost_s,
                                    signing_key=signing_key)
        self.transport: asyncio.DatagramTransport | None = None
        self._timer: asyncio.TimerHandle | None = None

    async def open(self) -> Addr:
        loop = asyncio.get_running_loop()
        if self.listen is not None:
            transport, _ = await loop.create_datagram_endpoint(lambda: _Protocol(self),
                                                               local_addr=self.listen)
        else:  # push only: connected, so the kernel drops datagrams from anyone but the GCS
            # (bound to every interface and unconnected, any host that saw the pushed
            # traffic's source port could send a HEARTBEAT there and get the fleet's stream)
            assert self.out is not None
            transport, _ = await loop.create_datagram_endpoint(lambda: _Protocol(self),
                                                               remote_addr=self.out)
        self.transport = transport
        host, port = self.transport.get_extra_info("sockname")[:2]
        log.info("MAVLink 2 fleet mirror on udp://%s:%d%s%s", host, port,
                 f", sending to {self.out[0]}:{self.out[1]}" if self.out else "",
                 ", signed" if self.mirror.signing is not None else "")
        self._arm()
        return str(host), int(port)

    def close(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        if self.transport is not None:
            self.transport.close()
            self.transport = None

    def on_data(self, drone: str, data: Mapping[str, Any]) -> None:
        """The hook the ground station's receiver calls for every message and status; a
        fault here is logged and counted, never raised into the fleet's receive path."""
        try:
            self.mirror.on_data(drone, data, now=self.clock())
            self._transmit()
        except Exception:
            self.mirror.counters["errors"] += 1
            if self.mirror.counters["errors"] in (1, 10, 100, 1000):
                log.exception("MAVLink mirror failed on data from %s", drone)

    def _on_datagram(self, data: bytes, addr: Addr) -> None:
        self.mirror.receive_datagram(data, addr, self.clock())
        self._transmit()

    def _on_timer(self) -> None:
        self._timer = None
        self.mirror.handle_timer(self.clock())
        self._transmit()

    def _arm(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        deadline = self.mirror.get_timer()
        if self.transport is None:
            return
        delay = PERIOD_S if deadline is None else max(0.0, deadline - self.clock())
        self._timer = asyncio.get_running_loop().call_later(delay, self._on_timer)

    def _transmit(self) -> None:
        transport = self.transport
        if transport is None:
            return
        dests = self.mirror.live_clients(self.clock())
        if self.listen is None:  # connected: every frame goes once, to the socket's one peer
            for frame, _addr in self.mirror.datagrams_to_send():
                transport.sendto(frame)
            self._arm()
            return
        if self.out is not None and self.out not in dests:
            dests.append(self.out)
        for frame, addr in self.mirror.datagrams_to_send():
            for dest in [addr] if addr is not None else dests:
                transport.sendto(frame, dest)
        self._arm()


async def open_mavlink_out(config: Any, clock: Any) -> MavlinkOut | None:
    """The mirror the config asks for (``mavlink_out``/``mavlink_listen``), opened; or None."""
    out = getattr(config, "mavlink_out", None)
    listen = getattr(config, "mavlink_listen", None)
    if out is None and listen is None:
        return None
    mirror = MavlinkOut(clock=clock, out=parse_endpoint(out) if out else None,
                        listen=parse_endpoint(listen) if listen else None,
                        link_lost_s=config.link_lost_s,
                        signing_key=getattr(config, "mavlink_signing_key", None))
    await mirror.open()
    return mirror
