"""A minimal drone for tests, benchmarks and demos: real datagrams built with the codec.

It sends images (synthetic JPEGs or raw bytes) and telemetry to a ground station over UDP,
acknowledges every COMMAND it receives with a STATUS ``ack`` and reports ``done`` at its
execution time (as the companion does), or ``error`` where the companion refuses it (an
unknown command; ``set_params`` that the companion's own decider, on its defaults, rejects),
and keeps the reports and
commands it got so a test can check them. The companion app is the real thing; this is
the smallest honest peer for the ground station.
"""

from __future__ import annotations

import asyncio
import math
import secrets
import socket
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, cast

from companion.app import build_decider
from companion.commands import replaced_by
from companion.config import parse_config
from companion.protocol import (
    EPOCH_STATUS,
    CommandReceived,
    Decoder,
    Encoder,
    PacketDropped,
    ReportReceived,
    Status,
)
from companion.protocol.signing import decode_key_text, fleet_key_text
from utility_specs.message import Message

__all__ = ["FakeDrone", "synthetic_jpeg"]


def synthetic_jpeg(
    seq: int, *, red: float, width: int = 320, height: int = 240, label: str = ""
) -> bytes:
    """A small JPEG whose red area is ``red`` of the frame (what the dashboard shows)."""
    import cv2
    import numpy as np

    frame = np.zeros((height, width, 3), dtype=np.uint8)
    frame[:] = (70, 110 + seq * 7 % 30, 80)  # fields seen from above, BGR
    rows = (np.arange(height) // 24 + seq) % 2 == 0
    frame[rows] = (55, 95, 70)
    share = min(max(red, 0.0), 1.0)
    if share > 0:
        radius = round(math.sqrt(share * width * height / math.pi))
        center = (width // 2 + (seq * 13) % 40 - 20, height // 2)
        cv2.circle(frame, center, radius, (30, 30, 225), thickness=-1)
    cv2.putText(
        frame,
        f"{label} #{seq}",
        (8, height - 12),
        cv2.FONT_HERSHEY_SIMPLEX,
        0.7,
        (255, 255, 255),
        2,
    )
    ok, buf = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, 70])
    if not ok:  # pragma: no cover - OpenCV always encodes a uint8 frame
        raise RuntimeError("JPEG encoding failed")
    return bytes(buf)


