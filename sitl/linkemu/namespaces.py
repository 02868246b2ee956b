"""Namespaces that always go away, the two-namespace shaped link, and their helpers."""

from __future__ import annotations

import atexit
import contextlib
import os
import re
import shutil
import signal
import subprocess
import threading
from collections.abc import Sequence
from typing import Any

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
                with contextlib.suppress(subprocess.TimeoutExpired):  # stuck in the kernel:
                    proc.wait(timeout=3)  # leave it, the namespaces still go
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
