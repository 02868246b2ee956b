"""Thesis figure 5.7 at the thesis' statistics, on the Dask sweep runner.

``uav-sitl study fig5.7 --out DIR [--runs 30] [--quick] [--scheduler ADDR]`` runs the ch. 5.4
setup of :mod:`sitl.study.drop_rate` (10 agents, 100 s, three scenarios named by their utility
histogram) at 31 target drop shares x ``--runs`` runs per policy. Run r of a scenario is the
same generated mission for every policy and drop share (common random numbers); the policy's
and the channel's draws come from the cell's own seed. Curves are the mean over runs with a
95 % t-interval; the histograms are the random-drop cells of run 0 (the same draws as the
curves, the thesis' "30 simulations with different message drop rates").

Writes ``fig5_7.csv`` (one row per cell, streamed; rerun to resume), ``fig5_7_summary.csv``,
``fig5_7_characteristics.csv`` and ``fig5_7.png``, and prints the table.

The thesis states no numbers for fig. 5.7 (it is a figure only); the table shows its stated
setup and claims, and the curve of the thesis' reference implementation re-run (mostly-low
only) labelled "reference rerun". Note: the thesis' text gives ω = 3^(i+1) to "scenario (a)",
which it describes as mostly *high*; those weights make most messages worth little next to
stream 9, so here scenarios are named by the histogram they produce (checked in the tests).
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
import time
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sitl.netsim import simulate
from sitl.study import drop_rate as dr
from sitl.study.sweep import (
    add_cluster_options,
    cell_seed,
    dask_client,
    error_text,
    map_cells,
    mean_interval,
    run_sweep,
)

__all__ = ["DROPS", "POLICIES", "cells", "characteristics", "fifths", "main", "mission_cell",
           "summarise"]

DROPS: tuple[float, ...] = tuple(round(k / 30, 4) for k in range(31))
"""31 target drop shares 0, 1/30, ..., 1."""
POLICIES = ("mcts1500", "mcts300", "knapsack", "random")
DEFAULT_POLICIES = ("mcts1500", "random")
"""The thesis' figure: its MCTS (1500 iterations) against random drop."""
MESSAGES_PER_WINDOW = 25.0
"""10 agents x 1 Hz x T = 2.5 s: the budget that drops nothing."""
THESIS_HISTOGRAM = {"mostly-low": "most messages of low utility (thesis scenario (c))",
                    "uniform": "uniform distribution (thesis scenario (b))",
                    "mostly-high": "most messages of high utility (thesis scenario (a))"}
THESIS_CLAIM = {
    "mostly-low": "MCTS performs very well against random drop",
    "uniform": "middle ground between the two extremes",
    "mostly-high": "MCTS cannot perform much better than random drop",
}
TABLE_DROPS = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9)


def cells(scenarios: Sequence[str], policies: Sequence[str], runs: int, *, t_end: float,
          drops: Sequence[float] = DROPS, n_agents: int = 10) -> list[dict[str, Any]]:
    return [
        {"scenario": s, "policy": p, "drop": d, "run": r, "t_end": t_end, "n_agents": n_agents}
        for s in scenarios for r in range(runs) for d in drops for p in policies
    ]


def _param(policy: str, drop: float) -> float:
    return drop if policy == "random" else MESSAGES_PER_WINDOW * (1.0 - drop)


