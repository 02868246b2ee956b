"""Attacks on the fleet link (docs/security.md): crafted, authenticated-looking datagrams that
reach the body parsers, replays, another fleet's key, a forged sender, and a flood of
unauthenticated datagrams. Nothing raises out of the decoder, memory stays within its
limits, every drop is counted, and authenticated traffic still gets through."""

from __future__ import annotations

import random
import time
from dataclasses import replace

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from companion.protocol import (
    Decoder,
    DecoderLimits,
    Encoder,
    Event,
    MessageReassembled,
    PacketDropped,
)
from companion.protocol.wire import DATA_FIXED, PacketKind, pack_datagram
from utility_specs.message import Message

T0 = 1_700_000_000.0
KEY = bytes(range(32))
OTHER_KEY = bytes(range(100, 132))
FLEET = 42
ADDR = ("127.0.0.1", 40000)
LIMITS = DecoderLimits(max_message_bytes=64 << 10, max_buffered_bytes=128 << 10,
                       max_partials=4, max_fragments=64, max_senders=4,
                       max_pending_events=64, recent_messages=32, replay_window=64)


def _message(seq: int, sender: str = "drone1") -> Message:
    return Message(sender=sender, seq=seq, type="image", t_gen=T0 - 0.1, size=3000,
                   data={"red": 0.5})


def _drain(decoder: Decoder) -> list[Event]:
    events = []
    while (event := decoder.next_event()) is not None:
        events.append(event)
    return events


def _delivered(events: list[Event]) -> list[int]:
    return [e.message.seq for e in events if isinstance(e, MessageReassembled)]


@st.composite
def crafted_data(draw: st.DrawFn) -> bytes:
    """A correctly tagged DATA datagram (as any holder of the fleet key can make) whose
    fragment fields and body are hostile: huge counts, indices out of range, lengths that
    lie, empty or 64 kB bodies."""
    count = draw(st.one_of(st.integers(0, 3), st.just(0xFFFF), st.integers(0, 0xFFFF)))
    index = draw(st.one_of(st.integers(0, 3), st.just(0xFFFF), st.integers(0, 0xFFFF)))
    total = draw(st.one_of(st.integers(0, 5000), st.just(0xFFFF_FFFF)))
    mtype = draw(st.binary(min_size=0, max_size=40))
    fixed = DATA_FIXED.pack(draw(st.integers(0, 2**32 - 1)), T0, index, count, total,
                            min(len(mtype), 255))
    tail = draw(st.one_of(st.binary(max_size=300), st.just(b"\0" * 60_000),
                          st.just(b"{}" * 10)))
    body = (fixed + mtype + tail)[: draw(st.integers(0, 65_000))]
    sender = draw(st.sampled_from([b"drone1", b"d2", b"x" * 32, b"\xff\xfe"]))
    return pack_datagram(key=KEY, kind=PacketKind.DATA, fleet_id=FLEET,
                         packet_number=draw(st.integers(0, 2**64 - 1)), t_sent=T0,
                         sender_raw=sender, body=body[:0xFFFF - 200])


@given(st.lists(st.one_of(crafted_data(), st.binary(max_size=2000),
                          st.just(b""), st.just(b"\x00" * 65_536)), max_size=40))
@settings(max_examples=50, deadline=None, suppress_health_check=[HealthCheck.too_slow])
def test_crafted_datagrams_never_raise_and_stay_bounded(datagrams: list[bytes]) -> None:
    decoder = Decoder(FLEET, KEY, local_id="ground", limits=LIMITS)
    for i, data in enumerate(datagrams):
        decoder.receive_datagram(data, ADDR, T0 + i * 0.01)
        assert decoder.buffered_bytes <= LIMITS.max_buffered_bytes
        assert decoder.partial_count <= LIMITS.max_partials
        assert decoder.sender_count <= LIMITS.max_senders
    events = _drain(decoder)
    assert len(events) <= LIMITS.max_pending_events
    counts = decoder.counters
    assert counts["datagrams"] == len(datagrams)
    # every datagram is either accepted or counted under one drop reason
    rejected = sum(counts[k] for k in ("malformed", "unsupported_version", "wrong_fleet",
                                       "bad_tag", "stale", "replayed", "oversize",
                                       "late_fragment", "duplicate_fragment"))
    assert counts["accepted"] + rejected >= len(datagrams)
    decoder.handle_timer(T0 + 3600)  # everything partial expires
    assert decoder.partial_count == 0 and decoder.buffered_bytes == 0


