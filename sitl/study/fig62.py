"""Thesis figure 6.2 as curves: mean ‖W‖_Δ against publishing rate, per background traffic S.

``uav-sitl study fig6.2 --out DIR [--runs 5] [--quick] [--scheduler ADDR]`` runs the link
model of :mod:`sitl.study.adaptive` (1 Mbit/s FIFO bottleneck, 20 ms propagation, Poisson
application and background packets) open-loop at 21 publishing rates x 3 background levels
(S = 0, 0.25, 0.5 Mbit/s) x ``--runs`` seeded 60 s runs on the Dask sweep runner. Each curve is
the mean over runs with a 95 % t-interval; r* is where the mean curve crosses α = 0.5 Mbit/s
(linear interpolation), printed next to the thesis' stated values (about 0.9, 0.65 and 0.42
Mbit/s). Writes ``fig6_2.csv`` (cells, streamed, resumable), ``fig6_2_summary.csv`` and
``fig6_2.png``.
"""

from __future__ import annotations

import argparse
import time
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sitl.study.sweep import add_cluster_options, mean_interval, sweep_figure, write_rows

__all__ = ["THESIS_R_STAR_MBIT", "crossing", "main", "point_cell"]

MBIT = 125_000.0
"""1 Mbit/s in bytes/s (the link's capacity)."""
ALPHA_MBIT = 0.5
BACKGROUNDS_MBIT = (0.0, 0.25, 0.5)
THESIS_R_STAR_MBIT = {0.0: 0.9, 0.25: 0.65, 0.5: 0.42}
"""Thesis ch. 6.2: 'around ξ = 0.9, 0.65 and 0.42 Mbps' for S = 0, 0.25, 0.5 Mbps, α = 0.5."""
RATES_MBIT = tuple(round(0.05 * k, 4) for k in range(1, 22))
"""0.05 ... 1.05 Mbit/s."""


def point_cell(params: dict[str, Any], seed: int) -> dict[str, Any]:
    """One open-loop run at a fixed publishing rate: its mean ‖W‖_Δ (a sweep cell)."""
    from sitl.study.adaptive import mean_backlog_at_rate

    backlog = mean_backlog_at_rate(
        float(params["rate_mbit"]) * MBIT,
        background_bytes_per_s=float(params["background_mbit"]) * MBIT,
        duration_s=float(params["duration_s"]), seed=seed,
    )
    return {"mean_backlog_mbit": backlog / MBIT}


def crossing(rates: Sequence[float], backlog: Sequence[float], alpha: float) -> float | None:
    """The first rate at which ``backlog`` reaches ``alpha`` (linear between grid points)."""
    for k in range(1, len(rates)):
        b0, b1 = backlog[k - 1], backlog[k]
        if b0 < alpha <= b1:
            return rates[k - 1] + (alpha - b0) * (rates[k] - rates[k - 1]) / (b1 - b0)
    return None


