"""A mission's characteristics (thesis sec. 5.4, fig. 7.2): expected utility of each message
under random drops, and the utility left at each drop share."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import pytest

from utility_specs.characteristics import characteristics
from utility_specs.message import Message
from utility_specs.spec import MissionSpec, parse_spec

UTILITY = Path(sys.executable).parent / "uav-utility"


def _spec(aggregation: str) -> MissionSpec:
    return parse_spec({"types": {"x": {"utility": "linear", "aggregation": aggregation,
                                       "weight": 2.0, "per_sender": True,
                                       "params": {"initial": 1.0, "slope": 0.1}}}})


def _stream(times: list[float], sender: str = "a") -> list[Message]:
    return [Message(sender=sender, seq=k, type="x", t_gen=t) for k, t in enumerate(times)]


def test_independent_messages_are_each_worth_their_own_integral() -> None:
    """``sum``: a message adds its triangle (weight 2 x 1 x 10 s / 2 = 10) whatever else
    arrives, so the utility left is exactly the share of messages kept."""
    result = characteristics(_stream([float(t) for t in range(10)]), _spec("sum"),
                             t_start=0.0, t_end=30.0, drops=[0.0, 0.5], runs=4, seed=3)
    assert result.ideal == pytest.approx(100.0)
    assert all(v == pytest.approx(10.0) for v in result.expected.values())
    assert len(result.expected) == 10
    for r in result.runs:
        assert r.utility_pct == pytest.approx(100.0 * (1.0 - r.achieved_drop))
    assert [r.drop for r in result.runs] == [0.0] * 4 + [0.5] * 4
    assert (result.normalised() == 1.0).all()


def test_a_message_is_worth_what_the_stream_loses_without_it() -> None:
    """``max``: at 0 s and 1 s, each line 1 - 0.1 (t - t_gen); together 0.95 + 5 (x weight 2),
    either alone 5, so each adds 0.95 x 2 (leave-one-out, eq. 4.2)."""
    result = characteristics(_stream([0.0, 1.0]), _spec("max"), t_start=0.0, t_end=30.0,
                             drops=[0.0], runs=1, seed=1)
    assert result.ideal == pytest.approx(2 * 5.95)
    assert result.expected == {("a", 0, 0.0): pytest.approx(1.9), ("a", 1, 1.0): pytest.approx(1.9)}
    # another sender's stream is its own: nothing it sends lowers these
    both = characteristics(_stream([0.0, 1.0]) + _stream([0.5], sender="b"), _spec("max"),
                           t_start=0.0, t_end=30.0, drops=[0.0], runs=1, seed=1)
    assert both.expected[("a", 0, 0.0)] == pytest.approx(1.9)
    assert both.expected[("b", 0, 0.5)] == pytest.approx(10.0)


def test_bad_arguments_are_value_errors() -> None:
    with pytest.raises(ValueError, match="no generated message"):
        characteristics([], _spec("max"), t_start=0, t_end=1, drops=[0.1], runs=1, seed=1)
    with pytest.raises(ValueError, match="drop probability in"):
        characteristics(_stream([0.0]), _spec("max"), t_start=0, t_end=1, drops=[1.0],
                        runs=1, seed=1)


def _log(path: Path, times: list[float]) -> Path:
    lines = [json.dumps({"sender": "drone1", "receiver": None, "seq": k, "type": "battery",
                         "t_gen": t, "t_sent": t, "t_rcv": None, "size": 40,
                         "data": {"level": 0.9 - 0.001 * k}}) for k, t in enumerate(times)]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def test_the_command_writes_the_figure_and_the_tables(tmp_path: Path) -> None:
    log = _log(tmp_path / "drone1.jsonl", [100.0 + 5 * k for k in range(20)])
    run = subprocess.run([str(UTILITY), "characteristics", "--spec", "image_streaming",
                          "--type", "battery", "--runs", "2", "--drops", "0.2,0.6",
                          "--out", str(tmp_path / "out"), str(log)],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    assert "20 generated messages (battery) over 95.0 s" in run.stdout
    assert "random drop 0.60:" in run.stdout and "drop 0.60 run 2/2" in run.stderr
    rows = list(csv.DictReader((tmp_path / "out" / "characteristics.csv").open()))
    assert {r["type"] for r in rows} == {"battery"} and max(float(r["normalised"])
                                                            for r in rows) == 1.0
    assert len(list(csv.DictReader((tmp_path / "out" / "drop_runs.csv").open()))) == 4
    assert (tmp_path / "out" / "characteristics.png").stat().st_size > 20_000


@pytest.mark.parametrize(("args", "message"), [
    (["--type", "video"], "--type video: not a type of spec 'image_streaming'"),
    (["--drops", "0.1,x"], "--drops: numbers separated by commas expected"),
    (["--drops", "1.5"], "every drop probability in [0, 1)"),
    (["--type", "image"], "no message of type image in the logs"),
    # printed "5 drop probabilities x -1 replays" first, then failed
    (["--runs", "-1"], "--runs must be >= 1, got -1"),
    (["--t-start", "5", "--t-end", "2"], "need --t-start < --t-end, got 5.0 and 2.0"),
])
def test_bad_input_is_one_line_and_exit_2(tmp_path: Path, args: list[str],
                                          message: str) -> None:
    log = _log(tmp_path / "drone1.jsonl", [1.0, 2.0, 3.0])
    run = subprocess.run([str(UTILITY), "characteristics", "--spec", "image_streaming",
                          "--out", str(tmp_path / "out"), *args, str(log)],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and "Traceback" not in run.stderr
    assert message in run.stderr.splitlines()[-1]
    assert run.stdout == ""  # checked before anything is printed
