"""Ctrl-C on a long ``uav-sitl study``: one line (what it had written), exit 130.

Before: a KeyboardInterrupt traceback and death by the signal (-2); on a Dask study each
local worker process printed its own traceback too. The signal goes to the whole process
group, as a terminal's Ctrl-C does.
"""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

SITL = Path(sys.executable).parent / "uav-sitl"


def _sigint_as_on_a_terminal() -> None:
    # a runner started with & by a non-interactive shell passes SIGINT on ignored
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _wait_for(proc: subprocess.Popen[str], marker: str | None, timeout_s: float) -> str:
    """Stderr read until ``marker`` (or, for None, ``timeout_s`` of it)."""
    assert proc.stderr is not None
    seen = ""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and (marker is None or marker not in seen):
        ready, _, _ = select.select([proc.stderr], [], [], 0.1)
        if ready:
            chunk = os.read(proc.stderr.fileno(), 65536).decode(errors="replace")
            assert chunk, f"exited early ({proc.poll()}): {seen[-2000:]}"
            seen += chunk
    assert marker is None or marker in seen, seen[-2000:]
    return seen


@pytest.mark.parametrize(("argv", "marker", "wait_s"), [
    (["drop-rate-vs-utility"], "[1/", 60.0),
    (["fig4.13"], None, 2.5),
    (["fig5.7", "--runs", "3"], "fig5.7 [", 60.0),  # a local Dask cluster of 2 workers
])
def test_ctrl_c_on_a_study_is_one_line_and_130(tmp_path: Path, argv: list[str],
                                               marker: str | None, wait_s: float) -> None:
    out = tmp_path / "out"
    proc = subprocess.Popen([str(SITL), "study", *argv, "--out", str(out)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, preexec_fn=_sigint_as_on_a_terminal)
    try:
        seen = _wait_for(proc, marker, wait_s)
        os.killpg(proc.pid, signal.SIGINT)
        assert proc.stderr is not None
        _, rest = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    err = seen + rest
    assert "Traceback" not in err, err[-3000:]
    assert proc.returncode == 130, err[-2000:]
    last = err.strip().splitlines()[-1]
    assert last.startswith(f"uav-sitl study {argv[0]}: interrupted"), err[-2000:]
    assert "KeyboardInterrupt" not in err, err[-2000:]
