"""Fleet-size scaling (issue 16): decide time, report size, memory and utility at 10..100 agents.

``uav-sitl study scaling --out DIR [--quick] [--agents 10,25,50,100] [--scheduler ADDR]``
runs every fleet size on the shared medium of :mod:`sitl.netsim` (one broadcast channel:
every agent overhears every delivery, as in the thesis' ch. 5.4 setup) in two workloads:

- ``images``: the companion's own configuration (``build_decider``'s defaults: 300
  iterations, horizon 3 s, adaptive constraint fed by simulated receiver reports), each drone
  5 frames/s in 3 versions (40/10/2.5 kB), 1 Hz position, 0.2 Hz battery, on a 1 Mbit/s link;
- ``battery``: the thesis' reference scenario (mostly-low, 2048-byte messages at ~1 Hz per
  agent, 1500 iterations, horizon 5 s), the message budget per window scaled with the fleet
  (9.25 per 10 agents: drop share ~0.75 at every size, measured).

Per cell: decide() wall and CPU time (mean, p99) after the first horizon (the fleet is known
by then); the receiver reports the ground station would send for that run
(:class:`~ground_station.reports.ReportScheduler` and the product's
:class:`~companion.protocol.encoder.Encoder`): bytes per report and the downlink they take,
one copy per drone; memory: how far the process's peak RSS rose above its RSS at the start
of the run (a lower bound: memory freed by an earlier cell of the same process is reused;
tracemalloc would slow the timed run ~3x) and each agent's retained state at the end
(pickled; the mission spec they share counts once, so tiny fleets look heavier); utility.
``optimum`` cells compare MCTS with the exact offline optimum on short missions; ``long``
cells measure whether decide time grows with mission length (first vs last tenth). Timing
cells run one at a time by default (``--workers 1``) so they do not compete for the CPU.
Writes ``scaling.csv`` (streamed, resumable), ``scaling.png`` and prints the table with the
goals of issue 16.
"""

from __future__ import annotations

import argparse
import gc
import hashlib
import math
import pickle
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

FLEET_SIZES = (10, 25, 50, 100)
IMAGE_CAPACITY_BYTES_PER_S = 125_000.0
"""1 Mbit/s shared link (the near-capacity link of bench_mcts's companion-default row)."""
BATTERY_BUDGET_PER_10 = 9.25
"""Messages per 2.5 s window per 10 agents (the reference setup's budget 9.25)."""
OPTIMUM_AGENTS = (2, 4)
"""The exact offline optimum (DP over levels) is for small fleets only: at 10 agents it holds
more than 500 000 states on one level 2.3 s into the mission (measured), so the optimum cells
use 2 and 4 agents whatever ``--agents`` says."""
OPTIMUM_BUDGET_PER_AGENT = 0.75
"""Messages per window per agent in the optimum cells (bench_mcts: 3 for 4 agents)."""
REPORT_INTERVAL_S = 0.25
"""The ground station's report period (``ReportScheduler`` default in the product)."""
WARMUP = {"images": 3.0, "battery": 5.0, "long": 5.0}
"""Decisions before this simulated time are left out: the fleet is not known yet."""
GOAL_IMAGES_P99_MS = 10.0
GOAL_BATTERY_MEAN_MS = 15.0
GOAL_AGENTS = 50
GROWTH_LIMIT = 1.15
"""``long`` fails when even the low end of the 95 % interval of last/first tenth exceeds it."""

__all__ = [
    "FLEET_SIZES",
    "Goal",
    "check_goals",
    "growth",
    "image_agents",
    "main",
    "report_sizes",
    "scaling_cell",
]

COLUMNS = (
    "decisions", "mean_ms", "p99_ms", "cpu_mean_ms", "cpu_p99_ms", "fallback_share",
    "utility_pct", "optimum_pct", "drop_share", "report_bytes_mean", "report_bytes_max",
    "report_datagrams_mean", "report_downlink_kBps", "rss_growth_mb", "state_kB_per_agent",
    "first_tenth_ms", "last_tenth_ms", "growth", "growth_lo", "growth_hi", "sim_s",
)


def image_agents(n: int, make_policy: Callable[[str, int], Any]) -> list[Any]:
    """``n`` drones: 5 frames/s in 3 versions, 1 Hz position, 0.2 Hz battery (phases spread
    over each period so the fleet's frames do not all arrive at one instant)."""
    from sitl.netsim import SimAgent, StreamConfig
    from utility_specs.message import Version

    versions = (Version(name="full", size=40_000, quality=1.0),
                Version(name="half", size=10_000, quality=0.5),
                Version(name="quarter", size=2_500, quality=0.25))
    agents = []
    for i in range(n):
        def red(k: int, g: np.random.Generator, i: int = i) -> dict[str, Any]:
            return {"red": float(min(1.0, abs(g.normal(0.002 * i, 0.05))))}

        phase = (i / n)
        agents.append(SimAgent(name=f"uav{i}", policy=make_policy(f"uav{i}", i), streams=[
            StreamConfig(type="image", period_s=0.2, size=40_000, phase_s=0.2 * phase,
                         versions=versions, data=red),
            StreamConfig(type="position", period_s=1.0, size=64, phase_s=phase),
            StreamConfig(type="battery", period_s=5.0, size=32, phase_s=5.0 * phase,
                         data=lambda k, g: {"level": max(0.1, 1.0 - 0.001 * k)}),
        ]))
    return agents


