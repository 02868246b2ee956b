"""Study: MCTS against every baseline at equal budget and at equal delivered bytes (issue 18).

``uav-sitl study mcts-vs-baselines --out DIR [--quick]`` runs, on the simulated shared
channel, the three fig. 5.7 scenarios (10 agents, 2048-byte battery messages, budget in
messages per 2.5 s window) and image streaming (4 drones, 5 frames/s in 3 versions, 1 Hz
position, 0.2 Hz battery, budget ξ in bytes/s) with MCTS and the baselines: random drop,
greedy (best version that fits the window), knapsack-greedy (utility per byte over the next
window) and knapsack-fill (knapsack-greedy that also sends what still fits, so no budget is
left unused). Each (scenario, policy, budget) runs over several seeds.

* Equal budget: utility (% of receiving everything at once) per budget, mean and 95 %
  t-interval over seeds; random has no budget and is left out there.
* Equal bytes: each baseline's utility interpolated, per seed, at the bytes MCTS delivered
  (its utility/bytes curve over the budgets, or over drop probabilities for random).
* Planned violations: windows of the fleet's own send decisions above the known budget.

Writes ``baselines.csv`` (one row per run) and ``baselines.md`` (the tables).
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import sys
import time
from collections import defaultdict
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from companion.middleware.baselines import Greedy, KnapsackGreedy, Policy, RandomDrop
from companion.middleware.constraint import ConstantConstraint
from companion.middleware.middleware import Decision, Middleware, MiddlewareConfig
from sitl.netsim import ChannelConfig, SimAgent, StreamConfig, simulate
from sitl.study import drop_rate as dr
from sitl.study.sweep import mean_interval
from utility_specs.files import builtin_spec
from utility_specs.message import Message, Version
from utility_specs.spec import MissionSpec

__all__ = ["KnapsackFill", "at_bytes", "image_fleet", "main", "run_one"]

POLICIES = ("mcts300", "mcts300ks", "greedy", "knapsack", "knapsack-fill", "random")
"""mcts300ks: the same MCTS seeded with the knapsack-greedy plan (``knapsack_seed``); any
``mcts<N>[ks|u][m][c]`` runs with ``run_one`` (u: without the dynamic programme's seed,
alg. 2's rule alone, the default before round 13; m: ``learn_margin``; c: forecasts are
copies of each stream's last message, the model before the spread forecasts of round 5)."""
IMAGE_VERSIONS = (Version(name="full", size=40_000, quality=1.0),
                  Version(name="half", size=10_000, quality=0.5),
                  Version(name="quarter", size=2_500, quality=0.25))
IMAGE_WINDOW_S = 2.5
IMAGE_DRONES = 4
IMAGE_CHANNEL = ChannelConfig(capacity_bytes_per_s=125_000.0)


class KnapsackFill(KnapsackGreedy):
    """Knapsack-greedy that leaves no budget unused: a message that misses the density cut
    is still sent, in the best version that fits what is left of the window."""

    def decide(self, message: Message, now: float) -> Decision:
        decision = super().decide(message, now)
        if decision.send:
            return decision
        used = self.knowledge.sent_in_window(now=now, window_s=self.constraint.window_s)
        budget = self.constraint.budget_bytes(now=now)
        sizes = [v.size for v in message.versions] if message.versions else [message.size]
        for v, size in enumerate(sizes):
            if used + size <= budget + 1e-9:
                sent = Decision(send=True, version=v if message.versions else None,
                                reason="knapsack-fill")
                return self._commit(message, sent, now)
        return decision


def image_fleet(make_policy: Callable[[str, int], Policy], *, n: int = 4,
                seed: int = 0) -> list[SimAgent]:
    """4 drones: 5 frames/s in 3 versions (red share varies per drone), position, battery."""
    agents = []
    for i in range(n):
        def red(k: int, g: np.random.Generator, i: int = i) -> dict[str, Any]:
            return {"red": float(min(1.0, abs(g.normal(0.02 * i, 0.05))))}

        phase = 0.01 * i + 0.003 * (seed % 7)
        agents.append(SimAgent(name=f"uav{i}", policy=make_policy(f"uav{i}", i), streams=[
            StreamConfig(type="image", period_s=0.2, size=40_000, phase_s=phase,
                         versions=IMAGE_VERSIONS, data=red),
            StreamConfig(type="position", period_s=1.0, size=64, phase_s=0.1 + phase),
            StreamConfig(type="battery", period_s=5.0, size=32, phase_s=0.2 + phase,
                         data=lambda k, g: {"level": max(0.1, 1.0 - 0.001 * k)}),
        ]))
    return agents


def _mcts_name(name: str) -> tuple[int, str]:
    """``mcts<iterations>[ks|u][m][c]``: ks seeds the search with knapsack-greedy's plan
    instead of the dynamic programme's, u seeds it with neither (alg. 2's rule alone, the
    default before round 13), m plans with the overshoot margin (``learn_margin``), c
    forecasts copies of the last message."""
    digits = name[4:].rstrip("ksumc")
    return int(digits), name[4 + len(digits):]


def _policy(name: str, param: float, *, spec: MissionSpec, agent: str, index: int, seed: int,
            budget_bytes: float, window_s: float, horizon_s: float,
            fleet_size: int | None = None) -> Policy:
    def constraint() -> ConstantConstraint:
        return ConstantConstraint(limit_bytes_per_s=budget_bytes / window_s, window_s=window_s)

    if name.startswith("mcts"):
        iterations, suffix = _mcts_name(name)
        config = MiddlewareConfig(spec=spec, agent=agent, max_iterations=iterations,
                                  horizon_s=horizon_s, knapsack_seed="ks" in suffix,
                                  learn_margin="m" in suffix.replace("ks", ""),
                                  fleet_size=fleet_size)
        if "u" in suffix:  # alg. 2's search alone
            config = dataclasses.replace(config, dp_seed=None)
        middleware = Middleware(config, rng=np.random.default_rng([seed, index]),
                                constraint=constraint())
        if suffix.endswith("c"):
            middleware.knowledge.forecaster.worth = None
        return middleware
    if name == "random":
        return RandomDrop(param, rng=np.random.default_rng([seed, index, 1]))
    if name == "greedy":
        return Greedy(spec, agent=agent, constraint=constraint())
    if name == "knapsack":
        return KnapsackGreedy(spec, agent=agent, constraint=constraint(), horizon_s=horizon_s)
    if name == "knapsack-fill":
        return KnapsackFill(spec, agent=agent, constraint=constraint(), horizon_s=horizon_s)
    raise ValueError(f"unknown policy {name!r}")


def run_one(scenario: str, policy: str, param: float, *, seed: int, t_end: float
            ) -> dict[str, Any]:
    """One mission; ``param`` is the budget (messages per window for the fig. 5.7 scenarios,
    bytes/s for images) or, for random, the drop probability."""
    if scenario == "images":
        spec = builtin_spec("image_streaming")
        window_s, horizon_s = IMAGE_WINDOW_S, 3.0
        budget = param * window_s
        # the mission declares its 4 drones: MCTS shares the budget at the start (round 7)
        agents = image_fleet(lambda a, i: _policy(
            policy, param, spec=spec, agent=a, index=i, seed=seed, budget_bytes=budget,
            window_s=window_s, horizon_s=horizon_s, fleet_size=IMAGE_DRONES),
            n=IMAGE_DRONES, seed=seed)
        channel = IMAGE_CHANNEL
    else:
        window_s, horizon_s = dr.WINDOW_S, dr.HORIZON_S
        budget = dr.budget_bytes(param)

        def make(agent: str, spec: MissionSpec) -> Policy:
            return _policy(policy, param, spec=spec, agent=agent,
                           index=int(agent.removeprefix("agent")), seed=seed,
                           budget_bytes=budget, window_s=window_s, horizon_s=horizon_s)

        spec, agents = dr.make_agents(scenario, make, seed=seed)
        channel = dr.CHANNEL
    result = simulate(agents, channel=channel, t_end=t_end, rng=np.random.default_rng([seed, 3]))
    violations = 0 if policy == "random" else result.violations(window_s=window_s,
                                                                budget_bytes=budget)
    mws = [a.policy for a in agents if isinstance(a.policy, Middleware)]
    fallback = sum(mw.counters["fallback"] for mw in mws)
    over = sum(mw.counters["over_budget"] for mw in mws)
    announce = sum(mw.counters["announce"] for mw in mws)
    return {
        "scenario": scenario, "policy": policy, "param": param, "seed": seed, "t_end": t_end,
        "utility_pct": dr.utility_pct(spec, result.generated, t_end),
        "delivered_bytes": sum(m.size for m in result.delivered),
        "drop_share": result.drop_share, "planned_violations": violations,
        "fallback": fallback, "known_over_budget": over, "announce": announce,
    }


def plan(quick: bool) -> dict[str, Any]:
    return {
        "seeds": [1, 2, 3] if quick else [1, 2, 3, 4, 5],
        "t_end": 20.0 if quick else 40.0,
        "budgets": {sc: [40.0, 25.0, 19.25, 12.0, 9.25, 5.5, 2.5]
                    for sc in ("mostly-low", "uniform", "mostly-high")}
        | {"images": [25_000.0, 50_000.0, 75_000.0, 100_000.0, 150_000.0]},
        "drops": [0.0, 0.25, 0.5, 0.7, 0.85, 0.95, 1.0],
    }


def _interval(values: Sequence[float]) -> tuple[float, float]:
    """Mean and half-width of the 95 % t-interval (NaN for one seed)."""
    mean, _, high = mean_interval(values)
    return mean, high - mean


def at_bytes(curve: Sequence[tuple[float, float]], target: float) -> float | None:
    """A policy's (delivered bytes, value) curve over its budgets, sorted by bytes, read at
    ``target`` bytes (linear between its points: "at equal bytes"); None outside it."""
    if len(curve) < 2 or not curve[0][0] <= target <= curve[-1][0]:
        return None
    return float(np.interp(target, [c[0] for c in curve], [c[1] for c in curve]))


def tables(rows: Sequence[dict[str, Any]], reference: str | None = None) -> str:
    """Markdown tables per scenario: MCTS utility, then each baseline's utility minus MCTS's
    on the same seed (paired; negative: MCTS better) at equal budget and at equal bytes.
    ``reference``: the MCTS policy the others are compared with (default: the first)."""
    runs: dict[tuple[str, str, float], dict[int, dict[str, Any]]] = defaultdict(dict)
    for r in rows:
        runs[(r["scenario"], r["policy"], float(r["param"]))][int(r["seed"])] = r
    order = ["mostly-low", "uniform", "mostly-high", "images"]
    scenarios = sorted({r["scenario"] for r in rows}, key=order.index)
    policies = [p for p in POLICIES if any(r["policy"] == p for r in rows)]
    mcts = reference or next(p for p in policies if p.startswith("mcts"))
    budgeted = [p for p in policies if p not in (mcts, "random")]
    others = [p for p in policies if p != mcts]

    def cell(values: list[float], n: int) -> str:
        if len(values) < n:
            return "n/a"
        m, h = _interval(values)
        return f"{m:+.1f} ± {h:.1f}"

    out = []
    for sc in scenarios:
        unit = " B/s" if sc == "images" else " msgs/T"
        budgets = sorted({k[2] for k in runs if k[0] == sc and k[1] == mcts}, reverse=True)
        seeds = sorted(runs[(sc, mcts, budgets[0])])
        out.append(f"\n**{sc}** ({len(seeds)} seeds; mean ± 95 % t-interval; Δ = baseline − "
                   f"{mcts}, paired by seed, negative: {mcts} better)\n")
        out.append(f"| budget | {mcts} % | violations (max: fleet / known) | "
                   + " | ".join(f"Δ {p} equal budget" for p in budgeted) + " | "
                   + " | ".join(f"Δ {p} equal bytes" for p in others) + " |")
        out.append("|---|---|---|" + "---|" * (len(budgeted) + len(others)))
        for b in budgets:
            ours = runs[(sc, mcts, b)]
            m, h = _interval([ours[s]["utility_pct"] for s in seeds])
            viol = max(int(ours[s]["planned_violations"]) for s in seeds)
            known = max(int(ours[s].get("known_over_budget", 0)) for s in seeds)
            cells = [f"{m:.1f} ± {h:.1f}", f"{viol} / {known}"]
            for p in budgeted:
                got = runs.get((sc, p, b), {})
                cells.append(cell([got[s]["utility_pct"] - ours[s]["utility_pct"]
                                   for s in seeds if s in got], len(seeds)))
            for p in others:
                diffs = []
                for s in seeds:
                    curve = sorted((r[s]["delivered_bytes"], r[s]["utility_pct"])
                                   for k, r in runs.items() if k[0] == sc and k[1] == p and s in r)
                    theirs = at_bytes(curve, ours[s]["delivered_bytes"])
                    if theirs is not None:
                        diffs.append(theirs - ours[s]["utility_pct"])
                cells.append(cell(diffs, len(seeds)))
            out.append(f"| {b:g}{unit} | " + " | ".join(cells) + " |")
    return "\n".join(out) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="uav-sitl study mcts-vs-baselines",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("artifacts/baselines"),
                        help="output directory for baselines.csv and baselines.md "
                             "(default artifacts/baselines)")
    parser.add_argument("--quick", action="store_true",
                        help="3 seeds, 20 s missions (default 5 seeds, 40 s)")
    parser.add_argument("--scenarios", nargs="+", metavar="SCENARIO",
                        default=["mostly-low", "uniform", "mostly-high", "images"],
                        choices=["mostly-low", "uniform", "mostly-high", "images"],
                        help="any of mostly-low, uniform, mostly-high, images (default all)")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    cfg = plan(args.quick)
    rows: list[dict[str, Any]] = []
    t0 = time.perf_counter()
    for sc in args.scenarios:
        for seed in cfg["seeds"]:
            for policy in POLICIES:
                params = cfg["drops"] if policy == "random" else cfg["budgets"][sc]
                for param in params:
                    row = run_one(sc, policy, param, seed=seed, t_end=cfg["t_end"])
                    rows.append(row)
                    print(f"{time.perf_counter() - t0:6.0f} s {sc} {policy} {param:g} seed "
                          f"{seed}: {row['utility_pct']:.1f} % {row['delivered_bytes']} B "
                          f"viol {row['planned_violations']} (known {row['known_over_budget']}"
                          f", announce {row['announce']}) fallback {row['fallback']}",
                          flush=True)
        with (args.out / "baselines.csv").open("w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
    text = tables(rows) + tables(rows, reference="mcts300ks")
    (args.out / "baselines.md").write_text(text, encoding="utf-8")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
