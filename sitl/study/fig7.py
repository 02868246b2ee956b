"""Thesis figures 7.3 and 7.4 on the simulated shared channel, image streaming with MCTS.

``uav-sitl study fig7.3 --out DIR [--runs 3] [--quick]``: the demonstrator of ch. 7.2. Eight
robots stream 3 frames/s of 2.5 kB (one version, like the demonstrator's JPEG stream) under
one fleet-wide budget of 24 kB/s (every robot plans the others' frames into the same
window), MCTS with 300 iterations, eq. 7.1 with α = 10; robot 0 sees a red fire extinguisher (30 %
red), robots 1-2 see some red (wheels, 8 % and 5 %), the rest none. The thesis' figure is a
screenshot; its claims: the robot seeing red transmits most often, those seeing some red more
than the others, and the link is still shared (every robot gets frames through). Writes
``fig7_3.csv`` (cells), ``fig7_3_summary.csv`` and ``fig7_3.png`` (delivered frames/s and
bytes per robot) and prints the table with the claims checked.

``uav-sitl study fig7.4 --out DIR [--runs 3] [--quick]``: ch. 7.3. Four drones stream images
with MCTS 300 under the *adaptive* constraint (T = 0.5 s, as on the robots) over a 1 Mbit/s
channel; background traffic (0.88 Mbit/s of 1200-byte packets, iperf-like: sent whatever
happens and not overheard by the drones' planners) switches on at 35 % of the run (thesis:
"around 35 s"). Writes ``fig7_4.csv`` (cells; each carries its 1 s series as JSON),
``fig7_4_series.csv`` (run 0), ``fig7_4.png`` (reception rate of application and background,
and latency averaged over 3 s as in the thesis) and prints before/after numbers. The thesis'
statement: an immediate drop of the application traffic at the step, then latency decreases
over the next ~20 s and stabilises (10 Mbit/s of background on their WiFi; here scaled to the 1
Mbit/s channel).
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sitl.study.sweep import (
    add_cluster_options,
    dask_client,
    error_text,
    mean_interval,
    run_sweep,
)

__all__ = ["RED_SHARES", "fig73_cell", "fig74_cell", "main_73", "main_74"]

RED_SHARES = (0.30, 0.08, 0.05, 0.0, 0.0, 0.0, 0.0, 0.0)
"""Per robot: share of red pixels (robot 0: the extinguisher, 1-2: wheels of others)."""
FRAME_BYTES, FRAMES_HZ = 2_500, 3.0
"""One version per frame, as the demonstrator's JPEG stream (tests/middleware/test_mw_fig73)."""
BUDGET_73_BYTES_PER_S = 24_000.0
"""The fleet's shared ξ (every robot plans the others' frames into the same window)."""
CHANNEL_BYTES_PER_S = 125_000.0
BACKGROUND_74_BYTES_PER_S = 110_000.0
WINDOW_74_S = 0.5
"""T on the robots (ch. 7.3). ξ never goes below one frame per window: a drone that may send
nothing gets no receiver report and so could never learn that the link has recovered."""
MCTS_ITERATIONS = 300


def _fleet(n: int, red: Sequence[float], make_policy: Any) -> list[Any]:
    from sitl.netsim import SimAgent, StreamConfig
    from utility_specs.message import Version

    frame = (Version(name="jpeg", size=FRAME_BYTES, quality=1.0),)
    agents = []
    for i in range(n):
        def data(k: int, g: np.random.Generator, share: float = red[i]) -> dict[str, Any]:
            return {"red": float(min(1.0, max(0.0, share + g.normal(0.0, 0.005))))}

        agents.append(SimAgent(name=f"uav{i}", policy=make_policy(f"uav{i}", i), streams=[
            StreamConfig(type="image", period_s=1 / FRAMES_HZ, size=FRAME_BYTES,
                         phase_s=0.013 * i, jitter_s=0.01, versions=frame, data=data),
        ]))
    return agents


def _middleware(agent: str, index: int, *, seed: int, constraint: Any) -> Any:
    from companion.middleware.middleware import Middleware, MiddlewareConfig
    from utility_specs.files import builtin_spec

    config = MiddlewareConfig(spec=builtin_spec("image_streaming"), agent=agent,
                              max_iterations=MCTS_ITERATIONS, horizon_s=3.0)
    return Middleware(config, rng=np.random.default_rng([seed, index]), constraint=constraint)