def _image_run(n: int, t_end: float, seed: int) -> tuple[Any, Any, list[Any]]:
    from companion.middleware.adaptive import AdaptiveConstraint
    from companion.middleware.middleware import Middleware, MiddlewareConfig
    from sitl.netsim import ChannelConfig, simulate
    from utility_specs.files import builtin_spec

    spec = builtin_spec("image_streaming")
    middlewares: list[Middleware] = []

    def policy(name: str, i: int) -> Middleware:
        # build_decider's defaults: 300 iterations, horizon 3 s, adaptive constraint
        config = MiddlewareConfig(spec=spec, agent=name, max_iterations=300, horizon_s=3.0)
        mw = Middleware(config, rng=np.random.default_rng([seed, i]),
                        constraint=AdaptiveConstraint())
        middlewares.append(mw)
        return mw

    agents = image_agents(n, policy)
    result = simulate(agents, channel=ChannelConfig(capacity_bytes_per_s=IMAGE_CAPACITY_BYTES_PER_S,
                                                    report_interval_s=REPORT_INTERVAL_S),
                      t_end=t_end, rng=np.random.default_rng([seed, 5]))
    return spec, result, middlewares


def fleet_spec(scenario: str, n: int) -> Any:
    """The scenario's spec for ``n`` agents: agent i's stream ``battery_i`` has the weight
    of ``battery_{i % 10}`` (the fleet is copies of the thesis' 10-agent fleet; its weights
    3^(i+1) would otherwise reach 3^100)."""
    import tomllib
    from importlib import resources

    from sitl.study.drop_rate import SCENARIOS
    from utility_specs.spec import parse_spec

    name = SCENARIOS[scenario]
    raw = tomllib.loads((resources.files("utility_specs") / "missions" / f"{name}.toml")
                        .read_text(encoding="utf-8"))
    base = raw["types"]
    raw["types"] = {f"battery_{i}": dict(base[f"battery_{i % len(base)}"]) for i in range(n)}
    return parse_spec(raw, source=f"{name} x {n} agents")


def _battery_run(n: int, t_end: float, seed: int) -> tuple[Any, Any, list[Any]]:
    """The reference scenario (mostly-low, 1500 iterations) with ``n`` agents."""
    from sitl.netsim import SimAgent, simulate
    from sitl.study.drop_rate import CHANNEL, _scenario_streams, policy_factory

    seed = seed % 2**31
    spec = fleet_spec("mostly-low", n)
    make = policy_factory("mcts1500", BATTERY_BUDGET_PER_10 * n / 10, seed=seed)
    streams = _scenario_streams("mostly-low", n, np.random.default_rng([seed, 7]))
    policies = [make(f"agent{i}", spec) for i in range(n)]
    agents = [SimAgent(name=f"agent{i}", policy=policies[i], streams=[streams[i]])
              for i in range(n)]
    result = simulate(agents, channel=replace(CHANNEL, report_interval_s=REPORT_INTERVAL_S),
                      t_end=t_end, rng=np.random.default_rng([seed, 3]))
    return spec, result, policies


RUNS: dict[str, Callable[[int, float, int], tuple[Any, Any, list[Any]]]] = {
    "images": _image_run,
    "battery": _battery_run,
}


@dataclass(frozen=True, slots=True)
class ReportSizes:
    mean_bytes: float
    max_bytes: int
    mean_datagrams: float
    downlink_bytes_per_s: float
    """Every report goes to every drone (unicast copies), as ``ground_station.receiver`` does."""


