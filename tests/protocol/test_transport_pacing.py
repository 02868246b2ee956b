"""Paced sending on real sockets: two drones' images through a small shaped queue.

The bottleneck is :class:`sitl.relay.ShapedQueue` (the demo's relay, behaving like ``tc tbf``)
fed with the real arrival times of a real UDP socket. Unpaced, two 30 kB images sent at the
same moment arrive within a millisecond: 60 kB into a 37.5 kB queue, the tails dropped and
both images lost (what ``--netns`` runs saw). Paced, they fit and both arrive whole.
"""

from __future__ import annotations

import asyncio
import dataclasses
import random
import time
from typing import Any

from protocol_helpers import FLEET, KEY, image_message

from companion.protocol import Decoder, Encoder, MessageReassembled
from companion.transport import UdpTransport
from sitl.relay import ShapedQueue
from utility_specs.message import Message

LOCAL = ("127.0.0.1", 0)
QUEUE_BYTES = 37_500  # the --netns tbf queue


class Bottleneck(asyncio.DatagramProtocol):
    """A shaped link in front of the ground's decoder: what leaves it is decoded."""

    def __init__(self, rate_bytes_per_s: float) -> None:
        self.queue: ShapedQueue[bytes] = ShapedQueue(rate_bytes_per_s=rate_bytes_per_s,
                                                     queue_limit_bytes=QUEUE_BYTES)
        self.decoder = Decoder(FLEET, KEY, local_id="ground")
        self.arrivals: dict[str, list[float]] = {}
        self.whole: list[tuple[str, int]] = []

    def datagram_received(self, data: bytes, addr: Any) -> None:
        now = time.time()
        self.arrivals.setdefault(str(addr[1]), []).append(now)
        self.queue.offer(data, len(data), now)
        self.drain(now)

    def drain(self, now: float) -> None:
        for data in self.queue.pop_due(now):
            self.decoder.receive_datagram(data, ("127.0.0.1", 1), now)
        while (event := self.decoder.next_event()) is not None:
            if isinstance(event, MessageReassembled):
                self.whole.append((event.message.sender, event.message.seq))


async def _two_drones_send_at_once(pace_rate: float | None) -> tuple[Bottleneck, float]:
    loop = asyncio.get_running_loop()
    link = Bottleneck(rate_bytes_per_s=100_000.0)
    server, _ = await loop.create_datagram_endpoint(lambda: link, local_addr=LOCAL)
    port = server.get_extra_info("sockname")[1]
    drones = [UdpTransport(encoder=Encoder(FLEET, f"drone{i}", KEY), decoder=Decoder(FLEET, KEY),
                           remote_addr=("127.0.0.1", port), local_addr=LOCAL)
              for i in (1, 2)]
    if pace_rate is not None:
        for drone in drones:
            drone.pace(pace_rate)
    tasks = [asyncio.create_task(d.run()) for d in drones]
    try:
        for d in drones:
            await d.wait_started()
        payload = random.Random(1).randbytes(30_000)
        t0 = time.time()
        for i, drone in enumerate(drones, start=1):
            assert drone.send_message(_image_of(f"drone{i}", 7, t0), payload) == 27
        async with asyncio.timeout(5.0):
            while len(link.queue) or sum(map(len, link.arrivals.values())) < 54:
                await asyncio.sleep(0.02)
                link.drain(time.time())
        return link, time.time() - t0
    finally:
        for d in drones:
            d.stop()
        await asyncio.gather(*tasks)
        server.close()


def _image_of(sender: str, seq: int, t: float) -> Message:
    return dataclasses.replace(image_message(seq=seq, size=30_000, t_gen=t), sender=sender)


async def test_paced_bursts_of_two_drones_fit_a_small_queue() -> None:
    # each drone at 40 kB/s into a 100 kB/s link: together they never outrun it
    link, took = await _two_drones_send_at_once(pace_rate=40_000.0)
    print(f"max backlog {link.queue.max_backlog_bytes} B of {QUEUE_BYTES}, "
          f"{link.queue.counters}, {took:.2f} s")
    assert link.queue.counters["dropped_packets"] == 0
    assert link.queue.max_backlog_bytes < QUEUE_BYTES // 4
    assert sorted(link.whole) == [("drone1", 7), ("drone2", 7)]
    for times in link.arrivals.values():  # spread over ~(30.8 kB - one burst) / 40 kB/s
        assert max(times) - min(times) > 0.5


async def test_unpaced_bursts_overflow_it() -> None:
    """The failure the pacer removes (and proof the bottleneck above can overflow)."""
    link, _ = await _two_drones_send_at_once(pace_rate=None)
    assert link.queue.counters["dropped_packets"] > 0
    assert len(link.whole) < 2


async def test_a_message_the_busy_pacer_cannot_take_is_dropped_whole() -> None:
    loop = asyncio.get_running_loop()
    link = Bottleneck(rate_bytes_per_s=1e6)
    server, _ = await loop.create_datagram_endpoint(lambda: link, local_addr=LOCAL)
    drone = UdpTransport(encoder=Encoder(FLEET, "drone1", KEY), decoder=Decoder(FLEET, KEY),
                         remote_addr=("127.0.0.1", server.get_extra_info("sockname")[1]),
                         local_addr=LOCAL)
    drone.pace(20_000.0)  # 30 kB: 1.4 s of pacing, more than the pacer's max_delay_s
    task = asyncio.create_task(drone.run())
    try:
        await drone.wait_started()
        t0 = time.time()
        first, second = _image_of("drone1", 7, t0), _image_of("drone1", 8, t0)
        assert drone.send_message(first, bytes(30_000)) == 27
        assert drone.send_message(second, bytes(30_000)) == 0  # nothing of it queued
        assert drone.counters["send_dropped_pacer_full"] == 1
        assert drone.counters["messages_sent"] == 1
        async with asyncio.timeout(5.0):
            while not link.whole:
                await asyncio.sleep(0.02)
                link.drain(time.time())
        assert time.time() - t0 > 1.2  # it really was paced
        await asyncio.sleep(0.1)
        assert link.whole == [("drone1", 7)]
        assert sum(map(len, link.arrivals.values())) == 27  # not one datagram of the second
        assert drone.stats()["pacer"]["units_dropped"] == 1
    finally:
        drone.stop()
        await task
        server.close()
