"""A message carries its encoded versions: the bytes the transport sends are the chosen
version's own, not an entry of a tuple beside the message."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from companion.imaging import image_message
from companion.protocol.records import ReportEntry, report_messages
from utility_specs.errors import MessageError
from utility_specs.log import message_to_record
from utility_specs.message import Message, Version

T0 = 1_700_000_000.0


def _image() -> np.ndarray:
    rng = np.random.default_rng(3)
    return rng.integers(0, 255, (240, 320, 3), dtype=np.uint8)


def test_each_version_carries_its_jpeg() -> None:
    message = image_message(_image(), sender="d1", seq=1, t_gen=T0,
                            features={"red": 0.1, "object": False}, geotag={}).message
    for i, version in enumerate(message.versions):
        chosen = message.with_version(i)
        assert chosen.payload is version.payload and len(chosen.payload) == chosen.size
    half = cv2.imdecode(np.frombuffer(message.with_version(1).payload, np.uint8),
                        cv2.IMREAD_COLOR)
    assert half.shape == (120, 160, 3)
    # the bytes are a handle: not compared, not logged
    bare = Message(sender="d1", seq=1, type="image", t_gen=T0, size=message.size,
                   data=message.data, versions=tuple(
                       Version(name=v.name, size=v.size, quality=v.quality)
                       for v in message.versions), version=0)
    assert bare == message
    assert "payload" not in str(message_to_record(message))


def test_a_payload_must_match_its_size_and_be_there() -> None:
    with pytest.raises(MessageError, match="size 10 is not the 3 bytes of its payload"):
        Version(name="full", size=10, quality=1.0, payload=b"abc")
    telemetry = Message(sender="d1", seq=2, type="battery", t_gen=T0, data={"level": 0.5})
    assert telemetry.payload == b""  # its data travels in the metadata
    learned = report_messages([ReportEntry(sender="d1", seq=3, type="image", t_gen=T0,
                                           t_sent=T0, t_rcv=T0 + 0.1, size=500, version=1,
                                           quality=0.5)], receiver="ground")[0]
    with pytest.raises(MessageError, match="has no payload here"):
        _ = learned.payload
