"""iperf3 UDP background traffic across a shaped link."""

from __future__ import annotations

import contextlib
import math
import subprocess
from typing import Any

from sitl.linkemu.medium import SharedMedium
from sitl.linkemu.namespaces import NetnsLink


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
