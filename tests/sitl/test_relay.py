"""The demo's shaped relay: its token bucket and queue (exact values), and the UDP shell as a
real subprocess between a sender and a receiver."""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sitl.relay import BackgroundLoad, ShapedQueue


def queue(**kw: object) -> ShapedQueue[str]:
    params: dict[str, object] = {"rate_bytes_per_s": 1000.0, "queue_limit_bytes": 3000,
                                 "burst_bytes": 1000, "overhead_bytes": 0}
    params.update(kw)
    return ShapedQueue(**params)  # type: ignore[arg-type]


def test_burst_goes_at_once_then_the_rate_paces_and_a_full_queue_drops() -> None:
    q = queue()
    assert [q.offer(x, 1000, 0.0) for x in "abcde"] == [True, True, True, True, False]
    assert q.pop_due(0.0) == ["a"]  # the bucket starts full: one burst
    assert q.next_due() == 1.0
    assert q.pop_due(0.999) == []
    assert q.pop_due(1.0) == ["b"]
    assert q.backlog_bytes == 2000
    assert q.pop_due(10.0) == ["c", "d"]
    assert q.counters["sent_packets"] == 4 and q.counters["sent_bytes"] == 4000
    assert q.counters["dropped_packets"] == 1 and q.counters["dropped_bytes"] == 1000
    assert q.max_backlog_bytes == 3000
    assert q.next_due() is None


def test_departures_free_room_before_an_offer_is_judged() -> None:
    q = queue()
    for x in "abcd":
        q.offer(x, 1000, 0.0)
    # at 2.0 b and c have left (1.0, 2.0): e fits although the queue was full at 0
    assert q.offer("e", 1000, 2.0)
    assert q.pop_due(2.0) == ["a", "b", "c"]
    assert q.pop_due(4.0) == ["d", "e"]


def test_overhead_counts_against_rate_and_queue() -> None:
    q = queue(overhead_bytes=28)
    assert all(q.offer(x, 472, 0.0) for x in "abc")  # 500 B each on the link
    assert q.pop_due(0.0) == ["a", "b"]  # the 1000 B bucket pays two
    assert q.backlog_bytes == 500
    assert q.next_due() == 0.5
    assert q.pop_due(0.5) == ["c"]
    assert q.counters["sent_bytes"] == 3 * 472


def test_a_datagram_above_the_burst_leaves_a_debt() -> None:
    q = queue(burst_bytes=500)
    q.offer("big", 1500, 0.0)
    q.offer("next", 500, 0.0)
    assert q.pop_due(0.0) == ["big"]
    assert q.next_due() == pytest.approx(1.5)  # 1000 B of debt + 500 B of cost at 1000 B/s
    assert q.pop_due(1.5) == ["next"]


def test_background_takes_its_share_from_its_start_and_stops_after_its_duration() -> None:
    q = queue(rate_bytes_per_s=1000.0, queue_limit_bytes=10_000, burst_bytes=100,
              background=BackgroundLoad(500.0, start_s=1.0, duration_s=2.0, packet_bytes=100))
    origin = 1_795_480_000.123  # a real Unix time: no float drift may stall the schedule
    q.start_background(origin)
    assert q.next_due() == origin + 1.0
    assert q.pop_due(origin + 10.0) == []
    assert q.counters["background_sent_packets"] == 10  # 500 B/s for 2 s in 100 B packets
    assert q.counters["background_dropped_packets"] == 0
    assert q.next_due() is None


def test_background_delays_the_fleet_behind_it() -> None:
    bg = BackgroundLoad(1000.0, start_s=0.0, packet_bytes=1000)
    q = queue(queue_limit_bytes=2000, burst_bytes=1000, background=bg)
    q.start_background(0.0)
    q.offer("a", 1000, 0.0)  # behind the background's first packet, which takes the burst
    assert q.pop_due(0.5) == []
    assert q.pop_due(1.0) == ["a"]
    # the link is full: the background's packet at 1.0 and ours queue, one of them waits
    assert q.offer("b", 1000, 1.0)
    assert not q.offer("c", 1000, 1.0)