def fig73_cell(params: dict[str, Any], seed: int) -> dict[str, Any]:
    """One demonstrator run: delivered frames/s and kB/s per robot."""
    from companion.middleware.constraint import ConstantConstraint
    from sitl.netsim import ChannelConfig, simulate

    duration = float(params["duration_s"])
    agents = _fleet(len(RED_SHARES), RED_SHARES, lambda a, i: _middleware(
        a, i, seed=seed, constraint=ConstantConstraint(
            limit_bytes_per_s=BUDGET_73_BYTES_PER_S, window_s=2.5)))
    result = simulate(agents, channel=ChannelConfig(capacity_bytes_per_s=CHANNEL_BYTES_PER_S),
                      t_end=duration, rng=np.random.default_rng([seed, 3]))
    out: dict[str, Any] = {}
    for i in range(len(RED_SHARES)):
        got = [m for m in result.delivered if m.sender == f"uav{i}"]
        out[f"fps_{i}"] = len(got) / duration
        out[f"kbytes_per_s_{i}"] = sum(m.size for m in got) / duration / 1e3
    return out


def fig74_cell(params: dict[str, Any], seed: int) -> dict[str, Any]:
    """One background-step run: before/after numbers and the 1 s series (JSON)."""
    from companion.middleware.baselines import RandomDrop
    from companion.middleware.constraints import make_constraint
    from sitl.netsim import ChannelConfig, SimAgent, StreamConfig, simulate

    duration, t_on = float(params["duration_s"]), float(params["t_on_s"])
    agents = _fleet(4, (0.2, 0.05, 0.0, 0.0), lambda a, i: _middleware(
        a, i, seed=seed, constraint=make_constraint(
            "adaptive-thesis", window_s=WINDOW_74_S, alpha_bytes_per_s=12_500.0,
            learning_rate=0.05,
            initial_intercept_bytes_per_s=20_000.0,
            min_bytes_per_s=FRAME_BYTES / WINDOW_74_S)))
    period = 1200 / BACKGROUND_74_BYTES_PER_S
    iperf = StreamConfig(type="position", period_s=period, size=1200, phase_s=t_on,
                         jitter_s=period / 2)
    agents.append(SimAgent(name="background", policy=RandomDrop(0.0, rng=np.random.default_rng(0)),
                           overheard=False, streams=[iperf]))
    result = simulate(agents, channel=ChannelConfig(capacity_bytes_per_s=CHANNEL_BYTES_PER_S),
                      t_end=duration, rng=np.random.default_rng([seed, 3]))
    edges = np.arange(0.0, duration + 1e-9, 1.0)
    app = [m for m in result.delivered if m.sender != "background"]
    bg = [m for m in result.delivered if m.sender == "background"]
    app_t = np.array([float(m.t_rcv or 0.0) for m in app])
    app_size = np.array([float(m.size) for m in app])
    app_lat = np.array([float(m.t_rcv or 0.0) - float(m.t_sent or 0.0) for m in app])
    rx_app, _ = np.histogram(app_t, bins=edges, weights=app_size)
    rx_bg, _ = np.histogram(np.array([float(m.t_rcv or 0.0) for m in bg]), bins=edges,
                            weights=np.array([float(m.size) for m in bg]))
    latency = []  # thesis: byte-weighted average latency within a 3 s window
    for t in edges[1:]:
        m = (app_t > t - 3.0) & (app_t <= t)
        latency.append(float(np.average(app_lat[m], weights=app_size[m])) if m.any() else
                       float("nan"))
    lat = np.array(latency)
    before = (edges[1:] > t_on - 10) & (edges[1:] <= t_on)
    after = edges[1:] > duration - 10
    peak = float(np.nanmax(lat[edges[1:] > t_on])) if (edges[1:] > t_on).any() else float("nan")
    settled = np.nanmean(lat[after])
    recovery = next((float(t - t_on) for t, v in zip(edges[1:], lat, strict=True)
                     if t > t_on + 3 and v <= 1.2 * settled), float("nan"))
    return {
        "app_kbytes_per_s_before": float(rx_app[before].mean()) / 1e3,
        "app_kbytes_per_s_after": float(rx_app[after].mean()) / 1e3,
        "latency_ms_before": 1e3 * float(np.nanmean(lat[before])),
        "latency_ms_peak": 1e3 * peak,
        "latency_ms_after": 1e3 * float(settled),
        "latency_settle_s": recovery,
        "series": json.dumps({"t": edges[1:].tolist(), "app": rx_app.tolist(),
                              "bg": rx_bg.tolist(), "latency_s": lat.tolist()}),
    }


