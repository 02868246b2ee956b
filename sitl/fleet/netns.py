"""``--netns``: the fleet on network namespaces joined by one shaped medium (root)."""

from __future__ import annotations

import contextlib
import ctypes
import math
import os
import socket
import subprocess
from collections.abc import Sequence
from typing import Any

from sitl.fleet.link import Background
from sitl.fleet.processes import FleetError

CLONE_NEWNET = 0x40000000


def _enter_netns(name: str) -> None:
    """Move the calling thread (only) into network namespace ``name`` (setns(2))."""
    libc = ctypes.CDLL(None, use_errno=True)
    fd = os.open(f"/var/run/netns/{name}", os.O_RDONLY)
    try:
        if libc.setns(fd, CLONE_NEWNET) != 0:
            err = ctypes.get_errno()
            raise OSError(err, f"setns({name}): {os.strerror(err)}")
    finally:
        os.close(fd)


class _NsForwarder:
    """TCP 127.0.0.1:port here -> 127.0.0.1:port inside a namespace (the dashboard and API).

    Each connection is served by a thread that first enters the namespace, so the socket it
    opens lives there; the accepted socket stays in ours.
    """

    def __init__(self, ns: str, target_port: int) -> None:
        import threading

        self.ns = ns
        self.target_port = target_port
        self.listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self.listener.bind(("127.0.0.1", target_port))
        except OSError:
            self.listener.bind(("127.0.0.1", 0))
        self.listener.listen(16)
        self.port = int(self.listener.getsockname()[1])
        self._closed = False
        threading.Thread(target=self._accept, name="ns-forward", daemon=True).start()

    def _accept(self) -> None:
        import threading

        while not self._closed:
            try:
                conn, _ = self.listener.accept()
            except OSError:
                return
            threading.Thread(target=self._pipe, args=(conn,), daemon=True).start()

    def _pipe(self, conn: socket.socket) -> None:
        import select

        try:
            _enter_netns(self.ns)
            upstream = socket.create_connection(("127.0.0.1", self.target_port), timeout=5)
        except OSError:
            conn.close()
            return
        with conn, upstream:
            pair = {conn: upstream, upstream: conn}
            while not self._closed:
                readable, _, _ = select.select(list(pair), [], [], 1.0)
                for sock in readable:
                    data = sock.recv(65536)
                    if not data:
                        return
                    pair[sock].sendall(data)

    def close(self) -> None:
        self._closed = True
        self.listener.close()


class FleetNetns:
    """``--netns``: each drone's companion in its own namespace, the ground station in
    another, all on the shaped bridge of :class:`sitl.linkemu.SharedMedium` (``tc tbf`` rate
    and queue once, toward the station: the drones contend like stations on one radio
    channel; netem delay/loss where the kernel has it). The vehicles share a namespace, each
    reached from its drone over an unshaped veth. Optional ``iperf3`` background traffic from
    another host on the medium, on at a given time (thesis fig. 7.4).
    """

    def __init__(self, *, drones: int, rate_bit_s: float, delay_s: float = 0.0,
                 loss: float = 0.0) -> None:
        from sitl.linkemu import SharedMedium

        self.medium = SharedMedium(drones=drones, rate_bit_per_s=rate_bit_s, delay_s=delay_s,
                                   loss=loss,
                                   queue_limit_bytes=max(15_000, int(rate_bit_s / 8 * 0.05)))
        self._forwarder: _NsForwarder | None = None
        self._background: Any = None
        self._plan: tuple[Background, float] | None = None
        self._bg_on = False

    def open(self) -> None:
        from sitl.linkemu import LinkEmuError, cleanup_stale

        cleanup_stale()
        try:
            self.medium.open()  # removes what it built if it fails half-way
        except LinkEmuError as exc:
            raise FleetError(f"--netns: cannot build the shared link: {exc}") from None

    def wrap_drone(self, index: int, argv: Sequence[str]) -> list[str]:
        return self.medium.wrap(self.medium.ns_drones[index], argv)

    def wrap_vehicles(self, argv: Sequence[str]) -> list[str]:
        assert self.medium.ns_vehicles is not None
        return self.medium.wrap(self.medium.ns_vehicles, argv)

    def wrap_gs(self, argv: Sequence[str]) -> list[str]:
        return self.medium.wrap(self.medium.ns_ground, argv)

    def forward_http(self, port: int) -> str:
        self._forwarder = _NsForwarder(self.medium.ns_ground, port)
        return f"http://127.0.0.1:{self._forwarder.port}"

    def schedule_background(self, background: Background, t_start: float) -> None:
        from sitl.linkemu import Iperf3Background

        self._background = Iperf3Background(self.medium)
        self._background.start_server()
        self._plan = (background, t_start)

    def tick(self, now: float) -> None:
        """Switch the background traffic on/off at its times (called about once a second)."""
        if self._plan is None or self._background is None:
            return
        bg, t_start = self._plan
        t_on = t_start + bg.start_s
        t_off = math.inf if bg.duration_s is None else t_on + bg.duration_s
        if not self._bg_on and t_on <= now < t_off:
            self._background.start(rate_bit_per_s=bg.rate_bit_s,
                                   duration_s=min(t_off - now, 24 * 3600.0))
            self._bg_on = True
        elif self._bg_on and now >= t_off:
            self._background.stop()
            self._plan = None

    def describe(self) -> dict[str, Any]:
        """The link of the run for the summary: namespaces, shaping, what netem did, and the
        bottleneck's counters (call before :meth:`close`)."""
        from sitl.linkemu import LinkEmuError, parse_qdisc_counters

        m = self.medium
        counters = None
        with contextlib.suppress(LinkEmuError, OSError, subprocess.SubprocessError):
            counters = parse_qdisc_counters(m.qdisc_stats())
        return {
            "description": m.describe(),
            "rate_bit_s": m.rate_bit_per_s,
            "queue_limit_bytes": m.queue_limit_bytes,
            "delay_s": m.delay_s,
            "loss": m.loss,
            "netem": m.netem,
            "impairment_note": m.impairment_note,
            "namespaces": {"medium": m.ns_medium, "ground_station": m.ns_ground,
                           "vehicles": m.ns_vehicles, "background": m.ns_background,
                           "drones": list(m.ns_drones)},
            "addresses": {"ground_station": m.ground_addr, "background": m.background_addr,
                          "drones": [m.drone_addr(i) for i in range(m.drones)]},
            "bottleneck": counters,
        }

    def close(self) -> None:
        if self._forwarder is not None:
            self._forwarder.close()
        if self._background is not None:
            self._background.stop()
        self.medium.close()


class Loopback:
    """The process wrappers of :class:`FleetNetns` for a run on 127.0.0.1: none."""

    def wrap_drone(self, index: int, argv: Sequence[str]) -> list[str]:
        return list(argv)

    def wrap_vehicles(self, argv: Sequence[str]) -> list[str]:
        return list(argv)

    def wrap_gs(self, argv: Sequence[str]) -> list[str]:
        return list(argv)
