"""Thesis figure 6.1: reception rate and latency against publishing rate, for send jitter σ.

``uav-sitl study fig6.1 --out DIR [--runs 5] [--quick] [--scheduler ADDR]``: equal 1200-byte
messages, the i-th sent at N(i/r, σ) (thesis ch. 6.1), through the 1 Mbit/s FIFO bottleneck
of :mod:`sitl.study.adaptive` (60 kB queue, 20 ms propagation), 10 s per run, for
σ = 0.001, 0.01, 0.1 s at 21 publishing rates x ``--runs`` seeded runs on the Dask sweep
runner. Writes ``fig6_1.csv`` (cells, resumable), ``fig6_1_summary.csv`` and ``fig6_1.png``
(top: reception rate, bottom: mean latency; mean and 95 % interval) and prints the table.
The thesis states no numbers for this figure, only its shape: with σ = 0.001 latency stays
near its minimum until the link is full; with larger σ it grows well before that.
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

__all__ = ["SIGMAS", "jittered_link", "main", "point_cell"]

MBIT = 125_000.0
SIGMAS = (0.001, 0.01, 0.1)
RATES_MBIT = tuple(round(0.05 * k, 4) for k in range(1, 22))
MESSAGE_BYTES = 1200
DURATION_S = 10.0


def jittered_link(rate_bytes_per_s: float, sigma_s: float, *, duration_s: float,
                  rng: np.random.Generator, capacity_bytes_per_s: float = MBIT,
                  queue_limit_bytes: int = 60_000, propagation_s: float = 0.02,
                  size: int = MESSAGE_BYTES) -> tuple[float, float, int]:
    """(received bytes/s, mean latency s, messages lost) of one run; sans-I/O, time simulated.

    Message i is sent at N(i/r, σ); a FIFO serves ``capacity`` bytes/s and drops a message
    that finds ``queue_limit_bytes`` already waiting (tail drop).
    """
    n = int(rate_bytes_per_s / size * duration_s)
    if n == 0:
        return 0.0, propagation_s, 0
    period = size / rate_bytes_per_s
    sent = np.sort(np.arange(n) * period + rng.normal(0.0, sigma_s, size=n))
    service = size / capacity_bytes_per_s
    busy_until = -np.inf
    departures: list[float] = []  # of messages in the queue or being served, oldest first
    received, lost = 0, 0
    latencies: list[float] = []
    for t in sent:
        while departures and departures[0] <= t:
            departures.pop(0)
        if len(departures) * size >= queue_limit_bytes:
            lost += 1
            continue
        start = max(float(t), busy_until)
        busy_until = start + service
        departures.append(busy_until)
        received += size
        latencies.append(busy_until + propagation_s - float(t))
    span = busy_until - float(sent[0])  # first send to last delivery off the queue
    return received / span, float(np.mean(latencies)) if latencies else 0.0, lost


def point_cell(params: dict[str, Any], seed: int) -> dict[str, Any]:
    """One run at a publishing rate and jitter (a sweep cell)."""
    rate, latency, lost = jittered_link(
        float(params["rate_mbit"]) * MBIT, float(params["sigma_s"]),
        duration_s=float(params["duration_s"]), rng=np.random.default_rng(seed))
    return {"reception_mbit": rate / MBIT, "latency_ms": latency * 1e3, "lost": lost}


def _summary(rows: Sequence[dict[str, str]]) -> list[dict[str, Any]]:

    groups: dict[tuple[float, float], list[dict[str, str]]] = defaultdict(list)
    for r in rows:
        groups[(float(r["sigma_s"]), float(r["rate_mbit"]))].append(r)
    out = []
    for (sigma, rate), rs in sorted(groups.items()):
        rx, rx_lo, rx_hi = mean_interval([float(r["reception_mbit"]) for r in rs])
        lat, lat_lo, lat_hi = mean_interval([float(r["latency_ms"]) for r in rs])
        out.append({"sigma_s": sigma, "rate_mbit": rate, "runs": len(rs),
                    "reception_mean_mbit": rx, "reception_lo_mbit": rx_lo,
                    "reception_hi_mbit": rx_hi, "latency_mean_ms": lat,
                    "latency_lo_ms": lat_lo, "latency_hi_ms": lat_hi})
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="uav-sitl study fig6.1",
        description="Thesis figure 6.1: reception rate and latency vs publishing rate, on Dask.",
    )
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    parser.add_argument("--runs", type=int, default=5, help="seeded runs per point (default 5)")
    add_cluster_options(parser)
    parser.add_argument("--quick", action="store_true", help="2 runs at every other rate")
    args = parser.parse_args(argv)
    if args.runs < 1 or args.workers < 1:
        parser.error("--runs and --workers must be at least 1")
    runs = min(args.runs, 2) if args.quick else args.runs
    rates = RATES_MBIT[1::2] if args.quick else RATES_MBIT
    cells = [{"sigma_s": s, "rate_mbit": r, "run": k, "duration_s": DURATION_S}
             for s in SIGMAS for k in range(runs) for r in rates]
    out: Path = args.out
    started = time.perf_counter()
    sweep = sweep_figure(point_cell, cells, args=args, name="fig6_1", label="fig6.1")
    if sweep is None:
        return 1
    summary = _summary(sweep.rows)
    write_rows(out / "fig6_1_summary.csv", summary)
    by = {(s["sigma_s"], s["rate_mbit"]): s for s in summary}
    lines = ["fig. 6.1: reception rate Mbit/s | mean latency ms [95 % interval] per publishing "
             "rate (link 1 Mbit/s); thesis: no numbers stated (figure only)",
             f"{'rate':>5}" + "".join(f" | {'σ = ' + format(s, 'g'):^34}" for s in SIGMAS)]
    for rate in rates[::2]:
        row = f"{rate:5.2f}"
        for sigma in SIGMAS:
            c = by.get((sigma, rate))
            row += (f" | {c['reception_mean_mbit']:5.3f} | {c['latency_mean_ms']:7.1f} "
                    f"[{c['latency_lo_ms']:7.1f},{c['latency_hi_ms']:7.1f}]" if c else
                    f" | {'-':^34}")
        lines.append(row)
    _plot(out / "fig6_1.png", summary)
    print("\n".join(lines))
    print(f"\n{len(cells)} cells ({sweep.ran} run now, {sweep.skipped} from an earlier run, "
          f"{len(sweep.failed)} failed) in {time.perf_counter() - started:.0f} s; "
          f"wrote {out}/fig6_1.csv, fig6_1_summary.csv, fig6_1.png")
    return 1 if sweep.failed else 0


def _plot(path: Path, summary: Sequence[dict[str, Any]]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (top, bottom) = plt.subplots(2, 1, figsize=(6, 7), sharex=True)
    styles = {0.001: ("tab:blue", "-"), 0.01: ("tab:red", "--"), 0.1: ("tab:green", ":")}
    for sigma, (color, style) in styles.items():
        pts = [s for s in summary if s["sigma_s"] == sigma]
        if not pts:
            continue
        x = np.array([p["rate_mbit"] for p in pts])
        for ax, key in ((top, "reception"), (bottom, "latency")):
            unit = "mbit" if key == "reception" else "ms"
            y = np.array([p[f"{key}_mean_{unit}"] for p in pts])
            lo = np.array([p[f"{key}_lo_{unit}"] for p in pts])
            hi = np.array([p[f"{key}_hi_{unit}"] for p in pts])
            ax.plot(x, y, color=color, linestyle=style, label=f"σ = {sigma:g}")
            if np.isfinite(lo).all():
                ax.fill_between(x, lo, hi, color=color, alpha=0.2, linewidth=0)
    top.set_ylabel("reception rate (Mbit/s)")
    bottom.set_ylabel("mean latency (ms)")
    bottom.set_xlabel("publishing rate (Mbit/s)")
    for ax in (top, bottom):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    top.set_title("fig. 6.1")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
