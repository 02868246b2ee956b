"""``python -m ground_station.fake_drone``, the demo fleet of docs/ground_station.md.

Before: an address without a port was a ValueError traceback, a port past 65535 an
AttributeError traceback, Ctrl-C a CancelledError/KeyboardInterrupt traceback, and it
printed nothing while it ran. Now: usage errors are one line and exit 2, it says what it
sends where, and Ctrl-C is one line and exit 130.
"""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import pytest

from tests.keys import write_test_keys
from tests.processes import assert_one_line_error, interrupt

FAKE = [sys.executable, "-m", "ground_station.fake_drone"]


@pytest.fixture
def keys(tmp_path: Path) -> Path:
    return write_test_keys(tmp_path / "keys")


@pytest.mark.parametrize(("argv", "fragment"), [
    (["127.0.0.1"], "expected HOST:PORT (127.0.0.1:14600), got '127.0.0.1'"),
    (["127.0.0.1:99999"], "port must be in 1..65535, got '127.0.0.1:99999'"),
    (["127.0.0.1:abc"], "expected HOST:PORT"),
    (["nosuch.invalid:14600"], "cannot resolve 'nosuch.invalid'"),
    (["127.0.0.1:14600", "--drones", "0"], "--drones must be in 1..64, got 0"),
    (["127.0.0.1:14600", "--duration", "nan"], "--duration must be a finite number"),
])
def test_bad_input_is_one_line_and_2(keys: Path, argv: list[str], fragment: str) -> None:
    result = subprocess.run([*FAKE, *argv, "--keys", str(keys)], capture_output=True,
                            text=True, timeout=60, check=False)
    assert_one_line_error(result, 2, fragment)


def test_it_says_what_it_sends_where_and_ctrl_c_is_one_line(keys: Path) -> None:
    proc = subprocess.Popen([*FAKE, "127.0.0.1:9", "--drones", "2", "--keys", str(keys)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    assert proc.stdout is not None and proc.stderr is not None
    first = proc.stdout.readline()
    assert first.startswith("fake_drone: 2 drone(s) send images, telemetry and status to "
                            "127.0.0.1:9 (fleet 1) for 60 s"), first
    code = interrupt(proc)
    err = proc.stderr.read()
    assert "Traceback" not in err, err
    assert code == 130, err
    assert err.strip() == "fake_drone: interrupted", err


def test_help_explains_every_option() -> None:
    text = subprocess.run([*FAKE, "--help"], capture_output=True, text=True, timeout=60,
                          check=True).stdout
    assert "how many drones" in text and "seconds to send for" in text
