"""The Dask sweep runner: seeds from parameters, streamed CSV, resume, failures, shutdown."""

from __future__ import annotations

import csv
import os
import random
import time
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

pytest.importorskip("dask.distributed", reason="pip install -e '.[study]' (Dask distributed)")

from sitl.study.sweep import cell_id, cell_seed, dask_client, read_done, run_sweep

scalars = st.one_of(st.integers(-10**6, 10**6), st.floats(allow_nan=False, width=32),
                    st.text(max_size=5), st.booleans())


@given(st.dictionaries(st.text(min_size=1, max_size=4), scalars, min_size=1, max_size=5))
def test_seed_and_id_depend_on_the_parameters_not_their_order(params: dict[str, Any]) -> None:
    items = list(params.items())
    random.Random(0).shuffle(items)
    shuffled = dict(items)
    assert cell_seed(shuffled) == cell_seed(params)
    assert cell_id(shuffled) == cell_id(params)
    assert 0 <= cell_seed(params) < 2**32


def test_seeds_are_pinned_so_old_csvs_stay_valid() -> None:
    assert cell_seed({"x": 1}) == cell_seed({"x": 1})
    assert cell_seed({"x": 1}) != cell_seed({"x": 2})
    assert cell_seed({"x": 1}) != cell_seed({"x": 1.5})
    assert cell_id({"scenario": "uniform", "run": 0}) == "14493519a30864e3"
    assert cell_seed({"scenario": "uniform", "run": 0}) == 4003785801


def square_cell(params: dict[str, Any], seed: int) -> dict[str, Any]:
    """A cell whose result depends on its seed."""
    return {"y": params["x"] ** 2, "draw": random.Random(seed).random(), "pid": os.getpid()}


@pytest.fixture(scope="module")
def client():
    with dask_client(workers=2) as c:
        pids = set(c.run(os.getpid).values())
        assert len(pids) == 2 and os.getpid() not in pids  # two worker processes
        yield c
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline and any(_alive(p) for p in pids):
        time.sleep(0.1)
    assert not any(_alive(p) for p in pids), "local cluster left worker processes behind"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return Path(f"/proc/{pid}/stat").exists() and " Z " not in Path(
        f"/proc/{pid}/stat").read_text()


def _rows(path: Path) -> list[dict[str, str]]:
    return list(csv.DictReader(path.open()))


def test_results_stream_to_the_csv_with_seeds_from_parameters(client, tmp_path: Path) -> None:
    out = tmp_path / "sweep.csv"
    cells = [{"x": x} for x in range(6)]
    lines: list[str] = []
    result = run_sweep(square_cell, cells, out=out, client=client, progress=lines.append)
    assert result.ran == 6 and result.skipped == 0 and not result.failed
    rows = _rows(out)
    assert sorted(int(r["y"]) for r in rows) == [0, 1, 4, 9, 16, 25]
    for r in rows:
        seed = cell_seed({"x": int(r["x"])})
        assert int(r["seed"]) == seed
        assert float(r["draw"]) == random.Random(seed).random()
    assert len({r["pid"] for r in rows}) >= 1
    assert lines[-1].startswith("cells [") and "6/6 done" in lines[-1] and "left" in lines[-1]
    # the same cells in another order, in another file: identical draws
    again = tmp_path / "again.csv"
    run_sweep(square_cell, cells[::-1], out=again, client=client, progress=lines.append)
    draws = {r["x"]: r["draw"] for r in _rows(again)}
    assert draws == {r["x"]: r["draw"] for r in rows}


