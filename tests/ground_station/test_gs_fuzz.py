"""Fuzzing the ground station's message handling with validly signed hostile payloads.

A key holder (a captured drone) can sign anything. Hypothesis writes DATA and STATUS
datagrams with arbitrary ids, numbers (NaN, 1e999, 2**70...), JSON shapes and fragment
fields, signed with the fleet key, and feeds them to a live station (real storage, real
cores) the way its UDP reader does. After each batch the station must still be whole: no
exception, JSON-clean stats and fleet view, an encodable receiver report, and a legitimate
image afterwards stored and reported. Bounded to a few seconds.
"""

from __future__ import annotations

import asyncio
import json
import math
import struct
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from aiohttp import web
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from companion.protocol import Encoder
from companion.protocol.wire import DATA_FIXED, METADATA_LEN, STATUS_FIXED, PacketKind
from ground_station.app import create_app
from ground_station.config import GroundConfig
from ground_station.keys import FLEET, LINK, STORAGE
from ground_station.receiver import GroundLink
from tests.keys import TEST_COMMAND_KEY
from utility_specs.message import Message

KEY = b"ground-station-fuzz-fleet-key-01"
ADDR = ("127.0.0.1", 45000)

_json_scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(2**70), max_value=2**70),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=12),
)
_json_values = st.recursive(
    _json_scalars,
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner,
                                                                 max_size=4),
    max_leaves=12,
)
_known_keys = st.sampled_from(["z", "d", "v", "i", "red", "level", "object", "lat", "text",
                               "report", "statustext", "severity", "mode", "error"])
_objects = st.dictionaries(_known_keys | st.text(max_size=6), _json_values, max_size=6)
_ids = st.text(st.characters(codec="utf-8"), min_size=1, max_size=8).filter(
    lambda s: 1 <= len(s.encode()) <= 32
)


def _json_bytes(value: Any) -> bytes:
    return json.dumps(value, allow_nan=True).encode()[:900]  # cut: broken JSON is fuzz too


@st.composite
def hostile(draw: st.DrawFn) -> tuple[str, PacketKind, bytes]:
    """(sender, kind, body) a key holder could sign."""
    sender = draw(_ids | st.sampled_from(["d1", "d2"]))
    if draw(st.booleans()):
        state = draw(_ids)
        body = (STATUS_FIXED.pack(draw(st.integers(0, 2**32 - 1)), len(state.encode()))
                + state.encode() + _json_bytes(draw(_objects)))
        return sender, PacketKind.STATUS, body
    msg_type = draw(st.sampled_from(["image", "battery", "position"]) | _ids).encode()
    payload = draw(st.binary(max_size=200))
    metadata = draw(st.one_of(
        _objects.map(_json_bytes),
        st.fixed_dictionaries({"z": _json_values, "d": _objects}).map(_json_bytes),
        st.sampled_from([b'{"z": 9223372036854775808}', b'{"z": 30, "d": {"red": 1e999}}',
                         b'{"z": -1}', b"{", b"[]", b'{"z": 1, "v": [["a", 1, 1e999]]}']),
    ))
    count = draw(st.integers(1, 3))
    index = draw(st.integers(0, count - 1)) if draw(st.booleans()) else 0
    total = draw(st.sampled_from([len(payload), len(payload) * count, 0, 2**32 - 1]))
    t_gen = draw(st.floats(allow_nan=True, allow_infinity=True) | st.just(1.7e9))
    fixed = DATA_FIXED.pack(draw(st.integers(0, 2**32 - 1)), t_gen, index, count, total,
                            len(msg_type))
    body = fixed + msg_type
    if index == 0:
        body += METADATA_LEN.pack(len(metadata)) + metadata
    return sender, PacketKind.DATA, body + payload


