"""docs/protocol.md stays true: its hex dumps are what the code produces."""

from __future__ import annotations

import re
from pathlib import Path

from companion.protocol import Command, Encoder
from utility_specs.message import Message

DOC = Path(__file__).resolve().parents[2] / "docs" / "protocol.md"
KEY = bytes(range(32))
COMMAND_KEY = bytes(range(32, 64))
"""The example's Ed25519 private seed (Ed25519 signatures are deterministic)."""
EPOCH = 0x0123456789ABCDEF
T0 = 1_700_000_000.0


def hexdump(data: bytes) -> str:
    lines = []
    for offset in range(0, len(data), 16):
        chunk = data[offset : offset + 16]
        hex_part = " ".join(f"{b:02x}" for b in chunk).ljust(48)
        text = "".join(chr(b) if 32 <= b < 127 else "." for b in chunk)
        lines.append(f"{offset:04x}  {hex_part}  {text}")
    return "\n".join(lines)


def documented(name: str) -> str:
    # every fence names its language (tests/integration/test_doc_recipes.py): ```text
    match = re.search(rf"<!-- example:{name} -->\n```text\n(.*?)\n```", DOC.read_text(), re.S)
    assert match is not None, f"example {name} missing from {DOC}"
    return match.group(1)


def test_data_example_matches_the_encoder() -> None:
    message = Message(
        sender="drone1", seq=7, type="battery", t_gen=T0 - 0.5, size=40, data={"level": 0.81}
    )
    (datagram,) = Encoder(42, "drone1", KEY).fragment(message, b"", now=T0)
    assert len(datagram) == 106
    assert documented("data") == hexdump(datagram)


def test_command_example_matches_the_encoder() -> None:
    command = Command(command_id=3, name="start", t_exec=T0 + 5.0, args={"mission": "m1"})
    ground = Encoder(42, "ground", KEY, command_key=COMMAND_KEY)
    datagram = ground.encode_command(command, now=T0, epoch=EPOCH)
    assert len(datagram) == 156
    assert documented("command") == hexdump(datagram)