def _summary(rows: Sequence[dict[str, str]]) -> list[dict[str, Any]]:

    groups: dict[tuple[float, float], list[float]] = defaultdict(list)
    for r in rows:
        groups[(float(r["background_mbit"]), float(r["rate_mbit"]))].append(
            float(r["mean_backlog_mbit"]))
    out = []
    for (s, rate), values in sorted(groups.items()):
        mean, lo, hi = mean_interval(values)
        out.append({"background_mbit": s, "rate_mbit": rate, "runs": len(values),
                    "backlog_mean_mbit": mean, "backlog_lo_mbit": lo, "backlog_hi_mbit": hi})
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="uav-sitl study fig6.2",
        description="Thesis figure 6.2: mean ‖W‖_Δ vs publishing rate per background S, on Dask.",
    )
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    parser.add_argument("--runs", type=int, default=5, help="seeded runs per point (default 5)")
    add_cluster_options(parser)
    parser.add_argument("--quick", action="store_true",
                        help="10 s runs, 2 runs at every other rate")
    args = parser.parse_args(argv)
    if args.runs < 1 or args.workers < 1:
        parser.error("--runs and --workers must be at least 1")
    runs, duration = (min(args.runs, 2), 10.0) if args.quick else (args.runs, 60.0)
    rates = RATES_MBIT[1::2] if args.quick else RATES_MBIT
    cells = [{"background_mbit": s, "rate_mbit": r, "run": k, "duration_s": duration}
             for s in BACKGROUNDS_MBIT for k in range(runs) for r in rates]
    out: Path = args.out
    started = time.perf_counter()
    sweep = sweep_figure(point_cell, cells, args=args, name="fig6_2", label="fig6.2")
    if sweep is None:
        return 1
    rows = [r for r in sweep.rows if float(r["duration_s"]) == duration]
    summary = _summary(rows)
    write_rows(out / "fig6_2_summary.csv", summary)
    lines = [f"fig. 6.2: r* = publishing rate where mean ‖W‖_Δ reaches α = {ALPHA_MBIT} Mbit/s "
             f"(link 1 Mbit/s; {runs} runs of {duration:g} s per point, 95 % interval)",
             f"{'S Mbit/s':>9} | {'r* measured':>11} | {'r* thesis':>9} | "
             f"{'‖W‖_Δ at 0.5 Mbit/s':>28}"]
    curves: dict[float, list[dict[str, Any]]] = defaultdict(list)
    for s in summary:
        curves[s["background_mbit"]].append(s)
    for s_mbit, pts in sorted(curves.items()):
        r_star = crossing([p["rate_mbit"] for p in pts], [p["backlog_mean_mbit"] for p in pts],
                          ALPHA_MBIT)
        half = next((p for p in pts if abs(p["rate_mbit"] - 0.5) < 1e-9), None)
        at = (f"{half['backlog_mean_mbit']:.3f} [{half['backlog_lo_mbit']:.3f},"
              f"{half['backlog_hi_mbit']:.3f}]" if half else "-")
        measured = f"{r_star:.2f}" if r_star is not None else "> grid"
        lines.append(f"{s_mbit:9.2f} | {measured:>11} | "
                     f"{THESIS_R_STAR_MBIT.get(s_mbit, float('nan')):9.2f} | {at:>28}")
    _plot(out / "fig6_2.png", curves)
    print("\n".join(lines))
    print(f"\n{len(cells)} cells ({sweep.ran} run now, {sweep.skipped} from an earlier run, "
          f"{len(sweep.failed)} failed) in {time.perf_counter() - started:.0f} s; "
          f"wrote {out}/fig6_2.csv, fig6_2_summary.csv, fig6_2.png")
    return 1 if sweep.failed else 0


def _plot(path: Path, curves: dict[float, list[dict[str, Any]]]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4.5))
    for s_mbit, pts in sorted(curves.items()):
        x = np.array([p["rate_mbit"] for p in pts])
        y = np.array([p["backlog_mean_mbit"] for p in pts])
        lo = np.array([p["backlog_lo_mbit"] for p in pts])
        hi = np.array([p["backlog_hi_mbit"] for p in pts])
        (line,) = ax.plot(x, y, marker=".", label=f"S = {s_mbit:g} Mbit/s")
        if np.isfinite(lo).all():
            ax.fill_between(x, lo, hi, color=line.get_color(), alpha=0.2, linewidth=0)
        if s_mbit in THESIS_R_STAR_MBIT:
            ax.axvline(THESIS_R_STAR_MBIT[s_mbit], color=line.get_color(), linestyle=":",
                       linewidth=0.8)
    ax.axhline(ALPHA_MBIT, color="black", linestyle="--", linewidth=0.8, label="α = 0.5 Mbit/s")
    ax.set_xlabel("publishing rate (Mbit/s)")
    ax.set_ylabel("mean ‖W‖_Δ (Mbit/s)")
    ax.set_title("fig. 6.2 (dotted: thesis r*)")
    ax.set_ylim(0, 2.0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
