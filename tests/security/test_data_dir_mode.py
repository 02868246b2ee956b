"""The station's data folder is its owner's alone (docs/security.md, 2026-11-24).

``uav-ground-station keygen`` and ``run`` made ``DATA_DIR`` (and ``DATA_DIR/keys``) with the
default umask: 0755, so every local user could read the database and every image and
position of the fleet (the key and token files were 0600, the rest was not). Now a folder
the station creates is 0700, parents included; one that exists keeps its mode.
"""

from __future__ import annotations

import os
import signal
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from companion.secret_files import make_private_dir
from tests.processes import interrupt

SCRIPT = Path(sys.executable).parent / "uav-ground-station"


def _mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


@pytest.fixture(autouse=True)
def _usual_umask() -> object:
    old = os.umask(0o022)  # what a login shell has: the leak needs nothing unusual
    yield
    os.umask(old)


def test_keygen_and_run_make_private_folders(tmp_path: Path) -> None:
    if not SCRIPT.exists():
        pytest.skip(f"{SCRIPT} missing: install the project in this venv")
    data = tmp_path / "new" / "gs-data"
    keygen = subprocess.run([str(SCRIPT), "keygen", "--data-dir", str(data)],
                            capture_output=True, text=True, timeout=60)
    assert keygen.returncode == 0, keygen.stderr
    assert (_mode(tmp_path / "new"), _mode(data), _mode(data / "keys")) == (0o700,) * 3
    config = tmp_path / "gs.toml"  # the keys from elsewhere: run creates the data folder
    config.write_text(f'fleet_key_file = "{data / "keys" / "fleet.key"}"\n'
                      f'command_key_file = "{data / "keys" / "command.key"}"\n')
    fresh = tmp_path / "run-only" / "data"
    proc = subprocess.Popen([str(SCRIPT), "run", "--config", str(config), "--data-dir",
                             str(fresh), "--http-port", "0", "--udp-port", "0"],
                            stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        assert proc.stdout is not None
        for line in proc.stdout:  # serving: the folder, database and token exist
            if line.startswith("dashboard:"):
                break
    finally:
        interrupt(proc, timeout_s=30, sig=signal.SIGTERM)
    assert proc.returncode == 0
    assert (_mode(fresh.parent), _mode(fresh)) == (0o700, 0o700)
    assert (fresh / "ground_station.sqlite3").is_file()


def test_an_existing_folder_keeps_its_mode(tmp_path: Path) -> None:
    shared = tmp_path / "shared"
    shared.mkdir(mode=0o750)
    os.chmod(shared, 0o750)
    make_private_dir(shared)
    make_private_dir(shared / "a" / "b")
    assert (_mode(shared), _mode(shared / "a"), _mode(shared / "a" / "b")) == (
        0o750, 0o700, 0o700)
