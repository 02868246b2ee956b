"""The UDP shell on real sockets: two endpoints on 127.0.0.1, port 0."""

from __future__ import annotations

import asyncio
import random
import socket
import time
from collections.abc import AsyncIterator

import pytest
from protocol_helpers import FLEET, KEY, image_message

from companion.protocol import (
    PROTOCOL_VERSION,
    ClockEcho,
    Command,
    CommandReceived,
    Decoder,
    DecoderLimits,
    Encoder,
    Event,
    MessageExpired,
    MessageReassembled,
    PacketDropped,
    Report,
    ReportReceived,
    Status,
    StatusReceived,
    entry_from_message,
)
from companion.transport import UdpTransport
from tests.keys import TEST_COMMAND_KEY, TEST_COMMAND_PUB
from utility_specs.message import Message

LOCAL = ("127.0.0.1", 0)


async def next_of(transport: UdpTransport, kind: type[Event], timeout_s: float = 5.0) -> Event:
    """The next event of a kind, skipping others (bounded wait, no sleeps)."""
    async with asyncio.timeout(timeout_s):
        while True:
            event = await transport.events.get()
            if isinstance(event, kind):
                return event


@pytest.fixture
async def pair() -> AsyncIterator[tuple[UdpTransport, UdpTransport]]:
    limits = DecoderLimits(reassembly_timeout_s=0.2)
    ground = UdpTransport(
        encoder=Encoder(FLEET, "ground", KEY, command_key=TEST_COMMAND_KEY),
        decoder=Decoder(FLEET, KEY, local_id="ground", limits=limits),
        local_addr=LOCAL,
    )
    await ground.start()
    drone = UdpTransport(
        encoder=Encoder(FLEET, "drone1", KEY),
        decoder=Decoder(FLEET, KEY, local_id="drone1", command_key=TEST_COMMAND_PUB),
        remote_addr=("localhost", ground.local_address[1]),
        local_addr=LOCAL,
    )
    tasks = [asyncio.create_task(t.run()) for t in (ground, drone)]
    await drone.wait_started()
    try:
        yield drone, ground
    finally:
        for t in (ground, drone):
            t.stop()
        await asyncio.gather(*tasks)


async def test_image_and_status_reach_the_ground(pair: tuple[UdpTransport, UdpTransport]) -> None:
    drone, ground = pair
    assert drone.remote_addr == ground.local_address  # "localhost" resolved at start
    payload = random.Random(1).randbytes(30_000)
    message = image_message(seq=5, size=30_000, t_gen=time.time() - 0.1)
    sent = drone.send_message(message, payload)
    assert sent == 27  # 1125 payload bytes per datagram (docs/protocol.md), metadata first
    event = await next_of(ground, MessageReassembled)
    assert isinstance(event, MessageReassembled)
    assert event.payload == payload
    assert event.message.seq == 5 and event.message.receiver == "ground"
    assert event.addr == drone.local_address

    drone.send_status(Status(state="done", command_id=9, info={"alpha": 10}))
    status = await next_of(ground, StatusReceived)
    assert isinstance(status, StatusReceived)
    assert status.status.command_id == 9 and status.sender == "drone1"
    assert drone.counters["datagrams_sent"] == 28 and drone.counters["messages_sent"] == 1


async def test_reports_and_commands_reach_the_drone(
    pair: tuple[UdpTransport, UdpTransport],
) -> None:
    drone, ground = pair
    now = time.time()
    telemetry = Message(sender="drone1", seq=1, type="battery", t_gen=now, data={"level": 0.5})
    drone.send_message(telemetry, b"")
    arrived = await next_of(ground, MessageReassembled)
    assert isinstance(arrived, MessageReassembled)
    report = Report(
        entries=(entry_from_message(arrived.message, t_rcv=arrived.t_rcv),),
        echoes=(ClockEcho(sender="drone1", t_sent=now, t_rcv=arrived.t_rcv),),
    )
    ground.send_report(report, arrived.addr)
    got = await next_of(drone, ReportReceived)
    assert isinstance(got, ReportReceived)
    assert got.report == report and got.reporter == "ground"

    command = Command(command_id=3, name="start", t_exec=now + 5.0, args={"mission": "m1"})
    ground.send_datagrams([ground.encoder.encode_command(command, time.time())], arrived.addr)
    received = await next_of(drone, CommandReceived)
    assert isinstance(received, CommandReceived)
    assert received.command == command


