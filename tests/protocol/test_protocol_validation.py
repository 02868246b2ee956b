"""Decoder-level validation: validly signed datagrams with out-of-range numbers.

Every such datagram is a counted ``malformed`` drop; nothing downstream (storage, reports,
the dashboard) ever sees a non-finite float, an integer beyond 64 bits or a negative size.
"""

from __future__ import annotations

import itertools
import json
import math
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from protocol_helpers import ADDR, FLEET, KEY, T0, drain, make_decoder

from companion.protocol import (
    MessageReassembled,
    PacketDropped,
    ReportReceived,
    StatusReceived,
)
from companion.protocol.wire import (
    DATA_FIXED,
    MAX_JSON_INT,
    METADATA_LEN,
    REPORT_FIXED,
    STATUS_FIXED,
    PacketKind,
    pack_datagram,
)

_numbers = itertools.count(1)


def signed(kind: PacketKind, body: bytes, *, sender: str = "drone1", now: float = T0) -> bytes:
    """A datagram with a valid tag (as any holder of the fleet key can make)."""
    return pack_datagram(key=KEY, kind=kind, fleet_id=FLEET, packet_number=next(_numbers),
                         t_sent=now, sender_raw=sender.encode(), body=body)


def data_datagram(meta_raw: bytes, *, payload: bytes = b"\xff\xd8jpeg", seq: int = 1) -> bytes:
    type_raw = b"image"
    body = (DATA_FIXED.pack(seq, T0 - 0.1, 0, 1, len(payload), len(type_raw)) + type_raw
            + METADATA_LEN.pack(len(meta_raw)) + meta_raw + payload)
    return signed(PacketKind.DATA, body)


def status_datagram(info_raw: bytes) -> bytes:
    return signed(PacketKind.STATUS, STATUS_FIXED.pack(7, 4) + b"done" + info_raw)


def report_datagram(body_raw: bytes) -> bytes:
    return signed(PacketKind.REPORT, REPORT_FIXED.pack(1, 0, 1) + body_raw, sender="ground")


HOSTILE_METADATA = [
    b'{"z": 9223372036854775808}',  # 2**63: the size that killed the storage writer
    b'{"z": 9223372036854775807}',  # fits 64 bits, but no message is 8 EiB
    b'{"z": -1}',
    b'{"z": 1e999}',
    b'{"z": 30000, "d": {"red": 1e999}}',
    b'{"z": 30000, "d": {"red": -1e999}}',
    b'{"z": 30000, "d": {"red": NaN}}',
    b'{"z": 30000, "d": {"alt": Infinity}}',
    b'{"z": 30000, "d": {"n": 123456789012345678901234567890}}',
    b'{"z": 30000, "d": {"deep": [[[{"n": -9223372036854775809}]]]}}',
    b'{"z": 30000, "d": {"n": ' + b"9" * 1000 + b"}}",
    b'{"z": 30000, "v": [["full", 4294967296, 1.0]], "i": 0}',
    b'{"z": 30000, "v": [["full", 30000, 1e999]], "i": 0}',
    b'{"z": 30000, "v": [["full", 30000, 1.0]], "i": -1}',
    b'{"z": 30000, "v": [["full", 30000, 1.0]], "i": 1}',
]


@pytest.mark.parametrize("meta", HOSTILE_METADATA, ids=lambda m: m[:40].decode())
def test_out_of_range_metadata_is_a_counted_malformed_drop(meta: bytes) -> None:
    decoder = make_decoder()
    decoder.receive_datagram(data_datagram(meta), ADDR, T0)
    [event] = drain(decoder)
    assert isinstance(event, PacketDropped) and event.reason == "malformed", event
    assert decoder.counters["malformed"] == 1 and decoder.counters["messages"] == 0
    # the sender is not punished beyond this datagram: its next valid image goes through
    decoder.receive_datagram(data_datagram(b'{"z": 4, "d": {"red": 0.5}}', seq=2), ADDR, T0)
    [ok] = drain(decoder)
    assert isinstance(ok, MessageReassembled) and ok.message.size == 4


