"""A key of the wrong length is named by its length, never echoed: the configuration error
printed the fleet key's or the Ed25519 private key's bytes to stderr (the journal, a CI log)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from ground_station.config import ConfigError, GroundConfig

STATION = Path(sys.executable).parent / "uav-ground-station"


@pytest.mark.parametrize(("field", "secret"), [("fleet_key", b"shortsecret"),
                                               ("command_key", b"private-key-bytes" * 2)])
def test_a_wrong_length_key_is_not_echoed(field: str, secret: bytes) -> None:
    with pytest.raises(ConfigError) as caught:
        GroundConfig(**{field: secret})  # type: ignore[arg-type]
    assert str(caught.value).endswith(f"got '{len(secret)} bytes'")
    assert secret.decode() not in str(caught.value)


def test_the_cli_does_not_print_a_short_fleet_key(tmp_path: Path) -> None:
    keys = tmp_path / "data" / "keys"
    keys.mkdir(parents=True)
    secret = b"fleet-secret"  # a truncated key file
    (keys / "fleet.key").write_bytes(secret)
    (keys / "fleet.key").chmod(0o600)
    result = subprocess.run([str(STATION), "run", "--data-dir", str(tmp_path / "data")],
                            capture_output=True, text=True, timeout=60, check=False)
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert "expected at least 16 bytes, got '12 bytes'" in result.stderr, result.stderr
    assert "fleet-secret" not in result.stderr
