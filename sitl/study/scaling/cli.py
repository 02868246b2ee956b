"""``uav-sitl study scaling`` command line: the cells, the sweep, the CSV and the plot."""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from sitl.study.scaling.cell import scaling_cell
from sitl.study.scaling.goals import (
    GOAL_BATTERY_MEAN_MS,
    GOAL_IMAGES_P99_MS,
    as_float,
    check_goals,
    table,
)
from sitl.study.scaling.workloads import FLEET_SIZES, OPTIMUM_AGENTS


def plan(agents: Sequence[int], *, quick: bool) -> list[dict[str, Any]]:
    """The cells: images and battery at every size, optimum on short missions, one long one."""
    t_img, t_bat = (4.0, 6.0) if quick else (8.0, 20.0)
    cells: list[dict[str, Any]] = []
    for n in agents:
        cells.append({"kind": "images", "agents": n, "t_end": t_img})
        cells.append({"kind": "battery", "agents": n, "t_end": t_bat})
    for n in OPTIMUM_AGENTS:
        cells.append({"kind": "optimum", "agents": n, "t_end": 4.0 if quick else 10.0})
    # two whole 10 s cycles after the warm-up at the least (first vs last, like phases)
    cells.append({"kind": "long", "agents": min(agents), "t_end": 30.0 if quick else 300.0})
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
    from sitl.study.sweep import add_cluster_options, dask_client, error_text, run_sweep

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
        print(f"uav-sitl study scaling: {error_text(exc)}", file=sys.stderr)
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
        pts = sorted((int(r["agents"]), as_float(r, key)) for r in rows if r["kind"] == kind)
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
