"""`uav-sitl study peers` (issue 15): freshness and utility at every drone, equal bytes."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from sitl.study import peers
from utility_specs.files import builtin_spec
from utility_specs.message import Message

SITL = Path(sys.executable).parent / "uav-sitl"


def swarm(sender: str, seq: int, t_gen: float, t_rcv: float | None) -> Message:
    m = Message(sender=sender, seq=seq, type="swarm", t_gen=t_gen, size=48)
    return m if t_rcv is None else m.delivered(receiver="ground", t_rcv=t_rcv)


def test_peer_ages_are_the_newest_held_at_each_instant() -> None:
    got = [swarm("a", 0, 1.0, 1.5), swarm("a", 1, 2.0, 2.05), swarm("b", 0, 0.5, 0.6)]
    ages = peer_grid = peers.peer_ages(got, ["a", "b"], t_from=1.0, t_end=2.2)
    grid = np.arange(1.0, 2.2, peers.AGE_STEP_S)
    # a's newest at b: nothing before 1.5 (age since 0), then the 1.0 one, then the 2.0 one
    want_a = np.where(grid < 1.5, grid, np.where(grid < 2.05, grid - 1.0, grid - 2.0))
    want_b = grid - 0.5
    assert peer_grid.shape == (2 * len(grid),)
    assert ages == pytest.approx(np.concatenate([want_a, want_b]))


def test_fixed_rate_sends_an_even_share_of_each_stream() -> None:
    policy = peers.FixedRate(0.25)
    sent = [policy.decide(swarm("a", k, k * 0.2, None), k * 0.2).send for k in range(12)]
    assert sent == [False, True, False, False] * 3


def test_every_receiver_of_a_type_gets_a_copy() -> None:
    spec = builtin_spec("sync_swarm")
    image = Message(sender="a", seq=2, type="image", t_gen=1.0, size=100,
                    data={"red": 0.1}).delivered(receiver="ground", t_rcv=1.1)
    battery = Message(sender="a", seq=3, type="battery", t_gen=1.0, size=32,
                      data={"level": 0.9}).delivered(receiver="ground", t_rcv=1.1)
    copies = peers.at_receivers(spec, [swarm("a", 1, 1.0, 1.1), image, battery,
                                       swarm("a", 4, 2.0, None)], ["a", "b", "c"])
    assert sorted((m.type, m.receiver) for m in copies) == [
        ("battery", "b"), ("battery", "c"), ("battery", "ground"), ("image", "ground"),
        ("swarm", "b"), ("swarm", "c")]


def test_quick_study_writes_csv_png_and_the_table_at_equal_bytes(tmp_path: Path) -> None:
    run = subprocess.run([str(SITL), "study", "peers", "--quick", "--t-end", "5", "--out",
                          str(tmp_path)], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    rows = list(csv.DictReader((tmp_path / "peers.csv").open()))
    assert [r["policy"] for r in rows] == list(peers.POLICIES)
    by = {r["policy"]: r for r in rows}
    matched = float(by["mcts"]["delivered_bytes_per_s"])
    assert matched > 0
    for policy in peers.POLICIES[1:]:  # the baselines got the bytes MCTS delivered
        assert float(by[policy]["delivered_bytes_per_s"]) == pytest.approx(matched, rel=0.25)
    for r in rows:
        assert 0 < float(r["utility_total_pct"]) <= 100.0
        for name in ("swarm", "image", "battery"):  # per type, where a policy gains or loses
            assert 0 <= float(r[f"utility_{name}_pct"]) <= 100.0
        assert 0 <= float(r["peer_age_mean_s"]) <= float(r["peer_age_p95_s"])
    assert (tmp_path / "peers.png").stat().st_size > 5_000
    table = (tmp_path / "peers.md").read_text()
    assert table in run.stdout
    assert "| mcts |" in table and "MCTS not below any baseline (total utility): " in table
    assert "Traceback" not in run.stderr


def test_bad_arguments_are_one_line_errors() -> None:
    run = subprocess.run([str(SITL), "study", "peers", "--drones", "1"], capture_output=True,
                         text=True, timeout=60)
    assert run.returncode == 2 and "Traceback" not in run.stderr
    assert "at least 2" in run.stderr.splitlines()[-1]


@pytest.mark.slow  # one 30 s mission per policy, about 30 s on a quiet core
def test_mcts_is_not_below_any_baseline(tmp_path: Path) -> None:
    rows = peers.run_seed(1, t_end=30.0)
    total = {r["policy"]: r["utility_total_pct"] for r in rows}
    assert all(total["mcts"] >= total[p] for p in peers.POLICIES[1:]), total
