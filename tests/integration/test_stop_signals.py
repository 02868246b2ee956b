"""A daemon stops on the SIGINT a supervisor sends the moment it has announced itself.

A shell starts background jobs with SIGINT ignored; the daemons used to take that
disposition over until their event loop installed its handlers, a few milliseconds after
their announcement line. A fresh-clone ``make test`` (run as a background job) lost the
signal that way and left a restarted ground station serving. Each case here starts the
shipped console script the way such a shell does and signals it right after its line.
"""

from __future__ import annotations

import asyncio
import os
import signal
import socket
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

from companion.stop_signals import EarlyStop
from tests.keys import write_test_keys

ROUNDS = 3


def _ignore_sigint() -> None:  # what `cmd &` in a non-interactive shell does
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _free_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _stops_right_after(argv: list[str], announced: Callable[[str], bool], *,
                       cwd: Path | None = None) -> None:
    for round_ in range(ROUNDS):
        proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True, cwd=cwd, preexec_fn=_ignore_sigint,
                                env=dict(os.environ, PYTHONUNBUFFERED="1"))
        try:
            assert proc.stdout is not None
            lines = []
            while not lines or not announced(lines[-1]):
                line = proc.stdout.readline()
                assert line, f"exited before announcing itself: {lines} {proc.stderr.read()}"  # type: ignore[union-attr]
                lines.append(line)
            proc.send_signal(signal.SIGINT)
            try:
                code = proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                pytest.fail(f"round {round_}: still running 15 s after SIGINT: {argv}")
            assert code == 0, proc.stderr.read()  # type: ignore[union-attr]
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
            for stream in (proc.stdout, proc.stderr):
                if stream is not None:
                    stream.close()


def test_a_signal_before_the_loop_reaches_the_loop() -> None:
    previous = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        early = EarlyStop()
        os.kill(os.getpid(), signal.SIGINT)  # no KeyboardInterrupt, not ignored
        assert early.received is signal.SIGINT

        async def main() -> int:
            stopped = asyncio.Event()
            loop = asyncio.get_running_loop()
            early.attach(loop, stopped.set)
            await asyncio.wait_for(stopped.wait(), 5)
            early.received = None
            stopped.clear()
            os.kill(os.getpid(), signal.SIGTERM)  # and later signals reach it too
            await asyncio.wait_for(stopped.wait(), 5)
            for sig in (signal.SIGINT, signal.SIGTERM):
                loop.remove_signal_handler(sig)
            return 0

        assert asyncio.run(main()) == 0
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def test_ground_station_stops_on_sigint_right_after_dashboard_line(tmp_path: Path) -> None:
    write_test_keys(tmp_path / "data" / "keys")
    config = tmp_path / "gs.toml"
    config.write_text(
        '[ground_station]\nfleet_id = 5\ndata_dir = "data"\nmission = "sig"\n'
        f'udp_host = "127.0.0.1"\nudp_port = {_free_port(socket.SOCK_DGRAM)}\n'
        f"http_port = {_free_port(socket.SOCK_STREAM)}\n"
    )
    _stops_right_after([sys.executable, "-m", "ground_station.cli", "run", "--config",
                        str(config)], lambda line: line.startswith("dashboard:"), cwd=tmp_path)


def test_vehicle_stops_on_sigint_right_after_ready() -> None:
    _stops_right_after([sys.executable, "-m", "sitl.cli", "vehicle", "--port", "0",
                        "--first-fix", "0"], lambda line: line.startswith("READY "))


def test_relay_stops_on_sigint_right_after_its_line() -> None:
    _stops_right_after([sys.executable, "-m", "sitl.relay_udp", "--listen",
                        f"127.0.0.1:{_free_port(socket.SOCK_DGRAM)}", "--to", "127.0.0.1:9",
                        "--rate", "20000"], lambda line: line.startswith("relay "))
