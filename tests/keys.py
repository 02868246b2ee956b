"""Explicit test keys: the code has no built-in key, so every test says which one it uses."""

from __future__ import annotations

import base64
from pathlib import Path

from companion.protocol.signing import public_key_of

TEST_FLEET_KEY = b"test-fleet-key-0123456789abcdef"
"""HMAC fleet key of tests (>= 16 bytes)."""
TEST_COMMAND_KEY = bytes(range(100, 132))
"""The test ground station's Ed25519 private seed."""
TEST_COMMAND_PUB = public_key_of(TEST_COMMAND_KEY)
"""Its public key, what test drones verify commands with."""


def write_test_keys(folder: Path, *, fleet_key: bytes = TEST_FLEET_KEY) -> Path:
    """fleet.key, command.key and command.pub in ``folder`` (as ``keygen`` lays them out)."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "fleet.key").write_bytes(fleet_key + b"\n")
    (folder / "command.key").write_bytes(base64.b64encode(TEST_COMMAND_KEY) + b"\n")
    (folder / "command.pub").write_bytes(base64.b64encode(TEST_COMMAND_PUB) + b"\n")
    (folder / "fleet.key").chmod(0o600)
    (folder / "command.key").chmod(0o600)
    return folder
