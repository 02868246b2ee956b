"""Benchmark of the MCTS middleware (issue 3): speed and quality targets; exits 1 on a miss.

    .venv/bin/python benchmarks/bench_mcts.py [--out DIR] [--quick]

Speed: reference setup of thesis ch. 5.4 (10 agents, 1500 iterations, 100 s) mean <= 15 ms,
p95 <= 30 ms per decision, flat (last 10 % of decisions vs the 2nd 10 %: <= 1.5x; the first
10 % are cheaper because the fleet is not known yet); image streaming (4 drones, 5 frames/s
with 3 versions, 1 Hz position, 0.2 Hz battery, 300 iterations) p99 <= 10 ms.
Companion default configuration (issue 18): the same fleet with ``build_decider``'s settings
(300 iterations, horizon 3 s, adaptive constraint fed by simulated receiver reports) on a
1 Mbit/s link near capacity (backlog of in-flight items): decide p99 <= 10 ms and the share
of decisions made by the greedy fallback <= 1 %.
Quality: utility >= the thesis reference at its drop shares (mostly-low), >= random at every
drop share in all scenarios (interpolated), within 5 % of the offline optimum on average over
20 seeded short missions, fewer violations than the reference (max 9 per run).
Offline optimum (``--only optimum``): MCTS 1500 over 20 short 4-agent missions, mean >= 95 %.
Anytime (``--only anytime``): mean utility over seeds 1-3 does not fall from 300 to 3000
iterations (20 s study missions, mostly-low and uniform at tight budgets).
Baselines (``--only baselines``, issue 18): MCTS (the companion's 300 iterations) minus
knapsack-greedy >= 0 at equal budget and at equal delivered bytes, mean over 3 seeds of
20 s study missions in the three fig. 5.7 scenarios; the pairing by seed and the bytes
interpolation are the study's (``sitl.study.baselines.tables``).
Like for like (``--only like-for-like``): the same checks against the thesis numbers on the
reference code's own message sequence (data/infdist_preset0_seed0.csv), on which they were
measured, instead of this project's draw of the scenario.
Decision rule (``--rule``, issue 18 round 7): every MCTS of the run answers by another rule
than the default (alg. 2's rule seeded by the beam dynamic programme, round 13), so a
candidate is measured on the same rows; ``--rule alg2`` is the unseeded rule of rounds 1-12.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import functools
import itertools
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from companion.middleware.adaptive import AdaptiveConstraint
from companion.middleware.constraint import ConstantConstraint
from companion.middleware.middleware import Middleware, MiddlewareConfig
from sitl.netsim import ChannelConfig, SimAgent, StreamConfig, simulate
from sitl.study.drop_rate import (
    CHANNEL,
    REFERENCE_DROP,
    REFERENCE_MCTS,
    REFERENCE_RANDOM,
    REFERENCE_VIOLATIONS_MAX,
    WINDOW_S,
    budget_bytes,
    optimum_gap,
    policy_factory,
    run_mission,
    utility_pct,
)
from utility_specs.files import builtin_spec
from utility_specs.message import Version
from utility_specs.spec import MissionSpec

ROWS: list[tuple[str, str, str, bool]] = []

RULES: dict[str, dict[str, Any]] = {
    "default": {},
    "best-plan": {"best_plan": True, "search_depth": 10, "dp_seed": None},
    "veto": {"best_plan": True, "search_depth": 10, "veto": 1.5, "dp_seed": None},
    "alg2": {"dp_seed": None},
}
"""``--rule``: MiddlewareConfig fields of each decision rule (docs/middleware.md, round 7)."""


def use_rule(name: str) -> None:
    """Every MiddlewareConfig this benchmark and the study missions build gets the rule's
    fields (a benchmark option: the product's default is not changed)."""
    import sitl.study.baselines
    import sitl.study.drop_rate

    make = functools.partial(MiddlewareConfig, **RULES[name])
    for module in (sitl.study.drop_rate, sitl.study.baselines):
        module.MiddlewareConfig = make  # type: ignore[attr-defined,misc]
    globals()["MiddlewareConfig"] = make


def use_roster() -> None:
    """Every fig. 5.7 and like-for-like mission declares its roster, which agent sends which
    type (``[mission.roster]``; knapsack-greedy and the other baselines do not read it):
    round 9's opt-in, measured with ``--roster``."""
    import sitl.study.drop_rate

    sitl.study.drop_rate.make_agents = functools.partial(
        sitl.study.drop_rate.make_agents, roster=True)
    globals()["ROSTER"] = True


ROSTER = False
"""``--roster``: the like-for-like missions declare theirs too."""


def use_periods() -> None:
    """Every fig. 5.7 and like-for-like mission declares its types' nominal period, 1 s
    (``[types.X] period_s``, read by every policy's forecaster: round 15's measurement)."""
    import sitl.study.drop_rate

    shipped = builtin_spec

    def declared(name: str) -> MissionSpec:
        spec = shipped(name)
        if not name.startswith("sim_"):  # the image missions' rates are the drones' own
            return spec
        return dataclasses.replace(spec, types={
            k: dataclasses.replace(info, period_s=1.0) for k, info in spec.types.items()})

    sitl.study.drop_rate.builtin_spec = declared  # type: ignore[attr-defined]
    globals()["builtin_spec"] = declared


def check(name: str, value: str, target: str, ok: bool) -> None:
    ROWS.append((name, value, target, ok))
    print(f"  {'ok  ' if ok else 'MISS'} {name}: {value} (target {target})", flush=True)


def speed_reference(t_end: float) -> None:
    _run, result, _ = run_mission("mostly-low", "mcts1500", 9.25, seed=11, t_end=t_end)
    wall = np.array(result.decide_wall_s[1:]) * 1e3  # the first call loads the compiled kernel
    cpu = np.array(result.decide_cpu_s[1:]) * 1e3
    tenth = max(1, len(wall) // 10)
    second, last = wall[tenth:2 * tenth].mean(), wall[-tenth:].mean()
    check("ref 1500 it mean", f"{wall.mean():.2f} ms (cpu {cpu.mean():.2f})", "<= 15 ms",
          wall.mean() <= 15)
    check("ref 1500 it p95", f"{np.percentile(wall, 95):.2f} ms (cpu "
          f"{np.percentile(cpu, 95):.2f})", "<= 30 ms", bool(np.percentile(wall, 95) <= 30))
    check("ref flat (last/2nd decile)", f"{last:.2f}/{second:.2f} ms", "ratio <= 1.5",
          last <= 1.5 * second)


def speed_images(t_end: float) -> None:
    spec = builtin_spec("image_streaming")
    versions = (Version(name="full", size=40_000, quality=1.0),
                Version(name="half", size=10_000, quality=0.5),
                Version(name="quarter", size=2_500, quality=0.25))
    agents = []
    for i in range(4):
        config = MiddlewareConfig(spec=spec, agent=f"uav{i}", max_iterations=300, horizon_s=1.0)
        mw = Middleware(config, rng=np.random.default_rng(i),
                        constraint=ConstantConstraint(limit_bytes_per_s=300_000, window_s=1.0))

        def red(k: int, g: np.random.Generator, i: int = i) -> dict[str, Any]:
            return {"red": float(min(1.0, abs(g.normal(0.02 * i, 0.05))))}

        agents.append(SimAgent(name=f"uav{i}", policy=mw, streams=[
            StreamConfig(type="image", period_s=0.2, size=40_000, phase_s=0.01 * i,
                         versions=versions, data=red),
            StreamConfig(type="position", period_s=1.0, size=64, phase_s=0.1 + 0.01 * i),
            StreamConfig(type="battery", period_s=5.0, size=32, phase_s=0.2 + 0.01 * i,
                         data=lambda k, g: {"level": max(0.1, 1.0 - 0.001 * k)}),
        ]))
    result = simulate(agents, channel=ChannelConfig(capacity_bytes_per_s=1_000_000),
                      t_end=t_end, rng=np.random.default_rng(5))
    wall = np.array(result.decide_wall_s[4:]) * 1e3
    cpu = np.array(result.decide_cpu_s[4:]) * 1e3
    check("images 300 it p99", f"{np.percentile(wall, 99):.2f} ms (mean {wall.mean():.2f}; "
          f"cpu p99 {np.percentile(cpu, 99):.2f})", "<= 10 ms", bool(np.percentile(wall, 99) <= 10))


def image_fleet(make_policy: Any, *, n: int = 4) -> list[SimAgent]:
    """4 drones: 5 frames/s in 3 versions, 1 Hz position, 0.2 Hz battery."""
    versions = (Version(name="full", size=40_000, quality=1.0),
                Version(name="half", size=10_000, quality=0.5),
                Version(name="quarter", size=2_500, quality=0.25))
    agents = []
    for i in range(n):
        def red(k: int, g: np.random.Generator, i: int = i) -> dict[str, Any]:
            return {"red": float(min(1.0, abs(g.normal(0.02 * i, 0.05))))}

        agents.append(SimAgent(name=f"uav{i}", policy=make_policy(f"uav{i}", i), streams=[
            StreamConfig(type="image", period_s=0.2, size=40_000, phase_s=0.01 * i,
                         versions=versions, data=red),
            StreamConfig(type="position", period_s=1.0, size=64, phase_s=0.1 + 0.01 * i),
            StreamConfig(type="battery", period_s=5.0, size=32, phase_s=0.2 + 0.01 * i,
                         data=lambda k, g: {"level": max(0.1, 1.0 - 0.001 * k)}),
        ]))
    return agents


def speed_companion_default(t_end: float) -> None:
    """The companion's own configuration under backlog (issue 18), not an easier case."""
    spec = builtin_spec("image_streaming")
    middlewares: list[Middleware] = []

    def policy(name: str, i: int) -> Middleware:
        config = MiddlewareConfig(spec=spec, agent=name, max_iterations=300, horizon_s=3.0)
        mw = Middleware(config, rng=np.random.default_rng(i), constraint=AdaptiveConstraint())
        middlewares.append(mw)
        return mw

    agents = image_fleet(policy)
    result = simulate(agents, channel=ChannelConfig(capacity_bytes_per_s=125_000),
                      t_end=t_end, rng=np.random.default_rng(5))
    wall = np.array(result.decide_wall_s[4:]) * 1e3
    cpu = np.array(result.decide_cpu_s[4:]) * 1e3
    decisions = sum(mw.counters["decisions"] for mw in middlewares)
    fallback = sum(mw.counters["fallback"] for mw in middlewares)
    share = fallback / max(1, decisions)
    sent = sum(m.size for m in result.sent) / t_end
    lat = [m.t_rcv - m.t_sent for m in result.delivered
           if m.t_rcv is not None and m.t_sent is not None]
    xi = [mw.constraint.limit_bytes_per_s(now=t_end) for mw in middlewares]
    print(f"    utility {utility_pct(spec, result.generated, t_end):.1f} %, "
          f"sent {sent / 1e3:.1f} kB/s, latency p95 {np.percentile(lat, 95):.2f} s, "
          f"link samples {result.link_samples}, xi at end "
          + " ".join(f"{x / 1e3:.1f}" for x in xi) + " kB/s", flush=True)
    check("companion default p99", f"{np.percentile(wall, 99):.2f} ms (mean {wall.mean():.2f}; "
          f"cpu p99 {np.percentile(cpu, 99):.2f})", "<= 10 ms",
          bool(np.percentile(wall, 99) <= 10))
    check("companion default fallback share", f"{100 * share:.1f} % ({fallback}/{decisions})",
          "<= 1 %", share <= 0.01)


REFERENCE_SEQUENCE = Path(__file__).with_name("data") / "infdist_preset0_seed0.csv"
"""The thesis code's own message sequence (preset 0, 10 agents, 100 s, np.random.seed(0));
see data/make_infdist_preset0.py for how it was made."""


def reference_sequence_agents(policy: str, param: float, *, seed: int) -> list[SimAgent]:
    """The 10 agents of the reference sequence, each replaying its recorded messages."""
    spec = builtin_spec("sim_mostly_low")
    with REFERENCE_SEQUENCE.open(newline="") as f:
        rows = list(csv.DictReader(f))
    senders = sorted({int(r["sender"]) for r in rows})
    if ROSTER:
        spec = dataclasses.replace(spec, roster={f"agent{i}": (f"battery_{i}",)
                                                 for i in senders})
    make = policy_factory(policy, param, seed=seed)
    agents = []
    for i in senders:
        mine = sorted((r for r in rows if int(r["sender"]) == i), key=lambda r: int(r["k"]))
        rho = [float(r["depletion_rate"]) for r in mine]
        stream = StreamConfig(
            type=f"battery_{i}", period_s=1.0, size=int(mine[0]["size"]),
            times=tuple(float(r["t_gen"]) for r in mine),
            data=lambda k, g, rho=rho: {"level": 1.0, "depletion_rate": rho[k]},
        )
        agents.append(SimAgent(name=f"agent{i}", policy=make(f"agent{i}", spec),
                               streams=[stream]))
    return agents


def like_for_like(t_end: float = 100.0) -> None:
    """MCTS 1500 and random on the reference's own sequence, at its drop shares (issue 18):
    the thesis numbers (REFERENCE_MCTS / REFERENCE_RANDOM) were measured on this sequence."""
    spec = builtin_spec("sim_mostly_low")
    curves: dict[str, list[tuple[float, float]]] = {"mcts1500": [], "random": []}
    worst_violations = 0
    for policy, params in (("mcts1500", [25.0, 19.25, 15.75, 12.0, 9.25, 5.5, 2.5, 1.0]),
                           ("random", [0.0, 0.1, 0.23, 0.37, 0.52, 0.63, 0.78, 0.9, 1.0])):
        for param in params:
            agents = reference_sequence_agents(policy, param, seed=21)
            result = simulate(agents, channel=CHANNEL, t_end=t_end,
                              rng=np.random.default_rng([21, 3]))
            pct = utility_pct(spec, result.generated, t_end)
            curves[policy].append((result.drop_share, pct))
            if policy != "random":
                worst_violations = max(worst_violations, result.violations(
                    window_s=WINDOW_S, budget_bytes=budget_bytes(param)))
            print(f"    like-for-like {policy} {param:g}: drop={result.drop_share:.2f} "
                  f"utility={pct:.1f}%", flush=True)
    at = {p: [float(np.interp(x, *zip(*sorted(c), strict=True))) for x in REFERENCE_DROP]
          for p, c in curves.items()}
    print("    like-for-like random at the reference drop shares: "
          + " ".join(f"{v:.1f}" for v in at["random"]) + " (reference's random: "
          + " ".join(f"{v:.1f}" for v in REFERENCE_RANDOM) + ")")
    diff = min(o - r for o, r in zip(at["mcts1500"], REFERENCE_MCTS, strict=True))
    check("like-for-like (reference's own sequence) vs thesis MCTS",
          " ".join(f"{v:.1f}" for v in at["mcts1500"]),
          " ".join(f"{r:.1f}" for r in REFERENCE_MCTS), diff >= 0)
    check("like-for-like: violations per run (max)", str(worst_violations),
          f"< {REFERENCE_VIOLATIONS_MAX}", worst_violations < REFERENCE_VIOLATIONS_MAX)


def quality(t_end: float, out: Path, scenarios: list[str]) -> None:
    budgets = [25.0, 22.0, 19.25, 15.75, 12.0, 9.25, 5.5, 2.5]
    drops = [0.0, 0.1, 0.23, 0.37, 0.52, 0.63, 0.78, 0.9, 1.0]
    rows = []
    for scenario in scenarios:
        mcts = []
        worst_violations = 0
        for b in budgets:
            run, _, _ = run_mission(scenario, "mcts1500", b, seed=21, t_end=t_end)
            mcts.append((run.drop_share, run.utility_pct))
            worst_violations = max(worst_violations, run.violations)
            rows.append({"scenario": scenario, "policy": "mcts1500", "param": b,
                         "drop": run.drop_share, "utility": run.utility_pct,
                         "violations": run.violations})
            print(f"    {scenario} mcts1500 budget={b}: drop={run.drop_share:.2f} "
                  f"utility={run.utility_pct:.1f}% violations={run.violations}", flush=True)
        rand = []
        for p in drops:
            run, _, _ = run_mission(scenario, "random", p, seed=21, t_end=t_end)
            rand.append((run.drop_share, run.utility_pct))
            rows.append({"scenario": scenario, "policy": "random", "param": p,
                         "drop": run.drop_share, "utility": run.utility_pct, "violations": 0})
        mx, my = zip(*sorted(mcts), strict=True)
        rx, ry = zip(*sorted(rand), strict=True)
        grid = [x for x in np.linspace(0.05, 0.95, 19) if mx[0] <= x <= mx[-1]]
        gap = min(float(np.interp(x, mx, my) - np.interp(x, rx, ry)) for x in grid)
        check(f"{scenario}: mcts - random (worst)", f"{gap:+.1f} points", ">= 0", gap >= 0)
        ours = [float(np.interp(x, mx, my)) for x in REFERENCE_DROP]
        if scenario == "mostly-low":
            # the issue gives the reference's numbers for this scenario only
            diff = min(o - r for o, r in zip(ours, REFERENCE_MCTS, strict=True))
            check(f"{scenario} vs thesis MCTS", " ".join(f"{o:.1f}" for o in ours),
                  " ".join(f"{r:.1f}" for r in REFERENCE_MCTS), diff >= 0)
        else:
            print(f"    {scenario} at the reference drop shares: "
                  + " ".join(f"{o:.1f}" for o in ours) + " (no reference numbers)")
        check(f"{scenario}: violations per run (max)", str(worst_violations),
              f"< {REFERENCE_VIOLATIONS_MAX}", worst_violations < REFERENCE_VIOLATIONS_MAX)
    with (out / "bench_mcts_quality.csv").open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


ANYTIME_CASES = (("mostly-low", 5.5), ("mostly-low", 2.5), ("uniform", 5.5))
ANYTIME_ITERATIONS = (300, 600, 1500, 3000)


def anytime(seeds: tuple[int, ...] = (1, 2, 3), t_end: float = 20.0) -> None:
    """Mean utility over seeds must not fall as the iteration budget grows (issue 18), on
    the study's missions (``sitl.study.baselines.run_one``, the companion's 300 and up)."""
    from sitl.study.baselines import run_one

    for scenario, budget in ANYTIME_CASES:
        means = []
        for iterations in ANYTIME_ITERATIONS:
            runs = [run_one(scenario, f"mcts{iterations}", budget, seed=s, t_end=t_end)
                    for s in seeds]
            means.append(float(np.mean([r["utility_pct"] for r in runs])))
        falls = [b - a for a, b in itertools.pairwise(means)]
        check(f"anytime {scenario} {budget:g} msgs/T, it. "
              + "/".join(str(i) for i in ANYTIME_ITERATIONS),
              " / ".join(f"{m:.1f}" for m in means) + " %", "never falls",
              min(falls) >= -1e-9)


BASELINE_SCENARIOS = ("mostly-low", "uniform", "mostly-high")
BASELINE_MCTS_BUDGETS = (9.25, 5.5, 2.5)
BASELINE_KNAPSACK_BUDGETS = (25.0, 19.25, 12.0, 9.25, 5.5, 2.5)
"""Knapsack leaves budget unused: it needs 1.2-2.3 times MCTS's budget to deliver MCTS's
bytes (docs/middleware.md, round 5), so its curve reaches up to 25 msgs/T."""


def _delta_cells(table: str) -> dict[tuple[str, float], dict[str, str]]:
    """(scenario, budget) -> {column: cell} from ``sitl.study.baselines.tables``' markdown."""
    cells: dict[tuple[str, float], dict[str, str]] = {}
    scenario, header = "", [""]
    for line in table.splitlines():
        if line.startswith("**"):
            scenario = line.split("**")[1]
        elif line.startswith("| budget"):
            header = [c.strip() for c in line.strip("|").split("|")]
        elif line.startswith("| ") and not line.startswith("|---"):
            row = [c.strip() for c in line.strip("|").split("|")]
            cells[(scenario, float(row[0].split()[0]))] = dict(zip(header, row, strict=True))
    return cells


def baselines(seeds: tuple[int, ...] = (1, 2, 3), t_end: float = 20.0,
              policy: str = "mcts300") -> None:
    """MCTS against knapsack-greedy at equal budget and at equal delivered bytes (issue 18):
    the study's missions (``run_one``) and its paired comparison (``tables``)."""
    from sitl.study.baselines import run_one, tables

    rows = []
    for scenario in BASELINE_SCENARIOS:
        for seed in seeds:
            rows += [run_one(scenario, policy, b, seed=seed, t_end=t_end)
                     for b in BASELINE_MCTS_BUDGETS]
            rows += [run_one(scenario, "knapsack", b, seed=seed, t_end=t_end)
                     for b in BASELINE_KNAPSACK_BUDGETS]
    table = tables(rows, reference=policy)
    cells = _delta_cells(table)
    for scenario in BASELINE_SCENARIOS:
        for kind in ("budget", "bytes"):
            shown, worst = [], -np.inf
            for b in BASELINE_MCTS_BUDGETS:
                cell = cells[(scenario, b)][f"Δ knapsack equal {kind}"]
                shown.append(f"{b:g}: {cell}")
                if cell != "n/a":  # knapsack never delivers as many bytes at any budget
                    worst = max(worst, float(cell.split()[0]))
            check(f"{policy} - knapsack, {scenario}, equal {kind}", "; ".join(shown),
                  "Δ knapsack <= 0 (mean)", worst <= 1e-9)


def optimum(n_missions: int, t_end: float) -> None:
    """MCTS (1500 it.) against the exact optimum with full knowledge, 4 agents, 3 msgs/T."""
    ratios = []
    for seed in range(n_missions):
        scenario = ("mostly-low", "uniform", "mostly-high")[seed % 3]
        mcts_pct, opt_pct, _ = optimum_gap(scenario, 3.0, seed=seed, t_end=t_end, n_agents=4)
        ratios.append(mcts_pct / opt_pct if opt_pct > 0 else 1.0)
    mean = float(np.mean(ratios))
    check(f"vs offline optimum ({n_missions} x {t_end:g} s)", f"{100 * mean:.1f} % (worst "
          f"{100 * min(ratios):.1f} %)", ">= 95 %", mean >= 0.95)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("artifacts/bench_mcts"))
    parser.add_argument("--quick", action="store_true", help="shorter missions (indicative)")
    parser.add_argument("--only", choices=["companion", "like-for-like", "anytime", "optimum",
                                           "baselines"],
                        help="run only these rows")
    parser.add_argument("--rule", choices=sorted(RULES), default="default",
                        help="decision rule of every MCTS (default: the product's)")
    parser.add_argument("--periods", action="store_true",
                        help="the fig. 5.7 and like-for-like missions declare their types' "
                             "nominal period (1 s), for every policy")
    parser.add_argument("--roster", action="store_true",
                        help="the fig. 5.7 and like-for-like missions declare which agent "
                             "sends which type (MCTS plans for the streams not heard yet)")
    args = parser.parse_args(argv)
    use_rule(args.rule)
    if args.roster:
        use_roster()
    if args.periods:
        use_periods()
    args.out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    t_end = 30.0 if args.quick else 100.0
    if args.only == "companion":
        speed_companion_default(10.0 if args.quick else 30.0)
        return 0 if all(ok for *_, ok in ROWS) else 1
    if args.only == "like-for-like":
        like_for_like(t_end)
        return 0 if all(ok for *_, ok in ROWS) else 1
    if args.only == "anytime":
        anytime()
        return 0 if all(ok for *_, ok in ROWS) else 1
    if args.only == "optimum":
        optimum(6 if args.quick else 20, 20.0)
        return 0 if all(ok for *_, ok in ROWS) else 1
    if args.only == "baselines":
        baselines()
        return 0 if all(ok for *_, ok in ROWS) else 1
    print("speed: reference setup", flush=True)
    speed_reference(t_end)
    print("speed: image streaming", flush=True)
    speed_images(10.0 if args.quick else 30.0)
    print("speed: companion default configuration under backlog", flush=True)
    speed_companion_default(10.0 if args.quick else 30.0)
    print("quality: drop share vs utility", flush=True)
    quality(t_end, args.out, ["mostly-low"] if args.quick else
            ["mostly-low", "uniform", "mostly-high"])
    print("quality: like for like on the reference's own message sequence", flush=True)
    like_for_like(t_end)
    print("quality: anytime (more iterations never lower the mean utility)", flush=True)
    anytime()
    print("quality: against knapsack-greedy at equal budget and equal bytes", flush=True)
    baselines()
    print("quality: offline optimum", flush=True)
    optimum(6 if args.quick else 20, 20.0)
    print(f"\n{'check':42s} {'measured':34s} {'target':28s} result")
    for name, value, target, ok in ROWS:
        print(f"{name:42s} {value:34s} {target:28s} {'ok' if ok else 'MISS'}")
    print(f"({time.perf_counter() - t0:.0f} s)")
    return 0 if all(ok for *_, ok in ROWS) else 1


if __name__ == "__main__":
    sys.exit(main())
