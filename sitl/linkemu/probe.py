"""The measurement probe: runs inside the namespaces as ``python -m sitl.linkemu probe-...``.

The receiver reports what arrived and when, as JSON datagrams a few times a second; the
sender lets a goodput constraint gate an offered load larger than the link.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import random
import select
import signal
import socket
import struct
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, TextIO

from sitl.linkemu.namespaces import RECEIVER_ADDR, SENDER_ADDR

if TYPE_CHECKING:
    from companion.middleware.reports import ReceiverReport

_DATA = struct.Struct("!4sIdI")
_MAGIC = b"UAVP"
MAX_ARRIVALS_PER_REPORT = 20
PROBE = "probe"
"""The probe sender's agent name, and the type of its messages."""


def probe_report(payload: bytes, *, now: float) -> ReceiverReport:
    """A probe receiver report (JSON) as the middleware's typed report: every arrival an
    entry of the probe, the last one its clock echo, sent at ``t_report``, received ``now``.

    Raises ValueError, KeyError or TypeError on a malformed report (one impossible arrival,
    e.g. a non-finite time, makes the whole report bad).
    """
    from companion.middleware.reports import ReceiverReport
    from companion.protocol.records import ClockEcho, ReportEntry

    report = json.loads(payload)
    t_report = float(report["t_report"])
    arrivals = [(int(seq), float(t_sent), float(t_rcv), int(size))
                for seq, t_sent, t_rcv, size in report["arrivals"]]
    entries = tuple(ReportEntry(sender=PROBE, type=PROBE, seq=seq, t_gen=t_sent,
                                t_sent=t_sent, t_rcv=t_rcv, size=size)
                    for seq, t_sent, t_rcv, size in arrivals)
    echoes = (ClockEcho(sender=PROBE, t_sent=arrivals[-1][1], t_rcv=arrivals[-1][2]),
              ) if arrivals else ()
    return ReceiverReport(entries=entries, echoes=echoes, t_sent=t_report, t_rcv=now)


def _probe_receiver(args: argparse.Namespace) -> int:
    """Receive probe datagrams; report arrivals every ``report_interval_s``; log on exit."""
    stop = False

    def on_term(signum: int, frame: object) -> None:
        nonlocal stop
        stop = True

    signal.signal(signal.SIGTERM, on_term)
    skew = float(args.clock_offset_s)

    def clock() -> float:
        return time.time() + skew

    data = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    data.bind((args.bind, args.port))
    reports = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    log: TextIO = open(args.log, "w", encoding="utf-8")  # noqa: SIM115 - closed in finally
    pending: list[list[float]] = []
    next_report = clock() + args.report_interval_s
    print("ready", flush=True)
    try:
        while not stop:
            timeout = max(0.0, next_report - clock())
            ready, _, _ = select.select([data], [], [], timeout)
            if ready:
                payload, _ = data.recvfrom(65535)
                t_rcv = clock()
                if len(payload) >= _DATA.size:
                    magic, seq, t_sent, _ = _DATA.unpack_from(payload)
                    if magic == _MAGIC:
                        pending.append([seq, t_sent, t_rcv, len(payload)])
                        log.write(f"{seq},{t_sent!r},{t_rcv!r},{len(payload)}\n")
            if clock() >= next_report:
                next_report += args.report_interval_s
                for i in range(0, max(len(pending), 1), MAX_ARRIVALS_PER_REPORT):
                    chunk = pending[i : i + MAX_ARRIVALS_PER_REPORT]
                    msg = {"t_report": clock(), "arrivals": chunk}
                    with contextlib.suppress(OSError):
                        reports.sendto(json.dumps(msg).encode(), (args.reply_to, args.reply_port))
                pending.clear()
    finally:
        log.close()
        data.close()
        reports.close()
    return 0