class FakeDrone(asyncio.DatagramProtocol):
    """One simulated drone endpoint on 127.0.0.1 (port 0)."""

    def __init__(
        self,
        drone_id: str,
        *,
        fleet_id: int,
        key: bytes,
        ground: tuple[str, int],
        clock: Callable[[], float] = time.time,
        auto_ack: bool = True,
        auto_done: bool = True,
        command_public_key: bytes | None = None,
        epoch: int | None = None,
    ) -> None:
        """Like a companion, it obeys only commands signed with ``command_public_key`` and
        carrying its ``epoch`` (random per instance unless given), announced at open; without
        the key it obeys none (and announces nothing)."""
        self.command_public_key = command_public_key
        self.drone_id = drone_id
        self.ground = ground
        self.clock = clock
        self.auto_ack = auto_ack
        self.auto_done = auto_done
        """Like the companion: ``done`` at the command's ``t_exec``, again on a repeat."""
        self.done: set[int] = set()
        self.errors: dict[int, str] = {}
        """Commands refused, with the companion's reason (sent again on a repeat)."""
        self._decider: Any = None
        """The companion's default decider, built at the first ``set_params`` (its checks)."""
        self.epoch = epoch if epoch is not None else secrets.randbits(63) + 1
        self.encoder = Encoder(fleet_id, drone_id, key)
        self.decoder = Decoder(fleet_id, key, local_id=drone_id,
                               command_key=command_public_key, epoch=self.epoch)
        self.transport: asyncio.DatagramTransport | None = None
        self.seq = 0
        self.commands: list[CommandReceived] = []
        self._phase: dict[int, tuple[str, float]] = {}
        """Start and end commands received (id -> name, t_exec), as the companion keeps them."""
        self.reports: list[ReportReceived] = []
        self.command_event = asyncio.Event()
        self.report_event = asyncio.Event()

    async def open(self, host: str = "127.0.0.1") -> None:
        loop = asyncio.get_running_loop()
        await loop.create_datagram_endpoint(lambda: self, local_addr=(host, 0))
        if self.command_public_key is not None:
            self.announce_epoch()

    def announce_epoch(self) -> None:
        self.send_status(EPOCH_STATUS, info={"epoch": self.epoch})

    def close(self) -> None:
        if self.transport is not None:
            self.transport.close()

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = cast(asyncio.DatagramTransport, transport)

    def datagram_received(self, data: bytes, addr: tuple[str | Any, int]) -> None:
        now = self.clock()
        self.decoder.receive_datagram(data, addr, now)
        while (event := self.decoder.next_event()) is not None:
            if isinstance(event, CommandReceived):
                self.commands.append(event)
                self.command_event.set()
                if self.auto_ack:
                    self._answer(event.command)
            elif isinstance(event, ReportReceived):
                self.reports.append(event)
                self.report_event.set()
            elif isinstance(event, PacketDropped) and event.reason == "wrong_epoch":
                self.announce_epoch()

    def _answer(self, command: Any) -> None:
        cid = command.command_id
        if cid in self.done:
            self.send_status("done", command_id=cid, info={"name": command.name})
            return
        if cid in self.errors:
            self.send_status("error", command_id=cid,
                             info={"name": command.name, "error": self.errors[cid]})
            return
        self.send_status("ack", command_id=cid)
        if not self.auto_done or any(c.command.command_id == cid for c in self.commands[:-1]):
            return
        if command.name in ("start", "end"):
            self._phase[cid] = (command.name, command.t_exec)
        delay = max(0.0, command.t_exec - self.clock())
        asyncio.get_running_loop().call_later(delay, self._execute, command)

    def _execute(self, command: Any) -> None:
        error = self._refusal(command)
        info: dict[str, Any] = {"name": command.name}
        if error is None:
            self.done.add(command.command_id)
        else:
            self.errors[command.command_id] = info["error"] = error
        if self.transport is not None and not self.transport.is_closing():
            self.send_status("done" if error is None else "error",
                             command_id=command.command_id, info=info)

    def _refusal(self, command: Any) -> str | None:
        """Why the companion would refuse ``command`` (None: it would run it)."""
        later = replaced_by(self._phase, command)
        if later is not None:
            return f"superseded by {later[1]} #{later[0]}"
        if command.name in ("start", "end", "request_report"):
            return None
        if command.name != "set_params":
            return f"unknown command {command.name!r}"
        if self._decider is None:  # ~10 ms
            self._decider = build_decider(parse_config({"drone": {"id": self.drone_id}}))
        result = self._decider.set_params(dict(command.args), self.clock())
        return None if result.ok else str(result.error)

    # -- sending --------------------------------------------------------------------------
    def sendto(self, datagram: bytes) -> None:
        assert self.transport is not None
        self.transport.sendto(datagram, self.ground)

    def message(
        self, msg_type: str, *, size: int, data: Mapping[str, Any], t_gen: float | None = None
    ) -> Message:
        self.seq += 1
        return Message(
            sender=self.drone_id,
            seq=self.seq,
            type=msg_type,
            t_gen=self.clock() if t_gen is None else t_gen,
            size=size,
            data=dict(data),
        )

    def datagrams_for_image(
        self, payload: bytes, *, data: Mapping[str, Any], msg_type: str = "image"
    ) -> list[bytes]:
        message = self.message(msg_type, size=len(payload), data=data)
        return self.encoder.fragment(message, payload, self.clock())

    def send_image(
        self, payload: bytes, *, data: Mapping[str, Any], msg_type: str = "image"
    ) -> int:
        """Send one image now; returns its seq."""
        for datagram in self.datagrams_for_image(payload, data=data, msg_type=msg_type):
            self.sendto(datagram)
        return self.seq

    def send_telemetry(self, msg_type: str, data: Mapping[str, Any]) -> int:
        message = self.message(msg_type, size=0, data=data)
        for datagram in self.encoder.fragment(message, b"", self.clock()):
            self.sendto(datagram)
        return self.seq

    def send_status(
        self, state: str, *, command_id: int | None = None, info: Mapping[str, Any] | None = None
    ) -> None:
        status = Status(state=state, command_id=command_id, info=dict(info or {}))
        self.sendto(self.encoder.encode_status(status, self.clock()))

    async def wait_command(self, timeout: float = 5.0) -> CommandReceived:
        async with asyncio.timeout(timeout):
            while not self.commands:
                self.command_event.clear()
                await self.command_event.wait()
        return self.commands[-1]

    async def wait_report(
        self, predicate: Callable[[ReportReceived], bool], timeout: float = 5.0
    ) -> ReportReceived:
        async with asyncio.timeout(timeout):
            while True:
                for report in self.reports:
                    if predicate(report):
                        return report
                self.report_event.clear()
                await self.report_event.wait()


