"""``Encoder.fragment`` packs its datagrams inline; they are byte for byte what
``pack_datagram`` makes of the same fragments (the documented layout)."""

from __future__ import annotations

from dataclasses import replace

from hypothesis import given, settings
from hypothesis import strategies as st
from protocol_helpers import FLEET, KEY, T0, image_message

from companion.protocol import Encoder
from companion.protocol.encoder import message_metadata
from companion.protocol.wire import (
    DATA_FIXED,
    METADATA_LEN,
    OVERHEAD_BYTES,
    PacketKind,
    dumps_json,
    pack_datagram,
)


def reference_fragments(
    sender: str, message: object, payload: bytes, now: float, first_pn: int, budget: int
) -> list[bytes]:
    """The layout of protocol.md, one pack_datagram per fragment."""
    type_raw = message.type.encode()  # type: ignore[attr-defined]
    metadata = dumps_json(message_metadata(message), "metadata")  # type: ignore[arg-type]
    body_budget = budget - OVERHEAD_BYTES - len(sender.encode())
    capacity = body_budget - DATA_FIXED.size - len(type_raw)
    first = capacity - METADATA_LEN.size - len(metadata)
    sizes = [min(len(payload), first)]
    while sum(sizes) < len(payload):
        sizes.append(min(capacity, len(payload) - sum(sizes)))
    out, start = [], 0
    for index, size in enumerate(sizes):
        body = DATA_FIXED.pack(message.seq, message.t_gen, index, len(sizes),  # type: ignore[attr-defined]
                               len(payload), len(type_raw)) + type_raw
        if index == 0:
            body += METADATA_LEN.pack(len(metadata)) + metadata
        body += payload[start : start + size]
        start += size
        out.append(pack_datagram(key=KEY, kind=PacketKind.DATA, fleet_id=FLEET,
                                 packet_number=first_pn + index, t_sent=now,
                                 sender_raw=sender.encode(), body=body))
    return out


@settings(max_examples=60, deadline=None)
@given(
    size=st.integers(0, 9000),
    budget=st.sampled_from([400, 1200]),
    seq=st.integers(0, 2**32 - 1),
    sender=st.sampled_from(["d", "drone07", "ü" * 16]),
    messages=st.integers(1, 3),
)
def test_fragments_are_the_documented_layout(
    size: int, budget: int, seq: int, sender: str, messages: int
) -> None:
    encoder = Encoder(FLEET, sender, KEY, max_datagram_bytes=budget)
    pn = int(T0) << 32
    for i in range(messages):
        message = replace(image_message(seq=seq), sender=sender, size=size)
        payload = bytes((j * 7 + i) % 251 for j in range(size))
        got = encoder.fragment(message, payload, T0 + i)
        assert got == reference_fragments(sender, message, payload, T0 + i, pn, budget)
        assert all(len(d) <= budget for d in got)
        pn += len(got)
