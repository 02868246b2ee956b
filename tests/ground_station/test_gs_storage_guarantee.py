"""The storage guarantee: durable or visibly not, and a writer that cannot die quietly.

``Storage.write_batch`` says per item whether it is durable (``BatchResult.stored``); the
receiver reports exactly those. ``StorageService`` survives any exception, restarts its
writer task, and bounds its backlog (docs/ground_station.md, "What a receiver report
promises").
"""

from __future__ import annotations

import asyncio
import errno
import os
import sqlite3
import threading
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

from ground_station.storage import BatchResult, Storage, StoreItem
from ground_station.store_service import StorageService
from tests.ground_station.test_gs_storage import T0, image, telemetry


def poisoned(seq: int) -> StoreItem:
    """An image whose size SQLite cannot hold (issue 13: a signed ``size`` of 2**63)."""
    item = image(seq)
    return replace(item, message=replace(item.message, size=2**63))


def test_a_value_sqlite_cannot_hold_fails_alone(tmp_path: Path) -> None:
    s = Storage(tmp_path, fsync=False)
    result = s.write_batch([image(1), poisoned(2), image(3), telemetry(4)], now=T0)
    assert result.stored == [True, False, True, True]
    [error] = result.errors
    assert "d1/2" in error and "OverflowError" in error
    # the connection is not left inside a failed transaction: the next batch lands
    again = s.write_batch([image(5), poisoned(6)], now=T0)
    assert again.stored == [True, False]
    assert {r.seq for r in s.images("m", limit=100)} == {1, 3, 5}
    assert s.counts("m") == {"images": 3, "images_on_disk": 3, "messages": 4}
    s.close()
    # what was stored is what the mission log has: no line for an item without a row
    log = Storage(tmp_path).log_path("m").read_text().splitlines()
    assert sum('"seq": ' in line for line in log) == 4


def test_a_failing_mission_mark_loses_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Issue 13 (a): ``mark_mission`` failing on the first batch (a disk that fills as the
    first image after a mission start arrives) used to escape ``write_batch``."""
    s = Storage(tmp_path, fsync=False)

    def full(self: Storage, *args: Any, **kwargs: Any) -> None:
        raise sqlite3.OperationalError("database or disk is full")

    monkeypatch.setattr(Storage, "mark_mission", full)
    result = s.write_batch([image(1), telemetry(2)], now=T0)
    assert result.stored == [True, True]
    assert any("mission bounds not stored" in e for e in result.errors)
    monkeypatch.undo()
    later = s.write_batch([image(3)], now=T0)  # bounds are retried with the next batch
    assert later.stored == [True] and later.errors == []
    assert [m["t_start"] for m in s.missions()] == [T0 + 1]
    s.close()


def test_an_image_whose_file_failed_is_not_durable(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    s = Storage(tmp_path, fsync=False)
    real = Storage._write_file

    def full_for_seq_2(self: Storage, relpath: Path, payload: bytes) -> None:
        if relpath.name.startswith("000000002"):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        real(self, relpath, payload)

    monkeypatch.setattr(Storage, "_write_file", full_for_seq_2)
    result = s.write_batch([image(1), image(2), telemetry(3)], now=T0)
    assert result.stored == [True, False, True]
    assert result.images_stored == 1
    s.close()


# -- the service -------------------------------------------------------------------------
class Batches:
    """Collects what ``on_batch`` reports: (seq, durable) per item."""

    def __init__(self) -> None:
        self.outcomes: dict[int, bool] = {}
        self.errors: list[str] = []

    def __call__(self, items: Sequence[StoreItem], result: BatchResult) -> None:
        for item, durable in zip(items, result.stored, strict=True):
            self.outcomes[item.message.seq] = durable
        self.errors += result.errors


async def until(predicate: Any, timeout: float = 5.0) -> None:
    async with asyncio.timeout(timeout):
        while not predicate():
            await asyncio.sleep(0.005)


async def test_the_writer_survives_any_exception(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    batches = Batches()
    service = StorageService(tmp_path, clock=lambda: T0, fsync=False, on_batch=batches)
    await service.open()
    real = Storage.write_batch
    calls = 0

    def explodes_once(self: Storage, items: Sequence[StoreItem], *, now: float) -> BatchResult:
        nonlocal calls
        calls += 1
        if calls == 1:
            raise RuntimeError("a bug nobody anticipated")
        return real(self, items, now=now)

    monkeypatch.setattr(Storage, "write_batch", explodes_once)
    assert service.submit(image(1))
    await until(lambda: 1 in batches.outcomes)
    assert batches.outcomes[1] is False  # failed visibly: never reported delivered
    assert any("a bug nobody anticipated" in e for e in batches.errors)
    for seq in (2, 3):
        assert service.submit(image(seq))
    await service.flush()
    assert batches.outcomes == {1: False, 2: True, 3: True}
    stats = service.stats()
    assert stats["batch_failures"] == 1 and stats["not_stored"] == 1
    assert stats["errors"] >= 1 and "a bug nobody anticipated" in stats["last_error"]
    assert stats["backlog_bytes"] == 0
    await service.close()


async def test_a_writer_task_that_ends_is_restarted(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    batches = Batches()
    service = StorageService(tmp_path, clock=lambda: T0, fsync=False, on_batch=batches)
    await service.open()
    real_drain = service._drain
    broken = True

    def drain_breaks_once() -> list[Any]:
        nonlocal broken
        if broken:
            broken = False
            raise RuntimeError("writer loop bug")
        return real_drain()

    monkeypatch.setattr(service, "_drain", drain_breaks_once)
    service.submit(image(1))  # taken by the writer task, which then dies
    await until(lambda: service.restarts == 1)
    service.submit(image(2))
    await until(lambda: 2 in batches.outcomes)
    assert batches.outcomes[2] is True
    assert service.stats()["writer_restarts"] == 1
    assert "writer loop bug" in (service.stats()["last_error"] or "")
    await service.close()


async def test_the_backlog_is_bounded_and_refusals_are_counted(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A disk that stalls: the queue stops growing at the bound, what is refused is counted
    (and never reported), and everything accepted is stored once the disk is back."""
    batches = Batches()
    service = StorageService(tmp_path, clock=lambda: T0, fsync=False, on_batch=batches,
                             max_backlog_bytes=20_000)
    await service.open()
    release = threading.Event()
    real = Storage.write_batch

    def stalls(self: Storage, items: Sequence[StoreItem], *, now: float) -> BatchResult:
        release.wait(10)
        return real(self, items, now=now)

    monkeypatch.setattr(Storage, "write_batch", stalls)
    accepted = [seq for seq in range(1, 41) if service.submit(image(seq))]
    # each image costs ~1 kB payload + 512 bytes of overhead: 13 fit 20 kB
    assert len(accepted) == 13 and accepted == list(range(1, 14))
    assert service.refused == 27 and service.backlog_bytes <= 20_000
    release.set()
    await service.flush()
    assert batches.outcomes == dict.fromkeys(accepted, True)
    stats = service.stats()
    assert stats["refused"] == 27 and stats["not_stored"] == 27 and stats["backlog_bytes"] == 0
    assert service.submit(image(41))  # room again
    await service.close()