def _simulate(params: dict[str, Any], seed: int) -> tuple[dr.Run, Any, Any]:
    scenario, policy = params["scenario"], params["policy"]
    t_end, n_agents = float(params["t_end"]), int(params["n_agents"])
    param = _param(policy, float(params["drop"]))
    mission_seed = cell_seed({"scenario": scenario, "run": params["run"], "t_end": t_end,
                              "n_agents": n_agents})
    factory = dr.policy_factory(policy, param, seed=seed)
    spec, agents = dr.make_agents(scenario, factory, seed=mission_seed, n_agents=n_agents)
    result = simulate(agents, channel=dr.CHANNEL, t_end=t_end,
                         rng=np.random.default_rng([seed, 3]))
    wall = np.array(result.decide_wall_s) * 1e3
    violations = 0
    if policy not in ("random", "send_all"):
        violations = result.violations(window_s=dr.WINDOW_S, budget_bytes=dr.budget_bytes(param))
    run = dr.Run(
        scenario=scenario, policy=policy, param=param, seed=seed, t_end=t_end,
        drop_share=result.drop_share, utility_pct=dr.utility_pct(spec, result.generated, t_end),
        violations=violations, decisions=len(wall),
        mean_decide_ms=float(wall.mean()) if len(wall) else 0.0,
        p95_decide_ms=float(np.percentile(wall, 95)) if len(wall) else 0.0,
    )
    return run, result, spec


def mission_cell(params: dict[str, Any], seed: int) -> dict[str, Any]:
    """One 100 s mission of one policy at one target drop share (a sweep cell)."""
    run, _, _ = _simulate(params, seed)
    return {"param": run.param, "drop_share": run.drop_share, "utility_pct": run.utility_pct,
            "violations": run.violations, "decisions": run.decisions,
            "mean_decide_ms": round(run.mean_decide_ms, 3),
            "p95_decide_ms": round(run.p95_decide_ms, 3)}


def message_cell(params: dict[str, Any], seed: int) -> dict[str, Any]:
    """The same mission as :func:`mission_cell`, returning what each delivered message added."""
    run, result, spec = _simulate(params, seed)
    utilities = dr.message_utilities(spec, result, float(params["t_end"]))
    return {"utility_pct": run.utility_pct,
            "messages": {f"{k[0]}/{k[1]}": u for k, u in utilities.items()}}


def characteristics(per_cell: Sequence[dict[str, float]]) -> np.ndarray:
    """Expected utility of each message (mean over the runs that delivered it), normalised to
    the highest (thesis ch. 5.4)."""
    values: dict[str, list[float]] = defaultdict(list)
    for messages in per_cell:
        for key, u in messages.items():
            values[key].append(u)
    means = np.array([np.mean(v) for v in values.values()])
    top = float(means.max()) if len(means) and means.max() > 0 else 1.0
    return means / top


def fifths(normalised: np.ndarray) -> list[float]:
    """Share of messages per fifth of the normalised utility range."""
    counts, _ = np.histogram(normalised, bins=5, range=(0.0, 1.0))
    return [float(c) / max(1, len(normalised)) for c in counts]


def summarise(rows: Sequence[dict[str, str]]) -> list[dict[str, Any]]:
    """Mean and 95 % interval of utility and achieved drop per (scenario, policy, drop)."""
    groups: dict[tuple[str, str, float], list[dict[str, str]]] = defaultdict(list)
    for r in rows:
        groups[(r["scenario"], r["policy"], float(r["drop"]))].append(r)
    out = []
    for (scenario, policy, drop), rs in sorted(groups.items()):
        u, u_lo, u_hi = mean_interval([float(r["utility_pct"]) for r in rs])
        d, d_lo, d_hi = mean_interval([float(r["drop_share"]) for r in rs])
        out.append({"scenario": scenario, "policy": policy, "target_drop": drop, "runs": len(rs),
                    "utility_mean": u, "utility_lo": u_lo, "utility_hi": u_hi,
                    "drop_mean": d, "drop_lo": d_lo, "drop_hi": d_hi,
                    "violations_max": max(int(r["violations"]) for r in rs)})
    return out


def _reference(policy: str, drop: float) -> float | None:
    ref = {"mcts1500": dr.REFERENCE_MCTS, "mcts300": dr.REFERENCE_MCTS,
           "random": dr.REFERENCE_RANDOM}.get(policy)
    if ref is None or not dr.REFERENCE_DROP[0] <= drop <= dr.REFERENCE_DROP[-1]:
        return None
    return float(np.interp(drop, dr.REFERENCE_DROP, ref))


