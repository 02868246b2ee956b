"""A key written in the wrong shape is not echoed (docs/security.md, 2026-11-24).

``fleet_key = ["..."]`` or ``{x = "..."}`` (a typo away from a string) failed with the value in
the message: the secret went to stderr, a service's journal. Finding 9 had fixed that for a
key of the wrong length at the station; the wrong type still showed it, at the companion too.
Both console scripts as a user runs them: one line, exit 2, the key's type but not its text.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

BIN = Path(sys.executable).parent
SECRET = "0123456789-do-not-show-me-abcdef"


@pytest.mark.parametrize("value", [f'["{SECRET}"]', f'{{ x = "{SECRET}" }}',
                                   f'[["{SECRET}"]]'])
@pytest.mark.parametrize("tool", ["uav-companion", "uav-ground-station"])
def test_a_misshapen_fleet_key_is_named_by_its_type(tmp_path: Path, tool: str,
                                                    value: str) -> None:
    script = BIN / tool
    if not script.exists():
        pytest.skip(f"{script} missing: install the project in this venv")
    config = tmp_path / "config.toml"
    if tool == "uav-companion":
        config.write_text(f'[drone]\nid = "d1"\n[ground_station]\nfleet_key = {value}\n')
        argv = [str(script), "check", "--config", str(config), "--skip-mavlink",
                "--skip-camera"]
    else:
        config.write_text(f"fleet_key = {value}\n")
        argv = [str(script), "run", "--config", str(config), "--data-dir",
                str(tmp_path / "data")]
    result = subprocess.run(argv, capture_output=True, text=True, timeout=60)
    output = result.stdout + result.stderr
    assert result.returncode == 2, output
    assert SECRET not in output, output
    assert "fleet_key" in output and "value not shown" in output, output
    assert "Traceback" not in output
