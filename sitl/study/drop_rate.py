"""Study: utility against drop share (thesis figure 5.7) on the simulated shared channel.

``uav-sitl study drop-rate-vs-utility --out DIR [--quick]`` runs the reference setup of
thesis ch. 5.4 (10 agents, one stream of 2048-byte ``battery`` messages each at a rate drawn
from N(1, 0.1) Hz, 100 s) in three scenarios named by their histogram (mostly-low: weights
3^(i+1), uniform: 1000i+1, mostly-high: i^0.1+1), with MCTS (300 and 1500 iterations),
random drop, knapsack-greedy and, on shortened missions, the exact offline optimum. The
constraint is a message budget per T = 2.5 s window set from a target drop share.
x = achieved share of messages not delivered, y = % of the utility of receiving everything
with zero delay. Writes ``drop_rate.csv``, ``characteristics.csv``, ``optimum.csv`` and
``drop_rate.png`` (top: utility vs drop share; bottom: histograms of the messages' expected
utility with eCDF).
"""

from __future__ import annotations

import argparse
import csv
import time
from collections import defaultdict
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from companion.middleware.baselines import (
    KnapsackGreedy,
    Policy,
    RandomDrop,
    SendAll,
    offline_optimum,
)
from companion.middleware.constraint import ConstantConstraint
from companion.middleware.incremental import PlanItem, build_problem, option_message
from companion.middleware.middleware import Middleware, MiddlewareConfig
from sitl.netsim import ChannelConfig, SimAgent, SimResult, StreamConfig, ideal_copies, simulate
from sitl.study.sweep import progress_line as _progress
from utility_specs.evaluate import evaluate
from utility_specs.files import builtin_spec
from utility_specs.message import Message, MessageKey
from utility_specs.spec import MissionSpec

__all__ = [
    "REFERENCE_MCTS",
    "REFERENCE_RANDOM",
    "SCENARIOS",
    "OfflineOptimum",
    "Run",
    "main",
    "make_agents",
    "offline_optimum_run",
    "optimum_gap",
    "run_mission",
]

SCENARIOS: dict[str, str] = {
    "mostly-low": "sim_mostly_low",
    "uniform": "sim_uniform",
    "mostly-high": "sim_mostly_high",
}
WINDOW_S = 2.5
HORIZON_S = 5.0
"""Planning horizon of the MCTS and knapsack policies (longer than the window T)."""
SIZE = 2048
REFERENCE_DROP = (0.23, 0.37, 0.52, 0.63, 0.78, 0.90)
REFERENCE_MCTS = (98.4, 96.7, 93.2, 89.5, 80.0, 39.4)
REFERENCE_RANDOM = (83.5, 71.4, 58.5, 48.7, 31.6, 14.3)
"""Thesis reference implementation, mostly-low scenario (% of utility at the drop shares)."""
REFERENCE_VIOLATIONS_MAX = 9
CHANNEL = ChannelConfig(capacity_bytes_per_s=250_000.0, overhead_bytes=64, propagation_s=0.001)


def _scenario_streams(scenario: str, n_agents: int, rng: np.random.Generator) -> list[StreamConfig]:
    """Per agent i: one ``battery_i`` stream with the scenario's depletion rates and jitter."""
    streams = []
    for i in range(n_agents):
        rate_hz = max(0.2, float(rng.normal(1.0, 0.1)))
        period = 1.0 / rate_hz
        if scenario == "mostly-high":
            mean, jitter = None, 0.0
        elif scenario == "mostly-low":
            mean, jitter = float(rng.normal(0.2, 0.2)), 0.1
        elif scenario == "uniform":
            # rho ~ 1/period: a message's line expires about when the next one arrives, so
            # what a message adds does not depend on which earlier ones were dropped and the
            # weights 1000i+1 alone spread the utilities evenly (with rho 0.3 a message after
            # a gap adds ~5x one after a delivered neighbour: histogram 63/24/10/2/1 %).
            mean, jitter = float(rng.normal(1.0, 0.01)), 0.001
        else:
            raise ValueError(f"unknown scenario {scenario!r}; expected one of {list(SCENARIOS)}")

        def data(k: int, g: np.random.Generator, mean: float | None = mean) -> Mapping[str, Any]:
            rho = 0.7 if mean is None else max(0.003, float(g.normal(mean, 0.001)))
            return {"level": 1.0, "depletion_rate": rho}

        streams.append(
            StreamConfig(
                type=f"battery_{i}", period_s=period, size=SIZE,
                phase_s=float(rng.uniform(0.0, period)), jitter_s=jitter, data=data,
            )
        )
    return streams