def table(summary: Sequence[dict[str, Any]], hist: dict[str, list[float]],
          scenarios: Sequence[str], policies: Sequence[str]) -> str:
    lines = ["fig. 5.7: % of utility, mean [95 % interval] over runs at each target drop share "
             "(achieved drop share in parentheses)",
             "thesis: no numbers stated (figure only; 30 runs per algorithm, 10 agents, 100 s, "
             "MCTS 1500 iterations); 'reference rerun' = the thesis' reference code re-run, "
             "mostly-low only"]
    by = {(s["scenario"], s["policy"], s["target_drop"]): s for s in summary}
    for scenario in scenarios:
        share = " / ".join(f"{100 * f:.0f}" for f in hist.get(scenario, []))
        lines.append("")
        lines.append(f"== {scenario}: histogram % per fifth (low..high) {share or 'n/a'}; "
                     f"thesis: {THESIS_HISTOGRAM[scenario]}; claim: {THESIS_CLAIM[scenario]}")
        head = f"{'drop':>5}" + "".join(f" | {p:^27}" for p in policies)
        head += "".join(f" | {'ref rerun ' + p:>18}" for p in policies if _has_ref(p))
        lines.append(head)
        for target in TABLE_DROPS:
            cells_ = [by.get((scenario, p, round(target, 4))) for p in policies]
            if all(c is None for c in cells_):
                continue
            row = f"{target:5.2f}"
            for c in cells_:
                row += " | " + (f"{c['utility_mean']:5.1f} [{c['utility_lo']:5.1f},"
                                f"{c['utility_hi']:5.1f}] ({c['drop_mean']:.2f})"
                                if c else f"{'-':^27}")
            for p, c in zip(policies, cells_, strict=True):
                if not _has_ref(p):
                    continue
                ref = _reference(p, c["drop_mean"]) if c and scenario == "mostly-low" else None
                row += f" | {ref:18.1f}" if ref is not None else f" | {'-':>18}"
            lines.append(row)
    return "\n".join(lines)


def _has_ref(policy: str) -> bool:
    return policy in ("mcts1500", "random")