def _probe_sender(args: argparse.Namespace) -> int:
    """Offer ``demand`` bytes/s of probe messages; send those the constraint admits."""
    from companion.middleware.constraints import make_constraint
    from companion.middleware.linkstats import LinkStats
    from companion.middleware.reports import feed_link, link_observations

    params = json.loads(args.params)
    constraint = make_constraint(args.constraint, **params)
    window_s = constraint.window_s
    observe = LinkStats(window_s=window_s)  # for the log, the same for every constraint
    rng = random.Random(args.seed)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setblocking(False)
    sock.bind((args.bind, args.report_port))
    size = args.message_bytes
    padding = bytes(size - _DATA.size)
    log: TextIO = open(args.log, "w", encoding="utf-8")  # noqa: SIM115 - closed in finally
    print("ready", flush=True)
    t0 = args.t0 if args.t0 is not None else float(sys.stdin.readline())
    while time.time() < t0:
        time.sleep(min(0.05, max(0.0, t0 - time.time())))
    t_end = t0 + args.duration_s
    seq = 0
    bad_reports = 0
    tokens = float(size)
    t_tokens = time.time()
    next_gen = time.time()
    try:
        while True:
            now = time.time()
            if now >= t_end:
                break
            ready, _, _ = select.select([sock], [], [], max(0.0, min(next_gen, t_end) - now))
            now = time.time()
            if ready:
                while True:
                    try:
                        payload = sock.recv(65535)
                    except BlockingIOError:
                        break
                    try:
                        report = probe_report(payload, now=now)
                    except (ValueError, KeyError, TypeError) as exc:
                        bad_reports += 1  # malformed report: counted and dropped
                        log.write(f"B,{now!r},{type(exc).__name__}\n")
                        continue
                    samples, trips, _ = link_observations(report, agent=PROBE)
                    for trip in trips:
                        observe.on_round_trip(trip)
                    for sample in samples:
                        observe.update(sample, now=now)
                    feed_link(constraint, report, agent=PROBE, now=now)
                    stats = observe.get()
                    offset = observe.clock.get()
                    xi = constraint.limit_bytes_per_s(now=now)
                    if stats is not None:
                        log.write(
                            f"R,{now!r},{xi!r},{stats.goodput_bytes_per_s!r},"
                            f"{stats.backlog_bytes_per_s!r},{stats.mean_latency_s!r},"
                            f"{stats.base_latency_s!r},"
                            f"{offset.offset_s if offset else 0.0!r},"
                            f"{offset.uncertainty_s if offset else math.inf!r}\n"
                        )
            while next_gen <= now:
                # A message is generated (Poisson, offered load = demand): send or drop.
                next_gen += rng.expovariate(args.demand_bytes_per_s / size)
                xi = constraint.limit_bytes_per_s(now=now)
                # Token bucket at rate ξ, depth pace_s·ξ (≥ one message); it may go one
                # message into debt, so the long-run rate is ξ, not less.
                tokens = min(max(float(size), xi * args.pace_s), tokens + xi * (now - t_tokens))
                t_tokens = now
                if tokens < 0 or not constraint.admits(size, now=now):
                    continue
                tokens -= size
                packet = _DATA.pack(_MAGIC, seq, now, size) + padding
                try:
                    sock.sendto(packet, (args.receiver, args.port))
                except (BlockingIOError, OSError):
                    log.write(f"E,{seq},{now!r}\n")
                constraint.on_sent(size, now=now)
                log.write(f"S,{seq},{now!r},{size}\n")
                seq += 1
    finally:
        log.write(f"X,bad_reports,{bad_reports}\n")
        log.close()
        sock.close()
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sitl.linkemu")
    sub = parser.add_subparsers(dest="command", required=True)
    rcv = sub.add_parser("probe-receiver", help="receive probe datagrams and report them")
    rcv.add_argument("--bind", default=RECEIVER_ADDR)
    rcv.add_argument("--port", type=int, default=47001)
    rcv.add_argument("--reply-to", default=SENDER_ADDR)
    rcv.add_argument("--reply-port", type=int, default=47002)
    rcv.add_argument("--report-interval-s", type=float, default=0.1)
    rcv.add_argument("--clock-offset-s", type=float, default=0.0,
                     help="skew this receiver's clock (to exercise offset estimation)")
    rcv.add_argument("--log", type=Path, required=True)
    snd = sub.add_parser("probe-sender", help="offer load, gated by a goodput constraint")
    snd.add_argument("--bind", default=SENDER_ADDR)
    snd.add_argument("--receiver", default=RECEIVER_ADDR)
    snd.add_argument("--port", type=int, default=47001)
    snd.add_argument("--report-port", type=int, default=47002)
    snd.add_argument("--constraint", default="adaptive")
    snd.add_argument("--params", default="{}", help="JSON keyword parameters")
    snd.add_argument("--demand-bytes-per-s", type=float, default=500_000.0)
    snd.add_argument("--message-bytes", type=int, default=1200)
    snd.add_argument("--pace-s", type=float, default=0.02,
                     help="token-bucket depth in seconds of ξ (spreads sends; 0: one message)")
    snd.add_argument("--t0", type=float, default=None,
                     help="start (Unix time); without it, read from stdin after 'ready'")
    snd.add_argument("--duration-s", type=float, required=True)
    snd.add_argument("--seed", type=int, default=0)
    snd.add_argument("--log", type=Path, required=True)
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    if args.command == "probe-receiver":
        return _probe_receiver(args)
    return _probe_sender(args)