async def fly_demo_fleet(
    ground: tuple[str, int],
    *,
    fleet_id: int,
    key: bytes,
    command_public_key: bytes | None = None,
    drones: int = 4,
    duration_s: float = 30.0,
    images_per_s: float = 2.0,
    clock: Callable[[], float] = time.time,
    on_start: Callable[[list[FakeDrone]], None] | None = None,
) -> list[FakeDrone]:
    """Drones circling a point 51.1 N 17.0 E: images (one sees red), position, battery,
    status with link statistics, one STATUSTEXT. For the browser test and demos."""
    fleet = [
        FakeDrone(f"uav{i + 1}", fleet_id=fleet_id, key=key, ground=ground, clock=clock,
                  command_public_key=command_public_key)
        for i in range(drones)
    ]
    for drone in fleet:
        await drone.open()
    if on_start is not None:
        on_start(fleet)
    jpegs = {
        (i, k): synthetic_jpeg(k, red=(0.45 if i == 1 else 0.02), label=f"uav{i + 1}")
        for i in range(drones)
        for k in range(4)
    }
    t0 = clock()
    step = 0
    fleet[0].send_status(
        "running", info={"statustext": "PreArm: demo autopilot ready", "severity": 6}
    )
    try:
        while clock() - t0 < duration_s:
            t = clock() - t0
            for i, drone in enumerate(fleet):
                angle = 0.2 * t + 2 * math.pi * i / drones
                lat = 51.1 + (60 + 15 * i) * math.sin(angle) / 111_320.0
                lon = 17.0 + (60 + 15 * i) * math.cos(angle) / (111_320.0 * math.cos(0.892))
                geo = {
                    "lat": lat,
                    "lon": lon,
                    "alt": 40.0 + 5 * i,
                    "yaw_deg": (math.degrees(angle) + 180.0) % 360.0,
                }
                red = 0.45 if i == 1 else 0.02
                drone.send_image(jpegs[(i, step % 4)], data={"red": red, "object": i == 2, **geo})
                if step % max(1, round(images_per_s)) == 0:
                    drone.send_telemetry("position", geo)
                    drone.send_telemetry(
                        "battery", {"level": max(0.0, 0.95 - 0.02 * i - t / 3000.0)}
                    )
                    drone.send_status(
                        "running",
                        info={
                            "mode": "AUTO" if i != 3 else "GUIDED",
                            "armed": True,
                            "gps_fix": 3,
                            "xi_bytes_per_s": 40_000.0 + 8_000.0 * math.sin(0.3 * t + i),
                            "delta_s": 0.05 + 0.02 * i,
                            "loss": 0.01 * i,
                        },
                    )
            step += 1
            await asyncio.sleep(1.0 / images_per_s)
    finally:
        for drone in fleet:
            drone.close()
    return fleet


