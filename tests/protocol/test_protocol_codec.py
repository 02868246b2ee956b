"""The sans-I/O codec: round trips, reassembly, loss, and every way a datagram is rejected."""

from __future__ import annotations

import random
import struct
from dataclasses import replace

import pytest
from protocol_helpers import (
    ADDR,
    FLEET,
    KEY,
    T0,
    drain,
    image_message,
    make_decoder,
    make_encoder,
    transfer,
)

from companion.protocol import (
    MAX_DATAGRAM_BYTES,
    TAG_BYTES,
    ClockEcho,
    Command,
    CommandReceived,
    Decoder,
    Encoder,
    LocalProtocolError,
    MessageExpired,
    MessageReassembled,
    PacketDropped,
    PacketKind,
    Report,
    ReportEntry,
    ReportReceived,
    Status,
    StatusReceived,
    clock_sample,
    entry_from_message,
    message_metadata,
    report_messages,
)
from companion.protocol.wire import HEADER, PROTOCOL_VERSION, dumps_json, pack_datagram
from utility_specs.message import Message

# Bytes around the payload in every DATA datagram of sender "drone1", type "image":
# common header 27 + sender 6 + tag 16 + DATA fixed part 21 + type 5.
DATA_OVERHEAD = 27 + 6 + TAG_BYTES + 21 + 5


def payload_bytes(n: int, seed: int = 0) -> bytes:
    return random.Random(seed).randbytes(n)


def reasons(events: list[object]) -> list[str]:
    return [e.reason for e in events if isinstance(e, PacketDropped)]


def only(events: list[object], kind: type) -> list:  # type: ignore[type-arg]
    return [e for e in events if isinstance(e, kind)]


# -- DATA round trips -------------------------------------------------------------------


def test_telemetry_without_payload_is_one_datagram_and_round_trips() -> None:
    encoder, decoder = make_encoder(), make_decoder()
    message = Message(
        sender="drone1", seq=7, type="battery", t_gen=T0 - 0.5, size=40, data={"level": 0.81}
    )
    datagrams = encoder.fragment(message, b"", now=T0)
    assert len(datagrams) == 1
    events = transfer(datagrams, decoder, now=T0 + 0.125)
    assert events == [
        MessageReassembled(
            message=replace(message, receiver="ground", t_sent=T0, t_rcv=T0 + 0.125),
            payload=b"",
            addr=ADDR,
            t_rcv=T0 + 0.125,
            fragments=1,
        )
    ]
    assert decoder.counters["messages"] == 1
    assert decoder.get_timer() is None


