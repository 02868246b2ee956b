"""Operator checks (audit 12): ``uav-sitl fleet --policy send_all`` (or ``random``) printed
``constraint: adaptive`` in its header and summary, though those baselines decide without a
goodput constraint (their drones report no ξ). The line now says it is not used."""

from __future__ import annotations

from typing import Any

from sitl.fleet import format_summary


def _summary(policy: str) -> dict[str, Any]:
    row = {"generated": 10, "sent": 10, "received": 1, "stored": 1, "fps": 0.1,
           "latency_mean_s": 0.8, "mean_red": 0.0, "fallback_share": 0.0, "decisions": 10}
    return {"policy": policy, "duration_s": 25.0, "drones": {"drone1": row},
            "utility": None, "link": None, "constraint": {"name": "adaptive"},
            "run_dir": "/x", "data": {"images": "/x/i", "ground_station_db": "/x/db",
                                      "ground_station_log": "/x/l", "companion_logs": [],
                                      "process_logs": "/x/p"}}


def test_the_constraint_line_says_when_the_policy_ignores_it() -> None:
    def line(policy: str) -> str:
        return next(x for x in format_summary(_summary(policy)).splitlines()
                    if x.startswith("constraint:"))

    assert line("mcts") == "constraint: adaptive"
    assert line("send_all") == "constraint: adaptive (not used: policy send_all ignores it)"
    assert line("random") == "constraint: adaptive (not used: policy random ignores it)"


def test_the_report_line_says_how_to_open_the_stopped_dashboard_again() -> None:
    """The summary comes after the station stopped: it offered "http://127.0.0.1:N/report while
    the station runs", a page no longer served (a newcomer's `make demo` walk)."""
    summary = {**_summary("mcts"), "report": "/x/utility.png",
               "dashboard": "http://127.0.0.1:39423/"}
    line = next(x for x in format_summary(summary).splitlines() if x.startswith("  report"))
    assert line == ("  report   /x/utility.png (the dashboard's /report page again: "
                    "uav-ground-station run --config /x/ground_station.toml)")
