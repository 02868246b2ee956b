"""Stock MAVProxy with MAVLink signing against the shipped ``uav-ground-station run`` whose
mirror has ``mavlink_signing_key_file`` (2026-11-25): after ``signing setup PASSPHRASE`` (the
same passphrase) it lists the drones; without it, it lists none. Skipped without MAVProxy
(`make test` installs it into .venv/mavproxy)."""

from __future__ import annotations

import asyncio
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.ground_station.test_mavlink_out import MAVPROXY, Expect, Station
from tests.processes import terminate

PASSPHRASE = "fleet-mirror-passphrase"  # one word: MAVProxy takes the first


async def _mavproxy(station: Station, tmp_path: Path, *, signed: bool) -> list[str]:
    mp_dir = tmp_path / ("signed" if signed else "unsigned")
    mp_dir.mkdir()
    commands = [f"--cmd=signing setup {PASSPHRASE}"] if signed else []
    proc = subprocess.Popen(
        [sys.executable, str(MAVPROXY), f"--master=udpout:127.0.0.1:{station.mav}",
         "--default-modules=link,signing", f"--state-basedir={mp_dir}", "--nowait", *commands],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        env=dict(os.environ, MAVLINK20="1"), cwd=mp_dir)
    try:
        mp = Expect(proc)
        if signed:
            await asyncio.to_thread(mp.expect_all, {"Detected vehicle 3:1"}, 60.0)
        else:
            with pytest.raises(AssertionError, match="never printed"):
                await asyncio.to_thread(mp.expect_all, {"Detected vehicle"}, 8.0)
        return mp.seen
    finally:
        terminate(proc)


@pytest.mark.skipif(MAVPROXY is None, reason="MAVProxy is not installed: `make test` installs "
                    "it into .venv/mavproxy, or set UAV_SITL_MAVPROXY to a mavproxy.py")
@pytest.mark.timeout(150)
async def test_mavproxy_needs_the_passphrase(tmp_path: Path) -> None:
    key_file = tmp_path / "mavlink.key"
    key_file.write_text(PASSPHRASE + "\n")
    key_file.chmod(0o600)
    station = Station(tmp_path, extra=f'mavlink_signing_key_file = "{key_file}"\n')
    stop = asyncio.Event()
    feeder = asyncio.create_task(station.feed(["drone3"], stop))
    try:
        await _mavproxy(station, tmp_path, signed=False)
        await _mavproxy(station, tmp_path, signed=True)
    finally:
        stop.set()
        await feeder
        err = station.close()
    assert "Traceback" not in err and ", signed" in err
