"""Operator checks (audit 12): Ctrl-C in ``uav-ground-station shell`` and ``uav-companion
check``.

Before: a Ctrl-C at the prompt printed a KeyboardInterrupt traceback and then the process
hung (the thread waiting for the terminal kept it alive) until killed; during a scripted
``sleep``/``wait`` it printed the traceback and exited -2. Now: one line at once, exit 0 at the
prompt and 130 in a script (``-c``).
The shell is the installed console script on a real pseudo-terminal; it needs no station
for this (it calls the API only for a command).
"""

from __future__ import annotations

import os
import pty
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from sitl.fleet_config import free_port
from tests.keys import write_test_keys
from tests.processes import interrupt
from tests.station_process import running_station

SCRIPT = Path(sys.executable).parent / "uav-ground-station"
SHELL = [str(SCRIPT) if SCRIPT.exists() else sys.executable, *(
    [] if SCRIPT.exists() else ["-m", "ground_station.cli"]),
    "shell", "--url", "http://127.0.0.1:9", "--token", "operator-test-token"]


def _read_until(fd: int, marker: bytes, timeout_s: float) -> bytes:
    out = b""
    deadline = time.monotonic() + timeout_s
    while marker not in out:
        assert time.monotonic() < deadline, out.decode(errors="replace")[-2000:]
        ready, _, _ = select.select([fd], [], [], 0.1)
        if ready:
            try:
                out += os.read(fd, 65536)
            except OSError:  # the child closed the terminal
                break
    return out


def _sigint_as_on_a_terminal() -> None:
    """A program started from a terminal gets SIGINT's default action; one started under a
    runner launched with ``&`` by a non-interactive shell inherits SIGINT ignored, and
    Python then never raises KeyboardInterrupt (the suite failed that way, launched so)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_ctrl_c_at_the_prompt_ends_the_shell_at_once() -> None:
    pid, fd = pty.fork()
    if pid == 0:  # the child: the shell on the terminal
        _sigint_as_on_a_terminal()
        os.execv(SHELL[0], SHELL)
    status: int | None = None
    try:
        _read_until(fd, b"CMD >> ", 30)
        os.write(fd, b"\x03")  # Ctrl-C typed on the terminal
        t0 = time.monotonic()
        out = b""
        while True:
            done, code = os.waitpid(pid, os.WNOHANG)
            if done:
                status = code
                break
            assert time.monotonic() - t0 < 5, "the shell hung after Ctrl-C"
            out += _read_until(fd, b"interrupted", 0.5) if b"interrupted" not in out else b""
            time.sleep(0.05)
        out += _read_until(fd, b"\n", 1) if b"interrupted" not in out else b""
    finally:
        if status is None:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
        os.close(fd)
    text = out.decode(errors="replace")
    assert os.waitstatus_to_exitcode(status) == 0, text
    assert "uav-ground-station shell: interrupted" in text
    assert "Traceback" not in text


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_during_a_scripted_wait_is_one_line_and_exit_130(sig: int) -> None:
    """Exit 130, not 0: a script (``shell -c \"drones 5\" && next``) must not carry on."""
    proc = subprocess.Popen([*SHELL, "-c", "help; sleep 30"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"},
                            preexec_fn=_sigint_as_on_a_terminal)
    assert proc.stdout is not None
    for line in proc.stdout:  # the help is printed: the shell runs, now it sleeps
        if line.startswith("Every wait gives up"):
            break
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=10)
    assert proc.returncode == 130, err
    assert err.strip().splitlines() == ["uav-ground-station shell: interrupted"], err


COMPANION = Path(sys.executable).parent / "uav-companion"
ROOT = Path(__file__).resolve().parents[2]


def test_ctrl_c_while_check_waits_for_the_autopilot(tmp_path: Path) -> None:
    """Before: a KeyboardInterrupt traceback. Now one line and 130 (nothing was checked)."""
    if not COMPANION.exists():
        pytest.skip(f"{COMPANION} missing: install the project in this venv")
    keys = write_test_keys(tmp_path / "keys")
    text = (ROOT / "examples" / "companion.toml").read_text()
    for old, new in {
        'url = "udpin:127.0.0.1:14550"': f'url = "udpin:127.0.0.1:{free_port()}"',  # silent
        '# fleet_key_file = "/etc/uav-companion/fleet.key"':
            f'fleet_key_file = "{keys / "fleet.key"}"',
        '# command_public_key_file = "/etc/uav-companion/command.pub"':
            f'command_public_key_file = "{keys / "command.pub"}"',
    }.items():
        assert text.count(old) == 1, old
        text = text.replace(old, new)
    config = tmp_path / "companion.toml"
    config.write_text(text)
    proc = subprocess.Popen([str(COMPANION), "check", "--config", str(config), "--timeout",
                             "60", "--skip-camera"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"},
                            preexec_fn=_sigint_as_on_a_terminal)
    assert proc.stdout is not None
    for line in proc.stdout:  # the config is read: now it waits for a HEARTBEAT
        if line.startswith("config:"):
            break
    time.sleep(0.5)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=15)
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    assert err.strip().splitlines()[-1] == "uav-companion check: interrupted"


def test_ctrl_c_with_stdin_a_pipe_is_always_clean(tmp_path: Path) -> None:
    """Before: the prompt was read on a daemon thread, so with stdin a pipe 1 run in 8 died
    with "Fatal Python error: _enter_buffered_busy" (the thread held stdin's lock at
    shutdown) and 1 in 3 printed "Exception in thread shell-input" (a line arriving after
    the loop closed). Now a pipe is read by the event loop, no thread."""
    with running_station(tmp_path) as station:
        shell = [*SHELL[:-4], "--url", f"http://127.0.0.1:{station.port}", "--token",
                 station.token]
        for attempt in range(8):
            proc = subprocess.Popen(shell, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                    stderr=subprocess.PIPE, text=True,
                                    env={**os.environ, "PYTHONUNBUFFERED": "1"},
                                    preexec_fn=_sigint_as_on_a_terminal)
            try:
                assert proc.stdin is not None and proc.stdout is not None
                proc.stdin.write("status\n")  # a command runs, then it waits for the next
                proc.stdin.flush()
                for line in proc.stdout:
                    if line.startswith(("CMD >> phase", "phase")):
                        break
                time.sleep(0.1 * (attempt % 4))
                code = interrupt(proc, timeout_s=10)
                err = proc.stderr.read() if proc.stderr else ""
            finally:
                if proc.poll() is None:
                    proc.kill()
                    proc.wait()
            assert "Traceback" not in err and "Fatal Python error" not in err, err
            assert code == 0, err
            assert err.strip().splitlines() == ["uav-ground-station shell: interrupted"], err


@pytest.mark.parametrize("stdin", ["file", "devnull"])
def test_stdin_a_file_or_dev_null_is_read_to_its_end(tmp_path: Path, stdin: str) -> None:
    """Neither can be polled by the event loop: read directly, and the shell ends at EOF."""
    script = tmp_path / "lines"
    script.write_text("help\nstatus\n")
    with open(script if stdin == "file" else os.devnull) as source:
        result = subprocess.run(SHELL, stdin=source, capture_output=True, text=True,
                                timeout=30, check=False)
    assert "Traceback" not in result.stderr, result.stderr
    assert result.returncode == 0, result.stderr
    if stdin == "file":  # both lines ran: status failed (no station at port 9), said so
        assert result.stdout.count("Available commands:") == 2, result.stdout
        assert "error: ground station at http://127.0.0.1:9 unreachable" in result.stdout
