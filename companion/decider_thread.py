"""The one thread the decider runs in: an executor whose worker is a daemon thread.

``ThreadPoolExecutor`` joins its workers at interpreter exit, so a companion stopped while its
optimiser warms up (numba compiling for up to a minute on a cold cache) logged "stopped" and
then hung until the compiler finished: SIGTERM took that long, and a supervisor's stop
timeout (20 s in the tests, 90 s under systemd) ended it with SIGKILL. Here the worker is a
daemon thread: once the app has stopped cleanly, the process exits even if the decider is
still busy. numba writes its cache files whole (a temporary file, then a rename), so an
abandoned compile leaves no broken cache behind.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable
from concurrent.futures import Executor, Future
from typing import Any

__all__ = ["DeciderThread"]

_Work = tuple["Future[Any]", Callable[..., Any], tuple[Any, ...], dict[str, Any]]


class DeciderThread(Executor):
    """Runs submitted calls one at a time, in order, on one daemon thread (started lazily)."""

    def __init__(self, name: str = "decide") -> None:
        self._name = name
        self._queue: queue.SimpleQueue[_Work | None] = queue.SimpleQueue()
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._shutdown = False

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Future[Any]:
        with self._lock:
            if self._shutdown:
                raise RuntimeError("cannot schedule new futures after shutdown")
            future: Future[Any] = Future()
            self._queue.put((future, fn, args, kwargs))
            if self._thread is None:
                self._thread = threading.Thread(target=self._work, name=self._name,
                                                daemon=True)
                self._thread.start()
            return future

    def _work(self) -> None:
        while (item := self._queue.get()) is not None:
            future, fn, args, kwargs = item
            if not future.set_running_or_notify_cancel():
                continue
            try:
                result = fn(*args, **kwargs)
            except BaseException as exc:  # as ThreadPoolExecutor: the caller sees it
                future.set_exception(exc)
            else:
                future.set_result(result)

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        with self._lock:
            self._shutdown = True
            if cancel_futures:
                while True:
                    try:
                        item = self._queue.get_nowait()
                    except queue.Empty:
                        break
                    if item is not None:
                        item[0].cancel()
            self._queue.put(None)
            thread = self._thread
        if wait and thread is not None:
            thread.join()