def report_sizes(delivered: Sequence[Any], *, senders: int, t_end: float,
                 interval_s: float = REPORT_INTERVAL_S) -> ReportSizes:
    """The receiver reports the ground station would send for these deliveries, encoded as
    the product encodes them (entries repeated in 2 reports, clock echoes rotating)."""
    from companion.protocol.encoder import Encoder
    from ground_station.reports import ReportScheduler

    key = hashlib.sha256(b"uav-infodist scaling study: sizes only").digest()
    encoder = Encoder(1, "gs", key)  # the ground station's default station_id
    scheduler = ReportScheduler(interval_s=interval_s, now=0.0)
    sizes: list[int] = []
    datagrams: list[int] = []

    def flush(until: float) -> None:
        while scheduler.get_timer() <= until:
            now = scheduler.get_timer()
            report = scheduler.due(now=now)
            if report is None:  # pragma: no cover - due at its own timer always reports
                break
            encoded = encoder.encode_report(report, now)
            sizes.append(sum(len(d) for d in encoded))
            datagrams.append(len(encoded))

    for m in sorted(delivered, key=lambda m: m.t_rcv):
        flush(m.t_rcv)
        scheduler.on_datagram(m.sender, t_sent=m.t_sent, t_rcv=m.t_rcv)
        scheduler.on_message(m, t_rcv=m.t_rcv)
    flush(t_end)
    if not sizes:
        return ReportSizes(0.0, 0, 0.0, 0.0)
    return ReportSizes(mean_bytes=float(np.mean(sizes)), max_bytes=max(sizes),
                       mean_datagrams=float(np.mean(datagrams)),
                       downlink_bytes_per_s=sum(sizes) * senders / t_end)


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


@dataclass(frozen=True, slots=True)
class Goal:
    name: str
    measured: str
    target: str
    ok: bool


def _f(row: Mapping[str, Any], key: str) -> float:
    try:
        return float(row[key])
    except (KeyError, TypeError, ValueError):
        return math.nan


def check_goals(rows: Sequence[Mapping[str, Any]]) -> list[Goal]:
    """Issue 16's goals on the rows that measure them (a goal without its row is a miss)."""
    goals = []

    def at(kind: str, n: int) -> Mapping[str, Any] | None:
        return next((r for r in rows if r["kind"] == kind and int(r["agents"]) == n), None)

    images, battery = at("images", GOAL_AGENTS), at("battery", GOAL_AGENTS)
    p99 = _f(images, "p99_ms") if images else math.nan
    goals.append(Goal(f"images decide p99 at {GOAL_AGENTS} drones",
                      f"{p99:.2f} ms (cpu {_f(images or {}, 'cpu_p99_ms'):.2f})",
                      f"<= {GOAL_IMAGES_P99_MS:g} ms", p99 <= GOAL_IMAGES_P99_MS))
    mean = _f(battery, "mean_ms") if battery else math.nan
    goals.append(Goal(f"battery 1500 it mean at {GOAL_AGENTS} agents",
                      f"{mean:.2f} ms (cpu {_f(battery or {}, 'cpu_mean_ms'):.2f})",
                      f"<= {GOAL_BATTERY_MEAN_MS:g} ms", mean <= GOAL_BATTERY_MEAN_MS))
    for r in rows:
        if r["kind"] != "long":
            continue
        g, lo, hi = _f(r, "growth"), _f(r, "growth_lo"), _f(r, "growth_hi")
        goals.append(Goal(
            f"decide cpu last/first tenth ({int(r['agents'])} agents, {_f(r, 't_end'):g} s)",
            f"{_f(r, 'first_tenth_ms'):.2f} -> {_f(r, 'last_tenth_ms'):.2f} ms: x{g:.2f} "
            f"[{lo:.2f}, {hi:.2f}]", f"low end <= {GROWTH_LIMIT:g}", lo <= GROWTH_LIMIT))
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
            x = _f(r, key)
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


def plan(agents: Sequence[int], *, quick: bool) -> list[dict[str, Any]]:
    """The cells: images and battery at every size, optimum on short missions, one long one."""
    t_img, t_bat = (4.0, 6.0) if quick else (8.0, 20.0)
    cells: list[dict[str, Any]] = []
    for n in agents:
        cells.append({"kind": "images", "agents": n, "t_end": t_img})
        cells.append({"kind": "battery", "agents": n, "t_end": t_bat})
    for n in OPTIMUM_AGENTS:
        cells.append({"kind": "optimum", "agents": n, "t_end": 4.0 if quick else 10.0})
    cells.append({"kind": "long", "agents": min(agents), "t_end": 20.0 if quick else 300.0})
    return cells


def _agents(text: str) -> list[int]:
    try:
        values = sorted({int(x) for x in text.split(",") if x.strip()})
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected sizes like 10,25,50, got {text!r}") from None
    if not values or values[0] < 1:
        raise argparse.ArgumentTypeError("fleet sizes must be >= 1")
    return values