def _address(text: str) -> tuple[str, int]:
    """HOST:PORT (HOST may be left out: 127.0.0.1) of the station's UDP port."""
    import argparse

    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit():
        raise argparse.ArgumentTypeError(f"expected HOST:PORT (127.0.0.1:14600), got {text!r}")
    if not 1 <= int(port) <= 65535:
        raise argparse.ArgumentTypeError(f"port must be in 1..65535, got {text!r}")
    return host.strip("[]") or "127.0.0.1", int(port)


def main(argv: list[str] | None = None) -> int:
    """``python -m ground_station.fake_drone HOST:PORT``: fly a demo fleet at a station."""
    import argparse
    import sys

    from companion.cli_help import DefaultsRawFormatter
    from ground_station.config import GroundConfig

    parser = argparse.ArgumentParser(
        prog="python -m ground_station.fake_drone", formatter_class=DefaultsRawFormatter,
        description="A demo fleet of fake drones circling 51.1 N 17.0 E: each sends images,\n"
                    "position, battery and status to a ground station over UDP and answers\n"
                    "its commands.",
        epilog="example:\n"
               "  python -m ground_station.fake_drone 127.0.0.1:14600 --keys gs-data/keys")
    parser.add_argument("ground", type=_address,
                        help="the ground station's UDP address HOST:PORT (its udp_port)")
    parser.add_argument("--drones", type=int, default=4,
                        help="how many drones (uav1, uav2, ...) circle the demo point")
    parser.add_argument("--duration", type=float, default=60.0,
                        help="seconds to send for, then stop (Ctrl-C stops it earlier)")
    parser.add_argument("--fleet-id", type=int, default=GroundConfig().fleet_id,
                        help="the station's fleet_id")
    parser.add_argument("--keys", type=Path, required=True,
                        help="folder with fleet.key and command.pub (uav-ground-station keygen)")
    args = parser.parse_args(argv)
    if not 1 <= args.drones <= 64:
        parser.error(f"--drones must be in 1..64, got {args.drones}")
    if not 0 <= args.duration < math.inf:
        parser.error(f"--duration must be a finite number of seconds >= 0, got {args.duration}")
    if not 0 <= args.fleet_id < 2**32:
        parser.error(f"--fleet-id must be in 0..4294967295, got {args.fleet_id}")
    try:
        key = fleet_key_text((args.keys / "fleet.key").read_bytes(), "fleet.key")
        public = decode_key_text((args.keys / "command.pub").read_bytes(), "command.pub")
    except (OSError, ValueError) as exc:
        parser.error(f"--keys {args.keys}: {exc}")
    host, port = args.ground
    try:  # sends to a name that does not resolve failed silently, all --duration long
        socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)
    except OSError as exc:
        parser.error(f"argument ground: cannot resolve {host!r}: {exc.strerror or exc}")
    def started(_: list[FakeDrone]) -> None:  # in the loop: Ctrl-C from here on is clean
        print(f"fake_drone: {args.drones} drone(s) send images, telemetry and status to "
              f"{host}:{port} (fleet {args.fleet_id}) for {args.duration:g} s; Ctrl-C stops",
              flush=True)

    try:
        asyncio.run(
            fly_demo_fleet(
                (host, port),
                fleet_id=args.fleet_id,
                key=key,
                command_public_key=public,
                drones=args.drones,
                duration_s=args.duration,
                on_start=started,
            )
        )
    except KeyboardInterrupt:
        print("fake_drone: interrupted", file=sys.stderr, flush=True)
        return 130
    except OSError as exc:  # a host name that does not resolve, a network that is down
        print(f"fake_drone: cannot send to {host}:{port}: {exc.strerror or exc}",
              file=sys.stderr)
        return 1
    print(f"fake_drone: done after {args.duration:g} s", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
