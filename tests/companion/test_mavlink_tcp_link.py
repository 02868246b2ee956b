"""The MAVLink thread on a TCP link (ArduPilot SITL's serial ports, mavlink-router's TCP
server): when the autopilot reboots, its port closes (ArduCopter 4.5 SITL execs itself) and
stays closed for a moment."""

from __future__ import annotations

import contextlib
import socket
import threading
import time

from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.mavlink import MavlinkReader, MavlinkSettings
from companion.telemetry import LinkStateSample, Sample


class TcpAutopilot:
    """An ArduPilot-like TCP port: HEARTBEATs at 10 Hz to whoever connects; ``close()``
    drops the client and stops listening (a reboot), ``listen()`` comes back."""

    def __init__(self) -> None:
        self.port = 0
        self.server: socket.socket | None = None
        self.client: socket.socket | None = None
        self.connects = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self.listen()
        self._thread.start()

    def listen(self) -> None:
        server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        server.bind(("127.0.0.1", self.port))
        server.listen(1)
        server.settimeout(0.05)
        self.port = server.getsockname()[1]
        self.server = server

    def close(self) -> None:
        for sock in (self.client, self.server):
            if sock is not None:
                sock.close()
        self.client = self.server = None

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)
        self.close()

    def _run(self) -> None:
        encoder = mav.MAVLink(None, srcSystem=1, srcComponent=1)
        while not self._stop.is_set():
            server = self.server
            if self.client is None and server is not None:
                try:
                    self.client, _ = server.accept()
                    self.connects += 1
                except OSError:
                    continue
            client = self.client
            if client is not None:
                hb = mav.MAVLink_heartbeat_message(mav.MAV_TYPE_QUADROTOR,
                                                   mav.MAV_AUTOPILOT_ARDUPILOTMEGA, 81, 0, 4, 3)
                with contextlib.suppress(OSError):  # closed by close(): a reboot
                    client.sendall(hb.pack(encoder))
                    # read what the companion sent, so close() ends with a FIN (EOF), as
                    # a port that was read to the end does, not with a reset
                    client.setblocking(False)
                    with contextlib.suppress(BlockingIOError):
                        while client.recv(4096):
                            pass
            time.sleep(0.1)


def test_a_closed_tcp_port_is_a_lost_link_at_once_and_quietly(capfd) -> None:
    autopilot = TcpAutopilot()
    links: list[tuple[float, bool]] = []

    def post(sample: Sample) -> None:
        if isinstance(sample, LinkStateSample):
            links.append((time.monotonic(), sample.connected))

    settings = MavlinkSettings(url=f"tcp:127.0.0.1:{autopilot.port}", heartbeat_timeout_s=3.0,
                               reconnect_delay_s=0.2, recv_timeout_s=0.1)
    reader = MavlinkReader(settings, clock=time.time, post=post)
    reader.start()
    try:
        deadline = time.monotonic() + 5
        while not links and time.monotonic() < deadline:
            time.sleep(0.02)
        assert links == [(links[0][0], True)]
        closed = time.monotonic()
        autopilot.close()  # the autopilot reboots: its port closes and stays closed
        time.sleep(1.5)
        # lost at once (an EOF), not after the 3 s heartbeat timeout
        assert [c for _, c in links] == [True, False]
        assert links[1][0] - closed < 1.0
        # reopening while nothing listens fails at once (pymavlink's default blocks 3 s)
        t_stop = time.monotonic()
        autopilot.listen()  # back after the reboot
        deadline = time.monotonic() + 5
        while len(links) < 3 and time.monotonic() < deadline:
            time.sleep(0.02)
        assert [c for _, c in links] == [True, False, True]
        assert links[2][0] - t_stop < 1.5
    finally:
        reader.stop()
        reader.join(5)
        autopilot.stop()
    out = capfd.readouterr().out
    # pymavlink prints "EOF on TCP socket" on every read of a closed socket and "...
    # sleeping" per refused connect: thousands of lines on a Pi's journal per reboot
    assert "EOF on TCP socket" not in out and "sleeping" not in out, out[:300]
