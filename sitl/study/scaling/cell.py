"""One cell of the scaling sweep: run a workload and measure decide time, reports, memory,
utility (and, for ``long``, whether decide time grows with the mission: a young and an old
mission of a periodic scenario in turns, compared at like phases, :func:`like_phase_blocks`
and :mod:`~sitl.study.scaling.lockstep`)."""

from __future__ import annotations

import gc
import math
import pickle
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sitl.study.scaling.lockstep import run_interleaved
from sitl.study.scaling.workloads import (
    CYCLE_S,
    OPTIMUM_BUDGET_PER_AGENT,
    RUNS,
    WARMUP,
    GrowingCost,
    _battery_run,
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


def like_phase_blocks(t_end: float, *, cycle_s: float = CYCLE_S,
                      warmup_s: float = WARMUP["long"], share: float = 0.1) -> tuple[
        tuple[float, float], tuple[float, float]]:
    """The first and the last whole cycles of a periodic scenario after the warm-up (each
    about ``share`` of the mission), as [start, end) in seconds. Both hold every phase of
    the cycle once per cycle, so what differs between them is how long the mission has run,
    not where in its load pattern each block falls."""
    start = math.ceil(warmup_s / cycle_s)
    end = math.floor(t_end / cycle_s + 1e-9)
    cycles = end - start
    if cycles < 2:
        raise ValueError(f"a {t_end:g} s mission holds {max(0, cycles)} whole {cycle_s:g} s "
                         f"cycle(s) after the {warmup_s:g} s warm-up; need 2")
    m = max(1, min(cycles // 2, round(t_end / cycle_s * share)))
    return (start * cycle_s, (start + m) * cycle_s), ((end - m) * cycle_s, end * cycle_s)


def within(t: Sequence[float] | np.ndarray, values: Sequence[float] | np.ndarray,
           block: tuple[float, float]) -> np.ndarray:
    """``values`` whose ``t`` falls in [start, end)."""
    tt = np.asarray(t, dtype=float)
    return np.asarray(values, dtype=float)[(tt >= block[0]) & (tt < block[1])]


def _long_run(n: int, t_end: float, seed: int, inject_us_per_s: float) -> tuple[
        Any, Any, list[Any], np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The old and the young mission in turns (:mod:`~sitl.study.scaling.lockstep`): the
    old one's run, its decisions' wall and CPU ms after the warm-up, and the decide CPU ms
    of the young mission's first cycles and the old one's last cycles."""
    first, last = like_phase_blocks(t_end)

    def run(length: float, wrap: Callable[[Any], Any]) -> tuple[Any, Any, list[Any]]:
        def planted(p: Any) -> Any:
            return wrap(GrowingCost(p, inject_us_per_s))

        return _battery_run(n, length, seed, cycle_s=CYCLE_S,
                            wrap=planted if inject_us_per_s > 0 else wrap)

    (spec, result, middlewares), old, young = run_interleaved(
        run, t_end=t_end, offset_s=last[0] - first[0])
    keep = np.asarray(old.t) >= WARMUP["long"]
    return (spec, result, middlewares, np.asarray(old.wall_s)[keep] * 1e3,
            old.cpu_ms()[keep], within(young.t, young.cpu_ms(), first),
            within(old.t, old.cpu_ms(), last))


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
    """One sweep cell: ``kind`` in images/battery/optimum/long, ``agents``, ``t_end``
    (``long`` also takes ``inject_growth_us_per_s``: a planted growing cost, the check's
    self-test)."""
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
        gc.collect()
        rss_start = _peak_rss_reset()
        if kind == "long":  # a young and an old mission in turns, compared at like phases
            spec, result, middlewares, wall, cpu, first, last = _long_run(
                n, t_end, seed, float(params.get("inject_growth_us_per_s", 0.0)))
        else:
            spec, result, middlewares = RUNS[kind](n, t_end, seed)
            wall, cpu = _timing(result, WARMUP[kind])
        row["rss_growth_mb"] = _rss_growth_mb(rss_start)
        # what each agent keeps at the end (fleet knowledge, constraint, last problem):
        # bounded if it does not grow with the fleet's history (compare long with battery)
        row["state_kB_per_agent"] = len(pickle.dumps(middlewares)) / n / 1e3
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
            ratio, lo, hi = growth(first.tolist(), last.tolist(), seed=seed)
            row.update(first_tenth_ms=float(np.median(first)),
                       last_tenth_ms=float(np.median(last)), growth=ratio,
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
