"""Parameter sweeps on Dask distributed: seeded cells, results streamed to a CSV, resumable.

A study is a list of *cells* (dicts of scalar parameters) and a module-level *cell function*
``fn(params, seed) -> dict of scalars``. :func:`run_sweep` runs the cells on a Dask cluster
(a local one by default, or an existing scheduler), appends one CSV row per cell as it
finishes, prints a progress line with cells done and time left, and on a second call with the
same CSV skips the cells already there, so an interrupted sweep resumes where it stopped.

Each cell's seed is a hash of its parameters, never of its position in the list: adding,
removing or reordering cells, or resuming, gives every cell the same draws.
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import json
import logging
import math
import signal
import socket
import sys
import threading
import time
import uuid
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import numpy as np

__all__ = [
    "CellFailed",
    "SweepResult",
    "cell_id",
    "cell_seed",
    "dask_client",
    "map_cells",
    "mean_interval",
    "progress_line",
    "read_done",
    "run_sweep",
]

Scalar = str | int | float | bool
CellFn = Callable[[dict[str, Any], int], dict[str, Any]]
ID_COLUMN = "cell_id"
SEED_COLUMN = "seed"


class CellFailed(RuntimeError):
    """A cell raised on its worker; the sweep goes on and reports the failures at the end."""


def _canonical(params: Mapping[str, Any]) -> str:
    for name, value in params.items():
        if not isinstance(value, str | int | float | bool):
            raise TypeError(f"cell parameter {name}={value!r} is not a scalar")
    return json.dumps(dict(params), sort_keys=True, separators=(",", ":"))


def cell_id(params: Mapping[str, Any]) -> str:
    """Stable name of a cell: a hash of its parameters (order of keys does not matter)."""
    return hashlib.sha256(_canonical(params).encode()).hexdigest()[:16]


def cell_seed(params: Mapping[str, Any]) -> int:
    """The cell's seed (0 .. 2^32-1), derived from its parameters alone."""
    digest = hashlib.sha256(b"seed:" + _canonical(params).encode()).digest()
    return int.from_bytes(digest[:4], "big")


@dataclass(frozen=True, slots=True)
class SweepResult:
    rows: list[dict[str, str]]
    """Every row of the CSV (earlier runs' and this one's), as read back from the file."""
    ran: int
    skipped: int
    failed: list[tuple[dict[str, Any], str]]
    wall_s: float


def read_done(path: Path) -> tuple[list[str] | None, list[dict[str, str]]]:
    """(header, complete rows) of a sweep CSV; a row torn by an interruption is cut off."""
    if not path.exists():
        return None, []
    text = path.read_text(encoding="utf-8")
    if text and not text.endswith("\n"):
        text = text[: text.rfind("\n") + 1]
        path.write_text(text, encoding="utf-8")
    lines = text.splitlines()
    if not lines:
        return None, []
    reader = csv.DictReader(lines)
    header = list(reader.fieldnames or [])
    rows = [r for r in reader if r.get(ID_COLUMN) and None not in r.values()]
    return header, rows


@contextmanager
def dask_client(
    scheduler: str | None = None, *, workers: int = 2, connect_timeout_s: float = 10.0
) -> Iterator[Any]:
    """A Dask client: on ``scheduler`` (``tcp://host:8786``) or on a local cluster of
    ``workers`` single-threaded worker processes that is shut down on exit."""
    from dask.distributed import Client, LocalCluster

    if scheduler:
        _refuse_fast(scheduler, timeout_s=connect_timeout_s)
        client = Client(scheduler, timeout=connect_timeout_s)  # type: ignore[no-untyped-call]
        with client:
            yield client
        return
    # numba/BLAS inside a cell must not start a thread per core in each worker
    one_thread = {name: "1" for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                                         "MKL_NUM_THREADS", "NUMBA_NUM_THREADS")}
    # Ctrl-C at a terminal reaches the whole process group: each worker printed a
    # KeyboardInterrupt traceback. They start with SIGINT ignored (inherited across exec);
    # the study itself stops on it and closes the cluster.
    # Their logs only at CRITICAL: after a Ctrl-C the scheduler may close before a worker,
    # whose next heartbeat then logged an ERROR with a CommClosedError traceback (seen once
    # in make test). A cell that fails raises in the study through its future anyway.
    ignore = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN) if ignore else None
    try:
        cluster = LocalCluster(  # type: ignore[no-untyped-call]
            n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
            dashboard_address="127.0.0.1:0", silence_logs=logging.CRITICAL, env=one_thread,
        )
    finally:
        if ignore:
            signal.signal(signal.SIGINT, previous)
    local = Client(cluster)  # type: ignore[no-untyped-call]
    try:
        yield local
    finally:
        _shut_down(local, cluster)


