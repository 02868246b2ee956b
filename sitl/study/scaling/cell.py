"""One cell of the scaling sweep: run a workload and measure decide time, reports, memory,
utility (and, for ``long``, whether decide time grows with the mission)."""

from __future__ import annotations

import gc
import math
import pickle
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sitl.study.scaling.workloads import (
    OPTIMUM_BUDGET_PER_AGENT,
    RUNS,
    WARMUP,
    _image_run,
    report_sizes,
)

COLUMNS = (
    "decisions", "mean_ms", "p99_ms", "cpu_mean_ms", "cpu_p99_ms", "fallback_share",
    "utility_pct", "optimum_pct", "drop_share", "report_bytes_mean", "report_bytes_max",
    "report_datagrams_mean", "report_downlink_kBps", "rss_growth_mb", "state_kB_per_agent",
    "first_tenth_ms", "last_tenth_ms", "growth", "growth_lo", "growth_hi", "sim_s",
)


def growth(first: Sequence[float], last: Sequence[float], *, seed: int = 0,
           resamples: int = 2000) -> tuple[float, float, float]:
    """median(last) / median(first) and its 95 % bootstrap interval."""
    a, b = np.asarray(first, dtype=float), np.asarray(last, dtype=float)
    ratio = float(np.median(b) / np.median(a))
    rng = np.random.default_rng(seed)
    ra = np.median(rng.choice(a, size=(resamples, len(a))), axis=1)
    rb = np.median(rng.choice(b, size=(resamples, len(b))), axis=1)
    lo, hi = np.percentile(rb / ra, [2.5, 97.5])
    return ratio, float(lo), float(hi)


def _nan_row() -> dict[str, Any]:
    return {name: math.nan for name in COLUMNS}


def _timing(result: Any, warmup_s: float) -> tuple[np.ndarray, np.ndarray]:
    t = np.asarray(result.decide_t)
    keep = t >= warmup_s
    return (np.asarray(result.decide_wall_s)[keep] * 1e3,
            np.asarray(result.decide_cpu_s)[keep] * 1e3)


def _warm_up() -> None:
    """One tiny mission first: the compiled kernel is loaded outside the measurement."""
    _image_run(2, 1.0, 0)


def scaling_cell(params: Mapping[str, Any], seed: int) -> dict[str, Any]:
    """One sweep cell: ``kind`` in images/battery/optimum/long, ``agents``, ``t_end``."""
    from sitl.study.drop_rate import utility_pct

    kind, n, t_end = str(params["kind"]), int(params["agents"]), float(params["t_end"])
    row = _nan_row()
    started = time.perf_counter()
    if kind == "optimum":
        from sitl.study.drop_rate import optimum_gap

        mcts_pct, opt_pct, _ = optimum_gap(
            str(params.get("scenario", "mostly-low")), OPTIMUM_BUDGET_PER_AGENT * n,
            seed=seed % 2**31, t_end=t_end, n_agents=n, iterations=1500)
        row.update(utility_pct=mcts_pct, optimum_pct=opt_pct)
    elif kind in RUNS or kind == "long":
        _warm_up()
        run = RUNS["battery" if kind == "long" else kind]
        gc.collect()
        rss_start = _peak_rss_reset()
        spec, result, middlewares = run(n, t_end, seed)
        row["rss_growth_mb"] = _rss_growth_mb(rss_start)
        # what each agent keeps at the end (fleet knowledge, constraint, last problem):
        # bounded if it does not grow with the fleet's history (compare long with battery)
        row["state_kB_per_agent"] = len(pickle.dumps(middlewares)) / n / 1e3
        wall, cpu = _timing(result, WARMUP[kind])
        decisions = sum(mw.counters["decisions"] for mw in middlewares)
        fallback = sum(mw.counters["fallback"] for mw in middlewares)
        unknown = sum(mw.counters["unknown_type"] for mw in middlewares)
        if unknown:  # a decision that never searched would flatter the timing
            raise RuntimeError(f"{unknown} decisions on a type the spec does not define")
        sizes = report_sizes(result.delivered, senders=n, t_end=t_end)
        row.update(
            decisions=len(wall), mean_ms=float(wall.mean()),
            p99_ms=float(np.percentile(wall, 99)), cpu_mean_ms=float(cpu.mean()),
            cpu_p99_ms=float(np.percentile(cpu, 99)),
            fallback_share=fallback / decisions if decisions else math.nan,
            utility_pct=utility_pct(spec, result.generated, t_end),
            drop_share=result.drop_share, report_bytes_mean=sizes.mean_bytes,
            report_bytes_max=sizes.max_bytes, report_datagrams_mean=sizes.mean_datagrams,
            report_downlink_kBps=sizes.downlink_bytes_per_s / 1e3,
        )
        if kind == "long":
            tenth = max(1, len(cpu) // 10)
            ratio, lo, hi = growth(cpu[:tenth].tolist(), cpu[-tenth:].tolist(), seed=seed)
            row.update(first_tenth_ms=float(np.median(cpu[:tenth])),
                       last_tenth_ms=float(np.median(cpu[-tenth:])), growth=ratio,
                       growth_lo=lo, growth_hi=hi)
    else:
        raise ValueError(f"unknown cell kind {kind!r}")
    row["sim_s"] = round(time.perf_counter() - started, 2)
    return row


def _peak_rss_reset() -> int | None:
    """Reset this process's peak RSS to its current RSS (Linux >= 4.0); its RSS in bytes."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return _proc_status_kb("VmRSS") * 1024
    except (OSError, ValueError):
        return None


def _proc_status_kb(field: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1])
    raise ValueError(f"no {field} in /proc/self/status")


def _rss_growth_mb(start: int | None) -> float:
    """Peak RSS since :func:`_peak_rss_reset` minus the RSS then (NaN where not Linux)."""
    if start is None:
        return math.nan
    try:
        return max(0, _proc_status_kb("VmHWM") * 1024 - start) / 1e6
    except (OSError, ValueError):
        return math.nan
