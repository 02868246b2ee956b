"""``uav-sitl study adaptive-vs-aimd``: figure 6.5 and RFC 8867 5.1 runs, CSVs and plots."""

from __future__ import annotations

import argparse
import csv
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from companion.middleware.constraint import GoodputConstraint
from companion.middleware.constraints import make_constraint
from sitl.study.adaptive.model import ObservedConstant, SimLink, SimTrace, simulate, steps
from sitl.study.adaptive.reallink import (
    REAL_LINK_CONSTRAINTS,
    LinkRun,
    rfc8867_5_1,
    run_link_experiment,
)

MBIT = 125_000.0
"""Bytes per second in one Mbit/s."""


FIG65_CONSTRAINTS = ("adaptive", "adaptive-weighted", "adaptive-smooth", "aimd")
"""adaptive: the thesis' SGD (equal steps, the default); adaptive-weighted: use-weighted steps
only; adaptive-smooth: use-weighted steps and the knee memory; AIMD."""


def figure_6_5_constraint(name: str, *, alpha_bytes_per_s: float = 0.1 * MBIT,
                          learning_rate: float = 0.01) -> GoodputConstraint:
    """One of :data:`FIG65_CONSTRAINTS` as figure 6.5 runs it."""
    if name == "aimd":
        return make_constraint("aimd", alpha_bytes_per_s=alpha_bytes_per_s,
                               initial_bytes_per_s=0.4 * MBIT)
    if name not in FIG65_CONSTRAINTS:
        raise ValueError(f"unknown figure 6.5 constraint {name!r}; expected one of "
                         f"{FIG65_CONSTRAINTS}")
    return make_constraint("adaptive" if name == "adaptive-weighted" else name,
                           alpha_bytes_per_s=alpha_bytes_per_s, learning_rate=learning_rate,
                           initial_intercept_bytes_per_s=0.3 * MBIT,
                           **({"use_weighted": True} if name == "adaptive-weighted" else {}))


def figure_6_5_run(constraint: GoodputConstraint, *, seed: int = 1,
                   duration_s: float = 100.0) -> SimTrace:
    """Figure 6.5 on the model: on/off demand every 25 s, background 0.1 -> 0.25 Mbit/s at
    half time (50 s of the thesis' 100 s)."""
    k = duration_s / 100.0
    on_off = steps(*[(k * (25.0 * i + dt), level) for i in range(4)
                     for dt, level in ((0.0, 1.5 * MBIT), (15.0, 0.08 * MBIT))])
    background = steps((0.0, 0.1 * MBIT), (50.0 * k, 0.25 * MBIT))
    return simulate(constraint, duration_s=duration_s, rng=np.random.default_rng(seed),
                    demand_bytes_per_s=on_off, background_bytes_per_s=background)


def figure_6_5_runs(*, seed: int = 1, alpha_bytes_per_s: float = 0.1 * MBIT,
                    learning_rate: float = 0.01,
                    names: tuple[str, ...] = ("adaptive", "aimd")) -> dict[str, SimTrace]:
    """Figure 6.5 on the model, one run per constraint (same seed: same demand draws)."""
    return {name: figure_6_5_run(figure_6_5_constraint(
                name, alpha_bytes_per_s=alpha_bytes_per_s, learning_rate=learning_rate),
                seed=seed)
            for name in names}


def rfc8867_model_runs(*, seed: int = 1, alpha_bytes_per_s: float = 0.5 * MBIT,
                       time_scale: float = 1.0) -> dict[str, SimTrace]:
    """RFC 8867 5.1 capacity schedule on the model, for adaptive, AIMD and a fixed ξ."""
    k = time_scale
    capacity = steps((0.0, MBIT), (40 * k, 2.5 * MBIT), (60 * k, 0.6 * MBIT), (80 * k, MBIT))
    link = SimLink(capacity_bytes_per_s=capacity)
    constraints: dict[str, GoodputConstraint] = {
        "adaptive": make_constraint("adaptive", alpha_bytes_per_s=alpha_bytes_per_s,
                                    learning_rate=0.02, window_s=1.0,
                                    initial_intercept_bytes_per_s=0.3 * MBIT),
        "aimd": make_constraint("aimd", alpha_bytes_per_s=alpha_bytes_per_s, window_s=1.0,
                                initial_bytes_per_s=0.4 * MBIT),
        "fixed": ObservedConstant(limit_bytes_per_s=0.8 * MBIT, window_s=1.0),
    }
    return {
        name: simulate(c, duration_s=100.0 * k, rng=np.random.default_rng(seed), link=link,
                       demand_bytes_per_s=steps((0.0, 4 * MBIT)))
        for name, c in constraints.items()
    }


