"""Thesis figures 6.3 and 6.4: the α sweep of the adaptive goodput constraint.

``uav-sitl study fig6.3 --out DIR [--runs 3] [--quick] [--scheduler ADDR]`` (``fig6.4`` is the
same command; one run draws both figures). Thesis ch. 6.3: eight agents publish equal
messages at 6 Hz each, 100 s, a 1 Mbit/s link carrying 0.5 Mbit/s of background traffic,
T = 2.5 s; each message is sent when the adaptive constraint admits it. Every × of the
thesis' figures is one run at one α; the solid line is open-loop publishing at fixed rates
(no adaptation) and the dotted one the ideal (everything sent arrives).

Here the link is the packet model of :mod:`sitl.study.adaptive` (FIFO bottleneck, 60 kB
queue, 20 ms propagation, Poisson background), the fleet's 8 x 6 Hz offered load is one
aggregate Poisson stream of 2048-byte messages (0.79 Mbit/s offered, more than the 0.5 Mbit/s
the background leaves) and ‖W‖ counts every delivered message (all agents hear all
broadcasts). Measured after a 10 s warm-up: publishing rate, reception rate, loss and mean
latency per run. Writes ``fig6_3.csv`` (cells, resumable), ``fig6_3_summary.csv``,
``fig6_3.png`` (reception vs publishing rate) and ``fig6_4.png`` (latency vs publishing rate).
The thesis states no numbers for these figures, only that higher α gives a higher publishing
rate, a higher drop rate and a higher latency; the table checks those claims.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sitl.study.sweep import add_cluster_options, mean_interval, sweep_figure, write_rows

__all__ = ["ALPHAS_MBIT", "FIXED_RATES_MBIT", "alpha_cell", "main"]

MBIT = 125_000.0
AGENTS, RATE_HZ, MESSAGE_BYTES = 8, 6.0, 2048
BACKGROUND_MBIT = 0.5
DURATION_S, WARMUP_S = 100.0, 10.0
ALPHAS_MBIT = (0.1, 0.25, 0.5, 1.0, 1.5, 2.0)
"""α (tolerated ‖W‖_Δ) of the sweep; fig. 6.2: α = 0.5 Mbit/s sits near r* with S = 0.5."""
FIXED_RATES_MBIT = tuple(round(0.05 * k, 4) for k in range(1, 17))
"""Open-loop publishing rates of the 'no adaptation' line: 0.05 ... 0.8 Mbit/s."""
THESIS_CLAIMS = ("higher α -> higher publishing rate", "higher α -> higher drop rate",
                 "higher α -> higher latency")


def alpha_cell(params: dict[str, Any], seed: int) -> dict[str, Any]:
    """One 100 s run: adaptive at ``alpha_mbit``, or fixed publishing at ``fixed_mbit``."""
    from companion.middleware.constraints import make_constraint
    from sitl.study.adaptive import ObservedConstant, SimLink, simulate, steps

    duration = float(params["duration_s"])
    offered = AGENTS * RATE_HZ * MESSAGE_BYTES
    if params["mode"] == "adaptive":
        constraint: Any = make_constraint(
            "adaptive-thesis", alpha_bytes_per_s=float(params["alpha_mbit"]) * MBIT,
            learning_rate=0.01, initial_intercept_bytes_per_s=0.3 * MBIT)
        demand = offered
    else:
        demand = float(params["fixed_mbit"]) * MBIT
        constraint = ObservedConstant(limit_bytes_per_s=demand)
    trace = simulate(constraint, duration_s=duration, rng=np.random.default_rng(seed),
                     link=SimLink(message_bytes=MESSAGE_BYTES),
                     demand_bytes_per_s=steps((0.0, demand)),
                     background_bytes_per_s=steps((0.0, BACKGROUND_MBIT * MBIT)))
    span = duration - WARMUP_S
    sent = [(s, r, z) for s, r, z in trace.sent if s >= WARMUP_S]
    got = [(s, r, z) for s, r, z in sent if r is not None]
    return {
        "publishing_mbit": sum(z for *_, z in sent) / span / MBIT,
        "reception_mbit": sum(z for *_, z in got) / span / MBIT,
        "loss": 1 - len(got) / len(sent) if sent else 0.0,
        "latency_ms": 1e3 * float(np.mean([r - s for s, r, _ in got])) if got else float("nan"),
    }


def _summary(rows: Sequence[dict[str, str]]) -> list[dict[str, Any]]:

    groups: dict[tuple[str, float], list[dict[str, str]]] = defaultdict(list)
    for r in rows:
        key = float(r["alpha_mbit"] if r["mode"] == "adaptive" else r["fixed_mbit"])
        groups[(r["mode"], key)].append(r)
    out = []
    for (mode, key), rs in sorted(groups.items()):
        row: dict[str, Any] = {"mode": mode, "alpha_or_rate_mbit": key, "runs": len(rs)}
        for col in ("publishing_mbit", "reception_mbit", "loss", "latency_ms"):
            mean, lo, hi = mean_interval([float(r[col]) for r in rs])
            row.update({f"{col}_mean": mean, f"{col}_lo": lo, f"{col}_hi": hi})
        out.append(row)
    return out


def _claims(adaptive: Sequence[dict[str, Any]]) -> list[str]:
    """Whether each of the thesis' claims holds across the α sweep (Spearman's ρ > 0.5)."""
    alphas = [a["alpha_or_rate_mbit"] for a in adaptive]
    out = []
    for claim, col in zip(THESIS_CLAIMS, ("publishing_mbit_mean", "loss_mean",
                                          "latency_ms_mean"), strict=True):
        if len(alphas) < 2:
            out.append(f"  {claim}: too few α to tell")
            continue
        rho = _spearman(alphas, [a[col] for a in adaptive])
        out.append(f"  {claim}: {'holds' if rho > 0.5 else 'does NOT hold'} "
                   f"(Spearman ρ = {rho:+.2f})")
    return out


def _spearman(x: Sequence[float], y: Sequence[float]) -> float:
    """Spearman's rank correlation (ties broken by order; enough for a monotonicity check)."""
    rx, ry = (np.argsort(np.argsort(np.asarray(v, dtype=float))) for v in (x, y))
    if rx.std() == 0 or ry.std() == 0:
        return 0.0
    return float(np.corrcoef(rx, ry)[0, 1])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="uav-sitl study fig6.3",
        description="Thesis figures 6.3/6.4: the α sweep (8 agents x 6 Hz, 0.5 Mbit/s "
                    "background, 1 Mbit/s link), on Dask.",
    )
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    parser.add_argument("--runs", type=int, default=3, help="seeded runs per point (default 3)")
    add_cluster_options(parser)
    parser.add_argument("--quick", action="store_true",
                        help="20 s runs, 3 values of α, 4 fixed rates, 1 run")
    args = parser.parse_args(argv)
    if args.runs < 1 or args.workers < 1:
        parser.error("--runs and --workers must be at least 1")
    runs = 1 if args.quick else args.runs
    duration = 20.0 if args.quick else DURATION_S
    alphas = ALPHAS_MBIT[1::2] if args.quick else ALPHAS_MBIT
    fixed = FIXED_RATES_MBIT[1::4] if args.quick else FIXED_RATES_MBIT
    cells = ([{"mode": "adaptive", "alpha_mbit": a, "fixed_mbit": 0.0, "run": k,
               "duration_s": duration} for a in alphas for k in range(runs)]
             + [{"mode": "fixed", "alpha_mbit": 0.0, "fixed_mbit": r, "run": k,
                 "duration_s": duration} for r in fixed for k in range(runs)])
    out: Path = args.out
    started = time.perf_counter()
    sweep = sweep_figure(alpha_cell, cells, args=args, name="fig6_3", label="fig6.3")
    if sweep is None:
        return 1
    summary = _summary(sweep.rows)
    if not summary:
        print("uav-sitl study fig6.3: no cell finished", file=sys.stderr)
        return 1
    write_rows(out / "fig6_3_summary.csv", summary)
    adaptive = [s for s in summary if s["mode"] == "adaptive"]
    lines = [f"figs. 6.3/6.4: {AGENTS} agents x {RATE_HZ:g} Hz x {MESSAGE_BYTES} B, "
             f"{BACKGROUND_MBIT} Mbit/s background on 1 Mbit/s, {duration:g} s runs, mean of "
             f"{runs} [95 % interval]; thesis: no numbers stated (figures only)",
             f"{'α Mbit/s':>9} | {'publishing':>10} | {'reception':>9} | {'loss %':>6} | "
             f"{'latency ms':>24}"]
    for a in adaptive:
        lines.append(
            f"{a['alpha_or_rate_mbit']:9.3f} | {a['publishing_mbit_mean']:10.3f} | "
            f"{a['reception_mbit_mean']:9.3f} | {100 * a['loss_mean']:6.2f} | "
            f"{a['latency_ms_mean']:7.1f} [{a['latency_ms_lo']:7.1f},{a['latency_ms_hi']:7.1f}]")
    lines.append("thesis' claims (ch. 6.3) on this sweep:")
    lines += _claims(adaptive)
    _plot(out, summary)
    print("\n".join(lines))
    print(f"\n{len(cells)} cells ({sweep.ran} run now, {sweep.skipped} from an earlier run, "
          f"{len(sweep.failed)} failed) in {time.perf_counter() - started:.0f} s; "
          f"wrote {out}/fig6_3.csv, fig6_3_summary.csv, fig6_3.png, fig6_4.png")
    return 1 if sweep.failed else 0


