"""Fuzzing the decoder: nothing raises out of receive_datagram, memory stays bounded.

Mutations that keep a valid tag (re-signed with the fleet key) reach the body parsers,
which random bytes alone would never get past the HMAC.
"""

from __future__ import annotations

import json
import random
import struct
from dataclasses import replace

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from protocol_helpers import ADDR, FLEET, KEY, T0, drain, image_message, make_decoder

from companion.protocol import (
    ClockEcho,
    Command,
    Decoder,
    Encoder,
    MessageReassembled,
    Report,
    Status,
    entry_from_message,
)
from companion.protocol.wire import TAG_BYTES, PacketKind, pack_datagram, tag
from tests.keys import TEST_COMMAND_KEY, TEST_COMMAND_PUB

LIMITS = {
    "max_message_bytes": 6000,
    "max_buffered_bytes": 9000,
    "max_partials": 3,
    "max_fragments": 8,
    "max_senders": 3,
    "max_pending_events": 40,
    "recent_messages": 16,
    "replay_window": 64,
}


def valid_datagrams() -> list[bytes]:
    """A corpus of every packet kind from several senders."""
    rng = random.Random(7)
    corpus: list[bytes] = []
    for i, sender in enumerate(["drone1", "drone2", "d3", "drone4"]):
        encoder = Encoder(FLEET, sender, KEY)
        for seq in range(3):
            message = replace(image_message(seq=seq, size=5000), sender=sender)
            payload = rng.randbytes(rng.choice([0, 700, 2500, 5000]))
            corpus += encoder.fragment(message, payload, now=T0 + i * 0.01)
        corpus.append(encoder.encode_status(Status(state="done", command_id=3), now=T0))
    ground = Encoder(FLEET, "ground", KEY, command_key=TEST_COMMAND_KEY)
    entries = tuple(entry_from_message(image_message(seq=s), t_rcv=T0) for s in range(12))
    echoes = (ClockEcho(sender="drone1", t_sent=T0, t_rcv=T0 + 0.1),)
    corpus += ground.encode_report(Report(entries=entries, echoes=echoes), now=T0)
    corpus.append(ground.encode_command(Command(command_id=3, name="start", t_exec=T0 + 5), now=T0))
    return corpus


CORPUS = valid_datagrams()


def resign(data: bytes) -> bytes:
    """Replace the tag so the mutated datagram authenticates (if its lengths still match)."""
    if len(data) <= TAG_BYTES:
        return data
    return data[:-TAG_BYTES] + tag(KEY, data[:-TAG_BYTES])


@st.composite
def mutated(draw: st.DrawFn) -> bytes:
    base = draw(st.sampled_from(CORPUS))
    op = draw(
        st.sampled_from(["flip", "truncate", "splice", "bytes", "resign_flip", "rebody", "resign"])
    )
    data = bytearray(base)
    if op in ("flip", "resign_flip"):
        for _ in range(draw(st.integers(1, 8))):
            position = draw(st.integers(0, len(data) - 1))
            data[position] ^= 1 << draw(st.integers(0, 7))
    elif op == "truncate":
        data = data[: draw(st.integers(0, len(data) - 1))]
    elif op == "splice":
        other = draw(st.sampled_from(CORPUS))
        cut = draw(st.integers(0, len(data)))
        data = data[:cut] + other[draw(st.integers(0, len(other))) :]
    elif op == "bytes":
        position = draw(st.integers(27, len(data) - TAG_BYTES))
        data[position:position] = draw(st.binary(max_size=40))
    elif op == "rebody":
        # Keep the header, replace or cut the body, fix the body length: the parsers see it.
        (sender_len,) = struct.unpack_from("!B", data, 26)
        start = 27 + sender_len
        body = bytes(data[start:-TAG_BYTES])
        cut = draw(st.integers(0, len(body)))
        body = body[:cut] + draw(st.binary(max_size=60))
        data = data[:start] + body + bytes(TAG_BYTES)
        struct.pack_into("!H", data, 24, len(body))
    if op.startswith("resign") or op in ("bytes", "rebody"):
        data = bytearray(resign(bytes(data)))
    return bytes(data)


json_scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(2**53), 2**53),
    st.floats(allow_nan=False, allow_infinity=False),
    st.text(max_size=12),
)
json_values = st.recursive(
    json_scalars,
    lambda children: (
        st.lists(children, max_size=3) | st.dictionaries(st.text(max_size=6), children, max_size=3)
    ),
    max_leaves=12,
)


