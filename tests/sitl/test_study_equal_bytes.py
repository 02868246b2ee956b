"""The equal-bytes study's offline optimum held to the budget (issue 18, round 13)."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from companion.middleware.incremental import window_violations
from sitl.study import drop_rate as dr
from sitl.study import equal_bytes as eb


def test_the_offline_optimum_keeps_the_budget_and_grows_with_it() -> None:
    best = dr.offline_optimum_run("uniform", 2.5, seed=1, t_end=8.0)
    budget = dr.budget_bytes(2.5)
    assert best.sends, "a 2.5 msgs/T budget lets some messages through"
    assert window_violations(list(best.sends), window_s=dr.WINDOW_S, budget_bytes=budget) == 0
    assert best.delivered_bytes == dr.SIZE * len(best.sends)
    # a plan that keeps 1.5 msgs/T keeps 2.5 too, so the tighter optimum is never better
    tighter = dr.offline_optimum_run("uniform", 1.5, seed=1, t_end=8.0)
    assert 0 < tighter.utility_pct <= best.utility_pct
    assert tighter.delivered_bytes <= best.delivered_bytes + dr.SIZE


def test_optimum_gap_reports_the_same_optimum() -> None:
    _, opt_pct, drop = dr.optimum_gap("mostly-low", 3.0, seed=2, t_end=6.0, n_agents=4,
                                      iterations=50)
    best = dr.offline_optimum_run("mostly-low", 3.0, seed=2, t_end=6.0, n_agents=4)
    assert opt_pct == best.utility_pct
    assert drop == best.drop_share


def test_rows_compare_knapsack_at_the_optimums_bytes_and_say_na_past_max_states(
        tmp_path: Path) -> None:
    rows = eb.rows_for("uniform", 1, t_end=6.0, mcts="mcts30", budgets=(2.5,), optimum=True)
    (row,) = rows
    assert row["optimum_windows_over_b"] == 0
    assert row["optimum_bytes"] > 0
    curve = [tuple(map(float, c.split(":"))) for c in row["knapsack_curve"].split(";")]
    xs, ys = zip(*curve, strict=True)
    if xs[0] <= row["optimum_bytes"] <= xs[-1]:
        expected = float(np.interp(row["optimum_bytes"], xs, ys)) - row["optimum_pct"]
        # the curve column carries utilities to 4 decimals: the interpolation agrees to that
        assert row["delta_knapsack_optimum"] == pytest.approx(expected, abs=1e-4)
    (tiny,) = eb.rows_for("uniform", 1, t_end=6.0, mcts="mcts30", budgets=(2.5,),
                          optimum=True, max_states=1)
    assert tiny["optimum_bytes"] == -1 and np.isnan(tiny["optimum_pct"])
    text = eb.table([row])
    assert "optimum held to b" in text and "n/a" not in text.splitlines()[-1].split("|")[9]
    assert eb.table([tiny]).splitlines()[-1].count("n/a") >= 2
    eb.plot(rows, tmp_path / "equal_bytes.png")
    assert (tmp_path / "equal_bytes.png").stat().st_size > 10_000


def test_bad_budgets_are_a_one_line_usage_error(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, "-m", "sitl.study.equal_bytes", "--out",
                           str(tmp_path), "--budgets", "2.5,x"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    assert "Traceback" not in done.stderr
    assert "--budgets: numbers separated by commas expected" in done.stderr.splitlines()[-1]


def test_seeds_and_mission_length_are_options_and_bad_ones_a_usage_error(
        tmp_path: Path) -> None:
    """Round 18: the thesis' missions are 100 s long, the quick study's 20 s, and how long a
    mission is decides how much its blind start weighs in a cell."""
    done = subprocess.run([sys.executable, "-m", "sitl.study.equal_bytes", "--out",
                           str(tmp_path), "--seeds", "1", "--t-end", "4", "--scenarios",
                           "uniform", "--budgets", "9.25"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "uniform seed 1 done" in done.stdout and "seed 2" not in done.stdout
    with (tmp_path / "equal_bytes.csv").open() as f:
        (row,) = csv.DictReader(f)
    assert (row["seed"], float(row["t_end"]), float(row["budget"])) == ("1", 4.0, 9.25)
    for bad in (["--seeds", "0"], ["--t-end", "nan"], ["--t-end", "0.5"]):
        done = subprocess.run([sys.executable, "-m", "sitl.study.equal_bytes", "--out",
                               str(tmp_path), *bad], capture_output=True, text=True, timeout=60)
        assert done.returncode == 2 and "Traceback" not in done.stderr, bad
        assert "--seeds must be >= 1 and --t-end in 1..10000 s" in done.stderr.splitlines()[-1]


def test_the_first_window_share_and_the_rest_add_up_to_the_mission() -> None:
    """Round 15: each Δ is split at the end of the first window T, so a row says whether
    a cell is lost at the mission start or after it; the two parts are the whole utility."""
    r = eb.run("uniform", "knapsack", 9.25, seed=1, t_end=6.0)
    assert 0 < r["first_window_pct"] < r["utility_pct"]
    (row,) = eb.rows_for("uniform", 1, t_end=6.0, mcts="mcts30", budgets=(9.25,))
    assert np.isfinite(row["delta_knapsack"]) and np.isfinite(row["delta_knapsack_first_window"])
    line = eb.table([row]).splitlines()[-1].split("|")
    first, after = (float(x) for x in line[5].split("/"))
    assert first + after == pytest.approx(row["delta_knapsack"], abs=0.11)


def test_the_first_window_is_evaluated_from_the_missions_start() -> None:
    from sitl.netsim import ideal_copies, simulate
    from utility_specs.evaluate import evaluate

    spec, agents = dr.make_agents("uniform", dr.policy_factory("knapsack", 9.25, seed=1), seed=1)
    result = simulate(agents, channel=dr.CHANNEL, t_end=6.0, rng=np.random.default_rng([1, 3]))
    got = [m for m in result.generated if m.t_rcv is not None]
    ideal = evaluate(ideal_copies(result.generated), spec, t_end=6.0).total
    after = 100 * evaluate(got, spec, t_start=dr.WINDOW_S, t_end=6.0).total / ideal
    r = eb.run("uniform", "knapsack", 9.25, seed=1, t_end=6.0)
    assert r["first_window_pct"] + after == pytest.approx(r["utility_pct"])
