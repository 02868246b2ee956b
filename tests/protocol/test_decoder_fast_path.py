"""The decoder's inlined DATA path (``receive_datagrams``) agrees with the general one.

``Decoder.receive_datagrams`` handles an in-order DATA datagram of a known sender without a
call per check; everything else goes through ``_receive_one``. The reference below sends
every datagram through ``_receive_one``: both must produce the same events, counters and
state for any stream (hostile, replayed, stale, out of order, restored replay floors), in
bursts of any size.
"""

from __future__ import annotations

import random
from collections.abc import Sequence
from dataclasses import replace

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from protocol_helpers import ADDR, FLEET, KEY, T0, drain, image_message
from test_protocol_fuzz import CORPUS, LIMITS, mutated, signed_structured

from companion.protocol import Decoder, DecoderLimits, Encoder, MessageReassembled
from companion.protocol.decoder import Address
from companion.protocol.errors import RemoteProtocolError
from tests.keys import TEST_COMMAND_PUB


class ReferenceDecoder(Decoder):
    """Every datagram through the general path, one at a time."""

    def receive_datagrams(self, datagrams: Sequence[tuple[bytes, Address]], now: float) -> None:
        for data, addr in datagrams:
            self.counters["datagrams"] += 1
            try:
                self._receive_one(bytes(data), addr, now)
            except RemoteProtocolError as exc:
                self._refuse(exc, addr)


def pair(**limits: object) -> tuple[Decoder, Decoder]:
    made = []
    for cls in (Decoder, ReferenceDecoder):
        made.append(cls(FLEET, KEY, local_id="ground", command_key=TEST_COMMAND_PUB,
                        limits=DecoderLimits(**limits)))  # type: ignore[arg-type]
    return made[0], made[1]


def snapshot(decoder: Decoder) -> tuple[object, ...]:
    return (
        drain(decoder),
        dict(decoder.counters),
        decoder.buffered_bytes,
        decoder.partial_count,
        decoder.sender_count,
        decoder.get_timer(),
        decoder.replay_state(T0 + 1000),
    )


def streams() -> st.SearchStrategy[list[bytes]]:
    """Valid fragments of several senders (so the fast path is taken), hostile datagrams,
    and datagrams sent 40 s off the receiver's clock (stale)."""
    rng = random.Random(3)
    valid: list[bytes] = []
    for i, sender in enumerate(["drone1", "drone2", "d3"]):
        encoder = Encoder(FLEET, sender, KEY)
        for seq in range(4):
            payload = rng.randbytes(rng.choice([0, 900, 2500, 4000]))
            valid += encoder.fragment(replace(image_message(seq=seq), sender=sender), payload,
                                      now=T0 + i * 0.01 + seq * 0.001)
        stale = Encoder(FLEET, sender, KEY)
        valid += stale.fragment(replace(image_message(seq=9), sender=sender),
                                rng.randbytes(2500), now=T0 - 40.0)
    one = st.one_of(st.sampled_from(valid), st.sampled_from(valid), mutated(),
                    signed_structured(), st.sampled_from(CORPUS), st.binary(max_size=80))
    return st.lists(one, min_size=1, max_size=40)


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    datagrams=streams(),
    bursts=st.lists(st.integers(1, 20), min_size=1, max_size=10),
    steps=st.lists(st.floats(0.0, 2.0), min_size=1, max_size=10),
    tight=st.booleans(),
    floors=st.booleans(),
)
def test_bursts_agree_with_the_general_path(
    datagrams: list[bytes], bursts: list[int], steps: list[float], tight: bool, floors: bool
) -> None:
    fast, reference = pair(**(LIMITS if tight else {}))
    if floors:  # a restarted receiver: the floors route datagrams to the general path
        state = {"drone2": [0, T0 - 5.0, T0 - 5.0]}
        assert fast.restore_replay_state(state, T0) == reference.restore_replay_state(state, T0)
    now, i, step = T0, 0, 0
    while i < len(datagrams):
        burst = [(data, ADDR) for data in datagrams[i : i + bursts[step % len(bursts)]]]
        i += len(burst)
        fast.receive_datagrams(burst, now)
        reference.receive_datagrams(burst, now)
        assert snapshot(fast) == snapshot(reference)
        now += steps[step % len(steps)]
        step += 1
        fast.handle_timer(now)
        reference.handle_timer(now)
    assert fast.counters["datagrams"] == len(datagrams)


def test_a_burst_with_a_replay_and_a_duplicate_fragment() -> None:
    """Exact counts for one burst: each fragment twice (the second is a replay), one message."""
    datagrams = Encoder(FLEET, "drone1", KEY).fragment(image_message(seq=1), bytes(3000), T0)
    decoder, _ = pair()
    decoder.receive_datagrams([(d, ADDR) for d in datagrams + datagrams], T0)
    events = drain(decoder)
    assert [type(e).__name__ for e in events].count("MessageReassembled") == 1
    assert decoder.counters["replayed"] == len(datagrams)
    assert decoder.counters["accepted"] == len(datagrams)
    message = next(e for e in events if isinstance(e, MessageReassembled))
    assert message.payload == bytes(3000) and message.fragments == len(datagrams) > 2


def test_a_reused_buffer_does_not_corrupt_a_message() -> None:
    """The decoder keeps views of fragments until the message is complete: a caller that
    reuses a bytearray per datagram must not change what was received."""
    payload = random.Random(5).randbytes(4000)
    datagrams = Encoder(FLEET, "drone1", KEY).fragment(image_message(seq=1), payload, T0)
    decoder, _ = pair()
    buffer = bytearray(2048)
    for data in datagrams:
        buffer[: len(data)] = data
        decoder.receive_datagram(memoryview(buffer)[: len(data)], ADDR, T0)  # type: ignore[arg-type]
        buffer[:] = bytes(2048)
    (event,) = [e for e in drain(decoder) if isinstance(e, MessageReassembled)]
    assert event.payload == payload


def test_the_inlined_path_keeps_senders_in_least_recently_heard_order() -> None:
    """With room for two senders, a third evicts the one heard least recently: A is heard
    again (inlined path) after B, so C evicts B and a replay of A is still refused."""
    decoder, _ = pair(max_senders=2)
    a, b, c = (Encoder(FLEET, name, KEY) for name in ("A", "B", "C"))

    def one(encoder: Encoder, seq: int) -> bytes:
        message = replace(image_message(seq=seq), sender=encoder.sender)
        (datagram,) = encoder.fragment(message, bytes(100), T0)
        return datagram

    a2 = one(a, 1), one(a, 2)
    decoder.receive_datagrams([(a2[0], ADDR), (one(b, 1), ADDR)], T0)
    decoder.receive_datagrams([(a2[1], ADDR)], T0)
    decoder.receive_datagrams([(one(c, 1), ADDR)], T0)
    decoder.receive_datagrams([(a2[1], ADDR)], T0)
    assert decoder.counters["replayed"] == 1
    assert decoder.counters["messages"] == 4