@st.composite
def signed_structured(draw: st.DrawFn) -> bytes:
    """Well-framed, correctly tagged datagrams whose fields and JSON are arbitrary."""
    kind = draw(st.sampled_from(list(PacketKind)))
    doc = json.dumps(
        draw(
            st.one_of(
                json_values,
                st.fixed_dictionaries({"e": st.lists(st.lists(json_values, max_size=11))}),
                st.fixed_dictionaries({"c": st.lists(st.lists(json_values, max_size=4))}),
                st.fixed_dictionaries(
                    {},
                    optional={
                        "z": json_values,
                        "d": json_values,
                        "v": json_values,
                        "i": json_values,
                    },
                ),
            )
        )
    ).encode()
    u16, u32 = st.integers(0, 0xFFFF), st.integers(0, 0xFFFF_FFFF)
    word = st.text(max_size=34).map(str.encode)
    if kind is PacketKind.DATA:
        fixed = struct.pack(
            "!IdHHI", draw(u32), T0, draw(st.integers(0, 3)), draw(st.integers(0, 4)), draw(u32)
        )
        type_raw = draw(word)
        body = fixed + bytes([len(type_raw)]) + type_raw + struct.pack("!H", len(doc)) + doc
        body += draw(st.binary(max_size=50))
    elif kind is PacketKind.REPORT:
        body = struct.pack("!IHH", draw(u32), draw(u16), draw(u16)) + doc
    elif kind is PacketKind.COMMAND:
        name, target = draw(word), draw(word)
        body = (
            struct.pack("!IdB", draw(u32), T0, len(name))
            + name
            + bytes([len(target)])
            + target
            + doc
        )
    else:
        state = draw(word)
        body = struct.pack("!IB", draw(u32), len(state)) + state + doc
    return pack_datagram(
        key=KEY,
        kind=kind,
        fleet_id=FLEET,
        packet_number=draw(st.integers(0, 2**64 - 1)),
        t_sent=T0,
        sender_raw=draw(st.sampled_from([b"drone1", b"drone2", b"ground", b"x"])),
        body=body[:1100],
    )


datagram_strategy = st.one_of(
    st.binary(max_size=1300), mutated(), signed_structured(), st.sampled_from(CORPUS)
)


def assert_bounded(decoder: Decoder) -> None:
    limits = decoder.limits
    assert 0 <= decoder.buffered_bytes <= limits.max_buffered_bytes
    assert decoder.partial_count <= limits.max_partials
    assert decoder.sender_count <= limits.max_senders
    # The byte count is the sum over the partial messages actually held.
    held = sum(p.buffered for p in decoder._partials.values())
    assert decoder.buffered_bytes == held
    assert len(decoder._recent) <= limits.recent_messages
    assert len(decoder._events) <= limits.max_pending_events


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    datagrams=st.lists(datagram_strategy, min_size=1, max_size=40),
    steps=st.lists(st.floats(0.0, 2.0), min_size=1, max_size=40),
)
def test_decoder_never_raises_and_stays_bounded(datagrams: list[bytes], steps: list[float]) -> None:
    decoder = make_decoder(**LIMITS)
    now = T0
    for i, data in enumerate(datagrams):
        now += steps[i % len(steps)]
        decoder.receive_datagram(data, ADDR, now)
        assert_bounded(decoder)
        if i % 7 == 6:
            drain(decoder)
        timer = decoder.get_timer()
        if timer is not None and timer <= now + 0.5:
            decoder.handle_timer(timer)
            assert decoder.get_timer() is None or decoder.get_timer() > timer
    assert decoder.counters["datagrams"] == len(datagrams)
    decoder.handle_timer(now + 1e6)
    assert decoder.partial_count == 0 and decoder.buffered_bytes == 0


def test_whole_corpus_decodes_cleanly() -> None:
    """The fuzz corpus itself is valid: every datagram is accepted and nothing is dropped."""
    decoder = Decoder(FLEET, KEY, local_id="ground", command_key=TEST_COMMAND_PUB)
    for data in CORPUS:
        decoder.receive_datagram(data, ADDR, T0)
    assert decoder.counters["accepted"] == len(CORPUS)
    assert decoder.counters["messages"] == 12
    assert decoder.partial_count == 0


@settings(max_examples=60, deadline=None)
@given(
    data=st.dictionaries(st.text(min_size=1, max_size=8), json_values, max_size=5),
    payload=st.binary(max_size=5000),
    seq=st.integers(0, 2**32 - 1),
    t_gen=st.floats(T0 - 1e4, T0),
    order_seed=st.integers(0, 1000),
)
def test_any_message_round_trips_in_any_fragment_order(
    data: dict[str, object], payload: bytes, seq: int, t_gen: float, order_seed: int
) -> None:
    message = replace(image_message(seq=seq, t_gen=t_gen), data=data)
    datagrams = Encoder(FLEET, "drone1", KEY).fragment(message, payload, now=T0)
    random.Random(order_seed).shuffle(datagrams)
    decoder = make_decoder()
    for datagram in datagrams:
        assert len(datagram) <= 1200
        decoder.receive_datagram(datagram, ADDR, T0 + 0.1)
    (event,) = drain(decoder)
    assert isinstance(event, MessageReassembled)
    assert event.payload == payload
    assert event.message == replace(message, receiver="ground", t_sent=T0, t_rcv=T0 + 0.1)