def test_the_largest_valid_values_still_pass() -> None:
    decoder = make_decoder()
    meta = json.dumps({"z": 2**32 - 1, "d": {"n": MAX_JSON_INT, "m": -MAX_JSON_INT - 1,
                                               "x": 1.7976931348623157e308}}).encode()
    decoder.receive_datagram(data_datagram(meta), ADDR, T0)
    [event] = drain(decoder)
    assert isinstance(event, MessageReassembled)
    assert event.message.size == 2**32 - 1
    assert event.message.data == {"n": MAX_JSON_INT, "m": -MAX_JSON_INT - 1,
                                  "x": 1.7976931348623157e308}


@pytest.mark.parametrize("info", [b'{"text": 1e999}', b'{"level": NaN}',
                                  b'{"n": 99999999999999999999999}'])
def test_a_signed_status_with_out_of_range_numbers_is_dropped(info: bytes) -> None:
    decoder = make_decoder()
    decoder.receive_datagram(status_datagram(info), ADDR, T0)
    [event] = drain(decoder)
    assert isinstance(event, PacketDropped) and event.reason == "malformed"
    decoder.receive_datagram(status_datagram(b'{"level": 0.5}'), ADDR, T0)
    [ok] = drain(decoder)
    assert isinstance(ok, StatusReceived) and ok.status.info == {"level": 0.5}


def _entry(**change: Any) -> list[Any]:
    fields = {"sender": "drone1", "seq": 3, "type": "image", "t_gen": T0 - 1, "t_sent": T0 - 1,
              "t_rcv": T0 - 0.5, "size": 3000, "version": None, "quality": 1.0, "data": {}}
    fields.update(change)
    return list(fields.values())


@pytest.mark.parametrize("change", [{"size": -1}, {"seq": -5}, {"size": 2**63},
                                    {"size": 2**32}, {"version": -1}, {"quality": 0.0}])
def test_report_entries_out_of_range_are_dropped(change: dict[str, Any]) -> None:
    decoder = make_decoder()
    body = json.dumps({"e": [_entry(**change)], "c": []}).encode()
    decoder.receive_datagram(report_datagram(body), ADDR, T0)
    [event] = drain(decoder)
    assert isinstance(event, PacketDropped) and event.reason == "malformed"
    decoder.receive_datagram(report_datagram(json.dumps({"e": [_entry()]}).encode()), ADDR, T0)
    [ok] = drain(decoder)
    assert isinstance(ok, ReportReceived) and ok.report.entries[0].size == 3000


def _all_numbers(value: Any) -> list[int | float]:
    if isinstance(value, bool) or value is None or isinstance(value, str):
        return []
    if isinstance(value, int | float):
        return [value]
    if isinstance(value, dict):
        return [n for v in value.values() for n in _all_numbers(v)]
    if isinstance(value, list | tuple):
        return [n for v in value for n in _all_numbers(v)]
    return []


_literals = st.one_of(
    st.integers(min_value=-(2**70), max_value=2**70).map(str),
    st.floats(allow_nan=False).map(repr),
    st.sampled_from(["1e999", "-1e999", "NaN", "Infinity", "-Infinity", "1e308", "4.9e-324",
                     "0", "-0", "9" * 30, "-" + "9" * 19]),
)


@settings(max_examples=150, deadline=None)
@given(z=_literals, values=st.lists(_literals, max_size=4))
def test_decoded_metadata_only_holds_in_range_numbers(z: str, values: list[str]) -> None:
    """Property: whatever literal a key holder writes, a reassembled message has a size in
    0..2**32-1 and only finite floats and 64-bit integers in its data; anything else is a
    malformed drop."""
    decoder = make_decoder()
    items = ",".join(f'"k{i}": {v}' for i, v in enumerate(values))
    meta = f'{{"z": {z}, "d": {{{items}}}}}'.encode()
    decoder.receive_datagram(data_datagram(meta), ADDR, T0)
    [event] = drain(decoder)
    if isinstance(event, MessageReassembled):
        assert 0 <= event.message.size <= 2**32 - 1
        for n in _all_numbers(event.message.data):
            assert (math.isfinite(n) if isinstance(n, float)
                    else -MAX_JSON_INT - 1 <= n <= MAX_JSON_INT)
    else:
        assert isinstance(event, PacketDropped) and event.reason == "malformed"
        assert decoder.counters["malformed"] == 1
