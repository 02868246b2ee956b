"""Ending a test's subprocess the way a supervisor does: SIGTERM, a grace period, then kill."""

from __future__ import annotations

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
