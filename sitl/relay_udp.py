"""``python -m sitl.relay_udp``: the UDP shell around :class:`sitl.relay.ShapedQueue`.

    python -m sitl.relay_udp --listen HOST:PORT --to HOST:PORT --rate BYTES_S
                             [--queue BYTES] [--background BYTES_S@START[+DURATION]]
                             [--stats FILE]

Drones send to ``--listen``; every datagram goes through the shaped queue to ``--to`` (the
ground station) from a socket of its own per drone address, so the station's reports and
commands to that socket come back to that drone (unshaped, like the downlink of the
``--netns`` medium). SIGUSR1 marks the mission start (the background schedule's origin);
SIGTERM/SIGINT stop it and write the counters to ``--stats`` as JSON.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import signal
import sys
import time
from pathlib import Path
from typing import Any

from companion.stop_signals import EarlyStop
from sitl.relay import BackgroundLoad, ShapedQueue

__all__ = ["UdpRelay", "main", "parse_background_bytes"]

Address = tuple[str, int]


class _Listen(asyncio.DatagramProtocol):
    def __init__(self, relay: UdpRelay) -> None:
        self.relay = relay

    def datagram_received(self, data: bytes, addr: Any) -> None:
        self.relay.from_drone(data, (str(addr[0]), int(addr[1])))


class _Upstream(asyncio.DatagramProtocol):
    """The relay's socket toward the station for one drone; replies go back to that drone."""

    def __init__(self, relay: UdpRelay, drone: Address) -> None:
        self.relay = relay
        self.drone = drone

    def datagram_received(self, data: bytes, addr: Any) -> None:
        self.relay.to_drone(data, self.drone)

    def error_received(self, exc: Exception) -> None:
        self.relay.counters["upstream_errors"] += 1


class UdpRelay:
    def __init__(self, queue: ShapedQueue[tuple[bytes, Address]], upstream: Address,
                 *, max_drones: int = 256) -> None:
        self.queue = queue
        self.upstream = upstream
        self.max_drones = max_drones
        self.counters = {"received": 0, "downlink": 0, "upstream_errors": 0,
                         "drones_refused": 0}
        self._listen: asyncio.DatagramTransport | None = None
        self._up: dict[Address, asyncio.DatagramTransport] = {}
        self._opening: dict[Address, list[bytes]] = {}
        self._timer: asyncio.TimerHandle | None = None

    async def start(self, listen: Address) -> Address:
        loop = asyncio.get_running_loop()
        self._listen, _ = await loop.create_datagram_endpoint(
            lambda: _Listen(self), local_addr=listen)
        sockname = self._listen.get_extra_info("sockname")
        return str(sockname[0]), int(sockname[1])

    def from_drone(self, data: bytes, drone: Address) -> None:
        self.counters["received"] += 1
        self.queue.offer((data, drone), len(data), time.time())
        self._flush()

    def to_drone(self, data: bytes, drone: Address) -> None:
        if self._listen is not None:
            self.counters["downlink"] += 1
            self._listen.sendto(data, drone)

    def mission_started(self) -> None:
        self.queue.start_background(time.time())
        self._flush()

    def _flush(self) -> None:
        for data, drone in self.queue.pop_due(time.time()):
            up = self._up.get(drone)
            if up is not None:
                up.sendto(data)
            elif drone in self._opening:
                self._opening[drone].append(data)
            elif len(self._up) + len(self._opening) < self.max_drones:
                self._opening[drone] = [data]
                asyncio.get_running_loop().create_task(self._open(drone))
            else:
                self.counters["drones_refused"] += 1
        self._arm()

    async def _open(self, drone: Address) -> None:
        loop = asyncio.get_running_loop()
        try:
            transport, _ = await loop.create_datagram_endpoint(
                lambda: _Upstream(self, drone), remote_addr=self.upstream)
        except OSError:
            self.counters["upstream_errors"] += 1
            self._opening.pop(drone, None)
            return
        self._up[drone] = transport
        for data in self._opening.pop(drone, []):
            transport.sendto(data)

    def _arm(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        due = self.queue.next_due()
        if due is not None:
            loop = asyncio.get_running_loop()
            delay = max(0.0, due - time.time())
            self._timer = loop.call_later(delay, self._flush)

    def stats(self) -> dict[str, Any]:
        q = self.queue
        return {"rate_bytes_per_s": q.rate_bytes_per_s, "queue_limit_bytes": q.queue_limit_bytes,
                "burst_bytes": q.burst_bytes, "max_backlog_bytes": q.max_backlog_bytes,
                "background": None if q.background is None else {
                    "rate_bytes_per_s": q.background.rate_bytes_per_s,
                    "start_s": q.background.start_s, "duration_s": q.background.duration_s},
                "origin": q.origin, **q.counters, **self.counters}

    def close(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
        for transport in self._up.values():
            transport.close()
        if self._listen is not None:
            self._listen.close()


def _address(text: str) -> Address:
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit() or not 0 <= int(port) < 65536:
        raise argparse.ArgumentTypeError(f"expected HOST:PORT, got {text!r}")
    return host or "127.0.0.1", int(port)


def parse_background_bytes(text: str) -> BackgroundLoad:
    """``20000@60`` (20000 B/s from 60 s after the mission start) or ``20000@60+30``."""
    rate, _, when = text.partition("@")
    start, _, length = when.partition("+")
    try:
        return BackgroundLoad(float(rate), float(start) if start else 0.0,
                              float(length) if length else None)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"expected BYTES_S[@START[+DURATION]]: {exc}"
                                         ) from None


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m sitl.relay_udp",
                                description="A shaped UDP relay (token bucket + bounded queue).")
    p.add_argument("--listen", type=_address, required=True)
    p.add_argument("--to", type=_address, required=True)
    p.add_argument("--rate", type=float, required=True, help="bytes/s")
    p.add_argument("--queue", type=int, default=30_000, help="queue limit in bytes")
    p.add_argument("--burst", type=int, default=3_000, help="bucket size in bytes")
    p.add_argument("--background", type=parse_background_bytes, default=None)
    p.add_argument("--stats", type=Path, default=None)
    args = p.parse_args(argv)
    stop_signals = EarlyStop()  # a stop signal right after the relay line is not lost
    try:
        queue: ShapedQueue[tuple[bytes, Address]] = ShapedQueue(
            rate_bytes_per_s=args.rate, queue_limit_bytes=args.queue, burst_bytes=args.burst,
            background=args.background)
    except ValueError as exc:
        print(f"relay: {exc}", file=sys.stderr)
        return 2

    async def serve() -> int:
        relay = UdpRelay(queue, args.to)
        try:
            where = await relay.start(args.listen)
        except OSError as exc:
            print(f"relay: cannot listen on {args.listen}: {exc}", file=sys.stderr)
            return 1
        print(f"relay {where[0]}:{where[1]} -> {args.to[0]}:{args.to[1]} at "
              f"{args.rate:g} B/s, queue {args.queue} B", flush=True)
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        stop_signals.attach(loop, stop.set)
        loop.add_signal_handler(signal.SIGUSR1, relay.mission_started)
        await stop.wait()
        relay.close()
        if args.stats is not None:
            with contextlib.suppress(OSError):
                args.stats.write_text(json.dumps(relay.stats(), indent=2) + "\n")
        print(f"relay stopped: {json.dumps(relay.stats())}", flush=True)
        return 0

    return asyncio.run(serve())


if __name__ == "__main__":
    sys.exit(main())
