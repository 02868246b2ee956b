"""The fleet summary survives an evaluation that outlasts its time limit (a loaded host)."""
from __future__ import annotations

from pathlib import Path

from sitl.fleet.summary import evaluate_utility


def test_an_evaluation_over_its_time_limit_is_an_error_entry_not_a_traceback(
        tmp_path: Path) -> None:
    log = tmp_path / "gs.jsonl"
    log.write_text("", encoding="utf-8")
    result = evaluate_utility([log], spec=tmp_path / "spec.toml", t_start=0.0, t_end=1.0,
                              timeout_s=0.001)
    assert "took over 0.001 s" in result["error"]
    assert "evaluate" in result["command"]
