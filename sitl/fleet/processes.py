"""The launcher's children: each in its own process group, stopped SIGTERM, wait, SIGKILL.

Also the stop flag the signal handlers set and the wait-until-ready loop that watches the
children while it polls (a child that dies is reported with the end of its log).
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO


class FleetError(RuntimeError):
    """The fleet could not be brought up (the text says which process and why)."""


class Stopped(FleetError):
    """The user stopped the fleet (Ctrl-C, SIGTERM) before its mission started: a clean
    exit (0), not a failure."""


def tool(script: str, module: str) -> list[str]:
    """The console script next to this interpreter, else ``python -m module``."""
    path = Path(sys.executable).parent / script
    return [str(path)] if path.exists() else [sys.executable, "-m", module]


def _die_with_parent() -> None:
    """In the child before exec: SIGTERM us if the launcher dies (Linux PR_SET_PDEATHSIG)."""
    with contextlib.suppress(Exception):
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM, 0, 0, 0)


@dataclass(slots=True)
class Child:
    name: str
    proc: subprocess.Popen[bytes]
    log_path: Path
    log: IO[bytes]

    def alive(self) -> bool:
        return self.proc.poll() is None

    def tail(self, n_bytes: int = 2000) -> str:
        with contextlib.suppress(OSError):
            self.log.flush()
            data = self.log_path.read_bytes()[-n_bytes:]
            return data.decode("utf-8", "replace")
        return ""


@dataclass(slots=True)
class Processes:
    """Every child of the launcher, each in its own session (process group)."""

    logs_dir: Path
    children: list[Child] = field(default_factory=list)

    def start(self, name: str, argv: Sequence[str], *, env: dict[str, str] | None = None
              ) -> Child:
        log_path = self.logs_dir / f"{name}.log"
        log = open(log_path, "ab")  # noqa: SIM115 - closed in stop()
        try:
            proc = subprocess.Popen(list(argv), stdin=subprocess.DEVNULL, stdout=log,
                                    stderr=subprocess.STDOUT, start_new_session=True,
                                    preexec_fn=_die_with_parent, env=env)
        except OSError as exc:
            log.close()
            raise FleetError(f"{name}: cannot start {argv[0]}: {exc}") from None
        child = Child(name, proc, log_path, log)
        self.children.append(child)
        return child

    def stop(self, children: Iterable[Child], *, timeout_s: float = 10.0) -> None:
        """SIGTERM each child's process group, wait up to ``timeout_s``, then SIGKILL."""
        children = list(children)
        for child in children:
            signal_group(child.proc, signal.SIGTERM)
        deadline = time.monotonic() + timeout_s
        for child in children:
            with contextlib.suppress(subprocess.TimeoutExpired):
                child.proc.wait(timeout=max(0.1, deadline - time.monotonic()))
        for child in children:
            signal_group(child.proc, signal.SIGKILL)  # stragglers and their children
            with contextlib.suppress(subprocess.TimeoutExpired):
                child.proc.wait(timeout=5.0)
            child.log.close()

    def stop_all(self, *, timeout_s: float = 10.0) -> None:
        self.stop(self.children, timeout_s=timeout_s)


def signal_group(proc: subprocess.Popen[bytes], sig: int) -> None:
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(proc.pid, sig)  # pgid == pid: start_new_session=True


class Stop:
    """Set by SIGINT/SIGTERM/SIGHUP; the launcher polls it between short sleeps."""

    def __init__(self) -> None:
        self.reason: str | None = None

    def __call__(self, signum: int, frame: object) -> None:
        self.reason = signal.Signals(signum).name

    def sleep(self, seconds: float) -> bool:
        """Sleep unless stopped; True when a stop was asked."""
        deadline = time.monotonic() + seconds
        while self.reason is None and time.monotonic() < deadline:
            time.sleep(min(0.1, max(0.0, deadline - time.monotonic())))
        return self.reason is not None


def wait(stop: Stop, what: str, timeout_s: float, ready: Callable[[], bool],
          watch: Sequence[Child]) -> None:
    deadline = time.monotonic() + timeout_s
    while not ready():
        for child in watch:
            if not child.alive():
                raise FleetError(f"{child.name} exited ({child.proc.returncode}) while waiting "
                                 f"for {what}; its log ({child.log_path}) ends with:\n"
                                 f"{child.tail()}")
        if time.monotonic() > deadline:
            raise FleetError(f"timed out after {timeout_s:g} s waiting for {what}")
        if stop.sleep(0.2):
            raise Stopped(f"stopped ({stop.reason}) while waiting for {what}")
