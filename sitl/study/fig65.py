"""Thesis figure 6.5 with numbers: how smooth and how fast ξ is, adaptive vs AIMD.

``uav-sitl study fig6.5 --out DIR [--runs 5] [--quick] [--scheduler ADDR]`` runs the figure
6.5 scenario of :mod:`sitl.study.adaptive` (on/off demand every 25 s, background 0.1 -> 0.25
Mbit/s at 50 s, α = 0.1 Mbit/s) for the thesis' SGD (``adaptive``, the default), the same
with use-weighted steps only (``adaptive-weighted``), with use-weighted steps and the knee
memory (``adaptive-smooth``) and AIMD, ``--runs`` seeds each (the same seed gives every
constraint the same demand draws), on the Dask sweep runner.
Per run: the CV of ξ in the two steady halves ([10, 50) and [60, 100) s), the p95 queueing
delay (latency minus the run's minimum) of application packets, loss, and the step response:
seconds after the 50 s step until ξ is half-way from its level before (mean over [40, 50))
to its level after (mean over [60, 100)). Targets (issue 16): CV <= AIMD's, p95 queueing
<= 100 ms, step response <= 5 s. Writes ``fig6_5.csv`` (cells, each with its ξ series as
JSON), ``fig6_5_summary.csv``, ``fig6_5.png`` (ξ and goodput of seed 0 per constraint).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sitl.study.sweep import add_cluster_options, mean_interval, sweep_figure, write_rows

__all__ = ["main", "run_cell", "step_response_s"]

TARGET_P95_MS, TARGET_STEP_S = 100.0, 5.0


def step_response_s(t: np.ndarray, xi: np.ndarray, *, t_step: float,
                    before: tuple[float, float], after: tuple[float, float]) -> float:
    """Seconds from ``t_step`` until ξ is half-way to its new level (0 if already there)."""
    old = float(xi[(t >= before[0]) & (t < before[1])].mean())
    new = float(xi[(t >= after[0]) & (t < after[1])].mean())
    half = (old + new) / 2
    for ti, x in zip(t, xi, strict=True):
        if ti >= t_step and (x - half) * (old - new) <= 0:
            return float(ti - t_step)
    return float("inf")


def run_cell(params: dict[str, Any], seed: int) -> dict[str, Any]:
    """One figure 6.5 run of one constraint: smoothness, delay and step-response numbers."""
    from sitl.study.adaptive.figures import figure_6_5_constraint, figure_6_5_run

    duration = float(params["duration_s"])
    k = duration / 100.0
    trace = figure_6_5_run(figure_6_5_constraint(str(params["constraint"])),
                           seed=int(params["run"]), duration_s=duration)
    del seed  # the run number is the seed: every constraint sees the same demand draws
    t, xi = np.asarray(trace.t), np.asarray(trace.xi_bytes_per_s)

    def cv(a: float, b: float) -> float:
        x = xi[(t >= a * k) & (t < b * k)]
        return float(x.std() / x.mean())

    lat = np.array([r - s for s, r, _ in trace.sent if r is not None])
    return {
        "cv_first_half": cv(10, 50), "cv_second_half": cv(60, 100),
        "xi_before_mbit": float(xi[(t >= 40 * k) & (t < 50 * k)].mean()) * 8 / 1e6,
        "xi_after_mbit": float(xi[(t >= 60 * k) & (t < 100 * k)].mean()) * 8 / 1e6,
        "p95_queueing_ms": 1e3 * float(np.percentile(lat - lat.min(), 95)),
        "loss": sum(r is None for _, r, _ in trace.sent) / max(1, len(trace.sent)),
        "step_response_s": step_response_s(t, xi, t_step=50 * k, before=(40 * k, 50 * k),
                                           after=(60 * k, 100 * k)),
        "series": json.dumps({"t": [round(v, 3) for v in t.tolist()],
                              "xi": [round(v, 1) for v in xi.tolist()]}),
    }


def _summary(rows: Sequence[dict[str, str]]) -> list[dict[str, Any]]:
    from sitl.study.adaptive.figures import FIG65_CONSTRAINTS

    out = []
    for name in FIG65_CONSTRAINTS:
        rs = [r for r in rows if r["constraint"] == name]
        if not rs:
            continue
        row: dict[str, Any] = {"constraint": name, "runs": len(rs)}
        for col in ("cv_first_half", "cv_second_half", "p95_queueing_ms", "loss",
                    "step_response_s", "xi_before_mbit", "xi_after_mbit"):
            mean, lo, hi = mean_interval([float(r[col]) for r in rs])
            row.update({f"{col}_mean": mean, f"{col}_lo": lo, f"{col}_hi": hi})
        out.append(row)
    return out


def main(argv: list[str] | None = None) -> int:
    from sitl.study.adaptive.figures import FIG65_CONSTRAINTS

    parser = argparse.ArgumentParser(
        prog="uav-sitl study fig6.5",
        description="Thesis figure 6.5 with numbers: CV of ξ, p95 queueing delay and step "
                    "response of the adaptive constraint (thesis' SGD, use-weighted, smooth) "
                    "and AIMD, on Dask.")
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    parser.add_argument("--runs", type=int, default=5, help="seeds per constraint (default 5)")
    add_cluster_options(parser)
    parser.add_argument("--quick", action="store_true", help="1 seed, a 40 s compressed run")
    args = parser.parse_args(argv)
    if args.runs < 1 or args.workers < 1:
        parser.error("--runs and --workers must be at least 1")
    runs, duration = (1, 40.0) if args.quick else (args.runs, 100.0)
    cells = [{"constraint": c, "run": k, "duration_s": duration}
             for k in range(runs) for c in FIG65_CONSTRAINTS]
    out: Path = args.out
    started = time.perf_counter()
    sweep = sweep_figure(run_cell, cells, args=args, name="fig6_5", label="fig6.5")
    if sweep is None:
        return 1
    summary = _summary(sweep.rows)
    if not summary:
        print("uav-sitl study fig6.5: no cell finished", file=sys.stderr)
        return 1
    write_rows(out / "fig6_5_summary.csv", summary)
    by = {s["constraint"]: s for s in summary}
    aimd_cv = max(by["aimd"]["cv_first_half_mean"], by["aimd"]["cv_second_half_mean"]) \
        if "aimd" in by else float("nan")
    lines = [f"fig. 6.5 (model, {duration:g} s, {runs} seed(s), mean [95 % interval]); "
             f"targets: CV <= AIMD's, p95 queueing <= {TARGET_P95_MS:g} ms, step response "
             f"<= {TARGET_STEP_S:g} s; thesis: no numbers stated",
             f"{'constraint':>18} | {'CV [10,50)':>10} | {'CV [60,100)':>11} | "
             f"{'p95 queue ms':>12} | {'step s':>6} | {'ξ before->after Mbit/s':>22} | targets"]
    for s in summary:
        cv = max(s["cv_first_half_mean"], s["cv_second_half_mean"])
        met = (cv <= aimd_cv + 1e-12 and s["p95_queueing_ms_mean"] <= TARGET_P95_MS
               and s["step_response_s_mean"] <= TARGET_STEP_S)
        lines.append(
            f"{s['constraint']:>18} | {s['cv_first_half_mean']:10.3f} | "
            f"{s['cv_second_half_mean']:11.3f} | {s['p95_queueing_ms_mean']:12.1f} | "
            f"{s['step_response_s_mean']:6.1f} | {s['xi_before_mbit_mean']:9.3f} -> "
            f"{s['xi_after_mbit_mean']:9.3f} | {'met' if met else 'MISSED'}")
    _plot(out / "fig6_5.png", [r for r in sweep.rows if int(r["run"]) == 0], duration)
    print("\n".join(lines))
    print(f"\n{len(cells)} cells ({sweep.ran} run now, {sweep.skipped} from an earlier run, "
          f"{len(sweep.failed)} failed) in {time.perf_counter() - started:.0f} s; "
          f"wrote {out}/fig6_5.csv, fig6_5_summary.csv, fig6_5.png")
    return 1 if sweep.failed else 0


def _plot(path: Path, rows: Sequence[dict[str, str]], duration: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(rows), 1, figsize=(9, 2.4 * len(rows)), sharex=True,
                             squeeze=False)
    for ax, row in zip(axes[:, 0], sorted(rows, key=lambda r: r["constraint"]), strict=True):
        series = json.loads(row["series"])
        ax.plot(series["t"], np.asarray(series["xi"]) * 8 / 1e6, lw=1.4, label="constraint ξ")
        ax.axvline(duration / 2, color="grey", lw=0.8, label="background 0.1 -> 0.25 Mbit/s")
        ax.set_ylabel("Mbit/s")
        ax.set_title(f"{row['constraint']}: CV {float(row['cv_first_half']):.3f} / "
                     f"{float(row['cv_second_half']):.3f}, step response "
                     f"{float(row['step_response_s']):.1f} s", loc="left", fontsize=9)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper right")
    axes[-1, 0].set_xlabel("time (s)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