def budget_bytes(messages_per_window: float) -> float:
    return messages_per_window * SIZE


def make_agents(
    scenario: str,
    policy: Callable[[str, MissionSpec], Policy],
    *,
    seed: int,
    n_agents: int = 10,
    roster: bool = False,
) -> tuple[MissionSpec, list[SimAgent]]:
    """One stream per agent; ``roster``: the spec names who sends what (MCTS reads it)."""
    spec = builtin_spec(SCENARIOS[scenario])
    rng = np.random.default_rng([seed, 7])
    streams = _scenario_streams(scenario, n_agents, rng)
    if roster:
        spec = replace(spec, roster={f"agent{i}": (streams[i].type,) for i in range(n_agents)})
    agents = [
        SimAgent(name=f"agent{i}", policy=policy(f"agent{i}", spec), streams=[streams[i]])
        for i in range(n_agents)
    ]
    return spec, agents


def policy_factory(
    name: str, param: float, *, seed: int, horizon_s: float = HORIZON_S
) -> Callable[[str, MissionSpec], Policy]:
    """``mcts300``/``mcts1500``/``knapsack`` take a budget (messages per window), ``random``
    a drop probability."""

    def constraint() -> ConstantConstraint:
        return ConstantConstraint(limit_bytes_per_s=budget_bytes(param) / WINDOW_S,
                                  window_s=WINDOW_S)

    def make(agent: str, spec: MissionSpec) -> Policy:
        index = int(agent.removeprefix("agent") or 0)
        if name.startswith("mcts"):
            config = MiddlewareConfig(spec=spec, agent=agent, max_iterations=int(name[4:]),
                                      horizon_s=horizon_s)
            return Middleware(config, rng=np.random.default_rng([seed, index]),
                              constraint=constraint())
        if name == "random":
            return RandomDrop(param, rng=np.random.default_rng([seed, index, 1]))
        if name == "knapsack":
            return KnapsackGreedy(spec, agent=agent, constraint=constraint(), horizon_s=horizon_s)
        if name == "send_all":
            return SendAll()
        raise ValueError(f"unknown policy {name!r}")

    return make


@dataclass(frozen=True, slots=True, kw_only=True)
class Run:
    scenario: str
    policy: str
    param: float
    seed: int
    t_end: float
    drop_share: float
    utility_pct: float
    violations: int
    decisions: int
    mean_decide_ms: float
    p95_decide_ms: float


def utility_pct(spec: MissionSpec, generated: Sequence[Message], t_end: float) -> float:
    return utility_pcts(spec, generated, t_end, ends=(t_end,))[0]


def utility_pcts(spec: MissionSpec, generated: Sequence[Message], t_end: float, *,
                 ends: Sequence[float]) -> list[float]:
    """The utility received over [0, e] per e of ``ends``, in % of the whole mission's ideal."""
    got = [m for m in generated if m.t_rcv is not None]
    ideal = evaluate(ideal_copies(generated), spec, t_end=t_end).total
    return [100.0 * evaluate(got, spec, t_end=e).total / ideal if ideal > 0 else 100.0
            for e in ends]


