"""Link emulation on a real kernel path: network namespaces, a veth pair, ``tc``, ``iperf3``.

:class:`NetnsLink` creates two namespaces joined by a veth pair (``10.199.0.1`` in the sender
namespace, ``10.199.0.2`` in the receiver namespace; nothing outside them is touched), shapes
the sender->receiver direction with a token bucket (``tc tbf``: rate and a byte-bounded queue),
changes the rate on the fly, starts processes inside either namespace, and always cleans up:
on ``close()``/context exit, at interpreter exit, and for leftovers of dead processes
(:func:`cleanup_stale`). Namespace names carry the pid, so parallel runs never collide.
``netem`` is not needed (some kernels lack it); the base latency is then the serialisation
time of one packet at the shaped rate.

The module also holds a tiny measurement probe (``python -m sitl.linkemu probe-sender|
probe-receiver``): the receiver reports what arrived and when, as JSON datagrams a few times a
second, and the sender lets a goodput constraint gate an offered load larger than the link.
"""

from __future__ import annotations

import argparse
import atexit
import contextlib
import json
import math
import os
import random
import re
import select
import shutil
import signal
import socket
import struct
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, TextIO

__all__ = [
    "REQUIREMENTS_HINT",
    "Iperf3Background",
    "LinkEmuError",
    "NetnsLink",
    "cleanup_stale",
    "missing_requirements",
]

REQUIREMENTS_HINT = "run as root with iproute2 and iperf3: apt-get install iproute2 iperf3"
NS_PREFIX = "uavle"
"""Prefix of every namespace this module creates: ``uavle<pid>x<n>s`` / ``...r``."""
SENDER_ADDR = "10.199.0.1"
RECEIVER_ADDR = "10.199.0.2"
L2_OVERHEAD_BYTES = 14 + 20 + 8
"""Ethernet + IPv4 + UDP header bytes that tbf counts on top of a UDP payload."""


class LinkEmuError(RuntimeError):
    """A command of the link emulation failed (message has the command and its stderr)."""


def missing_requirements() -> str | None:
    """None when this host can emulate links; else the exact reason (for pytest skips)."""
    if os.geteuid() != 0:
        return REQUIREMENTS_HINT
    if any(shutil.which(tool) is None for tool in ("ip", "tc", "iperf3")):
        return REQUIREMENTS_HINT
    return None


def _run(argv: Sequence[str]) -> str:
    proc = subprocess.run(list(argv), capture_output=True, text=True, check=False, timeout=30)
    if proc.returncode != 0:
        raise LinkEmuError(f"{' '.join(argv)} failed ({proc.returncode}): {proc.stderr.strip()}")
    return proc.stdout


def cleanup_stale() -> list[str]:
    """Delete namespaces left by processes of this module that no longer run."""
    removed = []
    out = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True, check=False)
    for line in out.stdout.splitlines():
        name = line.split()[0] if line.split() else ""
        match = re.fullmatch(rf"{NS_PREFIX}(\d+)x\d+[sr]", name)
        if match is None:
            continue
        pid = int(match.group(1))
        try:
            os.kill(pid, 0)
            continue  # owner still alive
        except ProcessLookupError:
            pass
        except PermissionError:
            continue
        subprocess.run(["ip", "netns", "del", name], capture_output=True, check=False)
        removed.append(name)
    return removed


_counter = 0


