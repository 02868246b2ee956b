"""Issue 16's goals on the sweep's rows, and the printed table."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

GOAL_IMAGES_P99_MS = 10.0
GOAL_BATTERY_MEAN_MS = 15.0
GOAL_AGENTS = 50
GROWTH_LIMIT = 1.15
"""``long`` fails when even the low end of the 95 % interval of last/first exceeds it (the
median decide CPU time in the last whole cycles of the periodic scenario over the first)."""


@dataclass(frozen=True, slots=True)
class Goal:
    name: str
    measured: str
    target: str
    ok: bool


def as_float(row: Mapping[str, Any], key: str) -> float:
    try:
        return float(row[key])
    except (KeyError, TypeError, ValueError):
        return math.nan


def check_goals(rows: Sequence[Mapping[str, Any]]) -> list[Goal]:
    """Issue 16's goals on the rows that measure them (a goal without its row is a miss)."""
    return speed_goals(rows) + growth_goals(rows)


def speed_goals(rows: Sequence[Mapping[str, Any]]) -> list[Goal]:
    """The two decide-time goals at :data:`GOAL_AGENTS` (a missing row is a miss)."""
    goals = []

    def at(kind: str, n: int) -> Mapping[str, Any] | None:
        return next((r for r in rows if r["kind"] == kind and int(r["agents"]) == n), None)

    images, battery = at("images", GOAL_AGENTS), at("battery", GOAL_AGENTS)
    p99 = as_float(images, "p99_ms") if images else math.nan
    goals.append(Goal(f"images decide p99 at {GOAL_AGENTS} drones",
                      f"{p99:.2f} ms (cpu {as_float(images or {}, 'cpu_p99_ms'):.2f})",
                      f"<= {GOAL_IMAGES_P99_MS:g} ms", p99 <= GOAL_IMAGES_P99_MS))
    mean = as_float(battery, "mean_ms") if battery else math.nan
    goals.append(Goal(f"battery 1500 it mean at {GOAL_AGENTS} agents",
                      f"{mean:.2f} ms (cpu {as_float(battery or {}, 'cpu_mean_ms'):.2f})",
                      f"<= {GOAL_BATTERY_MEAN_MS:g} ms", mean <= GOAL_BATTERY_MEAN_MS))
    return goals


def growth_goals(rows: Sequence[Mapping[str, Any]]) -> list[Goal]:
    """One goal per ``long`` row: decide CPU time late vs early at like phases."""
    goals = []
    for r in rows:
        if r["kind"] != "long":
            continue
        g, lo, hi = as_float(r, "growth"), as_float(r, "growth_lo"), as_float(r, "growth_hi")
        first, last = as_float(r, "first_tenth_ms"), as_float(r, "last_tenth_ms")
        goals.append(Goal(
            f"decide cpu last/first cycles ({int(r['agents'])} agents, "
            f"{as_float(r, 't_end'):g} s{_injected(r)})",
            f"{first:.2f} -> {last:.2f} ms: x{g:.2f} [{lo:.2f}, {hi:.2f}]",
            f"low end <= {GROWTH_LIMIT:g}", lo <= GROWTH_LIMIT))
    return goals


def table(rows: Sequence[Mapping[str, Any]]) -> list[str]:
    """One line per (kind, agents): time, reports, memory, utility."""
    lines = [f"{'kind':8s} {'agents':>6s} {'decisions':>9s} {'mean ms':>8s} {'p99 ms':>7s} "
             f"{'cpu p99':>7s} {'fallbk':>6s} {'report B':>8s} {'dgrams':>6s} "
             f"{'downlink kB/s':>13s} {'RSS+ MB':>7s} {'kB/agent':>8s} {'utility %':>9s} "
             f"{'optimum %':>9s}"]
    order = {"images": 0, "battery": 1, "optimum": 2, "long": 3}
    for r in sorted(rows, key=lambda r: (order.get(str(r["kind"]), 9), int(r["agents"]))):
        def v(key: str, fmt: str, r: Mapping[str, Any] = r) -> str:
            x = as_float(r, key)
            return "-" if math.isnan(x) else format(x, fmt)

        lines.append(
            f"{r['kind']!s:8s} {int(r['agents']):6d} {v('decisions', '.0f'):>9s} "
            f"{v('mean_ms', '.2f'):>8s} {v('p99_ms', '.2f'):>7s} {v('cpu_p99_ms', '.2f'):>7s} "
            f"{v('fallback_share', '.1%'):>6s} {v('report_bytes_mean', '.0f'):>8s} "
            f"{v('report_datagrams_mean', '.1f'):>6s} {v('report_downlink_kBps', '.1f'):>13s} "
            f"{v('rss_growth_mb', '.1f'):>7s} {v('state_kB_per_agent', '.1f'):>8s} "
            f"{v('utility_pct', '.1f'):>9s} "
            f"{v('optimum_pct', '.1f'):>9s}")
    return lines


def _injected(row: Mapping[str, Any]) -> str:
    us = as_float(row, "inject_growth_us_per_s")
    return "" if math.isnan(us) or us == 0 else f", +{us:g} us/s planted"