def run_mission(
    scenario: str, policy: str, param: float, *, seed: int, t_end: float, n_agents: int = 10,
    horizon_s: float = HORIZON_S,
) -> tuple[Run, SimResult, MissionSpec]:
    factory = policy_factory(policy, param, seed=seed, horizon_s=horizon_s)
    spec, agents = make_agents(scenario, factory, seed=seed, n_agents=n_agents)
    result = simulate(agents, channel=CHANNEL, t_end=t_end, rng=np.random.default_rng([seed, 3]))
    wall = np.array(result.decide_wall_s) * 1e3
    violations = 0
    if policy != "random" and policy != "send_all":
        violations = result.violations(window_s=WINDOW_S, budget_bytes=budget_bytes(param))
    run = Run(
        scenario=scenario, policy=policy, param=param, seed=seed, t_end=t_end,
        drop_share=result.drop_share, utility_pct=utility_pct(spec, result.generated, t_end),
        violations=violations, decisions=len(wall),
        mean_decide_ms=float(wall.mean()) if len(wall) else 0.0,
        p95_decide_ms=float(np.percentile(wall, 95)) if len(wall) else 0.0,
    )
    return run, result, spec


@dataclass(frozen=True, slots=True)
class OfflineOptimum:
    """The best plan of a whole mission held to the window budget, with full knowledge."""

    utility_pct: float
    sends: tuple[tuple[float, int], ...]
    """(send time, bytes) of every message the plan sends."""
    drop_share: float
    states: int

    @property
    def delivered_bytes(self) -> int:
        return sum(size for _, size in self.sends)


def offline_optimum_run(
    scenario: str, messages_per_window: float, *, seed: int, t_end: float, n_agents: int = 10,
    max_states: int = 500_000,
) -> OfflineOptimum:
    """The exact optimum of the mission under the budget (``offline_optimum``'s DP): it knows
    every message in advance and plans with the channel's unloaded latency, so no policy held
    to the same budget gets more. Raises ``MiddlewareError`` where the DP outgrows
    ``max_states`` (the fig. 5.7 missions above about 6 messages per window)."""
    spec, agents = make_agents(scenario, policy_factory("send_all", 0.0, seed=seed), seed=seed,
                               n_agents=n_agents)
    full = simulate(agents, channel=CHANNEL, t_end=t_end, rng=np.random.default_rng([seed, 3]))
    latency = (SIZE + CHANNEL.overhead_bytes) / CHANNEL.capacity_bytes_per_s + CHANNEL.propagation_s
    items = [PlanItem(message=m, send_t=m.t_gen, rcv_t=m.t_gen + latency, kind="forecast")
             for m in full.generated]
    problem = build_problem(spec, items=items, fixed=[], horizon_end=t_end,
                            budget_bytes=budget_bytes(messages_per_window), window_s=WINDOW_S)
    best = offline_optimum(problem, max_states=max_states)
    chosen = [
        (it, option_message(it.message, o).delivered(receiver="ground", t_rcv=it.rcv_t))
        for it, o in zip(problem.items, best.choices, strict=True) if o != 0
    ]
    got = evaluate([m for _, m in chosen], spec, t_end=t_end).total
    ideal = evaluate(ideal_copies(full.generated), spec, t_end=t_end).total
    return OfflineOptimum(
        utility_pct=100.0 * got / ideal if ideal > 0 else 100.0,
        sends=tuple((float(it.send_t), int(m.size)) for it, m in chosen),
        drop_share=1.0 - len(chosen) / len(full.generated) if full.generated else 0.0,
        states=best.states,
    )


def optimum_gap(
    scenario: str, messages_per_window: float, *, seed: int, t_end: float, n_agents: int,
    iterations: int = 1500, horizon_s: float = HORIZON_S,
) -> tuple[float, float, float]:
    """(MCTS %, offline optimum %, drop share of the optimum) on one short mission.

    The optimum knows every message in advance and plans with the channel's unloaded latency.
    """
    run, _, _ = run_mission(scenario, f"mcts{iterations}", messages_per_window, seed=seed,
                            t_end=t_end, n_agents=n_agents, horizon_s=horizon_s)
    best = offline_optimum_run(scenario, messages_per_window, seed=seed, t_end=t_end,
                               n_agents=n_agents)
    return run.utility_pct, best.utility_pct, best.drop_share