def main(argv: list[str] | None = None) -> int:
    from sitl.study.sweep import add_cluster_options, dask_client, run_sweep

    parser = argparse.ArgumentParser(
        prog="uav-sitl study scaling",
        description="Fleet-size scaling: decide time, report size, memory, utility vs optimum.",
    )
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    parser.add_argument("--agents", type=_agents, default=list(FLEET_SIZES),
                        help="fleet sizes, comma separated (default 10,25,50,100)")
    parser.add_argument("--quick", action="store_true",
                        help="short missions (indicative; for the test suite)")
    add_cluster_options(parser)
    parser.set_defaults(workers=1)  # timing cells must not compete for the CPU
    args = parser.parse_args(argv)
    if args.workers < 1:
        parser.error("--workers must be at least 1")
    cells = plan(args.agents, quick=args.quick)
    out: Path = args.out
    started = time.perf_counter()
    try:
        out.mkdir(parents=True, exist_ok=True)
        with dask_client(args.scheduler, workers=args.workers) as client:
            sweep = run_sweep(scaling_cell, cells, out=out / "scaling.csv", client=client,
                              label="scaling")
    except (OSError, ValueError) as exc:  # no scheduler, unwritable --out, another sweep's CSV
        print(f"uav-sitl study scaling: {exc}", file=sys.stderr)
        return 1
    wanted = {(c["kind"], c["agents"], c["t_end"]) for c in cells}
    rows = [r for r in sweep.rows
            if (r["kind"], int(r["agents"]), float(r["t_end"])) in wanted]
    if rows:
        _plot(out / "scaling.png", rows)
    print("\n".join(table(rows)))
    print()
    for g in check_goals(rows):
        print(f"{'ok  ' if g.ok else 'MISS'} {g.name}: {g.measured} (goal {g.target})")
    print(f"\n{len(cells)} cells ({sweep.ran} run now, {sweep.skipped} from an earlier run, "
          f"{len(sweep.failed)} failed) in {time.perf_counter() - started:.0f} s; "
          f"wrote {out}/scaling.csv, scaling.png")
    return 1 if sweep.failed else 0


def _plot(path: Path, rows: Sequence[Mapping[str, Any]]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(10, 7.5))

    def series(kind: str, key: str) -> tuple[list[int], list[float]]:
        pts = sorted((int(r["agents"]), _f(r, key)) for r in rows if r["kind"] == kind)
        return [p[0] for p in pts], [p[1] for p in pts]

    ax = axes[0][0]
    for kind, color in (("images", "tab:blue"), ("battery", "tab:red")):
        x, mean = series(kind, "mean_ms")
        _, p99 = series(kind, "p99_ms")
        ax.plot(x, mean, marker="o", color=color, label=f"{kind} mean")
        ax.plot(x, p99, marker="^", color=color, linestyle="--", label=f"{kind} p99")
        _, cpu99 = series(kind, "cpu_p99_ms")
        ax.plot(x, cpu99, marker="x", color=color, linestyle=":", linewidth=0.8,
                label=f"{kind} CPU p99")
    ax.axhline(GOAL_IMAGES_P99_MS, color="tab:blue", linestyle=":", linewidth=0.8,
               label="goal: images p99 at 50")
    ax.axhline(GOAL_BATTERY_MEAN_MS, color="tab:red", linestyle=":", linewidth=0.8,
               label="goal: battery mean at 50")
    ax.set_title("decide() wall time (CPU time dotted: the load's share left out)")
    ax.set_yscale("log")
    ax.set_ylabel("ms")
    ax = axes[0][1]
    for kind, color in (("images", "tab:blue"), ("battery", "tab:red")):
        x, size = series(kind, "report_bytes_mean")
        _, down = series(kind, "report_downlink_kBps")
        ax.plot(x, size, marker="o", color=color, label=f"{kind}: bytes per report")
        ax.plot(x, [d * 1e3 / max(1, n) for n, d in zip(x, down, strict=True)], marker="^",
                color=color, linestyle="--", label=f"{kind}: report B/s per drone")
    ax.set_title("receiver reports (as encoded)")
    ax.set_ylabel("bytes")
    ax = axes[1][0]
    for kind, color in (("images", "tab:blue"), ("battery", "tab:red")):
        x, mem = series(kind, "rss_growth_mb")
        ax.plot(x, mem, marker="o", color=color, label=kind)
    ax.set_title("peak RSS growth during the run (simulator + all agents)")
    ax.set_ylabel("MB")
    ax = axes[1][1]
    x, mcts = series("optimum", "utility_pct")
    _, opt = series("optimum", "optimum_pct")
    ax.plot(x, mcts, marker="o", color="darkred", label="MCTS 1500 (short missions)")
    ax.plot(x, opt, marker="*", color="black", label="offline optimum")
    for kind, color in (("images", "tab:blue"), ("battery", "tab:red")):
        xs, u = series(kind, "utility_pct")
        ax.plot(xs, u, marker=".", color=color, linestyle=":", label=f"{kind} utility")
    ax.set_title("% of utility of receiving everything")
    ax.set_ylim(0, 105)
    for ax in axes.flat:
        ax.set_xlabel("agents")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