def test_image_is_split_into_full_datagrams_and_reassembled_in_any_order() -> None:
    encoder, decoder = make_encoder(), make_decoder()
    message = image_message(size=20_000)
    payload = payload_bytes(20_000)
    datagrams = encoder.fragment(message, payload, now=T0)

    metadata_len = len(
        b'{"z":20000,"d":{"red":0.25,"object":true,"lat_deg":50.06,"alt_rel_m":30.5},'
        b'"v":[["full",20000,1.0],["half",5000,0.5]],"i":0}'
    )
    capacity = MAX_DATAGRAM_BYTES - DATA_OVERHEAD
    first = capacity - 2 - metadata_len
    assert len(datagrams) == 1 + -(-(20_000 - first) // capacity)
    assert all(len(d) == MAX_DATAGRAM_BYTES for d in datagrams[:-1])
    assert len(datagrams[-1]) == DATA_OVERHEAD + (20_000 - first) % capacity

    shuffled = datagrams[:]
    random.Random(3).shuffle(shuffled)
    assert shuffled != datagrams
    events = transfer(shuffled, decoder, now=T0 + 0.5)
    assert len(events) == 1
    event = events[0]
    assert isinstance(event, MessageReassembled)
    assert event.payload == payload
    assert event.fragments == len(datagrams)
    assert event.message == replace(message, receiver="ground", t_sent=T0, t_rcv=T0 + 0.5)
    assert event.message.quality == 1.0
    assert decoder.buffered_bytes == 0 and decoder.partial_count == 0


def test_message_carrying_a_lower_version_keeps_its_quality() -> None:
    encoder, decoder = make_encoder(), make_decoder()
    message = image_message(size=8000).with_version(1)
    events = transfer(encoder.fragment(message, payload_bytes(2000), now=T0), decoder, now=T0)
    (event,) = events
    assert isinstance(event, MessageReassembled)
    assert event.message.version == 1 and event.message.quality == 0.5
    assert event.message.size == 2000


def test_clock_of_sender_ahead_keeps_message_valid_and_raw_t_rcv() -> None:
    encoder, decoder = make_encoder(), make_decoder()
    message = image_message(t_gen=T0 + 2.0)  # drone clock 2 s ahead of the ground
    (event,) = transfer(encoder.fragment(message, b"x", now=T0 + 2.0), decoder, now=T0)
    assert isinstance(event, MessageReassembled)
    assert event.t_rcv == T0
    assert event.message.t_rcv == T0 + 2.0


# -- loss, timers, duplicates -----------------------------------------------------------


def test_lost_fragment_expires_exactly_at_the_reassembly_deadline() -> None:
    encoder, decoder = make_encoder(), make_decoder(reassembly_timeout_s=2.5)
    datagrams = encoder.fragment(image_message(size=6000), payload_bytes(6000), now=T0)
    assert len(datagrams) == 6
    decoder.receive_datagram(datagrams[0], ADDR, T0 + 0.25)
    assert decoder.get_timer() == T0 + 0.25 + 2.5
    for d in datagrams[1:3] + datagrams[4:]:
        decoder.receive_datagram(d, ADDR, T0 + 0.5)
    assert drain(decoder) == []
    deadline = T0 + 0.5 + 2.5
    assert decoder.get_timer() == deadline
    # Everything but the lost (full) fragment 3, plus the metadata of fragment 0.
    metadata = dumps_json(message_metadata(image_message(size=6000)), "metadata")
    capacity = MAX_DATAGRAM_BYTES - DATA_OVERHEAD
    assert decoder.buffered_bytes == 6000 - capacity + len(metadata)

    decoder.handle_timer(deadline - 0.001)
    assert drain(decoder) == []
    decoder.handle_timer(deadline)
    assert drain(decoder) == [
        MessageExpired(
            sender="drone1",
            seq=1,
            type="image",
            fragments_missing=1,
            fragment_count=6,
            evicted=False,
        )
    ]
    assert decoder.get_timer() is None
    assert decoder.buffered_bytes == 0
    assert decoder.counters["expired"] == 1

    # The missing fragment arriving late does not start a new partial message.
    decoder.receive_datagram(datagrams[3], ADDR, deadline + 0.1)
    assert reasons(drain(decoder)) == ["late_fragment"]
    assert decoder.partial_count == 0


def test_same_datagram_twice_is_a_replay_and_message_arrives_once() -> None:
    encoder, decoder = make_encoder(), make_decoder()
    datagrams = encoder.fragment(image_message(size=3000), payload_bytes(3000), now=T0)
    events = transfer([datagrams[0], *datagrams, datagrams[-1]], decoder, now=T0)
    assert reasons(events) == ["replayed", "replayed"]
    assert len(only(events, MessageReassembled)) == 1
    assert decoder.counters["replayed"] == 2


def test_reencoded_fragments_count_as_duplicates_then_late() -> None:
    encoder, decoder = make_encoder(), make_decoder()
    message = image_message(size=3000)
    first = encoder.fragment(message, payload_bytes(3000), now=T0)
    again = encoder.fragment(message, payload_bytes(3000), now=T0)  # new packet numbers
    events = transfer([first[0], again[0], *first[1:], again[1]], decoder, now=T0)
    assert reasons(events) == ["duplicate_fragment", "late_fragment"]
    assert len(only(events, MessageReassembled)) == 1


def test_restarted_sender_reusing_seq_is_not_mistaken_for_a_duplicate() -> None:
    decoder = make_decoder()
    first = make_encoder().fragment(image_message(seq=0, t_gen=T0), b"a", now=T0)
    second = make_encoder().fragment(image_message(seq=0, t_gen=T0 + 10), b"b", now=T0 + 10)
    events = transfer(first, decoder, now=T0) + transfer(second, decoder, now=T0 + 10)
    assert [e.payload for e in only(events, MessageReassembled)] == [b"a", b"b"]


# -- rejection ---------------------------------------------------------------------------


def telemetry_datagram(encoder: Encoder, seq: int = 1, now: float = T0) -> bytes:
    message = Message(sender=encoder.sender, seq=seq, type="position", t_gen=now, size=30)
    (datagram,) = encoder.fragment(message, b"", now=now)
    return datagram


@pytest.mark.parametrize("position", [0, 30, 60, -TAG_BYTES - 1, -1])
def test_any_flipped_byte_is_rejected(position: int) -> None:
    decoder = make_decoder()
    datagram = bytearray(telemetry_datagram(make_encoder()))
    datagram[position] ^= 0x01
    decoder.receive_datagram(bytes(datagram), ADDR, T0)
    (event,) = drain(decoder)
    assert isinstance(event, PacketDropped)
    assert event.reason == ("malformed" if position == 0 else "bad_tag")
    assert decoder.counters["accepted"] == 0


def test_other_fleet_key_is_a_bad_tag() -> None:
    decoder = make_decoder()
    datagram = telemetry_datagram(Encoder(FLEET, "drone1", b"another key of 32 bytes........."))
    assert reasons(transfer([datagram], decoder, now=T0)) == ["bad_tag"]


def test_wrong_fleet_and_unsupported_version() -> None:
    decoder = make_decoder()
    other_fleet = telemetry_datagram(Encoder(FLEET + 1, "drone1", KEY))
    future = bytearray(telemetry_datagram(make_encoder(), seq=2))
    future[2] = PROTOCOL_VERSION + 1
    assert reasons(transfer([other_fleet, bytes(future)], decoder, now=T0)) == [
        "wrong_fleet",
        "unsupported_version",
    ]


def test_every_truncation_is_malformed() -> None:
    decoder = make_decoder()
    datagram = make_encoder().fragment(image_message(size=900), payload_bytes(900), now=T0)[0]
    for n in range(len(datagram)):
        decoder.receive_datagram(datagram[:n], ADDR, T0)
    assert decoder.counters["malformed"] == len(datagram)
    assert decoder.counters["accepted"] == 0


def test_oversize_datagram_message_and_fragment_count() -> None:
    decoder = make_decoder()
    too_long = telemetry_datagram(Encoder(FLEET, "drone1", KEY, max_datagram_bytes=1400), now=T0)
    padded = Encoder(FLEET, "drone1", KEY, max_datagram_bytes=1400).fragment(
        image_message(), payload_bytes(1300), now=T0 + 1
    )[0]
    assert len(too_long) < MAX_DATAGRAM_BYTES < len(padded)
    assert reasons(transfer([too_long, padded], decoder, now=T0)) == ["oversize"]

    decoder = make_decoder(max_message_bytes=4000)
    big = make_encoder().fragment(image_message(), payload_bytes(4001), now=T0)
    assert set(reasons(transfer(big, decoder, now=T0))) == {"oversize"}

    decoder = make_decoder(max_fragments=3)
    many = make_encoder().fragment(image_message(), payload_bytes(4000), now=T0)
    assert len(many) == 4
    assert set(reasons(transfer(many, decoder, now=T0))) == {"oversize"}
    assert decoder.partial_count == 0 and decoder.buffered_bytes == 0


def test_stale_packets_are_rejected_but_a_few_seconds_of_skew_is_fine() -> None:
    decoder = make_decoder()
    encoder = make_encoder()
    ok_behind = telemetry_datagram(encoder, seq=1, now=T0 - 5.0)
    ok_ahead = telemetry_datagram(encoder, seq=2, now=T0 + 29.0)
    stale = telemetry_datagram(encoder, seq=3, now=T0 - 30.5)
    events = transfer([ok_behind, ok_ahead, stale], decoder, now=T0)
    assert len(only(events, MessageReassembled)) == 2
    assert reasons(events) == ["stale"]


def test_replay_window_accepts_reordering_inside_and_rejects_outside() -> None:
    decoder = make_decoder(replay_window=8)
    encoder = make_encoder()
    datagrams = [telemetry_datagram(encoder, seq=i) for i in range(10)]
    events = transfer([datagrams[9], datagrams[2], datagrams[1], datagrams[8]], decoder, now=T0)
    assert [e.message.seq for e in only(events, MessageReassembled)] == [9, 2, 8]
    assert reasons(events) == ["replayed"]


def test_replay_state_is_forgotten_after_twice_the_skew_of_silence() -> None:
    # A drone ran briefly, then rebooted with its clock 15 s behind: its packet numbers,
    # seeded from its clock, restart lower than those the ground last saw.
    decoder = make_decoder(max_clock_skew_s=20.0)
    before = telemetry_datagram(make_encoder(), seq=1, now=T0)
    rebooted = make_encoder()
    early = telemetry_datagram(rebooted, seq=1, now=T0 + 10.0 - 15.0)
    later = telemetry_datagram(rebooted, seq=2, now=T0 + 41.0 - 15.0)
    assert reasons(transfer([before], decoder, now=T0)) == []
    assert reasons(transfer([early], decoder, now=T0 + 10.0)) == ["replayed"]
    # 41 s after the last accepted packet (> 2 x 20 s) the window is forgotten.
    events = transfer([later], decoder, now=T0 + 41.0)
    assert len(only(events, MessageReassembled)) == 1
    # The old packet is stale by now, so forgetting its number opened no replay.
    assert reasons(transfer([before], decoder, now=T0 + 41.0)) == ["stale"]


def test_bad_metadata_under_a_valid_tag_is_malformed() -> None:
    decoder = make_decoder()
    header = struct.pack("!IdHHIB", 1, T0, 0, 1, 0, 5) + b"image"
    bodies = [
        header + struct.pack("!H", 5) + b"{bad}",
        header + struct.pack("!H", 4) + b"[1 ]",
        header + struct.pack("!H", 13) + b'{"z":1,"i":3}',  # version index without versions
        header + struct.pack("!H", 9) + b'{"z":-10}',
        header + struct.pack("!H", 30),  # metadata length beyond the body
        struct.pack("!IdHHIB", 1, T0, 1, 1, 0, 5) + b"image",  # index 1 of 1
        struct.pack("!IdHHIB", 1, float("nan"), 0, 1, 0, 5) + b"image",
    ]
    for pn, body in enumerate(bodies):
        datagram = pack_datagram(
            key=KEY,
            kind=PacketKind.DATA,
            fleet_id=FLEET,
            packet_number=pn,
            t_sent=T0,
            sender_raw=b"drone1",
            body=body,
        )
        decoder.receive_datagram(datagram, ADDR, T0)
    assert reasons(drain(decoder)) == ["malformed"] * len(bodies)
    assert decoder.counters["accepted"] == len(bodies)


@pytest.mark.parametrize(
    "report_json",
    [
        b'{"e":[["drone1",1,"image",1' + b"0" * 400 + b',null,1.0,5,null,1.0,{}]],"c":[]}',
        b'{"e":[],"c":[["drone1",1e999,2.0]]}',
        b'{"e":[["drone1",1,"image",1.0,null,2.0,5,null,0.0,{}]],"c":[]}',
        b'{"e":[["drone1",true,"image",1.0,null,2.0,5,null,1.0,{}]],"c":[]}',
        b'{"e":[["drone1",1,"image",1.0,null,2.0,5,null,1.0]],"c":[]}',
        b'{"e":{},"c":[]}',
        b'{"e":[],"c":[["drone1",NaN,2.0]]}',
        b"[" * 500 + b"]" * 500,
    ],
)
def test_bad_report_under_a_valid_tag_is_malformed(report_json: bytes) -> None:
    decoder = make_decoder()
    datagram = pack_datagram(
        key=KEY,
        kind=PacketKind.REPORT,
        fleet_id=FLEET,
        packet_number=1,
        t_sent=T0,
        sender_raw=b"ground",
        body=struct.pack("!IHH", 1, 0, 1) + report_json,
    )
    decoder.receive_datagram(datagram, ADDR, T0)
    assert reasons(drain(decoder)) == ["malformed"]


# -- memory bounds -----------------------------------------------------------------------


def test_oldest_partial_is_evicted_when_too_many_are_open() -> None:
    decoder = make_decoder(max_partials=2)
    encoder = make_encoder()
    for seq, now in ((1, T0), (2, T0 + 0.1), (3, T0 + 0.2)):
        first = encoder.fragment(image_message(seq=seq), payload_bytes(3000), now=now)[0]
        decoder.receive_datagram(first, ADDR, now)
    events = drain(decoder)
    assert events == [
        MessageExpired(
            sender="drone1",
            seq=1,
            type="image",
            fragments_missing=2,
            fragment_count=3,
            evicted=True,
        )
    ]
    assert decoder.partial_count == 2
    assert decoder.counters["evicted"] == 1


def test_buffered_bytes_never_exceed_the_bound() -> None:
    decoder = make_decoder(max_message_bytes=5000, max_buffered_bytes=5000)
    encoder = make_encoder()
    bound_seen = 0
    for seq in range(1, 5):
        datagrams = encoder.fragment(image_message(seq=seq), payload_bytes(4500), now=T0)
        for d in datagrams[:-1]:
            decoder.receive_datagram(d, ADDR, T0)
            assert decoder.buffered_bytes <= 5000
            bound_seen = max(bound_seen, decoder.buffered_bytes)
    assert bound_seen > 3000
    assert decoder.counters["evicted"] >= 2


def test_pending_events_are_bounded() -> None:
    decoder = make_decoder(max_pending_events=3)
    for _ in range(5):
        decoder.receive_datagram(b"junk", ADDR, T0)
    assert len(drain(decoder)) == 3
    assert decoder.counters["events_overflow"] == 2
    assert decoder.counters["malformed"] == 5


# -- reports, commands, status ----------------------------------------------------------


def make_entries(n: int) -> tuple[ReportEntry, ...]:
    return tuple(
        entry_from_message(
            replace(image_message(seq=i, size=1000 + i), t_sent=T0 - 0.2), t_rcv=T0 - 0.1
        )
        for i in range(n)
    )


def test_report_round_trip_in_one_datagram() -> None:
    ground, drone = make_encoder("ground"), make_decoder()
    report = Report(
        entries=make_entries(3),
        echoes=(ClockEcho(sender="drone1", t_sent=T0 - 0.3, t_rcv=T0 - 0.25),),
    )
    datagrams = ground.encode_report(report, now=T0)
    assert len(datagrams) == 1
    events = transfer(datagrams, drone, now=T0 + 0.05)
    assert events == [
        ReportReceived(
            report=report,
            reporter="ground",
            report_number=1,
            part_index=0,
            part_count=1,
            t_sent=T0,
            t_rcv=T0 + 0.05,
            addr=ADDR,
        )
    ]


def test_large_report_is_split_into_self_contained_datagrams() -> None:
    ground, drone = make_encoder("ground"), make_decoder()
    entries = make_entries(40)
    echoes = tuple(
        ClockEcho(sender=f"drone{i}", t_sent=T0 - i, t_rcv=T0 - i + 0.5) for i in range(5)
    )
    ground.encode_report(Report(), now=T0 - 1)  # report number 1
    datagrams = ground.encode_report(Report(entries=entries, echoes=echoes), now=T0)
    assert len(datagrams) > 2
    assert all(len(d) <= MAX_DATAGRAM_BYTES for d in datagrams)
    # Lose the second datagram: the others still decode on their own.
    events = transfer(datagrams, drone, now=T0, drop=lambda i: i == 1)
    parts = only(events, ReportReceived)
    assert [p.part_index for p in parts] == [0, *range(2, len(datagrams))]
    assert {p.report_number for p in parts} == {2}
    assert {p.part_count for p in parts} == {len(datagrams)}
    assert parts[0].report.echoes == echoes
    assert all(p.report.echoes == () for p in parts[1:])
    received = [e for p in parts for e in p.report.entries]
    lost = ground_entries_in(datagrams[1])
    assert received == [e for e in entries if e.seq not in lost]


def ground_entries_in(datagram: bytes) -> set[int]:
    decoder = make_decoder()
    (event,) = transfer([datagram], decoder, now=T0)
    assert isinstance(event, ReportReceived)
    return {e.seq for e in event.report.entries}


def test_report_entries_become_delivered_messages() -> None:
    entry = ReportEntry(
        sender="drone2",
        seq=4,
        type="image",
        t_gen=T0,
        t_sent=T0 + 0.1,
        t_rcv=T0 - 0.5,
        size=900,
        version=1,
        quality=0.5,
        data={"red": 0.5},
    )
    (message,) = report_messages([entry], receiver="ground")
    assert message.receiver == "ground"
    assert message.t_rcv == T0  # clamped: ground clock behind the drone's
    assert message.quality == 0.5 and message.size == 900
    assert message.data == {"red": 0.5}
    plain = replace(entry, version=None, quality=1.0, t_rcv=T0 + 1.0)
    (message,) = report_messages([plain], receiver="ground")
    assert message.versions == () and message.t_rcv == T0 + 1.0


def test_clock_sample_is_ntp_offset_and_round_trip() -> None:
    echo = ClockEcho(sender="drone1", t_sent=100.0, t_rcv=100.5)
    sample = clock_sample(echo, t_report_sent=101.0, t_report_rcv=100.75)
    assert sample.offset_s == 0.375
    assert sample.rtt_s == 0.25


@pytest.mark.parametrize("target", [None, "drone2"])
def test_command_round_trip(target: str | None) -> None:
    ground, drone = make_encoder("ground"), make_decoder()
    command = Command(
        command_id=17,
        name="set_params",
        t_exec=T0 + 5.0,
        args={"alpha": 10, "mcts_iterations": 300},
        target=target,
    )
    events = transfer([ground.encode_command(command, now=T0)], drone, now=T0 + 0.01)
    assert events == [
        CommandReceived(command=command, sender="ground", t_sent=T0, t_rcv=T0 + 0.01, addr=ADDR)
    ]


@pytest.mark.parametrize("command_id", [None, 17])
def test_status_round_trip(command_id: int | None) -> None:
    encoder, ground = make_encoder(), make_decoder()
    status = Status(state="done", command_id=command_id, info={"alpha": 10.0, "mode": "AUTO"})
    events = transfer([encoder.encode_status(status, now=T0)], ground, now=T0)
    assert events == [
        StatusReceived(status=status, sender="drone1", t_sent=T0, t_rcv=T0, addr=ADDR)
    ]


# -- the sending side refuses what the wire cannot carry --------------------------------


def test_encoder_refuses_what_the_wire_cannot_carry() -> None:
    encoder = make_encoder()
    with pytest.raises(LocalProtocolError, match="sender id"):
        Encoder(FLEET, "d" * 33, KEY)
    with pytest.raises(LocalProtocolError, match="at least 16 bytes"):
        Encoder(FLEET, "drone1", b"short")
    with pytest.raises(LocalProtocolError, match="not this encoder"):
        encoder.fragment(replace(image_message(), sender="drone2"), b"", now=T0)
    with pytest.raises(LocalProtocolError, match="metadata"):
        encoder.fragment(replace(image_message(), data={"cells": list(range(400))}), b"", now=T0)
    with pytest.raises(LocalProtocolError, match="JSON"):
        encoder.fragment(replace(image_message(), data={"alt_rel_m": float("nan")}), b"", now=T0)
    with pytest.raises(LocalProtocolError, match="message type"):
        encoder.fragment(replace(image_message(), type="t" * 40), b"", now=T0)


def test_packet_numbers_start_from_the_clock_and_increase() -> None:
    encoder = make_encoder()
    numbers = [
        HEADER.unpack_from(d)[4]
        for d in encoder.fragment(image_message(), payload_bytes(3000), now=T0 + 0.7)
    ]
    assert numbers == [(int(T0) << 32) + i for i in range(3)]


def test_decoder_rejects_a_short_key() -> None:
    with pytest.raises(LocalProtocolError):
        Decoder(FLEET, b"0123")