def _plot(out: Path, summary: Sequence[dict[str, Any]]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    adaptive = [s for s in summary if s["mode"] == "adaptive"]
    fixed = [s for s in summary if s["mode"] == "fixed"]
    for name, col, label in (("fig6_3", "reception_mbit", "reception rate (Mbit/s)"),
                             ("fig6_4", "latency_ms", "mean latency (ms)")):
        fig, ax = plt.subplots(figsize=(6, 4.5))
        if fixed:
            ax.plot([f["publishing_mbit_mean"] for f in fixed], [f[f"{col}_mean"] for f in fixed],
                    "-", color="0.35", label="fixed publishing rate (no adaptation)")
        if col == "reception_mbit" and fixed:
            top = max(f["publishing_mbit_mean"] for f in fixed)
            ax.plot([0, top], [0, top], ":", color="0.6", label="ideal (all received)")
        xs = [a["publishing_mbit_mean"] for a in adaptive]
        ys = [a[f"{col}_mean"] for a in adaptive]
        ax.plot(xs, ys, "x", color="tab:blue", ms=9, mew=2, label="adaptive constraint")
        for a, x, y in zip(adaptive, xs, ys, strict=True):
            ax.annotate(f"α={a['alpha_or_rate_mbit']:g}", (x, y), textcoords="offset points",
                        xytext=(5, -12), fontsize=8)
        ax.set_xlabel("publishing rate (Mbit/s)")
        ax.set_ylabel(label)
        ax.set_title(f"fig. {name[3]}.{name[5]} (model: 1 Mbit/s, 0.5 Mbit/s background)",
                     fontsize=10)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(out / f"{name}.png", dpi=110)
        plt.close(fig)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