def _write_csv(path: Path, rows: Sequence[dict[str, Any]]) -> None:
    with path.open("w", newline="", encoding="utf-8") as f:
        if rows:
            writer = csv.DictWriter(f, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="uav-sitl study fig5.7",
        description="Thesis figure 5.7 at 31 drop shares x --runs runs per policy on Dask.",
    )
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    parser.add_argument("--runs", type=int, default=30, help="runs per drop share (default 30)")
    parser.add_argument("--policy", action="append", choices=POLICIES,
                        help=f"repeatable; default {' and '.join(DEFAULT_POLICIES)}")
    parser.add_argument("--scenario", action="append", choices=sorted(dr.SCENARIOS),
                        help="only these scenarios (repeatable; default all three)")
    add_cluster_options(parser)
    parser.add_argument("--quick", action="store_true",
                        help="10 s missions, 2 drop shares, 2 runs, MCTS 300 iterations")
    args = parser.parse_args(argv)
    if args.runs < 1 or args.workers < 1:
        parser.error("--runs and --workers must be at least 1")
    scenarios = args.scenario or list(dr.SCENARIOS)
    if args.quick:
        policies = args.policy or ["mcts300", "random"]
        drops: Sequence[float] = (0.2, 0.8)
        runs, t_end = min(args.runs, 2), 10.0
    else:
        policies = args.policy or list(DEFAULT_POLICIES)
        drops, runs, t_end = DROPS, args.runs, 100.0
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    todo = cells(scenarios, policies, runs, t_end=t_end, drops=drops)
    try:
        with dask_client(args.scheduler, workers=args.workers) as client:
            sweep = run_sweep(mission_cell, todo, out=out / "fig5_7.csv", client=client,
                              label="fig5.7")
            char_cells = cells(scenarios, ["random"], 1, t_end=t_end, drops=drops)
            per_scenario: dict[str, list[dict[str, float]]] = defaultdict(list)
            check: dict[str, float] = {}
            for params, _, result in map_cells(client, message_cell, char_cells,
                                               label="histograms"):
                if isinstance(result, BaseException):
                    raise result
                per_scenario[params["scenario"]].append(result["messages"])
                check[f"{params['scenario']}/{params['drop']}"] = result["utility_pct"]
    except OSError as exc:  # no scheduler there, or the output cannot be written
        print(f"uav-sitl study fig5.7: {error_text(exc)}", file=sys.stderr)
        return 1
    except ValueError as exc:  # --out holds a CSV of another sweep
        print(f"uav-sitl study fig5.7: {error_text(exc)}", file=sys.stderr)
        return 1
    rows = [r for r in sweep.rows if r["scenario"] in scenarios and r["policy"] in policies]
    _same_draws(rows, check)
    summary = summarise(rows)
    _write_csv(out / "fig5_7_summary.csv", summary)
    hist = {s: characteristics(per_scenario[s]) for s in scenarios}
    _write_csv(out / "fig5_7_characteristics.csv",
               [{"scenario": s, "normalised_utility": float(v)} for s in scenarios
                for v in hist[s]])
    shares = {s: fifths(hist[s]) for s in scenarios}
    _plot(out / "fig5_7.png", summary, hist, scenarios, policies)
    print(table(summary, shares, scenarios, policies))
    print(f"\n{len(todo)} cells ({sweep.ran} run now, {sweep.skipped} from an earlier run, "
          f"{len(sweep.failed)} failed) in {time.perf_counter() - started:.0f} s; "
          f"wrote {out}/fig5_7.csv, fig5_7_summary.csv, fig5_7_characteristics.csv, fig5_7.png")
    return 1 if sweep.failed else 0


def _same_draws(rows: Sequence[dict[str, str]], check: dict[str, float]) -> None:
    """The histogram cells must be the curves' random-drop cells of run 0, draw for draw."""
    for r in rows:
        key = f"{r['scenario']}/{float(r['drop'])}"
        same = math.isclose(float(r["utility_pct"]), check.get(key, math.nan), rel_tol=1e-9)
        if r["policy"] == "random" and int(r["run"]) == 0 and key in check and not same:
            raise RuntimeError(f"histogram cell {key} differs from its curve cell: "
                                   f"{check[key]} vs {r['utility_pct']}")


def _plot(path: Path, summary: Sequence[dict[str, Any]], hist: dict[str, np.ndarray],
          scenarios: Sequence[str], policies: Sequence[str]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    styles = {"mcts300": ("tab:orange", "x"), "mcts1500": ("tab:red", "x"),
              "random": ("tab:blue", "+"), "knapsack": ("tab:green", "^")}
    fig, axes = plt.subplots(2, len(scenarios), figsize=(5 * len(scenarios), 8), squeeze=False)
    for col, scenario in enumerate(scenarios):
        ax = axes[0][col]
        for policy in policies:
            pts = sorted((s["drop_mean"], s["utility_mean"], s["utility_lo"], s["utility_hi"])
                         for s in summary if s["scenario"] == scenario and s["policy"] == policy)
            if not pts:
                continue
            x, y, lo, hi = (np.array(v) for v in zip(*pts, strict=True))
            color, marker = styles[policy]
            ax.plot(x, y, marker=marker, color=color, label=f"{policy} (mean)", linewidth=0.8)
            if np.isfinite(lo).all():
                ax.fill_between(x, lo, hi, color=color, alpha=0.2, linewidth=0,
                                label=f"{policy} 95 % interval")
        dr.finish_panels(ax, axes[1][col], scenario, hist.get(scenario, np.array([])))
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
