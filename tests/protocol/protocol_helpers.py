"""Helpers for the codec tests: explicit time, in-memory transfer, event draining."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

from companion.protocol import Decoder, DecoderLimits, Encoder, Event
from tests.keys import TEST_COMMAND_KEY, TEST_COMMAND_PUB
from utility_specs.message import Message, Version

T0 = 1_700_000_000.0
KEY = bytes(range(32))
FLEET = 42
ADDR = ("127.0.0.1", 40000)


def drain(decoder: Decoder) -> list[Event]:
    events = []
    while (event := decoder.next_event()) is not None:
        events.append(event)
    return events


def transfer(
    datagrams: Iterable[bytes],
    decoder: Decoder,
    *,
    now: float,
    drop: Callable[[int], bool] = lambda i: False,
) -> list[Event]:
    """Deliver datagrams in the given order (skipping dropped indices) and drain events."""
    for i, data in enumerate(datagrams):
        if not drop(i):
            decoder.receive_datagram(data, ADDR, now)
    return drain(decoder)


def image_message(seq: int = 1, *, size: int = 5000, t_gen: float = T0 - 0.25) -> Message:
    return Message(
        sender="drone1",
        seq=seq,
        type="image",
        t_gen=t_gen,
        size=size,
        data={"red": 0.25, "object": True, "lat_deg": 50.06, "alt_rel_m": 30.5},
        versions=(
            Version(name="full", size=size, quality=1.0),
            Version(name="half", size=size // 4, quality=0.5),
        ),
        version=0,
    )


def make_encoder(sender: str = "drone1") -> Encoder:
    """An encoder of ``sender``; "ground" holds the station's command key."""
    return Encoder(FLEET, sender, KEY,
                   command_key=TEST_COMMAND_KEY if sender == "ground" else None)


def make_decoder(**limits: Any) -> Decoder:
    """A decoder that verifies commands with the test station's public key (any epoch)."""
    return Decoder(FLEET, KEY, local_id="ground", limits=DecoderLimits(**limits),
                   command_key=TEST_COMMAND_PUB)
