"""A link that opens but brings no autopilot HEARTBEAT is closed and reopened every
``heartbeat_timeout_s + reconnect_delay_s`` (serial re-enumeration, a TCP reconnect, a UDP
rebind): the log says so once, instead of "mavlink connection opened" at every reopening
(``uav-companion check`` showed it twice in 5 s; ``run`` every 4 s for as long as the
autopilot is off)."""

from __future__ import annotations

import re
import socket
import subprocess
import sys
from pathlib import Path

from tests.keys import write_test_keys

SCRIPT = Path(sys.executable).parent / "uav-companion"


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_check_without_autopilot_says_once_that_it_reopens(tmp_path: Path) -> None:
    write_test_keys(tmp_path / "keys")
    url = f"udpin:127.0.0.1:{_free_udp_port()}"
    config = tmp_path / "companion.toml"
    config.write_text(f"""[drone]
id = "d1"
[mavlink]
url = "{url}"
heartbeat_timeout_s = 0.5
reconnect_delay_s = 0.2
[camera]
enabled = false
[ground_station]
fleet_key_file = "keys/fleet.key"
command_public_key_file = "keys/command.pub"
""")
    result = subprocess.run([str(SCRIPT), "--log-format", "text", "check", "--config",
                             str(config), "--timeout", "2"], capture_output=True, text=True,
                            timeout=60, check=False)
    assert result.returncode == 1
    assert f"mavlink: {url}: no autopilot HEARTBEAT within 2 s" in result.stdout
    log = result.stderr.splitlines()
    # ~3 reopenings in 2 s; each used to log "opened" at INFO
    said = [line.split(" INFO ")[1] for line in log if "mavlink" in line]
    assert len(said) == 2, result.stderr
    assert said[0] == f"companion.mavlink: mavlink connection opened: {url}"
    assert re.fullmatch(rf"companion\.mavlink: mavlink: no HEARTBEAT for [01]\.\d s on "
                        rf"{re.escape(url)}: closing it and reopening every ~0\.7 s until an "
                        r"autopilot HEARTBEAT arrives \(nothing sent MAVLink to "
                        rf"{re.escape(url.partition(':')[2])}: .*\)", said[1]), said[1]