def _run(args: argparse.Namespace, fn: Any, cells: list[dict[str, Any]], name: str) -> Any:
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    try:
        with dask_client(args.scheduler, workers=args.workers) as client:
            return run_sweep(fn, cells, out=out / f"{name.replace('.', '_')}.csv",
                             client=client, label=name)
    except (OSError, ValueError) as exc:
        print(f"uav-sitl study {name}: {error_text(exc)}", file=sys.stderr)
        return None


def _parser(name: str, text: str) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=f"uav-sitl study {name}", description=text)
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    parser.add_argument("--runs", type=int, default=3, help="seeded runs (default 3)")
    add_cluster_options(parser)
    parser.add_argument("--quick", action="store_true", help="1 short run")
    return parser


def main_73(argv: list[str] | None = None) -> int:

    parser = _parser("fig7.3", "Thesis fig. 7.3: frames per robot by red content (MCTS 300).")
    args = parser.parse_args(argv)
    if args.runs < 1 or args.workers < 1:
        parser.error("--runs and --workers must be at least 1")
    runs, duration = (1, 8.0) if args.quick else (args.runs, 60.0)
    started = time.perf_counter()
    sweep = _run(args, fig73_cell, [{"run": k, "duration_s": duration} for k in range(runs)],
                 "fig7.3")
    if sweep is None or not sweep.rows:
        return 1
    summary = []
    for i, red in enumerate(RED_SHARES):
        fps = mean_interval([float(r[f"fps_{i}"]) for r in sweep.rows])
        kb = mean_interval([float(r[f"kbytes_per_s_{i}"]) for r in sweep.rows])
        summary.append({"robot": i, "red_share": red, "fps_mean": fps[0], "fps_lo": fps[1],
                        "fps_hi": fps[2], "kbytes_per_s_mean": kb[0]})
    with (args.out / "fig7_3_summary.csv").open("w", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, fieldnames=list(summary[0]))
        writer.writeheader()
        writer.writerows(summary)
    rates = [float(s["fps_mean"]) for s in summary]
    claims = [
        ("the robot seeing red transmits most often", rates[0] >= max(rates)),
        ("robots seeing some red send more than the others", min(rates[1:3]) > max(rates[3:])),
        ("the link is shared: every robot gets frames through", min(rates) > 0),
    ]
    lines = [f"fig. 7.3: {len(RED_SHARES)} robots x {FRAMES_HZ:g} frames/s, budget "
             f"{BUDGET_73_BYTES_PER_S / 1e3:g} kB/s shared, MCTS {MCTS_ITERATIONS}, eq. 7.1 "
             f"α = 10, {duration:g} s x {len(sweep.rows)} runs; thesis: a screenshot, no numbers",
             f"{'robot':>5} | {'red %':>5} | {'frames/s [95 % interval]':>26} | {'kB/s':>6}"]
    for s in summary:
        lines.append(f"{s['robot']:5d} | {100 * s['red_share']:5.1f} | {s['fps_mean']:6.2f} "
                     f"[{s['fps_lo']:6.2f}, {s['fps_hi']:6.2f}]   | "
                     f"{s['kbytes_per_s_mean']:6.1f}")
    lines.append("thesis' claims (ch. 7.2):")
    lines += [f"  {c}: {'holds' if ok else 'does NOT hold'}" for c, ok in claims]
    _plot_73(args.out / "fig7_3.png", summary)
    print("\n".join(lines))
    print(f"\n{sweep.ran} cells run now, {sweep.skipped} resumed, {len(sweep.failed)} failed, "
          f"{time.perf_counter() - started:.0f} s; wrote {args.out}/fig7_3.csv, "
          f"fig7_3_summary.csv, fig7_3.png")
    return 1 if sweep.failed else 0


