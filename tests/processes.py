"""Ending a test's subprocess the way a supervisor or a user does: a signal (SIGTERM, Ctrl-C),
a grace period, then kill."""

from __future__ import annotations

import signal
import subprocess
from typing import Any


def terminate(proc: subprocess.Popen[Any], *, timeout_s: float = 5.0) -> None:
    """SIGTERM and wait up to ``timeout_s``; a process that does not exit by then is killed."""
    proc.terminate()
    try:
        proc.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def interrupt(proc: subprocess.Popen[Any], *, timeout_s: float = 20.0,
              sig: int = signal.SIGINT) -> int:
    """Ctrl-C (or ``sig``) and wait up to ``timeout_s`` for the exit code. A process still
    running then is killed and the TimeoutExpired propagates: the test fails, nothing leaks."""
    proc.send_signal(sig)
    try:
        return proc.wait(timeout=timeout_s)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def assert_one_line_error(result: subprocess.CompletedProcess[str], code: int,
                          fragment: str) -> None:
    """Bad input: exit ``code``, no traceback, one stderr line (besides argparse's usage)
    that says ``fragment``."""
    assert "Traceback" not in result.stderr, result.stderr[-3000:]
    assert result.returncode == code, result.stderr
    errors = [line for line in result.stderr.splitlines()
              if line.strip() and not line.startswith(("usage:", " "))]
    assert len(errors) == 1, result.stderr
    assert fragment in errors[0], errors[0]