def _refuse_fast(scheduler: str, *, timeout_s: float) -> None:
    """Raise at once when nothing listens at a ``tcp://`` scheduler (a mistyped port): Dask
    retries a refused connection for its whole connect timeout before it says so."""
    parts = urlsplit(scheduler)
    try:
        host, port = parts.hostname, parts.port or 8786
    except ValueError:  # urlsplit's own message is "Port could not be cast to integer value"
        raise ValueError(f"--scheduler {scheduler}: the port is not a number "
                         "(tcp://HOST:8786)") from None
    if parts.scheme != "tcp" or not host:
        return
    try:
        socket.create_connection((host, port), timeout=timeout_s).close()
    except ConnectionRefusedError:
        raise ConnectionRefusedError(
            f"nothing listens at {scheduler} (connection refused): start the scheduler there "
            "or leave --scheduler out for a local cluster") from None
    except OSError:
        return  # unreachable or slow: Dask tries for its timeout and says so


def _shut_down(client: Any, cluster: Any) -> None:
    """Close the local cluster; a slow shutdown on a loaded host is not the sweep's failure
    (every finished cell is already in the CSV), so it is a note, not an error."""
    for closable in (client, cluster):
        try:
            closable.close()
        except (TimeoutError, OSError) as exc:
            print(f"note: the local Dask cluster shut down slowly ({error_text(exc)}); "
                  "the results are complete", file=sys.stderr)


def error_text(exc: BaseException) -> str:
    """An exception as one line, also when it carries no message (Dask's TimeoutError)."""
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


def mean_interval(values: Sequence[float]) -> tuple[float, float, float]:
    """Mean and its 95 % t-interval (low, high) over runs or seeds, as every study's tables
    and error bars give them; NaN bounds for a single value (no interval)."""
    from scipy import stats  # type: ignore[import-untyped]

    a = np.asarray(values, dtype=float)
    mean = float(a.mean())
    if len(a) < 2:
        return mean, math.nan, math.nan
    half = float(stats.t.ppf(0.975, len(a) - 1) * a.std(ddof=1) / math.sqrt(len(a)))
    return mean, mean - half, mean + half


def add_cluster_options(parser: argparse.ArgumentParser) -> None:
    """``--scheduler`` and ``--workers``, the same for every study on this runner."""
    parser.add_argument("--scheduler", metavar="ADDRESS",
                        help="Dask scheduler to use (tcp://host:8786); default a local cluster")
    parser.add_argument("--workers", type=int, default=2,
                        help="worker processes of the local cluster (default 2)")


def _fmt_s(s: float) -> str:
    s = max(0.0, s)
    if s < 120:
        return f"{s:.0f}s"
    if s < 7200:
        return f"{s / 60:.0f}min"
    return f"{s / 3600:.1f}h"


def progress_line(text: str) -> None:
    """A study's progress line on stderr."""
    # one write: print() writes the text and its newline apart, and a Ctrl-C between the
    # two left the "interrupted" line glued to the progress line (seen once in make test)
    sys.stderr.write(text + "\n")
    sys.stderr.flush()


def _call(fn: CellFn, params: dict[str, Any], seed: int) -> dict[str, Any]:
    started = time.perf_counter()
    out = dict(fn(params, seed))
    out.setdefault("cell_wall_s", round(time.perf_counter() - started, 3))
    return out


def map_cells(
    client: Any,
    fn: CellFn,
    cells: Sequence[Mapping[str, Any]],
    *,
    label: str = "cells",
    progress: Callable[[str], None] = progress_line,
) -> Iterator[tuple[dict[str, Any], int, dict[str, Any] | BaseException]]:
    """Run ``cells`` on ``client``; yield (params, seed, result or exception) as each finishes."""
    from dask.distributed import as_completed

    if not cells:
        return
    started = time.perf_counter()
    submitted, by_key = [], {}
    for params in cells:
        p = dict(params)
        seed = cell_seed(p)
        # a fresh key each time: a cell that failed is run again, not answered from memory
        key = f"{label}-{cell_id(p)}-{uuid.uuid4().hex[:8]}"
        fut = client.submit(_call, fn, p, seed, key=key, pure=False)
        submitted.append(fut)
        by_key[fut.key] = (p, seed)
    del fut
    total = len(submitted)
    pending = as_completed(submitted)  # type: ignore[no-untyped-call]
    submitted.clear()  # as_completed holds them; release each as it is consumed
    for done, fut in enumerate(pending, start=1):
        p, seed = by_key[fut.key]
        try:
            result: dict[str, Any] | BaseException = fut.result()
        except Exception as exc:  # a cell's own error, reported at the end
            result = exc
        fut.release()
        elapsed = time.perf_counter() - started
        left = elapsed / done * (total - done)
        width = 24
        bar = "#" * round(width * done / total)
        progress(f"{label} [{bar:<{width}}] {done}/{total} done, {_fmt_s(elapsed)} elapsed, "
                 f"~{_fmt_s(left)} left")
        yield p, seed, result


