"""SIGINT/SIGTERM honoured from a daemon's first line on.

A daemon announces itself (the dashboard URL, ``READY``, the relay line) a moment before its
event loop installs its signal handlers. A stop signal in that moment was lost: a shell
starts background jobs with SIGINT ignored (``cmd &``), and the loop only replaced that
disposition later, so a supervisor that read the line and sent SIGINT at once left the daemon
running. Created first thing in ``main``, :class:`EarlyStop` records such a signal and hands
it to the loop when the loop takes over.
"""

from __future__ import annotations

import asyncio
import contextlib
import signal
import threading
from collections.abc import Callable
from types import FrameType

__all__ = ["STOP_SIGNALS", "EarlyStop"]

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class EarlyStop:
    """Catches the stop signals now; :meth:`attach` moves them to an event loop."""

    __slots__ = ("received",)

    def __init__(self) -> None:
        self.received: signal.Signals | None = None
        if threading.current_thread() is not threading.main_thread():
            return  # only the main thread may set handlers (an embedding test, not the CLI)
        for sig in STOP_SIGNALS:
            signal.signal(sig, self._record)

    def _record(self, signum: int, frame: FrameType | None) -> None:
        self.received = signal.Signals(signum)

    def attach(self, loop: asyncio.AbstractEventLoop, stop: Callable[[], object]) -> None:
        """``stop`` runs on every later stop signal, and soon if one came before."""
        for sig in STOP_SIGNALS:
            with contextlib.suppress(NotImplementedError, RuntimeError, ValueError):
                loop.add_signal_handler(sig, stop)
        if self.received is not None:
            loop.call_soon(stop)
