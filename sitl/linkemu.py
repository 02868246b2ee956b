"""Link emulation on a real kernel path: network namespaces, veths, a bridge, ``tc``, ``iperf3``.

Two topologies, both made only of namespaces this module creates (addresses ``10.199.x.y`` and
``10.198.x.y`` live inside them; nothing of the host is touched):

- :class:`NetnsLink`: two namespaces joined by a veth pair (``10.199.0.1`` sender,
  ``10.199.0.2`` receiver), the sender->receiver direction shaped with a token bucket
  (``tc tbf``: rate and a byte-bounded queue). The probe experiments of ch. 6 use it.
- :class:`SharedMedium`: a radio channel for a fleet. Every drone has its own namespace, the
  ground station and an ``iperf3`` background host have theirs, and all of them hang on one
  bridge in a "medium" namespace through one veth each. The bridge's port toward the ground
  station is shaped once (tbf), so every drone and the background contend for one queue and
  one rate like stations on one channel. Optional delay and loss use ``netem`` on every
  station's radio interface (each crossing of the medium pays them once), *only when the
  kernel has* ``sch_netem``: :func:`netem_missing` says why not, and the medium reports that
  delay/loss are not emulated rather than faking them. A "vehicles" namespace holds the
  simulated autopilots, each reached from its drone over its own unshaped veth (the
  flight controller's serial line).

Both start processes inside their namespaces and always clean up: on ``close()``/context
exit, on errors while building, at interpreter exit, on SIGTERM/SIGHUP when nobody else
handles them, and for leftovers of dead processes (:func:`cleanup_stale`). Namespace names
carry the pid (``uavle<pid>x<n>...``), so parallel runs never collide.

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
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, TextIO

__all__ = [
    "REQUIREMENTS_HINT",
    "Iperf3Background",
    "LinkEmuError",
    "NetnsLink",
    "SharedMedium",
    "cleanup_stale",
    "missing_requirements",
    "netem_missing",
]

REQUIREMENTS_HINT = "run as root with iproute2 and iperf3: apt-get install iproute2 iperf3"
NS_PREFIX = "uavle"
"""Prefix of every namespace this module creates: ``uavle<pid>x<n>`` + a role suffix."""
_NS_NAME = re.compile(rf"{NS_PREFIX}(\d+)x\d+(?:[srmgbvp]|d\d+)")
"""Roles: s/r sender/receiver (NetnsLink), m medium, g ground, b background, v vehicles,
d<i> drone i (SharedMedium), p a throwaway probe of :func:`netem_missing`."""
SENDER_ADDR = "10.199.0.1"
RECEIVER_ADDR = "10.199.0.2"
GROUND_ADDR = RECEIVER_ADDR
"""The ground station on the shared medium (the same address as NetnsLink's receiver)."""
BACKGROUND_ADDR = "10.199.0.3"
MAX_DRONES = 64
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
        match = _NS_NAME.fullmatch(name)
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
_netem_cache: list[str | None] = []


def _next_tag() -> str:
    global _counter
    _counter += 1
    return f"{NS_PREFIX}{os.getpid()}x{_counter}"


def netem_missing() -> str | None:
    """None when ``tc netem`` works here; else why not (e.g. the kernel lacks ``sch_netem``).

    Tried once per process on the loopback of a throwaway namespace of ours.
    """
    if _netem_cache:
        return _netem_cache[0]
    reason = missing_requirements()
    if reason is None:
        ns = f"{_next_tag()}p"
        try:
            _run(["ip", "netns", "add", ns])
            try:
                proc = subprocess.run(["tc", "-n", ns, "qdisc", "add", "dev", "lo", "root",
                                       "netem", "delay", "1ms"], capture_output=True,
                                      text=True, check=False, timeout=30)
            finally:
                subprocess.run(["ip", "netns", "del", ns], capture_output=True, check=False)
            if proc.returncode != 0:
                reason = (f"the kernel has no netem qdisc (sch_netem; tc: "
                          f"{proc.stderr.strip() or proc.returncode})")
        except LinkEmuError as exc:
            reason = f"cannot check for netem: {exc}"
    _netem_cache.append(reason)
    return reason


class _Namespaces:
    """Namespaces and processes that always go away: on close(), on errors while building,
    at interpreter exit, and on SIGTERM/SIGHUP when their handler is still the default one
    (turned into SystemExit so ``finally``/``with`` run)."""

    def __init__(self) -> None:
        self._procs: list[subprocess.Popen[Any]] = []
        self._created: list[str] = []
        self._closed = False
        self._old_handlers: dict[int, Any] = {}

    def __enter__(self) -> Any:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _build(self) -> None:
        raise NotImplementedError

    def open(self) -> None:
        atexit.register(self.close)
        self._catch_signals()
        try:
            self._build()
        except BaseException:
            self.close()
            raise

    def _add_ns(self, ns: str) -> None:
        _run(["ip", "netns", "add", ns])
        self._created.append(ns)
        _run(["ip", "-n", ns, "link", "set", "lo", "up"])

    def _catch_signals(self) -> None:
        if threading.current_thread() is not threading.main_thread():
            return

        def on_signal(signum: int, frame: object) -> None:
            raise SystemExit(128 + signum)

        for sig in (signal.SIGTERM, signal.SIGHUP):
            if signal.getsignal(sig) == signal.SIG_DFL:
                self._old_handlers[sig] = signal.signal(sig, on_signal)

    def close(self) -> None:
        """Stop every process started here, then delete the namespaces (and their links)."""
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
        if threading.current_thread() is threading.main_thread():
            for sig, handler in self._old_handlers.items():
                with contextlib.suppress(ValueError, TypeError):
                    signal.signal(sig, handler)
        self._old_handlers.clear()
        with contextlib.suppress(Exception):
            atexit.unregister(self.close)

    @property
    def namespaces(self) -> list[str]:
        """The namespaces that exist now (created and not yet deleted)."""
        return list(self._created)

    def popen(self, ns: str, argv: Sequence[str], **kwargs: Any) -> subprocess.Popen[Any]:
        """Start ``argv`` inside namespace ``ns``; it is terminated by :meth:`close`."""
        proc = subprocess.Popen(["ip", "netns", "exec", ns, *argv], **kwargs)
        self._procs.append(proc)
        return proc


class _ShapedLink(_Namespaces):
    """Namespaces joined through one ``tc tbf`` bottleneck that can be re-rated live."""

    rate_bit_per_s: float
    burst_bytes: int
    queue_limit_bytes: int

    @property
    def bottleneck(self) -> tuple[str, str]:
        """(namespace, device) of the shaped egress."""
        raise NotImplementedError

    def _tbf(self, verb: str) -> None:
        ns, dev = self.bottleneck
        _tbf(verb, ns, dev, rate_bit_per_s=self.rate_bit_per_s,
             burst_bytes=self.burst_bytes, queue_limit_bytes=self.queue_limit_bytes)

    def set_rate(self, rate_bit_per_s: float) -> None:
        """Change the bottleneck rate now (the queue bound stays)."""
        self.rate_bit_per_s = float(rate_bit_per_s)
        self._tbf("change")

    def payload_capacity_bytes_per_s(self, payload_bytes: int) -> float:
        """UDP payload bytes per second the current rate carries for ``payload_bytes`` packets."""
        return self.rate_bit_per_s / 8 * payload_bytes / (payload_bytes + L2_OVERHEAD_BYTES)

    def qdisc_stats(self) -> str:
        """``tc -s`` of the bottleneck."""
        ns, dev = self.bottleneck
        return _run(["tc", "-s", "-n", ns, "qdisc", "show", "dev", dev])


class NetnsLink(_ShapedLink):
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
        super().__init__()
        tag = _next_tag()
        self.ns_sender = f"{tag}s"
        self.ns_receiver = f"{tag}r"
        self.dev_sender = "veth-s"
        self.dev_receiver = "veth-r"
        self.rate_bit_per_s = float(rate_bit_per_s)
        self.queue_limit_bytes = int(queue_limit_bytes)
        self.burst_bytes = int(burst_bytes)

    def __enter__(self) -> NetnsLink:
        self.open()
        return self

    # iperf3 background: from the sender namespace to the receiver.
    @property
    def bg_client_ns(self) -> str:
        return self.ns_sender

    @property
    def bg_server_ns(self) -> str:
        return self.ns_receiver

    bg_server_addr = RECEIVER_ADDR

    def _build(self) -> None:
        for ns in (self.ns_sender, self.ns_receiver):
            self._add_ns(ns)
        _run(["ip", "link", "add", self.dev_sender, "netns", self.ns_sender, "type", "veth",
              "peer", "name", self.dev_receiver, "netns", self.ns_receiver])
        for ns, dev, addr in (
            (self.ns_sender, self.dev_sender, SENDER_ADDR),
            (self.ns_receiver, self.dev_receiver, RECEIVER_ADDR),
        ):
            _run(["ip", "-n", ns, "addr", "add", f"{addr}/30", "dev", dev])
            _run(["ip", "-n", ns, "link", "set", dev, "up"])
        self._tbf("add")

    @property
    def bottleneck(self) -> tuple[str, str]:
        return self.ns_sender, self.dev_sender



def _tbf(verb: str, ns: str, dev: str, *, rate_bit_per_s: float, burst_bytes: int,
         queue_limit_bytes: int) -> None:
    _run(["tc", "-n", ns, "qdisc", verb, "dev", dev, "root", "handle", "1:", "tbf",
          "rate", f"{int(rate_bit_per_s)}bit", "burst", str(burst_bytes),
          "limit", str(queue_limit_bytes)])


_QDISC_COUNTERS = re.compile(r"Sent (\d+) bytes (\d+) pkt \(dropped (\d+), overlimits (\d+)")


def parse_qdisc_counters(text: str) -> dict[str, int] | None:
    """The first qdisc's ``Sent B bytes P pkt (dropped D, overlimits O`` of ``tc -s`` output."""
    match = _QDISC_COUNTERS.search(text)
    if match is None:
        return None
    sent_bytes, sent_packets, dropped, overlimits = (int(g) for g in match.groups())
    return {"sent_bytes": sent_bytes, "sent_packets": sent_packets, "dropped": dropped,
            "overlimits": overlimits}


RADIO_DEV = "radio0"
"""Each station's interface on the medium (drones, ground station, background host)."""
MAVLINK_DEV = "mav0"
"""A drone's interface toward its simulated autopilot in the vehicles namespace."""


class SharedMedium(_ShapedLink):
    """A fleet's radio channel: one namespace per drone, one for the ground station, one for
    an iperf3 background host, all bridged in a medium namespace, the bridge's port toward the
    ground station shaped once with tbf (so all of them share one rate and one queue).

    ``delay_s`` and ``loss`` (a probability per datagram) are applied with netem on every
    station's radio interface when the kernel has netem; otherwise :attr:`netem` is False,
    :attr:`impairment_note` says so, and the link has rate and queue only.
    Addresses: ground ``10.199.0.2``, background ``10.199.0.3``, drone i ``10.199.0.(10+i)``
    (/24); drone i <-> vehicles namespace ``10.198.i.2`` <-> ``10.198.i.1`` (/30, unshaped).
    """

    def __init__(
        self,
        *,
        drones: int,
        rate_bit_per_s: float = 6_000_000.0,
        delay_s: float = 0.0,
        loss: float = 0.0,
        queue_limit_bytes: int = 37_500,
        burst_bytes: int = 3_000,
        vehicles: bool = True,
        background: bool = True,
        netem_check: Callable[[], str | None] = netem_missing,
    ) -> None:
        super().__init__()
        if not 1 <= drones <= MAX_DRONES:
            raise ValueError(f"drones must be in 1..{MAX_DRONES}, got {drones}")
        if delay_s < 0 or not 0.0 <= loss < 1.0:
            raise ValueError(f"need delay_s >= 0 and 0 <= loss < 1, got {delay_s}, {loss}")
        if rate_bit_per_s <= 0:
            raise ValueError(f"rate must be > 0, got {rate_bit_per_s}")
        tag = _next_tag()
        self.drones = drones
        self.ns_medium = f"{tag}m"
        self.ns_ground = f"{tag}g"
        self.ns_background: str | None = f"{tag}b" if background else None
        self.ns_vehicles: str | None = f"{tag}v" if vehicles else None
        self.ns_drones = tuple(f"{tag}d{i}" for i in range(drones))
        self.rate_bit_per_s = float(rate_bit_per_s)
        self.delay_s = float(delay_s)
        self.loss = float(loss)
        self.queue_limit_bytes = int(queue_limit_bytes)
        self.burst_bytes = int(burst_bytes)
        self.bottleneck_dev = "gs"
        """The medium namespace's bridge port toward the ground station (shaped)."""
        self._netem_check = netem_check
        self.netem: bool | None = None
        """True: delay/loss applied; False: asked for but netem is missing; None: not asked."""
        self.impairment_note: str | None = None

    def __enter__(self) -> SharedMedium:
        self.open()
        return self

    # -- addresses -------------------------------------------------------------------------

    @staticmethod
    def drone_addr(index: int) -> str:
        return f"10.199.0.{10 + index}"

    @staticmethod
    def vehicle_addrs(index: int) -> tuple[str, str]:
        """(vehicle side, drone side) of drone ``index``'s autopilot link."""
        return f"10.198.{index}.1", f"10.198.{index}.2"

    ground_addr = GROUND_ADDR
    background_addr = BACKGROUND_ADDR

    # iperf3 background: from the background host to the ground station, over the medium.
    @property
    def bg_client_ns(self) -> str:
        if self.ns_background is None:
            raise LinkEmuError("this medium was built without a background host")
        return self.ns_background

    @property
    def bg_server_ns(self) -> str:
        return self.ns_ground

    bg_server_addr = GROUND_ADDR

    # -- building --------------------------------------------------------------------------

    def _stations(self) -> list[tuple[str, str, str]]:
        """(namespace, bridge port name in the medium, address) of every station."""
        out = [(self.ns_ground, self.bottleneck_dev, GROUND_ADDR)]
        if self.ns_background is not None:
            out.append((self.ns_background, "bg", BACKGROUND_ADDR))
        out += [(ns, f"d{i}", self.drone_addr(i)) for i, ns in enumerate(self.ns_drones)]
        return out

    def _build(self) -> None:
        stations = self._stations()
        self._add_ns(self.ns_medium)
        for ns, _, _ in stations:
            self._add_ns(ns)
        m = self.ns_medium
        _run(["ip", "-n", m, "link", "add", "br0", "type", "bridge"])
        for ns, port, addr in stations:
            _run(["ip", "link", "add", RADIO_DEV, "netns", ns, "type", "veth",
                  "peer", "name", port, "netns", m])
            _run(["ip", "-n", m, "link", "set", port, "master", "br0"])
            _run(["ip", "-n", m, "link", "set", port, "up"])
            _run(["ip", "-n", ns, "addr", "add", f"{addr}/24", "dev", RADIO_DEV])
            _run(["ip", "-n", ns, "link", "set", RADIO_DEV, "up"])
        _run(["ip", "-n", m, "link", "set", "br0", "up"])
        if self.ns_vehicles is not None:
            v = self.ns_vehicles
            self._add_ns(v)
            for i, ns in enumerate(self.ns_drones):
                vehicle, drone = self.vehicle_addrs(i)
                _run(["ip", "link", "add", MAVLINK_DEV, "netns", ns, "type", "veth",
                      "peer", "name", f"v{i}", "netns", v])
                for where, dev, addr in ((ns, MAVLINK_DEV, drone), (v, f"v{i}", vehicle)):
                    _run(["ip", "-n", where, "addr", "add", f"{addr}/30", "dev", dev])
                    _run(["ip", "-n", where, "link", "set", dev, "up"])
        self._tbf("add")
        self._impair(stations)

    def _impair(self, stations: list[tuple[str, str, str]]) -> None:
        if self.delay_s == 0 and self.loss == 0:
            return
        asked = f"delay {1000 * self.delay_s:g} ms, loss {100 * self.loss:g} %"
        reason = self._netem_check()
        if reason is not None:
            self.netem = False
            self.impairment_note = (f"{asked} NOT emulated: {reason}; the medium has rate "
                                    f"and queue only")
            return
        for ns, _, _ in stations:
            _run(["tc", "-n", ns, "qdisc", "add", "dev", RADIO_DEV, "root", "netem",
                  "delay", f"{1e6 * self.delay_s:.0f}us", "loss", f"{100 * self.loss:g}%"])
        self.netem = True
        self.impairment_note = f"{asked} per crossing of the medium (netem on every station)"

    @property
    def bottleneck(self) -> tuple[str, str]:
        """The shared bottleneck: the medium's port toward the ground station."""
        return self.ns_medium, self.bottleneck_dev

    def describe(self) -> str:
        """One line for a run's output: topology, rate, queue, and what delay/loss do."""
        impair = self.impairment_note or "no delay/loss asked"
        return (f"{self.drones} drone namespace(s) {self.ns_drones[0]}..; ground "
                f"{self.ns_ground} ({GROUND_ADDR}); bridge in {self.ns_medium}; "
                f"rate {self.rate_bit_per_s / 1e6:g} Mbit/s, queue {self.queue_limit_bytes} B "
                f"(tbf toward the ground station); {impair}")

    def wrap(self, ns: str, argv: Sequence[str]) -> list[str]:
        """``argv`` run inside ``ns`` (for launchers that start processes themselves)."""
        if ns not in self._created:
            raise LinkEmuError(f"{ns} is not a namespace of this medium")
        return ["ip", "netns", "exec", ns, *argv]


class Iperf3Background:
    """UDP background traffic of ``link`` (a NetnsLink: sender -> receiver namespace; a
    SharedMedium: background host -> ground station, across the shared bottleneck)."""

    def __init__(self, link: NetnsLink | SharedMedium, *, port: int = 5201) -> None:
        self.link = link
        self.port = port
        self._server: subprocess.Popen[Any] | None = None
        self._client: subprocess.Popen[Any] | None = None

    def start_server(self) -> None:
        self._server = self.link.popen(
            self.link.bg_server_ns,
            ["iperf3", "-s", "-B", self.link.bg_server_addr, "-p", str(self.port)],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )

    def start(self, *, rate_bit_per_s: float, duration_s: float, payload_bytes: int = 1200) -> None:
        """Start a client sending ``rate_bit_per_s`` of UDP payload for ``duration_s``."""
        self.stop()
        self._client = self.link.popen(
            self.link.bg_client_ns,
            ["iperf3", "-c", self.link.bg_server_addr, "-p", str(self.port), "-u",
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
                        constraint.on_round_trip(round_trip, now=now)
                        for sample in samples:
                            observe.update(sample, now=now)
                        constraint.on_samples(samples, now=now)
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