@settings(max_examples=50, deadline=None)
@given(st.lists(st.tuples(st.floats(0.0, 5.0), st.integers(1, 3000)), max_size=60),
       st.floats(100.0, 10_000.0), st.integers(500, 20_000))
def test_never_faster_than_rate_plus_burst_and_never_over_the_queue_limit(
        offers: list[tuple[float, int]], rate: float, limit: int) -> None:
    q: ShapedQueue[int] = ShapedQueue(rate_bytes_per_s=rate, queue_limit_bytes=limit,
                                      burst_bytes=1500, overhead_bytes=28)
    out: list[tuple[float, int]] = []
    sizes = {}
    for i, (t, size) in enumerate(sorted(offers)):
        sizes[i] = size
        out += [(t, x) for x in q.pop_due(t)]
        q.offer(i, size, t)
        assert q.backlog_bytes <= limit
    out += [(1e6, x) for x in q.pop_due(1e6)]
    sent = [x for _, x in out]
    assert sent == sorted(sent)  # FIFO
    assert q.counters["sent_packets"] + q.counters["dropped_packets"] == len(offers)
    assert q.backlog_bytes == 0
    for t, _ in out:
        if t < 1e6:
            before = sum(sizes[x] + 28 for tt, x in out if tt <= t)
            assert before <= 1500 + rate * t + 3000 + 28  # bucket + rate (+ one debt)


def test_relay_process_forwards_shapes_replies_and_writes_its_counters(tmp_path: Path) -> None:
    station = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    station.bind(("127.0.0.1", 0))
    station.settimeout(5.0)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        listen = probe.getsockname()[1]
    stats = tmp_path / "relay.json"
    proc = subprocess.Popen(
        [sys.executable, "-m", "sitl.relay_udp", "--listen", f"127.0.0.1:{listen}",
         "--to", f"127.0.0.1:{station.getsockname()[1]}", "--rate", "20000",
         "--queue", "5000", "--burst", "1000", "--stats", str(stats)],
        stdout=subprocess.PIPE, text=True)
    drone = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    drone.bind(("127.0.0.1", 0))
    drone.settimeout(5.0)
    try:
        assert proc.stdout is not None and "relay 127.0.0.1" in proc.stdout.readline()
        t0 = time.monotonic()
        for i in range(20):  # 20 kB offered at once: 1 kB burst + 4-ish kB queue pass
            drone.sendto(bytes([i]) * 972, ("127.0.0.1", listen))
        got = []
        station.settimeout(1.0)
        with pytest.raises(TimeoutError):
            while True:
                data, relay_addr = station.recvfrom(2000)
                got.append((time.monotonic() - t0, data[0]))
        assert 5 <= len(got) <= 7, got  # the rest were dropped at the full queue
        assert [x for _, x in got] == list(range(len(got)))
        assert got[-1][0] >= (len(got) - 1) * 1000 / 20000 * 0.9  # paced at 20 kB/s
        station.sendto(b"report", relay_addr)  # the way back reaches the drone
        assert drone.recvfrom(100)[0] == b"report"
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=10)
        drone.close()
        station.close()
    counters = json.loads(stats.read_text())
    assert counters["sent_packets"] == len(got)
    assert counters["dropped_packets"] == 20 - len(got)
    assert counters["downlink"] == 1


def test_relay_bad_arguments_give_one_line_and_exit_2() -> None:
    proc = subprocess.run([sys.executable, "-m", "sitl.relay_udp", "--listen", "nowhere",
                           "--to", "127.0.0.1:9", "--rate", "1000"],
                          capture_output=True, text=True, timeout=30)
    assert proc.returncode == 2
    assert "expected HOST:PORT" in proc.stderr and "Traceback" not in proc.stderr