def run_sweep(
    fn: CellFn,
    cells: Sequence[Mapping[str, Any]],
    *,
    out: Path,
    scheduler: str | None = None,
    workers: int = 2,
    label: str = "cells",
    progress: Callable[[str], None] = progress_line,
    client: Any = None,
) -> SweepResult:
    """Run the cells not yet in ``out``; append each result to ``out`` as it finishes.

    The CSV columns are the cell's parameters, ``cell_id``, ``seed`` and then the result's
    keys (every cell of one sweep returns the same keys). A cell that raises is reported and
    left out of the CSV, so the next run retries it.
    """
    started = time.perf_counter()
    header, rows = read_done(out)
    done_ids = {r[ID_COLUMN] for r in rows}
    todo, seen = [], set()
    for params in cells:
        cid = cell_id(params)
        if cid in done_ids or cid in seen:
            continue
        seen.add(cid)
        todo.append(dict(params))
    skipped = len({cell_id(p) for p in cells} & done_ids)
    if skipped:
        progress(f"{label}: {skipped} of {skipped + len(todo)} cells already in {out}, "
                 f"running {len(todo)}")
    failed: list[tuple[dict[str, Any], str]] = []
    if todo:
        out.parent.mkdir(parents=True, exist_ok=True)
        with _client_or(client, scheduler, workers) as c, out.open("a", newline="",
                                                                  encoding="utf-8") as f:
            writer: csv.DictWriter[str] | None = None
            if header is not None:
                writer = csv.DictWriter(f, fieldnames=header)
            for p, seed, result in map_cells(c, fn, todo, label=label, progress=progress):
                if isinstance(result, BaseException):
                    failed.append((p, f"{type(result).__name__}: {result}"))
                    progress(f"{label}: cell {p} failed: {type(result).__name__}: {result}")
                    continue
                row = {**p, ID_COLUMN: cell_id(p), SEED_COLUMN: seed, **result}
                if writer is None:
                    writer = csv.DictWriter(f, fieldnames=list(row))
                    writer.writeheader()
                missing = set(writer.fieldnames) - set(row)
                extra = set(row) - set(writer.fieldnames)
                if missing or extra:
                    raise ValueError(f"cell {p} returned columns {sorted(row)}, the CSV has "
                                     f"{list(writer.fieldnames)}; use a new --out")
                writer.writerow(row)
                f.flush()
    _, rows = read_done(out)
    return SweepResult(rows=rows, ran=len(todo) - len(failed), skipped=skipped, failed=failed,
                       wall_s=time.perf_counter() - started)


@contextmanager
def _client_or(client: Any, scheduler: str | None, workers: int) -> Iterator[Any]:
    if client is not None:
        yield client
        return
    with dask_client(scheduler, workers=workers) as c:
        yield c


def sweep_figure(fn: CellFn, cells: Sequence[Mapping[str, Any]], *, args: Any, name: str,
                 label: str) -> SweepResult | None:
    """A figure command's cells on Dask (``args.out``, ``args.scheduler``, ``args.workers``)
    into ``args.out/NAME.csv`` (streamed, resumable); None after a one-line error (no
    scheduler there, an unwritable folder, or a CSV of another sweep in it)."""
    out: Path = args.out
    try:
        out.mkdir(parents=True, exist_ok=True)
        with dask_client(args.scheduler, workers=args.workers) as client:
            return run_sweep(fn, cells, out=out / f"{name}.csv", client=client, label=label)
    except (OSError, ValueError) as exc:
        print(f"uav-sitl study {label}: {error_text(exc)}", file=sys.stderr)
        return None


def write_rows(path: Path, rows: Sequence[Mapping[str, Any]]) -> None:
    """A summary table as CSV (columns of the first row)."""
    with path.open("w", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
