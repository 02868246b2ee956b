"""Hypothesis against the REPORT, COMMAND and STATUS parsers (2026-11-25): correctly tagged
datagrams (what any holder of the fleet key can make) whose fixed fields and JSON bodies are
hostile (random, truncated, 60 kB, JSON of every shape, numbers at every limit), at a drone's
decoder (which holds the station's command key and a boot epoch) and at the station's.

Held: nothing raises; every datagram is accepted or counted; state stays within the
limits; and no COMMAND is ever delivered but the station's: one signed with another Ed25519
key, one with the right signature but a flipped byte, one for another epoch and a replay of
a real one are all refused, the real one is delivered once.
"""

from __future__ import annotations

import json
from typing import Any

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from companion.protocol import (
    COUNTER_NAMES,
    Command,
    CommandReceived,
    Decoder,
    DecoderLimits,
    Encoder,
)
from companion.protocol.signing import CommandSigner, public_key_of
from companion.protocol.wire import (
    COMMAND_FIXED,
    REPORT_FIXED,
    STATUS_FIXED,
    U8,
    PacketKind,
    pack_datagram,
)

T0 = 1_700_000_000.0
KEY = bytes(range(32))
FLEET = 42
ADDR = ("127.0.0.1", 40000)
STATION_KEY = bytes(range(100, 132))
ROGUE_KEY = bytes(range(1, 33))
EPOCH = 7
LIMITS = DecoderLimits(max_message_bytes=64 << 10, max_buffered_bytes=128 << 10,
                       max_partials=4, max_fragments=64, max_senders=4,
                       max_pending_events=64, recent_messages=32, replay_window=64)
DROPS = tuple(name for name in COUNTER_NAMES if name not in (
    "datagrams", "accepted", "messages", "reports", "commands", "statuses", "events_overflow",
    "expired",
    "evicted"))

LIMIT_NUMBERS = st.sampled_from([0, -1, 2**31, 2**63 - 1, -(2**63), 2**64, 1e308, -1e308,
                                 5e-324, 0.1])
JSON_VALUES = st.recursive(
    st.one_of(st.none(), st.booleans(), LIMIT_NUMBERS, st.integers(), st.text(max_size=30),
              st.floats(allow_nan=False, allow_infinity=False)),
    lambda inner: st.one_of(st.lists(inner, max_size=5),
                            st.dictionaries(st.text(max_size=8), inner, max_size=5)),
    max_leaves=30)


@st.composite
def hostile_json(draw: st.DrawFn) -> bytes:
    return draw(st.one_of(
        JSON_VALUES.map(lambda v: json.dumps(v).encode()),
        st.binary(max_size=200),
        st.just(b'{"e":' + b"[" * 5000 + b"]" * 5000 + b"}"),
        st.just(b"{" + b'"a":1,' * 5000 + b'"b":NaN}'),
        st.just(b'{"c":[[1e999, -1e999, 0]], "e": [' + b"9" * 5000 + b"]}"),
        st.just(b"\x00" * 60_000),
    ))


@st.composite
def crafted(draw: st.DrawFn) -> bytes:
    kind = draw(st.sampled_from([PacketKind.REPORT, PacketKind.COMMAND, PacketKind.STATUS]))
    u32, u16 = st.integers(0, 2**32 - 1), st.integers(0, 2**16 - 1)
    text = draw(st.binary(max_size=40))
    if kind == PacketKind.REPORT:
        fixed = REPORT_FIXED.pack(draw(u32), draw(u16), draw(u16))
    elif kind == PacketKind.STATUS:
        fixed = STATUS_FIXED.pack(draw(u32), min(len(text), 255)) + text
    else:
        fixed = (COMMAND_FIXED.pack(draw(st.sampled_from([0, EPOCH, 2**64 - 1])), draw(u32),
                                    draw(st.sampled_from([T0, 0.0, 1e308, -1e308])),
                                    min(len(text), 255)) + text + U8.pack(0))
    body = (fixed + draw(hostile_json()))[: draw(st.integers(0, 65_000))]
    signer = CommandSigner(draw(st.sampled_from([ROGUE_KEY, STATION_KEY])))
    return pack_datagram(key=KEY, kind=kind, fleet_id=FLEET,
                         packet_number=draw(st.integers(0, 2**64 - 1)), t_sent=T0,
                         sender_raw=draw(st.sampled_from([b"gs", b"drone1", b"\xff"])),
                         body=body[:0xFFFF - 300],
                         sign=signer.sign if kind == PacketKind.COMMAND and draw(
                             st.booleans()) else None)


def _drain(decoder: Decoder) -> list[Any]:
    events = []
    while (event := decoder.next_event()) is not None:
        events.append(event)
    return events


@given(st.lists(st.one_of(crafted(), st.binary(max_size=300)), max_size=30))
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                 HealthCheck.data_too_large])
def test_crafted_reports_commands_and_statuses_never_raise(datagrams: list[bytes]) -> None:
    drone = Decoder(FLEET, KEY, local_id="drone1", limits=LIMITS,
                    command_key=public_key_of(STATION_KEY), epoch=EPOCH)
    ground = Decoder(FLEET, KEY, local_id="gs", limits=LIMITS)
    for decoder in (drone, ground):
        for i, data in enumerate(datagrams):
            decoder.receive_datagram(data, ADDR, T0 + i * 0.01)
            assert decoder.buffered_bytes <= LIMITS.max_buffered_bytes
            assert decoder.sender_count <= LIMITS.max_senders
        events = _drain(decoder)
        assert len(events) <= LIMITS.max_pending_events
        counts = decoder.counters
        assert counts["datagrams"] == len(datagrams)
        assert counts["accepted"] + sum(counts[k] for k in DROPS) >= len(datagrams), counts
        for event in events:  # a command reaches the drone only if the station signed it
            if isinstance(event, CommandReceived):
                assert decoder is drone


def test_only_the_stations_command_for_this_epoch_is_obeyed_once() -> None:
    station = Encoder(FLEET, "gs", KEY, command_key=STATION_KEY)
    rogue = Encoder(FLEET, "gs", KEY, command_key=ROGUE_KEY)
    command = Command(command_id=5, name="start", t_exec=T0 + 1, args={}, target="drone1")
    real = station.encode_command(command, T0, epoch=EPOCH)
    flipped = bytearray(station.encode_command(command, T0, epoch=EPOCH))
    flipped[-70] ^= 1  # a byte of the signed body, the fleet tag recomputed below
    drone = Decoder(FLEET, KEY, local_id="drone1", limits=LIMITS,
                    command_key=public_key_of(STATION_KEY), epoch=EPOCH)
    attempts = [rogue.encode_command(command, T0, epoch=EPOCH),
                station.encode_command(command, T0, epoch=EPOCH + 1),
                bytes(flipped), real, real]
    for i, data in enumerate(attempts):
        drone.receive_datagram(data, ADDR, T0 + i * 0.01)
    obeyed = [e for e in _drain(drone) if isinstance(e, CommandReceived)]
    assert [e.command.command_id for e in obeyed] == [5]
    assert drone.counters["replayed"] >= 1
    assert drone.counters["commands"] == 1
