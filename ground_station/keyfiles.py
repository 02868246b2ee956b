"""The fleet's key files: made once on the ground station, copied to drones (docs/protocol.md).

``uav-ground-station keygen`` writes three files into one folder:

    fleet.key     HMAC key of all bulk traffic (32 random bytes, base64), mode 0600;
                  ground station and every drone
    command.key   the ground station's Ed25519 private key (base64), mode 0600; ground only
    command.pub   its public key (base64), mode 0644; every drone

A drone gets ``fleet.key`` and ``command.pub``, never ``command.key``: with it alone it can
send data but cannot make a command another companion obeys. Each file is one line naming
its kind before the key (``uav-infodist command public key (...): BASE64``,
:func:`companion.protocol.signing.key_file_line`), which the readers check.
"""

from __future__ import annotations

import os
import secrets
from dataclasses import dataclass
from pathlib import Path

from companion.protocol.signing import KEY_BYTES, key_file_line, public_key_of
from companion.secret_files import make_private_dir

__all__ = ["COMMAND_KEY", "COMMAND_PUB", "FLEET_KEY", "KeyFiles", "generate_keys"]

FLEET_KEY = "fleet.key"
COMMAND_KEY = "command.key"
COMMAND_PUB = "command.pub"


@dataclass(frozen=True, slots=True)
class KeyFiles:
    folder: Path

    @property
    def fleet_key(self) -> Path:
        return self.folder / FLEET_KEY

    @property
    def command_key(self) -> Path:
        return self.folder / COMMAND_KEY

    @property
    def command_pub(self) -> Path:
        return self.folder / COMMAND_PUB


def _write_new(path: Path, text: bytes, mode: int, *, replace: bool) -> None:
    """Create ``path`` with ``mode`` from the start (never briefly readable by others)."""
    if replace and path.exists():
        path.unlink()
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, mode)
    with os.fdopen(fd, "wb") as handle:
        handle.write(text + b"\n")
        handle.flush()
        os.fsync(handle.fileno())


def generate_keys(folder: Path, *, replace: bool = False) -> KeyFiles:
    """Fresh random fleet and command keys in ``folder``.

    Raises FileExistsError rather than overwrite keys a fleet may already use (``replace``
    overrides); OSError when the folder is not writable.
    """
    files = KeyFiles(folder)
    make_private_dir(folder)
    if not replace:
        for path in (files.fleet_key, files.command_key, files.command_pub):
            if path.exists():
                raise FileExistsError(f"{path} exists (pass --force to replace the fleet's keys)")
    seed = secrets.token_bytes(KEY_BYTES)
    _write_new(files.fleet_key, key_file_line("fleet key", secrets.token_bytes(32)), 0o600,
               replace=replace)
    _write_new(files.command_key, key_file_line("command key", seed), 0o600, replace=replace)
    _write_new(files.command_pub, key_file_line("command public key", public_key_of(seed)),
               0o644, replace=replace)
    return files