def main_74(argv: list[str] | None = None) -> int:

    parser = _parser("fig7.4", "Thesis fig. 7.4 with image streaming: a background step "
                               "under the adaptive constraint (MCTS 300).")
    args = parser.parse_args(argv)
    if args.runs < 1 or args.workers < 1:
        parser.error("--runs and --workers must be at least 1")
    runs, duration = (1, 16.0) if args.quick else (args.runs, 100.0)
    t_on = 0.35 * duration
    started = time.perf_counter()
    sweep = _run(args, fig74_cell, [{"run": k, "duration_s": duration, "t_on_s": t_on}
                                    for k in range(runs)], "fig7.4")
    if sweep is None or not sweep.rows:
        return 1
    first = min(sweep.rows, key=lambda r: int(r["run"]))
    series = json.loads(first["series"])
    with (args.out / "fig7_4_series.csv").open("w", newline="", encoding="utf-8") as f:
        writer = csv.writer(f)
        writer.writerow(["t_s", "app_bytes_per_s", "background_bytes_per_s", "latency_3s_s"])
        writer.writerows(zip(*series.values(), strict=True))
    keys = ("app_kbytes_per_s_before", "app_kbytes_per_s_after", "latency_ms_before",
            "latency_ms_peak", "latency_ms_after", "latency_settle_s")
    lines = [f"fig. 7.4 (image streaming): 4 drones, MCTS {MCTS_ITERATIONS}, adaptive "
             f"constraint, 1 Mbit/s channel, {BACKGROUND_74_BYTES_PER_S * 8 / 1e6:g} Mbit/s "
             f"background from {t_on:g} s, {duration:g} s x {len(sweep.rows)} runs",
             "thesis (ch. 7.3, robots, 10 Mbit/s background): immediate drop of application "
             "traffic, latency falls over ~20 s and stabilises; no numbers stated"]
    for k in keys:
        mean, lo, hi = mean_interval([float(r[k]) for r in sweep.rows])
        lines.append(f"  {k:26s} {mean:8.1f} [{lo:8.1f}, {hi:8.1f}]")
    _plot_74(args.out / "fig7_4.png", series, t_on)
    print("\n".join(lines))
    print(f"\n{sweep.ran} cells run now, {sweep.skipped} resumed, {len(sweep.failed)} failed, "
          f"{time.perf_counter() - started:.0f} s; wrote {args.out}/fig7_4.csv, "
          f"fig7_4_series.csv, fig7_4.png")
    return 1 if sweep.failed else 0


def _plot_73(path: Path, summary: Sequence[dict[str, Any]]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.8))
    x = np.arange(len(summary))
    ax.bar(x, [s["fps_mean"] for s in summary], color=[
        (1.0, 0.2, 0.2) if s["red_share"] > 0.1 else (1.0, 0.6, 0.6) if s["red_share"] > 0
        else (0.6, 0.6, 0.6) for s in summary])
    ax.errorbar(x, [s["fps_mean"] for s in summary],
                yerr=[[s["fps_mean"] - s["fps_lo"] for s in summary],
                      [s["fps_hi"] - s["fps_mean"] for s in summary]], fmt="none", color="k")
    ax.set_xticks(x, [f"robot {s['robot']}\n{100 * s['red_share']:g} % red" for s in summary],
                  fontsize=8)
    ax.set_ylabel("delivered frames/s")
    ax.set_title("fig. 7.3 (simulated): frames per robot by red content", fontsize=10)
    ax.grid(alpha=0.3, axis="y")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _plot_74(path: Path, series: dict[str, list[float]], t_on: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (top, bottom) = plt.subplots(2, 1, figsize=(8, 5.5), sharex=True)
    t = np.array(series["t"])
    top.plot(t, np.array(series["app"]) * 8 / 1e6, color="tab:green", label="application")
    top.plot(t, np.array(series["bg"]) * 8 / 1e6, color="tab:purple", label="background")
    top.set_ylabel("reception rate (Mbit/s)")
    bottom.plot(t, np.array(series["latency_s"]) * 1e3, ".", color="tab:blue",
                label="latency (byte-weighted, 3 s window)")
    bottom.set_ylabel("latency (ms)")
    bottom.set_xlabel("time (s)")
    for ax in (top, bottom):
        ax.axvline(t_on, color="grey", lw=0.8)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    top.set_title("fig. 7.4 (simulated image streaming): background step", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
