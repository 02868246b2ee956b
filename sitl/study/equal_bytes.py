"""Equal delivered bytes: MCTS, knapsack-greedy and the best a budget allows (issue 18).

``python -m sitl.study.equal_bytes --out DIR [--quick]`` runs, in the fig. 5.7 scenarios,
MCTS (the companion's 300 iterations) and knapsack-greedy over the study's budgets. For each
(scenario, seed, MCTS budget b) it finds the knapsack budget b' at which knapsack delivers as
many bytes as MCTS did (knapsack leaves budget unused, so b' > b), knapsack's utility there
(interpolated, as in ``mcts-vs-baselines``), and how many fleet windows of the knapsack run
at the first budget >= b' carry more than b: the budget MCTS was held to. A knapsack that
matches MCTS's bytes only by going over MCTS's budget in some windows is not compared on
equal terms.

With ``--optimum`` it also solves, where the dynamic programme fits (about 6 messages per
window and less), the exact offline optimum held to b (``drop_rate.offline_optimum_run``:
every message known in advance, no window over b) and compares knapsack with it at the
optimum's bytes. That answers whether the equal-bytes cell can be won at all by a policy
that keeps the budget: if the optimum loses it too, no policy held to b wins it.
Each Δ is also split at the end of the first window T: what was won or lost at the mission
start, when no agent has heard the others, and what after it (round 15: uniform 9.25
msgs/T is lost only at the start, where knapsack's higher budget lets it send more first
messages than MCTS's budget allows). Writes ``equal_bytes.csv``, ``equal_bytes.md`` and
``equal_bytes.png`` (utility against delivered bytes).
"""

from __future__ import annotations

import argparse
import csv
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from companion.middleware.errors import MiddlewareError
from companion.middleware.incremental import window_violations
from sitl.netsim import simulate
from sitl.study import baselines as bl
from sitl.study import drop_rate as dr

__all__ = ["main", "rows_for", "run"]

SCENARIOS = ("mostly-low", "uniform", "mostly-high")
BUDGETS = (40.0, 25.0, 19.25, 12.0, 9.25, 5.5, 2.5)


def run(scenario: str, policy: str, budget: float, *, seed: int, t_end: float
        ) -> dict[str, Any]:
    """One fig. 5.7 mission: utility, delivered bytes and the fleet's (send time, bytes)."""
    window_s, horizon_s = dr.WINDOW_S, dr.HORIZON_S
    budget_bytes = dr.budget_bytes(budget)

    def make(agent: str, spec: Any) -> Any:
        return bl._policy(policy, budget, spec=spec, agent=agent,
                          index=int(agent.removeprefix("agent")), seed=seed,
                          budget_bytes=budget_bytes, window_s=window_s, horizon_s=horizon_s)

    spec, agents = dr.make_agents(scenario, make, seed=seed)
    result = simulate(agents, channel=dr.CHANNEL, t_end=t_end,
                      rng=np.random.default_rng([seed, 3]))
    total, first = dr.utility_pcts(spec, result.generated, t_end,
                                   ends=(t_end, min(window_s, t_end)))
    return {"utility_pct": total, "first_window_pct": first,
            "delivered_bytes": sum(m.size for m in result.delivered),
            "sends": [(m.t_sent, m.size) for m in result.sent if m.t_sent is not None]}


def _optimum_columns(scenario: str, b: float, seed: int, t_end: float, max_states: int,
                     curve: Sequence[tuple[float, float]]) -> dict[str, Any]:
    """The offline optimum held to b, and knapsack's utility at the optimum's bytes."""
    nan = float("nan")
    try:
        best = dr.offline_optimum_run(scenario, b, seed=seed, t_end=t_end,
                                      max_states=max_states)
    except MiddlewareError:  # the DP outgrew max_states: not computed, said as n/a
        return {"optimum_pct": nan, "optimum_bytes": -1, "optimum_windows_over_b": -1,
                "delta_knapsack_optimum": nan}
    theirs = bl.at_bytes(curve, best.delivered_bytes)
    delta = nan if theirs is None else theirs - best.utility_pct
    return {"optimum_pct": best.utility_pct, "optimum_bytes": best.delivered_bytes,
            "optimum_windows_over_b": window_violations(
                list(best.sends), window_s=dr.WINDOW_S, budget_bytes=dr.budget_bytes(b)),
            "delta_knapsack_optimum": delta}