class Station:
    """The ground-station app without HTTP: cleanup contexts run, so storage and the UDP
    link are the real ones."""

    def __init__(self, data_dir: Path) -> None:
        self.loop = asyncio.new_event_loop()
        config = GroundConfig(fleet_id=9, fleet_key=KEY, command_key=TEST_COMMAND_KEY,
                              data_dir=data_dir, mission="fz",
                              udp_host="127.0.0.1", udp_port=0, fsync=False,
                              # the tests build the reports themselves (link.reports.due)
                              report_interval_s=3600.0)
        self.app = create_app(config, token="fuzz-token-0123456789")
        self.runner = web.AppRunner(self.app)
        self.loop.run_until_complete(self.runner.setup())
        self.encoders: dict[str, Encoder] = {}
        self.legit = Encoder(9, "legit", KEY)
        self.legit_seq = 0

    @property
    def link(self) -> GroundLink:
        link: GroundLink = self.app[LINK]
        return link

    def close(self) -> None:
        self.loop.run_until_complete(self.runner.cleanup())
        self.loop.close()

    def sign(self, sender: str, kind: PacketKind, body: bytes) -> bytes:
        encoder = self.encoders.setdefault(sender, Encoder(9, sender, KEY))
        return encoder._pack(kind, body, self.link.clock())

    async def feed(self, datagrams: list[bytes]) -> None:
        for data in datagrams:
            self.link.datagram_received(data, ADDR)
        await asyncio.sleep(0)

    async def legit_image_is_stored(self) -> bool:
        self.legit_seq += 1
        now = self.link.clock()
        message = Message(sender="legit", seq=self.legit_seq, type="image", t_gen=now - 0.1,
                          size=1000, data={"red": 0.5})
        for data in self.legit.fragment(message, b"\xff\xd8" + b"j" * 998, now):
            self.link.datagram_received(data, ADDR)
        storage = self.app[STORAGE]
        await storage.flush()
        rows = await storage.read(lambda s: s.images("fz", sender="legit", order="time"))
        return any(r.seq == self.legit_seq and r.path is not None for r in rows)


@pytest.fixture(scope="module")
def station(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Station]:
    station = Station(tmp_path_factory.mktemp("fuzz") / "gs")
    yield station
    station.close()


def _assert_json_clean(value: Any) -> None:
    json.dumps(value, allow_nan=False, default=str)  # raises on NaN/inf


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                 HealthCheck.data_too_large])
@given(batch=st.lists(hostile(), min_size=1, max_size=12))
def test_signed_hostile_payloads_never_break_the_station(
    station: Station, batch: list[tuple[str, PacketKind, bytes]]
) -> None:
    datagrams = []
    for sender, kind, body in batch:
        try:
            datagrams.append(station.sign(sender, kind, body))
        except struct.error:  # a body longer than the u16 length field: not a datagram
            continue
    station.loop.run_until_complete(station.feed(datagrams))
    link = station.link
    now = link.clock()
    _assert_json_clean(link.stats(now=now))
    _assert_json_clean(station.app[FLEET].snapshot(now=now))
    for state in station.app[FLEET].drones.values():
        for name in ("battery", "lat_deg", "alt_m", "latency_s"):
            value = getattr(state, name)
            assert value is None or math.isfinite(value)
    assert station.loop.run_until_complete(station.legit_image_is_stored())
    report = link.reports.due(now=link.reports.get_timer())
    assert report is not None
    link.encoder.encode_report(report, now)  # every entry the station holds encodes
    assert any(e.sender == "legit" and e.seq == station.legit_seq for e in report.entries)
    stats = link.storage.stats()
    assert stats["batch_failures"] == 0 and stats["writer_restarts"] == 0


def test_the_largest_metadata_a_datagram_holds_never_blocks_reports(station: Station) -> None:
    """A message whose metadata fills its datagram (ids of escaped characters, a long
    string) yields a report entry that would not fit a report datagram: it is reported
    without its data, and every report still encodes."""
    sender, msg_type = "\x01" * 32, "\x02" * 32
    encoder = Encoder(9, sender, KEY)
    link = station.link
    now = link.clock()
    for n in range(400, 0, -5):
        message = Message(sender=sender, seq=n, type=msg_type, t_gen=now - 0.1, size=4,
                          data={"s": "\x03" * n})
        try:
            datagrams = encoder.fragment(message, b"\xff\xd8ab", now)
        except ValueError:  # LocalProtocolError: metadata does not fit, try smaller
            continue
        break
    assert len(datagrams[0]) > 1100  # metadata fills the first fragment
    station.loop.run_until_complete(station.feed(datagrams))
    assert station.loop.run_until_complete(station.legit_image_is_stored())
    report = link.reports.due(now=link.reports.get_timer())
    assert report is not None
    parts = link.encoder.encode_report(report, now)
    assert parts and all(len(p) <= 1200 for p in parts)
    [big] = [e for e in report.entries if e.sender == sender]
    assert big.data == {} and link.reports.entries_trimmed >= 1
    [legit] = [e for e in report.entries if e.sender == "legit" and e.seq == station.legit_seq]
    assert legit.data == {"red": 0.5}