async def test_lost_fragment_expires_through_the_armed_timer(
    pair: tuple[UdpTransport, UdpTransport],
) -> None:
    drone, ground = pair
    message = image_message(seq=8, size=4000, t_gen=time.time())
    datagrams = drone.encoder.fragment(message, bytes(4000), time.time())
    drone.send_datagrams(datagrams[:1] + datagrams[2:])  # fragment 1 lost on the air
    expired = await next_of(ground, MessageExpired, timeout_s=3.0)
    assert expired == MessageExpired(
        sender="drone1",
        seq=8,
        type="image",
        fragments_missing=1,
        fragment_count=len(datagrams),
        evicted=False,
    )
    assert ground.decoder.get_timer() is None


async def test_garbage_on_the_socket_is_counted_not_fatal(
    pair: tuple[UdpTransport, UdpTransport],
) -> None:
    drone, ground = pair
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as raw:
        raw.sendto(b"\x00" * 50, ground.local_address)
        raw.sendto(b"UV" + bytes([PROTOCOL_VERSION]) + b"\x01" * 99, ground.local_address)
    first = await next_of(ground, PacketDropped)
    second = await next_of(ground, PacketDropped)
    assert isinstance(first, PacketDropped) and isinstance(second, PacketDropped)
    assert ground.decoder.counters["malformed"] == 1
    assert ground.decoder.counters["wrong_fleet"] == 1
    # Still serving.
    drone.send_message(Message(sender="drone1", seq=2, type="battery", t_gen=time.time()), b"")
    assert isinstance(await next_of(ground, MessageReassembled), MessageReassembled)


async def test_send_errors_and_full_buffers_are_counted() -> None:
    drone = UdpTransport(
        encoder=Encoder(FLEET, "drone1", KEY),
        decoder=Decoder(FLEET, KEY),
        remote_addr=("127.0.0.1", 9),
        local_addr=LOCAL,
        max_write_buffer_bytes=2000,
    )
    message = image_message(seq=1, size=5000, t_gen=time.time())
    assert drone.send_message(message, b"") == 0  # before the socket is bound
    assert drone.counters["send_not_ready"] == 1
    task = asyncio.create_task(drone.run())
    await drone.wait_started()
    try:
        assert drone.send_message(message, bytes(5000)) == 0  # > 2000 bytes: dropped whole
        assert drone.counters["send_dropped_buffer_full"] == 1
        # Port 0 is not a valid destination: the kernel refuses, the shell counts it.
        drone.send_datagrams([b"x" * 10], ("127.0.0.1", 0))
        assert drone.counters["send_errors"] == 1
    finally:
        drone.stop()
        await task


async def test_a_remote_name_that_does_not_resolve_is_retried(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """No DNS yet at boot (or a typo): a WARNING naming the setting, nothing sent, and the
    lookup retried until it resolves; it killed the companion with a gaierror traceback."""
    import companion.remote_lookup as lookup

    ground = UdpTransport(encoder=Encoder(FLEET, "ground", KEY), decoder=Decoder(FLEET, KEY),
                          local_addr=LOCAL)
    ground_task = asyncio.create_task(ground.run())
    await ground.wait_started()
    answers: list[tuple[str, int] | None] = [None, None, ground.local_address]

    async def flaky(addr: tuple[str, int]) -> tuple[str, int]:
        answer = answers.pop(0) if answers else ground.local_address
        if answer is None:
            raise socket.gaierror(socket.EAI_NONAME, "Name or service not known")
        return answer

    monkeypatch.setattr(lookup, "_resolve", flaky)
    monkeypatch.setattr(lookup, "RESOLVE_RETRY_S", 0.05)
    drone = UdpTransport(encoder=Encoder(FLEET, "drone1", KEY), decoder=Decoder(FLEET, KEY),
                         remote_addr=("gs.field.lan", 14600), local_addr=LOCAL, epoch=7,
                         remote_name="ground_station.host")
    drone_task = asyncio.create_task(drone.run())
    try:
        await drone.wait_started()
        assert [r.getMessage() for r in caplog.records if r.levelname == "WARNING"] == [
            "ground_station.host 'gs.field.lan' does not resolve (Name or service not known): "
            "nothing is sent to it until it does; retrying every 0.05 s"]
        assert drone.send_status(Status(state="idle")) == 0  # not to a name: lost, counted
        assert drone.counters["send_not_ready"] >= 1
        announced = await next_of(ground, StatusReceived)  # the epoch, once it resolved
        assert isinstance(announced, StatusReceived) and announced.status.info == {"epoch": 7}
        assert drone.remote_addr == ground.local_address
        assert drone.send_status(Status(state="idle")) == 1
    finally:
        for t in (ground, drone):
            t.stop()
        await asyncio.gather(ground_task, drone_task)