def message_utilities(
    spec: MissionSpec, result: SimResult, t_end: float
) -> dict[MessageKey, float]:
    """What each delivered message added to its stream (eq. 4.5 chain: until the next one)."""
    by_stream: dict[str, list[Message]] = defaultdict(list)
    for m in result.delivered:
        by_stream[m.type].append(m)
    out: dict[MessageKey, float] = {}
    for type_name, msgs in by_stream.items():
        info = spec.types[type_name]
        fn = info.utility
        msgs.sort(key=lambda m: m.t_rcv or 0.0)
        for k, m in enumerate(msgs):
            a = m.t_rcv or 0.0
            nxt = msgs[k + 1].t_rcv if k + 1 < len(msgs) else None
            b = t_end if nxt is None else nxt
            own = fn.integral(m, a, b)
            prev = fn.integral(msgs[k - 1], a, b) if k > 0 else 0.0
            out[m.key] = info.weight * max(0.0, own - prev)
    return out


def plan(quick: bool) -> dict[str, Any]:
    if quick:
        return {
            "t_end": 20.0, "seeds": [1], "budgets": [19.25, 9.25, 2.5],
            "drops": [0.2, 0.5, 0.8], "mcts": ["mcts300"],
            "opt": {"n_agents": 3, "t_end": 8.0, "seeds": [1], "budget": 2.0},
        }
    return {
        "t_end": 100.0, "seeds": [1], "budgets": [25.0, 22.0, 19.25, 15.75, 12.0, 9.25, 5.5, 2.5],
        "drops": [0.1, 0.23, 0.37, 0.52, 0.63, 0.78, 0.9], "mcts": ["mcts300", "mcts1500"],
        "opt": {"n_agents": 4, "t_end": 20.0, "seeds": [1, 2, 3, 4, 5, 6], "budget": 3.0},
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="uav-sitl study drop-rate-vs-utility",
        description="Thesis figure 5.7: % of utility against achieved drop share.",
    )
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    parser.add_argument("--quick", action="store_true", help="short missions, few points")
    parser.add_argument("--scenario", action="append", choices=sorted(SCENARIOS),
                        help="only these scenarios (repeatable; default all)")
    args = parser.parse_args(argv)
    cfg = plan(args.quick)
    scenarios = args.scenario or list(SCENARIOS)
    args.out.mkdir(parents=True, exist_ok=True)
    jobs: list[tuple[str, str, float, int]] = []
    for scenario in scenarios:
        for seed in cfg["seeds"]:
            jobs += [(scenario, p, b, seed) for p in cfg["mcts"] for b in cfg["budgets"]]
            jobs += [(scenario, "knapsack", b, seed) for b in cfg["budgets"]]
            jobs += [(scenario, "random", d, seed) for d in cfg["drops"]]
    runs: list[Run] = []
    started = time.perf_counter()
    for k, (scenario, policy, param, seed) in enumerate(jobs, start=1):
        run, _, _ = run_mission(scenario, policy, param, seed=seed, t_end=cfg["t_end"])
        runs.append(run)
        _progress(
            f"[{k}/{len(jobs)}] {scenario:11s} {policy:9s} param={param:<6g} "
            f"drop={run.drop_share:.2f} utility={run.utility_pct:5.1f}% "
            f"violations={run.violations} decide={run.mean_decide_ms:.1f}ms "
            f"({time.perf_counter() - started:.0f}s)"
        )
    _write_csv(args.out / "drop_rate.csv", [_row(r) for r in runs])
    chars: dict[str, list[float]] = {}
    char_rows = []
    for scenario in scenarios:
        values: dict[MessageKey, list[float]] = defaultdict(list)
        # the random-drop runs of the curves themselves (same seed, same drop shares)
        for p in cfg["drops"]:
            _, result, spec = run_mission(scenario, "random", p, seed=cfg["seeds"][0],
                                          t_end=cfg["t_end"])
            for key, u in message_utilities(spec, result, cfg["t_end"]).items():
                values[key].append(u)
        means = np.array([np.mean(v) for v in values.values()])
        top = float(means.max()) if len(means) and means.max() > 0 else 1.0
        chars[scenario] = list(means / top)
        char_rows += [{"scenario": scenario, "normalised_utility": v} for v in chars[scenario]]
        _progress(f"characteristics {scenario}: {len(means)} messages")
    _write_csv(args.out / "characteristics.csv", char_rows)
    opt_rows = []
    o = cfg["opt"]
    for scenario in scenarios:
        for seed in o["seeds"]:
            mcts_pct, opt_pct, opt_drop = optimum_gap(
                scenario, o["budget"], seed=seed, t_end=o["t_end"], n_agents=o["n_agents"],
                iterations=300 if args.quick else 1500,
            )
            opt_rows.append({"scenario": scenario, "seed": seed, "n_agents": o["n_agents"],
                             "t_end": o["t_end"], "budget_msgs": o["budget"],
                             "mcts_pct": mcts_pct, "optimum_pct": opt_pct,
                             "optimum_drop": opt_drop})
            _progress(f"optimum {scenario} seed={seed}: mcts={mcts_pct:.1f}% "
                      f"optimum={opt_pct:.1f}%")
    _write_csv(args.out / "optimum.csv", opt_rows)
    _plot(args.out / "drop_rate.png", runs, chars, opt_rows, scenarios)
    _progress(f"wrote {args.out}/drop_rate.csv, characteristics.csv, optimum.csv, drop_rate.png")
    return 0