def rows_for(scenario: str, seed: int, *, t_end: float, mcts: str = "mcts300",
             budgets: Sequence[float] = BUDGETS, optimum: bool = False,
             max_states: int = 500_000) -> list[dict[str, Any]]:
    ours = {b: run(scenario, mcts, b, seed=seed, t_end=t_end) for b in budgets}
    # knapsack's bytes curve always spans the study's budgets: it needs 1.2-2.3 times MCTS's
    # budget to deliver MCTS's bytes (docs/middleware.md, round 5)
    ks = {b: run(scenario, "knapsack", b, seed=seed, t_end=t_end)
          for b in sorted({*BUDGETS, *budgets})}
    curve = sorted((r["delivered_bytes"], r["utility_pct"], b) for b, r in ks.items())
    utility = [(c[0], c[1]) for c in curve]
    budget_for = [(c[0], c[2]) for c in curve]
    first = sorted((r["delivered_bytes"], r["first_window_pct"]) for r in ks.values())
    rows = []
    for b, r in ours.items():
        target = r["delivered_bytes"]
        row: dict[str, Any] = {
            "scenario": scenario, "seed": seed, "t_end": t_end, "budget": b,
            "mcts_pct": r["utility_pct"],
            "mcts_bytes": target,
            "mcts_windows_over_b": window_violations(r["sends"], window_s=dr.WINDOW_S,
                                                     budget_bytes=dr.budget_bytes(b)),
            "knapsack_budget": float("nan"), "delta_knapsack": float("nan"),
            "delta_knapsack_first_window": float("nan"),
            "knapsack_windows_over_b": -1,
            "knapsack_curve": ";".join(f"{c[0]}:{c[1]:.4f}" for c in curve),
        }
        theirs = bl.at_bytes(utility, target)
        if theirs is not None:
            row["knapsack_budget"] = bl.at_bytes(budget_for, target)
            row["delta_knapsack"] = theirs - r["utility_pct"]
            theirs_first = bl.at_bytes(first, target)
            assert theirs_first is not None  # the same bytes as ``utility``'s
            row["delta_knapsack_first_window"] = theirs_first - r["first_window_pct"]
            at = next(c[2] for c in curve if c[0] >= target)
            row["knapsack_windows_over_b"] = window_violations(
                ks[at]["sends"], window_s=dr.WINDOW_S, budget_bytes=dr.budget_bytes(b))
        if optimum:
            row |= _optimum_columns(scenario, b, seed, t_end, max_states, utility)
        rows.append(row)
    return rows


def _per_seed(values: Sequence[float], fmt: str) -> str:
    """Mean and per-seed values; the mean is over the seeds that have one (n/a: none)."""
    have = [v for v in values if not np.isnan(v)]
    if not have:
        return "n/a"
    shown = ", ".join("n/a" if np.isnan(v) else f"{v:{fmt}}" for v in values)
    return f"{np.mean(have):{fmt}} ({shown})"


def table(rows: Sequence[dict[str, Any]]) -> str:
    optimum = any("optimum_pct" in r for r in rows)
    head = ("| scenario | budget b (msgs/T) | mcts % | Δ knapsack at equal bytes (mean, per seed) "
            "| of it in the first window T / after it (mean) "
            "| knapsack budget for those bytes (msgs/T) | knapsack windows over b (per seed) "
            "| mcts windows over b (per seed) |")
    rule = "|---|---|---|---|---|---|---|---|"
    if optimum:
        head += (" optimum held to b % (mean, per seed) | optimum bytes / mcts bytes "
                 "| Δ knapsack at the optimum's bytes (mean, per seed) |")
        rule += "---|---|---|"
    out = [head, rule]
    keys = sorted({(r["scenario"], r["budget"]) for r in rows},
                  key=lambda k: (SCENARIOS.index(k[0]), -k[1]))
    for sc, b in keys:
        rs = sorted((r for r in rows if r["scenario"] == sc and r["budget"] == b),
                    key=lambda r: r["seed"])
        deltas = [r["delta_knapsack"] for r in rs]
        shown = "n/a" if any(np.isnan(deltas)) else _per_seed(deltas, "+.1f")
        firsts = [r["delta_knapsack_first_window"] for r in rs]
        split = "n/a" if any(np.isnan(deltas)) else \
            f"{np.mean(firsts):+.1f} / {np.mean(deltas) - np.mean(firsts):+.1f}"
        budgets = ", ".join("n/a" if np.isnan(r["knapsack_budget"]) else
                            f"{r['knapsack_budget']:.1f}" for r in rs)
        over = ", ".join("n/a" if r["knapsack_windows_over_b"] < 0 else
                         str(r["knapsack_windows_over_b"]) for r in rs)
        mine = ", ".join(str(r["mcts_windows_over_b"]) for r in rs)
        mean = np.mean([r["mcts_pct"] for r in rs])
        line = f"| {sc} | {b:g} | {mean:.1f} | {shown} | {split} | {budgets} | {over} | {mine} |"
        if optimum:
            ratios = [r["optimum_bytes"] / r["mcts_bytes"] for r in rs if r["optimum_bytes"] >= 0]
            ratio = f"{np.mean(ratios):.2f}" if ratios else "n/a"
            line += (f" {_per_seed([r['optimum_pct'] for r in rs], '.1f')} | {ratio} "
                     f"| {_per_seed([r['delta_knapsack_optimum'] for r in rs], '+.1f')} |")
        out.append(line)
    return "\n".join(out) + "\n"