def write_trace_csv(trace: SimTrace, path: Path) -> None:
    columns = trace.columns()
    with path.open("w", newline="", encoding="utf-8") as f:
        writer = csv.writer(f)
        writer.writerow(list(columns))
        writer.writerows(zip(*columns.values(), strict=True))


def _binned_goodput(trace: SimTrace, duration_s: float, bin_s: float = 1.0
                    ) -> tuple[np.ndarray, np.ndarray]:
    edges = np.arange(int(duration_s // bin_s) + 1) * bin_s
    rcv = np.array([r for _, r, _ in trace.sent if r is not None], dtype=np.float64)
    size = np.array([s for _, r, s in trace.sent if r is not None], dtype=np.float64)
    total, _ = np.histogram(rcv, bins=edges, weights=size)
    return edges[:-1] + bin_s / 2, total / bin_s


def plot_model_runs(runs: dict[str, SimTrace], path: Path, *, title: str,
                    reference: str = "background") -> None:
    """Figure 6.5 style: per constraint, ξ, application goodput and background (Mbit/s)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(runs), 1, figsize=(9, 2.8 * len(runs)), sharex=True,
                             squeeze=False)
    for ax, (name, trace) in zip(axes[:, 0], runs.items(), strict=True):
        t = np.asarray(trace.t)
        duration = float(t.max()) if len(t) else 0.0
        centers, goodput = _binned_goodput(trace, duration)
        ax.plot(t, np.asarray(trace.xi_bytes_per_s) * 8 / 1e6, label="constraint ξ", lw=1.6)
        ax.plot(centers, goodput * 8 / 1e6, "--", label="application goodput", lw=1.2)
        if reference == "background":
            ax.plot(t, np.asarray(trace.background_bytes_per_s) * 8 / 1e6, ":",
                    label="background", lw=1.4)
        else:
            ax.plot(t, np.asarray(trace.capacity_bytes_per_s) * 8 / 1e6, ":",
                    label="link capacity", lw=1.4)
        ax.set_ylabel("Mbit/s")
        ax.set_title(name, loc="left", fontsize=10)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="upper right")
    axes[-1, 0].set_xlabel("time (s)")
    fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_link_runs(runs: Sequence[LinkRun], path: Path) -> None:
    """Real-link runs: ξ, goodput and what the link has left (top); latency (bottom)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(runs), 2, figsize=(12, 2.8 * len(runs)), squeeze=False)
    for row, run in zip(axes, runs, strict=True):
        duration = run.scenario.duration_s
        grid = np.linspace(0.0, duration, 500)
        left = [run.scenario.left_bytes_per_s(t) * 8 / 1e6 for t in grid]
        edges = np.arange(0.0, duration + 0.5, 0.5)
        total, _ = np.histogram(run.arrivals[:, 2], bins=edges, weights=run.arrivals[:, 3])
        row[0].plot(run.reports[:, 0], run.reports[:, 1] * 8 / 1e6, label="constraint ξ")
        row[0].plot(edges[:-1] + 0.25, total / 0.5 * 8 / 1e6, "--", label="app goodput")
        row[0].plot(grid, left, ":", label="link left (capacity − background)")
        row[0].set_ylabel("Mbit/s")
        row[0].set_title(f"{run.scenario.name}: {run.constraint}", loc="left", fontsize=10)
        row[0].legend(fontsize=7, loc="upper right")
        row[0].grid(alpha=0.3)
        latency = (run.arrivals[:, 2] - run.arrivals[:, 1]) * 1000
        row[1].plot(run.arrivals[:, 1], latency, ".", ms=1.5)
        row[1].set_ylabel("one-way latency (ms)")
        row[1].grid(alpha=0.3)
        for ax in row:
            ax.set_xlabel("time (s)")
            for t in run.scenario.step_times[1:]:
                ax.axvline(t, color="grey", lw=0.8, alpha=0.6)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_link_csv(run: LinkRun, path: Path) -> None:
    with path.open("w", newline="", encoding="utf-8") as f:
        writer = csv.writer(f)
        writer.writerow(["t_s", "xi_bytes_per_s", "goodput_bytes_per_s", "backlog_bytes_per_s",
                         "mean_latency_s", "base_latency_s", "clock_offset_s",
                         "clock_offset_uncertainty_s"])
        writer.writerows(run.reports.tolist())


def main(argv: list[str]) -> int:
    """``uav-sitl study adaptive-vs-aimd --out DIR [--real] [--time-scale K]``."""
    parser = argparse.ArgumentParser(
        prog="uav-sitl study adaptive-vs-aimd",
        description="Thesis figure 6.5 (adaptive constraint vs AIMD) and RFC 8867 test 5.1 "
                    "on a packet-level link model; with --real also on a kernel link.",
    )
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    parser.add_argument("--seed", type=int, default=1,
                        help="seed of the simulated link's noise (default 1)")
    parser.add_argument("--time-scale", type=float, default=1.0,
                        help="compress the RFC 8867 schedule (0.5: 50 s instead of 100 s)")
    parser.add_argument("--real", action="store_true",
                        help="also run the RFC schedule over network namespaces (root)")
    args = parser.parse_args(argv)
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    print("figure 6.5 on the link model (adaptive, AIMD) ...", flush=True)
    fig65 = figure_6_5_runs(seed=args.seed)
    for name, trace in fig65.items():
        write_trace_csv(trace, out / f"fig6_5_{name}.csv")
    plot_model_runs(fig65, out / "fig6_5.png",
                    title="Figure 6.5 (model): constraint, application goodput, background")
    print("RFC 8867 test 5.1 on the link model (adaptive, AIMD, fixed) ...", flush=True)
    rfc = rfc8867_model_runs(seed=args.seed, time_scale=args.time_scale)
    for name, trace in rfc.items():
        write_trace_csv(trace, out / f"rfc8867_model_{name}.csv")
    plot_model_runs(rfc, out / "rfc8867_model.png", reference="capacity",
                    title="RFC 8867 5.1 capacity schedule (model)")
    for name, trace in {**{f"fig6_5 {k}": v for k, v in fig65.items()},
                        **{f"rfc8867 {k}": v for k, v in rfc.items()}}.items():
        xi = np.asarray(trace.xi_bytes_per_s)
        print(f"  {name:18s} mean ξ {xi.mean() * 8 / 1e6:6.3f} Mbit/s, "
              f"CV {xi.std() / xi.mean():.3f}")
    if args.real:
        from sitl.linkemu import missing_requirements

        reason = missing_requirements()
        if reason is not None:
            print(f"--real skipped: {reason}", file=sys.stderr)
            return 1
        scenario = rfc8867_5_1(time_scale=args.time_scale)
        runs = []
        for name, params in REAL_LINK_CONSTRAINTS.items():
            print(f"RFC 8867 5.1 on a real link: {name} ({scenario.duration_s:g} s) ...",
                  flush=True)
            kind = "constant" if name == "fixed" else name
            run = run_link_experiment(scenario, constraint=kind, params=dict(params),
                                      workdir=out / "real", progress=print)
            run.constraint = name
            write_link_csv(run, out / f"rfc8867_real_{name}.csv")
            runs.append(run)
        plot_link_runs(runs, out / "rfc8867_real.png")
    print(f"wrote CSV and PNG to {out}")
    return 0
