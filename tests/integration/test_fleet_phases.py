"""The fleet summary's per-phase goodput share (sitl.fleet.red_phases): exact values."""

from __future__ import annotations

import pytest

from sitl.fleet import format_phases, red_phases


def test_share_while_over_red_and_elsewhere_against_the_others_mean() -> None:
    # 2 bins of 5 s; d3 sees red in the first only
    seen = {"d1": [(1.0, 0.0), (6.0, 0.0)], "d2": [(1.0, 0.0), (6.0, 0.0)],
            "d3": [(1.0, 0.30), (2.0, 0.10), (6.0, 0.01)]}
    received = [("d1", 1.0, 1000), ("d2", 2.0, 1000), ("d3", 1.5, 3000), ("d3", 2.5, 1000),
                ("d1", 6.0, 1000), ("d2", 7.0, 1000), ("d3", 8.0, 2000),
                ("d3", 20.0, 9999), ("ghost", 1.0, 5000)]  # outside the window / unknown
    p = red_phases(seen, received, t_start=0.0, t_end=10.0, bin_s=5.0, red_seen=0.05)
    d3 = p["drones"]["d3"]
    assert d3["red"] == {"seconds": 5.0, "share": 4 / 6, "others_mean_share": 1 / 6,
                         "ratio": pytest.approx(4.0)}
    assert d3["plain"] == {"seconds": 5.0, "share": 0.5, "others_mean_share": 0.25,
                           "ratio": 2.0}
    assert p["drones"]["d1"]["red"] is None
    assert p["drones"]["d1"]["plain"]["seconds"] == 10.0
    assert p["drones"]["d1"]["plain"]["share"] == pytest.approx((1 / 6 + 1 / 4) / 2)
    lines = format_phases(p)
    assert lines[2].split() == ["d2", "over", "red", "-;", "elsewhere", "10", "s:", "share",
                                "21", "%", "vs", "others'", "mean", "40", "%", "(0.5x)"]
    assert "over red 5 s: share 67 % vs others' mean 17 % (4.0x)" in lines[3]


def test_no_traffic_no_phase() -> None:
    p = red_phases({"d1": [(1.0, 0.5)]}, [], t_start=0.0, t_end=3.0)
    assert p["drones"]["d1"] == {"red": None, "plain": None}
