"""The decider's executor: one daemon thread, calls in order, exceptions to the caller,
queued calls cancelled by ``shutdown(cancel_futures=True)``, nothing after shutdown."""

from __future__ import annotations

import asyncio
import threading

import pytest

from companion.decider_thread import DeciderThread


async def test_calls_run_in_order_on_one_daemon_thread_and_raise_to_the_caller() -> None:
    pool = DeciderThread("decide-test")
    loop = asyncio.get_running_loop()
    seen: list[tuple[int, str, bool]] = []

    def work(i: int) -> int:
        me = threading.current_thread()
        seen.append((i, me.name, me.daemon))
        return i * i

    try:
        results = await asyncio.gather(*(loop.run_in_executor(pool, work, i) for i in range(5)))
        assert results == [0, 1, 4, 9, 16]
        assert seen == [(i, "decide-test", True) for i in range(5)]

        def boom() -> None:
            raise ValueError("bad spec")

        with pytest.raises(ValueError, match="bad spec"):
            await loop.run_in_executor(pool, boom)
    finally:
        pool.shutdown(wait=True)


def test_shutdown_cancels_what_waits_and_refuses_new_work() -> None:
    pool = DeciderThread()
    started, release = threading.Event(), threading.Event()

    def hold() -> bool:
        started.set()
        return release.wait(10.0)

    running = pool.submit(hold)
    assert started.wait(10.0)
    queued = pool.submit(lambda: "never")
    pool.shutdown(wait=False, cancel_futures=True)
    assert queued.cancelled()
    with pytest.raises(RuntimeError, match="after shutdown"):
        pool.submit(lambda: None)
    release.set()
    assert running.result(timeout=5.0) is True