class NetnsLink:
    """Two namespaces and a shaped veth pair; a context manager that always cleans up.

    Parameters
    ----------
    rate_bit_per_s
        tbf rate of the sender->receiver direction (counts Ethernet/IP/UDP headers).
    queue_limit_bytes
        tbf queue bound: packets that would exceed it are dropped (tail drop).
    burst_bytes
        tbf bucket depth (at least one MTU-sized packet).
    """

    def __init__(
        self,
        *,
        rate_bit_per_s: float = 1_000_000.0,
        queue_limit_bytes: int = 37_500,
        burst_bytes: int = 3_000,
    ) -> None:
        global _counter
        _counter += 1
        tag = f"{NS_PREFIX}{os.getpid()}x{_counter}"
        self.ns_sender = f"{tag}s"
        self.ns_receiver = f"{tag}r"
        self.dev_sender = "veth-s"
        self.dev_receiver = "veth-r"
        self.rate_bit_per_s = float(rate_bit_per_s)
        self.queue_limit_bytes = int(queue_limit_bytes)
        self.burst_bytes = int(burst_bytes)
        self._procs: list[subprocess.Popen[Any]] = []
        self._created: list[str] = []
        self._closed = False

    # -- lifecycle -------------------------------------------------------------------------

    def __enter__(self) -> NetnsLink:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def open(self) -> None:
        atexit.register(self.close)
        try:
            for ns in (self.ns_sender, self.ns_receiver):
                _run(["ip", "netns", "add", ns])
                self._created.append(ns)
            _run(["ip", "link", "add", self.dev_sender, "netns", self.ns_sender, "type", "veth",
                  "peer", "name", self.dev_receiver, "netns", self.ns_receiver])
            for ns, dev, addr in (
                (self.ns_sender, self.dev_sender, SENDER_ADDR),
                (self.ns_receiver, self.dev_receiver, RECEIVER_ADDR),
            ):
                _run(["ip", "-n", ns, "addr", "add", f"{addr}/30", "dev", dev])
                _run(["ip", "-n", ns, "link", "set", dev, "up"])
                _run(["ip", "-n", ns, "link", "set", "lo", "up"])
            self._tbf("add")
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        """Stop every process started here, then delete the namespaces (and the veth)."""
        if self._closed:
            return
        self._closed = True
        for proc in self._procs:
            if proc.poll() is None:
                proc.terminate()
        for proc in self._procs:
            try:
                proc.wait(timeout=3)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=3)
        for ns in reversed(self._created):
            subprocess.run(["ip", "netns", "del", ns], capture_output=True, check=False)
        self._created.clear()
        with contextlib.suppress(Exception):
            atexit.unregister(self.close)

    # -- shaping ---------------------------------------------------------------------------

    def _tbf(self, verb: str) -> None:
        _run(["tc", "-n", self.ns_sender, "qdisc", verb, "dev", self.dev_sender, "root",
              "handle", "1:", "tbf", "rate", f"{int(self.rate_bit_per_s)}bit",
              "burst", str(self.burst_bytes), "limit", str(self.queue_limit_bytes)])

    def set_rate(self, rate_bit_per_s: float) -> None:
        """Change the bottleneck rate now (the queue bound stays)."""
        self.rate_bit_per_s = float(rate_bit_per_s)
        self._tbf("change")

    def payload_capacity_bytes_per_s(self, payload_bytes: int) -> float:
        """UDP payload bytes per second the current rate carries for ``payload_bytes`` packets."""
        return self.rate_bit_per_s / 8 * payload_bytes / (payload_bytes + L2_OVERHEAD_BYTES)

    def qdisc_stats(self) -> str:
        return _run(["tc", "-s", "-n", self.ns_sender, "qdisc", "show", "dev", self.dev_sender])

    # -- processes -------------------------------------------------------------------------

    def popen(self, ns: str, argv: Sequence[str], **kwargs: Any) -> subprocess.Popen[Any]:
        """Start ``argv`` inside namespace ``ns``; it is terminated by :meth:`close`."""
        proc = subprocess.Popen(["ip", "netns", "exec", ns, *argv], **kwargs)
        self._procs.append(proc)
        return proc


class Iperf3Background:
    """UDP background traffic from the sender namespace to the receiver namespace."""

    def __init__(self, link: NetnsLink, *, port: int = 5201) -> None:
        self.link = link
        self.port = port
        self._server: subprocess.Popen[Any] | None = None
        self._client: subprocess.Popen[Any] | None = None

    def start_server(self) -> None:
        self._server = self.link.popen(
            self.link.ns_receiver,
            ["iperf3", "-s", "-B", RECEIVER_ADDR, "-p", str(self.port)],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )

    def start(self, *, rate_bit_per_s: float, duration_s: float, payload_bytes: int = 1200) -> None:
        """Start a client sending ``rate_bit_per_s`` of UDP payload for ``duration_s``."""
        self.stop()
        self._client = self.link.popen(
            self.link.ns_sender,
            ["iperf3", "-c", RECEIVER_ADDR, "-p", str(self.port), "-u",
             "-b", f"{int(rate_bit_per_s)}", "-l", str(payload_bytes),
             "-t", f"{max(1, math.ceil(duration_s))}", "--connect-timeout", "3000"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )

    def stop(self) -> None:
        if self._client is not None and self._client.poll() is None:
            self._client.terminate()
            with contextlib.suppress(subprocess.TimeoutExpired):
                self._client.wait(timeout=3)
        self._client = None


# --------------------------------------------------------------------------------------------
# Measurement probe: runs inside the namespaces as ``python -m sitl.linkemu probe-...``.

_DATA = struct.Struct("!4sIdI")
_MAGIC = b"UAVP"
MAX_ARRIVALS_PER_REPORT = 20


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
    from companion.middleware.constraint import LinkSample
    from companion.middleware.constraints import make_constraint
    from companion.middleware.linkstats import LinkStats, RoundTrip

    params = json.loads(args.params)
    constraint = make_constraint(args.constraint, **params)
    window_s = constraint.window_s
    observe = LinkStats(window_s=window_s)  # for the log, the same for every constraint
    learn = getattr(constraint, "on_samples", None)
    round_trip_hook = getattr(constraint, "on_round_trip", None)
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
                        report = json.loads(payload)
                        t_report = float(report["t_report"])
                        samples = [
                            LinkSample(t_sent=float(t_sent), t_rcv=float(t_rcv), size=int(sz),
                                       sender="probe", seq=int(seq_r))
                            for seq_r, t_sent, t_rcv, sz in report["arrivals"]
                        ]
                        round_trip = (
                            RoundTrip(t_sent=samples[-1].t_sent, t_remote_rcv=samples[-1].t_rcv,
                                      t_remote_sent=t_report, t_rcv=now)
                            if samples else None
                        )
                    except (ValueError, KeyError, TypeError) as exc:
                        bad_reports += 1  # malformed report: counted and dropped
                        log.write(f"B,{now!r},{type(exc).__name__}\n")
                        continue
                    if round_trip is not None:
                        observe.on_round_trip(round_trip)
                        if round_trip_hook is not None:
                            round_trip_hook(round_trip, now=now)
                        for sample in samples:
                            observe.update(sample, now=now)
                        if learn is not None:
                            learn(samples, now=now)
                        else:
                            for sample in samples:
                                constraint.on_sample(sample, now=now)
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


if __name__ == "__main__":
    raise SystemExit(main())
