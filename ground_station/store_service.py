"""Asyncio shell around :class:`~ground_station.storage.Storage`: writes off the event loop.

One owned single-thread executor does every write (file fsyncs, SQLite transactions, log
lines) in arrival order, in batches; a second one serves reads on its own WAL connection so
the dashboard never waits behind an fsync. The receiver only calls :meth:`submit` (no await).

The writer cannot die quietly: any exception a batch raises fails that batch (every item
reported not stored through ``on_batch``, counted, alerted) and the writer goes on; should
the writer task itself end, it is restarted and the restart counted. Memory is bounded:
past ``max_backlog_bytes`` or ``max_backlog_items`` :meth:`submit` refuses (back-pressure:
the item is never reported delivered, so the drones' optimisers see it as lost).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, TypeVar

from ground_station.fleet import Alert
from ground_station.storage import BatchResult, Storage, StoreItem

__all__ = ["StorageService"]

log = logging.getLogger(__name__)
T = TypeVar("T")

MAX_BATCH = 256
LOG_EVERY_S = 10.0
MAX_BACKLOG_BYTES = 64 << 20
"""Payload bytes queued or being written beyond which new items are refused."""
MAX_BACKLOG_ITEMS = 50_000
ITEM_OVERHEAD_BYTES = 512
"""What one queued item costs besides its payload (message, metadata), roughly."""
RESTART_DELAY_S = 0.1


class StorageService:
    """Queue + writer task + reader; start with :meth:`open`, stop with :meth:`close`."""

    def __init__(
        self,
        root: Path,
        *,
        clock: Callable[[], float],
        fsync: bool = True,
        on_batch: Callable[[Sequence[StoreItem], BatchResult], None] | None = None,
        max_backlog_bytes: int = MAX_BACKLOG_BYTES,
        max_backlog_items: int = MAX_BACKLOG_ITEMS,
    ) -> None:
        self.root = root
        self.clock = clock
        self.fsync = fsync
        self.on_batch = on_batch
        self.max_backlog_bytes = max_backlog_bytes
        self.max_backlog_items = max_backlog_items
        self.backlog_bytes = 0
        """Payload (+ overhead) bytes of items queued or in the batch being written."""
        self.refused = 0
        """Items refused by :meth:`submit` because the backlog was full."""
        self.not_stored = 0
        """Submitted items that did not become durable (failed or refused)."""
        self.batch_failures = 0
        """Batches whose write raised (every item of such a batch is not stored)."""
        self.restarts = 0
        """Times the writer task ended unexpectedly and was started again."""
        self._closing = False
        self._queue: asyncio.Queue[StoreItem | tuple[str, Alert]] = asyncio.Queue()
        self._write_pool = ThreadPoolExecutor(1, thread_name_prefix="gs-store-write")
        self._read_pool = ThreadPoolExecutor(1, thread_name_prefix="gs-store-read")
        self._writer: Storage | None = None
        self._reader: Storage | None = None
        self._task: asyncio.Task[None] | None = None
        self.submitted = 0
        self.written = 0
        self.images_stored = 0
        self.errors = 0
        self.last_error: str | None = None
        self._unlogged = 0
        self._logged_at = -math.inf

    async def open(self) -> None:
        loop = asyncio.get_running_loop()
        self._writer = await loop.run_in_executor(
            self._write_pool, lambda: Storage(self.root, fsync=self.fsync)
        )
        if self._writer.removed_temp_files:
            log.warning("storage: removed %d half-written image files of an earlier crash",
                        self._writer.removed_temp_files)
        self._reader = await loop.run_in_executor(
            self._read_pool, lambda: Storage(self.root, readonly=True)
        )
        self._start_writer()

    def _start_writer(self) -> None:
        if self._closing:
            return
        self._task = asyncio.create_task(self._run(), name="gs-storage-writer")
        self._task.add_done_callback(self._writer_ended)

    def _writer_ended(self, task: asyncio.Task[None]) -> None:
        """Supervision: a writer task that ends while the service is open is restarted."""
        if self._closing or task.cancelled():
            return
        exc = task.exception()
        self.restarts += 1
        self.errors += 1
        self.last_error = f"storage writer restarted after {exc!r}"
        log.error("storage: writer task ended (%r); restarting it", exc)
        asyncio.get_running_loop().call_later(RESTART_DELAY_S, self._start_writer)

    def submit(self, item: StoreItem) -> bool:
        """Queue ``item``; False (and counted) when the backlog is full: it will not be
        stored, so it must not be reported delivered."""
        cost = _cost(item)
        if (
            self.backlog_bytes + cost > self.max_backlog_bytes
            or self._queue.qsize() >= self.max_backlog_items
        ):
            self.refused += 1
            self.not_stored += 1
            return False
        self.submitted += 1
        self.backlog_bytes += cost
        self._queue.put_nowait(item)
        return True

    def submit_alert(self, mission: str, alert: Alert) -> None:
        self._queue.put_nowait((mission, alert))

    @property
    def backlog(self) -> int:
        return self._queue.qsize()

    async def _run(self) -> None:
        while True:
            first = await self._queue.get()
            await self._write([first, *self._drain()])

    def _drain(self) -> list[StoreItem | tuple[str, Alert]]:
        batch: list[StoreItem | tuple[str, Alert]] = []
        while len(batch) < MAX_BATCH - 1:
            try:
                batch.append(self._queue.get_nowait())
            except asyncio.QueueEmpty:
                break
        return batch

    async def _write(self, queued: list[StoreItem | tuple[str, Alert]]) -> None:
        writer = self._writer
        assert writer is not None
        loop = asyncio.get_running_loop()
        now = self.clock()
        batch = [item for item in queued if isinstance(item, StoreItem)]
        alerts = [
            (mission, a.t, a.level, a.kind, a.drone, a.text)
            for item in queued
            if isinstance(item, tuple)
            for mission, a in [item]
        ]

        def work() -> BatchResult:
            result = writer.write_batch(batch, now=now) if batch else BatchResult()
            if alerts:
                try:
                    writer.write_alerts(alerts)
                except Exception as exc:  # alerts never stop images
                    result.errors.append(f"alert not stored: {exc}")
            return result

        try:
            result = await loop.run_in_executor(self._write_pool, work)
        except Exception as exc:  # a batch may fail; the writer may not
            self.batch_failures += 1
            result = BatchResult(
                image_ids=[None] * len(batch),
                errors=[f"storage batch of {len(batch)} failed: {exc!r}"],
                stored=[False] * len(batch),
            )
        finally:
            self.backlog_bytes -= sum(_cost(item) for item in batch)
        if len(result.stored) != len(batch):  # a Storage that does not say: nothing durable
            result.stored = [False] * len(batch)
        self.written += len(batch)
        self.images_stored += result.images_stored
        self.not_stored += result.stored.count(False)
        if result.errors:
            self.errors += len(result.errors)
            self.last_error = result.errors[-1]
            self._log_errors(result.errors, now)
        if self.on_batch is not None:
            try:
                self.on_batch(batch, result)
            except Exception:  # a bug in the callback must not stop the writer
                log.exception("storage: on_batch callback failed")

    def _log_errors(self, errors: Sequence[str], now: float) -> None:
        """Every error is counted; the log gets one line per ``LOG_EVERY_S`` with how many it
        skipped, so a full disk (errors in every batch) does not flood it."""
        self._unlogged += len(errors)
        if now - self._logged_at < LOG_EVERY_S:
            return
        skipped = self._unlogged - 1
        log.error("storage: %s%s", errors[-1],
                  f" (and {skipped} more errors since the last line)" if skipped else "")
        self._unlogged, self._logged_at = 0, now

    async def call_writer(self, fn: Callable[[Storage], T]) -> T:
        """Run ``fn(storage)`` in the write thread, ordered after queued batches' writes."""
        assert self._writer is not None
        writer = self._writer
        return await asyncio.get_running_loop().run_in_executor(self._write_pool, fn, writer)

    async def read(self, fn: Callable[[Storage], T]) -> T:
        """Run a query ``fn(storage)`` in the read thread (its own WAL connection)."""
        assert self._reader is not None
        reader = self._reader
        return await asyncio.get_running_loop().run_in_executor(self._read_pool, fn, reader)

    async def flush(self) -> None:
        """Write everything queued so far (used at shutdown and by tests)."""
        while self._queue.qsize():
            batch = self._drain()
            if batch:
                await self._write(batch)
        # Wait for a batch the writer task may be in the middle of.
        await self.call_writer(lambda _s: None)

    async def close(self) -> None:
        """Write what is queued, stop the writer task, close both connections."""
        if self._writer is not None:
            await self.flush()
        self._closing = True
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
            self._task = None
        loop = asyncio.get_running_loop()
        if self._writer is not None:
            closing_now = self.clock()
            writer = self._writer
            await loop.run_in_executor(self._write_pool, lambda: writer.close(now=closing_now))
            self._writer = None
        if self._reader is not None:
            await loop.run_in_executor(self._read_pool, self._reader.close)
            self._reader = None
        self._write_pool.shutdown(wait=True)
        self._read_pool.shutdown(wait=True)

    def stats(self) -> dict[str, Any]:
        return {
            "submitted": self.submitted,
            "written": self.written,
            "images_stored": self.images_stored,
            "backlog": self.backlog,
            "backlog_bytes": self.backlog_bytes,
            "refused": self.refused,
            "not_stored": self.not_stored,
            "batch_failures": self.batch_failures,
            "writer_restarts": self.restarts,
            "errors": self.errors,
            "last_error": self.last_error,
        }


def _cost(item: StoreItem | tuple[str, Alert]) -> int:
    if not isinstance(item, StoreItem):
        return 0
    return ITEM_OVERHEAD_BYTES + (len(item.payload) if item.payload is not None else 0)
