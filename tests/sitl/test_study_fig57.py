"""``uav-sitl study fig5.7``: scenarios match the thesis' histograms; the command on Dask."""

from __future__ import annotations

import csv
import math
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("dask.distributed", reason="pip install -e '.[study]' (Dask distributed)")

from sitl.study import fig57

SITL = Path(sys.executable).parent / "uav-sitl"


def _fifths(scenario: str) -> list[float]:
    """The thesis' characteristic: random drop at 16 drop shares, mean per message."""
    per_cell = []
    for params in fig57.cells([scenario], ["random"], 1, t_end=50.0, drops=fig57.DROPS[::2]):
        per_cell.append(fig57.message_cell(params, fig57.cell_seed(params))["messages"])
    return fig57.fifths(fig57.characteristics(per_cell))


def test_uniform_scenario_has_a_flat_utility_histogram() -> None:
    """Thesis ch. 5.4 (b): 'a uniform distribution of messages with respect to utility'.
    (It came out 63/24/10/2/1 % per fifth when a message's line outlived the next message.)"""
    shares = _fifths("uniform")
    assert all(0.13 <= s <= 0.27 for s in shares), shares


def test_mostly_low_scenario_has_most_messages_of_low_utility() -> None:
    shares = _fifths("mostly-low")
    assert shares[0] >= 0.6 and shares[0] > 3 * max(shares[1:]), shares


def test_mostly_high_scenario_has_most_messages_of_high_utility() -> None:
    shares = _fifths("mostly-high")
    assert shares[3] + shares[4] >= 0.6 and shares[4] > max(shares[:3]), shares


def test_summary_is_the_mean_with_a_t_interval() -> None:
    rows = [{"scenario": "uniform", "policy": "random", "drop": "0.5", "run": str(k),
             "utility_pct": str(u), "drop_share": "0.5", "violations": "0"}
            for k, u in enumerate([40.0, 50.0, 60.0])]
    (s,) = fig57.summarise(rows)
    half = 4.302652729911275 * 10.0 / math.sqrt(3)  # t(0.975, 2) * sd / sqrt(n)
    assert s["runs"] == 3 and s["utility_mean"] == pytest.approx(50.0)
    assert s["utility_lo"] == pytest.approx(50.0 - half)
    assert s["utility_hi"] == pytest.approx(50.0 + half)
    assert s["drop_lo"] == pytest.approx(0.5) and s["drop_hi"] == pytest.approx(0.5)


def test_a_mission_is_shared_by_policies_and_drop_shares_of_one_run() -> None:
    """Common random numbers: run r is the same generated mission for every cell."""
    a = {"scenario": "uniform", "policy": "random", "drop": 0.0, "run": 0, "t_end": 10.0,
         "n_agents": 10}
    b = {**a, "drop": 0.5}
    c = {**a, "run": 1}
    ma = fig57.message_cell(a, fig57.cell_seed(a))["messages"]
    mb = fig57.message_cell(b, fig57.cell_seed(b))["messages"]
    mc = fig57.message_cell(c, fig57.cell_seed(c))["messages"]
    assert set(mb) < set(ma)  # the same messages, fewer delivered
    assert ma != mc
    timing = ("mean_decide_ms", "p95_decide_ms")
    once, twice = (fig57.mission_cell(b, fig57.cell_seed(b)) for _ in range(2))
    assert {k: v for k, v in once.items() if k not in timing} == {
        k: v for k, v in twice.items() if k not in timing}


def test_quick_study_runs_on_a_local_dask_cluster_and_resumes(tmp_path: Path) -> None:
    run = subprocess.run([str(SITL), "study", "fig5.7", "--quick", "--out", str(tmp_path)],
                         capture_output=True, text=True, timeout=240)
    assert run.returncode == 0, run.stderr[-2000:]
    rows = list(csv.DictReader((tmp_path / "fig5_7.csv").open()))
    # 3 scenarios x 2 runs x 2 drop shares x (mcts300, random)
    assert len(rows) == 24 and len({r["cell_id"] for r in rows}) == 24
    assert {r["scenario"] for r in rows} == {"mostly-low", "uniform", "mostly-high"}
    summary = list(csv.DictReader((tmp_path / "fig5_7_summary.csv").open()))
    assert len(summary) == 12 and all(r["runs"] == "2" for r in summary)
    assert (tmp_path / "fig5_7.png").stat().st_size > 20_000
    chars = list(csv.DictReader((tmp_path / "fig5_7_characteristics.csv").open()))
    assert max(float(r["normalised_utility"]) for r in chars) == 1.0
    out = run.stdout
    for scenario in ("mostly-low", "uniform", "mostly-high"):
        assert f"== {scenario}: histogram" in out
    assert "reference rerun" in out and "thesis: no numbers stated" in out
    assert "fig5.7 [" in run.stderr and "24/24 done" in run.stderr
    low = [line for line in out.splitlines() if line.startswith(" 0.80")]
    assert len(low) == 3 and all(line.count("[") == 2 for line in low)  # both with intervals
    assert "Traceback" not in run.stderr
    before = (tmp_path / "fig5_7.csv").read_text()
    again = subprocess.run([str(SITL), "study", "fig5.7", "--quick", "--out", str(tmp_path)],
                           capture_output=True, text=True, timeout=240)
    assert again.returncode == 0, again.stderr[-2000:]
    assert "24 of 24 cells already in" in again.stderr
    assert "(0 run now, 24 from an earlier run, 0 failed)" in again.stdout
    assert (tmp_path / "fig5_7.csv").read_text() == before


@pytest.mark.parametrize("args", [["--runs", "0"], ["--policy", "nope"]])
def test_bad_arguments_get_one_line_and_exit_2(args: list[str], tmp_path: Path) -> None:
    run = subprocess.run([str(SITL), "study", "fig5.7", "--out", str(tmp_path), *args],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 2
    assert "Traceback" not in run.stderr and "error:" in run.stderr.splitlines()[-1]


def test_an_unreachable_scheduler_is_one_line_and_exit_1(tmp_path: Path) -> None:
    run = subprocess.run([str(SITL), "study", "fig5.7", "--quick", "--out", str(tmp_path),
                          "--scheduler", "tcp://127.0.0.1:9"],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 1
    assert "Traceback" not in run.stderr
    last = run.stderr.strip().splitlines()[-1]
    assert last.startswith("uav-sitl study fig5.7: ") and "tcp://127.0.0.1:9" in last
