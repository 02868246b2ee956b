"""Key files name their kind (``DESCRIPTION: BASE64``); bare base64 files of an older keygen
still read; a file of another kind is refused by what it is."""

from __future__ import annotations

import base64

import pytest

from companion.protocol.errors import LocalProtocolError
from companion.protocol.signing import (
    WrongKeyKind,
    decode_key_text,
    key_file_line,
    key_text_kind,
    same_key,
)

RAW = bytes(range(32))


def test_tagged_and_bare_files_decode_alike() -> None:
    line = key_file_line("command public key", RAW)
    assert line.startswith(b"uav-infodist command public key (")
    assert key_text_kind(line + b"\n", "f") == "command public key"
    assert decode_key_text(line + b"\n", "f", kind="command public key") == RAW
    bare = base64.b64encode(RAW) + b"\n"
    assert key_text_kind(bare, "f") is None
    assert decode_key_text(bare, "f", kind="command public key") == RAW


def test_another_kind_is_refused_by_what_it_is() -> None:
    with pytest.raises(WrongKeyKind, match=r"^keys/command.key is the ground station's "
                                           r"PRIVATE command key .*: copy command.pub to the "
                                           r"drone, and never command.key$"):
        decode_key_text(key_file_line("command key", RAW), "keys/command.key",
                        kind="command public key")
    with pytest.raises(LocalProtocolError, match="names no known kind"):
        key_text_kind(b"uav-infodist secret sauce (x): AAAA", "f")


def test_the_fleet_key_is_recognised_tagged_or_bare() -> None:
    tagged = key_file_line("fleet key", RAW)
    assert same_key(tagged, RAW) and same_key(base64.b64encode(RAW), RAW)
    assert not same_key(tagged, bytes(32))