def plot(rows: Sequence[dict[str, Any]], path: Path) -> None:
    """Utility against delivered bytes per scenario: knapsack's curve per seed, MCTS and
    the optimum held to the same budgets."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenarios = [sc for sc in SCENARIOS if any(r["scenario"] == sc for r in rows)]
    fig, axes = plt.subplots(1, len(scenarios), figsize=(5 * len(scenarios), 4), squeeze=False)
    for ax, sc in zip(axes[0], scenarios, strict=True):
        mine = [r for r in rows if r["scenario"] == sc]
        for k, seed in enumerate(sorted({r["seed"] for r in mine})):
            rs = [r for r in mine if r["seed"] == seed]
            curve = [tuple(map(float, c.split(":"))) for c in rs[0]["knapsack_curve"].split(";")]
            label = "knapsack-greedy (its budgets)" if k == 0 else None
            ax.plot([c[0] / 1e3 for c in curve], [c[1] for c in curve], "-", color="0.6",
                    lw=1, label=label)
            ax.plot([r["mcts_bytes"] / 1e3 for r in rs], [r["mcts_pct"] for r in rs], "o",
                    color="tab:blue", ms=4, label="MCTS 300 at b" if k == 0 else None)
            opt = [r for r in rs if r.get("optimum_bytes", -1) >= 0]
            if opt:
                ax.plot([r["optimum_bytes"] / 1e3 for r in opt],
                        [r["optimum_pct"] for r in opt], "^", color="tab:red", ms=5,
                        label="offline optimum held to b" if k == 0 else None)
        ax.set_title(sc)
        ax.set_xlabel("delivered kB per mission")
        ax.set_ylabel("utility %")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sitl.study.equal_bytes",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("artifacts/equal_bytes"),
                        help="output directory (default artifacts/equal_bytes)")
    parser.add_argument("--quick", action="store_true",
                        help="3 seeds, 20 s missions (default 5 seeds, 40 s)")
    parser.add_argument("--seeds", type=int, default=None,
                        help="seeds 1..N (default 5; 3 with --quick)")
    parser.add_argument("--t-end", type=float, default=None, metavar="S",
                        help="mission length in s (default 40; 20 with --quick; the thesis' "
                             "fig. 5.7 missions are 100 s long: the blind start weighs less)")
    parser.add_argument("--scenarios", nargs="+", default=list(SCENARIOS), choices=SCENARIOS,
                        metavar="SCENARIO", help="any of " + ", ".join(SCENARIOS)
                        + " (default all)")
    parser.add_argument("--budgets", default=",".join(f"{b:g}" for b in BUDGETS),
                        help="MCTS budgets in messages per window T, comma separated "
                             "(default %(default)s)")
    parser.add_argument("--optimum", action="store_true",
                        help="also the exact offline optimum held to each budget, where its "
                             "DP fits (about 80 s a mission at 5.5 msgs/T; n/a above ~6)")
    parser.add_argument("--max-states", type=int, default=500_000,
                        help="DP states per level before a cell is n/a (default %(default)s)")
    args = parser.parse_args(argv)
    try:
        budgets = [float(b) for b in args.budgets.split(",")]
    except ValueError:
        parser.error(f"--budgets: numbers separated by commas expected, got {args.budgets!r}")
    if not budgets or min(budgets) <= 0 or args.max_states < 1:
        parser.error("--budgets must be > 0 and --max-states >= 1")
    n_seeds = args.seeds if args.seeds is not None else 3 if args.quick else 5
    t_end = args.t_end if args.t_end is not None else 20.0 if args.quick else 40.0
    if n_seeds < 1 or not 1.0 <= t_end <= 10_000.0:
        parser.error(f"--seeds must be >= 1 and --t-end in 1..10000 s, got {n_seeds}, {t_end:g}")
    args.out.mkdir(parents=True, exist_ok=True)
    seeds = list(range(1, n_seeds + 1))
    rows: list[dict[str, Any]] = []
    for sc in args.scenarios:
        for seed in seeds:
            rows += rows_for(sc, seed, t_end=t_end, budgets=budgets, optimum=args.optimum,
                             max_states=args.max_states)
            print(f"{sc} seed {seed} done", flush=True)
    with (args.out / "equal_bytes.csv").open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    text = table(rows)
    (args.out / "equal_bytes.md").write_text(text, encoding="utf-8")
    plot(rows, args.out / "equal_bytes.png")
    print(text)
    print(f"wrote {args.out / 'equal_bytes.csv'}, equal_bytes.md and equal_bytes.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