def _row(run: Run) -> dict[str, Any]:
    return {name: getattr(run, name) for name in Run.__slots__}


def _write_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    with path.open("w", newline="", encoding="utf-8") as f:
        if not rows:
            return
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def _plot(path: Path, runs: list[Run], chars: dict[str, list[float]],
          opt_rows: list[dict[str, Any]], scenarios: list[str]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, len(scenarios), figsize=(5 * len(scenarios), 8), squeeze=False)
    styles = {"mcts300": ("tab:red", "x"), "mcts1500": ("darkred", "X"),
              "random": ("tab:blue", "+"), "knapsack": ("tab:green", "^")}
    for col, scenario in enumerate(scenarios):
        ax = axes[0][col]
        for policy, (color, marker) in styles.items():
            pts = sorted((r.drop_share, r.utility_pct) for r in runs
                         if r.scenario == scenario and r.policy == policy)
            if pts:
                ax.plot(*zip(*pts, strict=True), marker=marker, color=color, label=policy,
                        linestyle="-", linewidth=0.8)
        opt = [(r["optimum_drop"], r["optimum_pct"]) for r in opt_rows if r["scenario"] == scenario]
        if opt:
            ax.scatter(*zip(*opt, strict=True), marker="*", s=90, color="black",
                       label="offline optimum (short)")
        finish_panels(ax, axes[1][col], scenario, np.array(chars.get(scenario, [])))
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def finish_panels(ax: Any, hx: Any, scenario: str, characteristics: np.ndarray) -> None:
    """A fig 5.7 column's common parts: the reference rerun's curves (mostly-low; the
    reference code rerun here, not the thesis' own numbers), axes, legend and histogram."""
    if scenario == "mostly-low":
        ax.plot(REFERENCE_DROP, REFERENCE_MCTS, "k--", linewidth=0.8,
                label="reference rerun MCTS")
        ax.plot(REFERENCE_DROP, REFERENCE_RANDOM, "k:", linewidth=0.8,
                label="reference rerun random")
    ax.set_title(scenario)
    ax.set_xlabel("drop share")
    ax.set_ylabel("% of utility")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 105)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    histogram_panel(hx, characteristics)


def histogram_panel(hx: Any, values: np.ndarray) -> None:
    """The lower panel of fig. 5.7: the scenario's message utilities, histogram and eCDF."""
    if len(values):
        hx.hist(values, bins=20, range=(0, 1), color="grey")
        ecdf = hx.twinx()
        xs = np.sort(values)
        ecdf.plot(xs, np.arange(1, len(xs) + 1) / len(xs), color="green")
        ecdf.set_ylim(0, 1.02)
        ecdf.set_ylabel("eCDF")
    hx.set_xlabel("expected utility of a message (normalised)")
    hx.set_ylabel("messages")


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