def test_a_resumed_sweep_does_not_redo_finished_cells(client, tmp_path: Path) -> None:
    out = tmp_path / "sweep.csv"
    run_sweep(square_cell, [{"x": x} for x in range(4)], out=out, client=client,
              progress=lambda _: None)
    first = out.read_text()
    # an interruption tore the last row in half: that cell is cut off and redone
    lines = first.splitlines(keepends=True)
    out.write_text("".join(lines[:-1]) + lines[-1][:7])
    torn_x = int(lines[-1].split(",")[0])
    # cells already done would now fail: running them again would show up as failures
    done = [x for x in range(4) if x != torn_x]
    cells = [{"x": x} for x in range(6)]
    seen: list[str] = []
    result = run_sweep(_fails_on(done), cells, out=out, client=client, progress=seen.append)
    assert not result.failed, result.failed
    assert result.skipped == 3 and result.ran == 3
    assert seen[0].startswith("cells: 3 of 6 cells already in")
    rows = _rows(out)
    assert sorted(int(r["x"]) for r in rows) == list(range(6))
    assert out.read_text().startswith(first[: first.index("\n") + 1])  # header kept once
    assert read_done(out)[1] == rows


def _fails_on(xs: list[int]) -> _FailOn:
    return _FailOn(tuple(xs))


class _FailOn:
    """Picklable cell function that refuses the given cells."""

    def __init__(self, xs: tuple[int, ...]) -> None:
        self.xs = xs

    def __call__(self, params: dict[str, Any], seed: int) -> dict[str, Any]:
        if params["x"] in self.xs:
            raise AssertionError(f"cell {params['x']} was run again")
        return square_cell(params, seed)


def test_a_failing_cell_is_reported_left_out_and_retried(client, tmp_path: Path) -> None:
    out = tmp_path / "sweep.csv"
    seen: list[str] = []
    result = run_sweep(_FailOn((2,)), [{"x": x} for x in range(4)], out=out, client=client,
                       progress=seen.append)
    assert [p for p, _ in result.failed] == [{"x": 2}]
    assert "AssertionError: cell 2 was run again" in result.failed[0][1]
    assert any("failed" in line for line in seen)
    assert sorted(int(r["x"]) for r in _rows(out)) == [0, 1, 3]
    retry = run_sweep(square_cell, [{"x": x} for x in range(4)], out=out, client=client,
                      progress=seen.append)
    assert retry.ran == 1 and retry.skipped == 3
    assert sorted(int(r["x"]) for r in _rows(out)) == [0, 1, 2, 3]


def test_non_scalar_parameters_are_refused() -> None:
    with pytest.raises(TypeError, match="not a scalar"):
        cell_seed({"x": [1, 2]})


def other_cell(params: dict[str, Any], seed: int) -> dict[str, Any]:
    return {"z": 1}


def test_a_csv_of_another_sweep_is_refused_not_mixed(client, tmp_path: Path) -> None:
    out = tmp_path / "sweep.csv"
    run_sweep(square_cell, [{"x": 0}], out=out, client=client, progress=lambda _: None)
    before = out.read_text()
    with pytest.raises(ValueError, match="use a new --out"):
        run_sweep(other_cell, [{"x": 1}], out=out, client=client, progress=lambda _: None)
    assert out.read_text() == before


def test_a_scheduler_address_where_nothing_listens_is_refused_at_once() -> None:
    """Dask retries a refused connection for its whole connect timeout (10 s); a mistyped
    port is said at once, and a listening address (or one that is not tcp://) is let through."""
    import socket
    import time

    from sitl.study.sweep import _refuse_fast

    with socket.socket() as listening:
        listening.bind(("127.0.0.1", 0))
        listening.listen()
        port = listening.getsockname()[1]
        _refuse_fast(f"tcp://127.0.0.1:{port}", timeout_s=5.0)  # nothing raised
    started = time.monotonic()
    with pytest.raises(ConnectionRefusedError, match=f"nothing listens at tcp://127.0.0.1:{port}"):
        _refuse_fast(f"tcp://127.0.0.1:{port}", timeout_s=5.0)
    assert time.monotonic() - started < 2.0
    _refuse_fast("tls://127.0.0.1:9", timeout_s=5.0)  # Dask's to judge
    with pytest.raises(ValueError, match="the port is not a number"):
        _refuse_fast("tcp://127.0.0.1:abc", timeout_s=5.0)