def test_replay_other_fleet_and_forged_sender_are_rejected_and_counted() -> None:
    encoder = Encoder(FLEET, "drone1", KEY)
    decoder = Decoder(FLEET, KEY, local_id="ground", limits=LIMITS)
    (good,) = encoder.fragment(_message(1), b"jpeg", now=T0)
    decoder.receive_datagram(good, ADDR, T0)
    decoder.receive_datagram(good, ADDR, T0 + 0.5)  # replayed as captured
    (foreign,) = Encoder(FLEET, "drone1", OTHER_KEY).fragment(_message(2), b"x", now=T0)
    decoder.receive_datagram(foreign, ADDR, T0)  # another fleet's key, same fleet id
    (other_id,) = Encoder(FLEET + 1, "drone1", KEY).fragment(_message(3), b"x", now=T0)
    decoder.receive_datagram(other_id, ADDR, T0)
    forged = bytearray(encoder.fragment(_message(4), b"x", now=T0)[0])
    forged[27:33] = b"drone9"  # the sender id rewritten, the tag kept
    decoder.receive_datagram(bytes(forged), ADDR, T0)
    events = _drain(decoder)
    assert _delivered(events) == [1]
    c = decoder.counters
    assert (c["replayed"], c["bad_tag"], c["wrong_fleet"]) == (1, 2, 1)
    assert sorted(e.reason for e in events if isinstance(e, PacketDropped)) == \
        ["bad_tag", "bad_tag", "replayed", "wrong_fleet"]


def test_a_flood_in_one_batch_does_not_push_out_authenticated_messages() -> None:
    """Before the fix a batch holding more junk than ``max_pending_events`` evicted the
    MessageReassembled events queued before it (and the decoder, remembering the message
    as complete, dropped its retransmissions as late): a flood erased real images."""
    rng = random.Random(1)
    encoder = Encoder(FLEET, "drone1", KEY)
    decoder = Decoder(FLEET, KEY, local_id="ground", limits=LIMITS)
    batch = []
    for seq in range(10):
        batch += [(d, ADDR) for d in encoder.fragment(_message(seq), rng.randbytes(3000),
                                                      now=T0)]
        batch += [(rng.randbytes(rng.randint(0, 1400)), ADDR) for _ in range(100)]
    decoder.receive_datagrams(batch, T0)
    assert _delivered(_drain(decoder)) == list(range(10))
    assert decoder.counters["events_overflow"] > 0  # junk notices went, counted


def test_a_flood_of_forgeries_does_not_starve_the_fleet() -> None:
    """50 000 forged datagrams (random bytes, right-looking headers with a wrong tag) mixed
    with a drone's real traffic: every real message arrives, and the cost of a forgery is
    small enough (measured, printed) that the station's 1-core budget outruns a radio."""
    rng = random.Random(2)
    encoder = Encoder(FLEET, "drone1", KEY)
    (template,) = encoder.fragment(_message(999), b"x" * 900, now=T0)
    forged_header = [template[:-16] + rng.randbytes(16) for _ in range(100)]
    junk = [rng.randbytes(rng.randint(1, 1400)) for _ in range(100)]
    decoder = Decoder(FLEET, KEY, local_id="ground")  # the station's default limits
    real = []
    for seq in range(50):
        real.append(encoder.fragment(replace(_message(seq), size=900), b"y" * 900, now=T0))
    t = time.perf_counter()
    for seq in range(50):
        batch = [((forged_header if i % 2 else junk)[i % 100], ADDR) for i in range(1000)]
        batch[500:500] = [(d, ADDR) for d in real[seq]]
        decoder.receive_datagrams(batch, T0 + seq * 0.01)
        assert _delivered(_drain(decoder)) == [seq]
    elapsed = time.perf_counter() - t
    per_forgery_us = elapsed / 50_000 * 1e6
    print(f"forged datagram cost: {per_forgery_us:.1f} us "
          f"({1e6 / per_forgery_us:,.0f}/s on one core)")
    assert decoder.counters["bad_tag"] == 25_000
    assert decoder.counters["malformed"] + decoder.counters["unsupported_version"] \
        + decoder.counters["wrong_fleet"] + decoder.counters["bad_tag"] \
        + decoder.counters["oversize"] == 50_000
    # generous (shared, noisy CI): a 2 Mbit/s radio carries < 200 full datagrams per second
    assert per_forgery_us < 200
