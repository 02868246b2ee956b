"""Thesis figures 4.11-4.13: a battery report over a direct radio link or over the Internet.

``uav-sitl study fig4.13 --out DIR [--agents 4] [--runs 50] [--quick]`` (also as ``fig4.11``
and ``fig4.12``) evaluates the model application of thesis ch. 4.5: each of ``--agents``
UAVs publishes its battery level once per second for 100 s and every other agent receives
it; the battery utility is eq. 4.9/4.10 with the pessimistic depletion rate of 1 % of
capacity per second while the real level falls linearly from 100 % to 88 %. Two links:

* **direct radio**: a constant 10 ms delay, each copy lost with probability p (best effort);
* **Internet**: reliable (nothing lost) with a delay d (constant, or uniform in
  d ± ``--jitter``·d).

Figure 4.11 is the total utility against d (no loss), 4.12 against p (10 ms), 4.13 the map
U(direct, p) − U(Internet, d) that tells a UAV which link to use. The thesis measured these
on ROS 2 / DDS in Containernet (its curves also carry the DDS implementations' overheads
and discovery times); this is the model alone, each copy's fate drawn independently. Its
break-even has a closed form: a loss rate p delays a stream's first report by p / (1 − p)
periods on average and adds as much to the mean age of the newest report, (1 + p) / (2 (1 − p))
s against 0.5 s; a delay d does both by d. So the Internet is worth more while
d < 10 ms + p / (1 − p) (:func:`break_even_delay_s`). Writes
``fig4_11_13.csv`` (one row per evaluated mission), ``fig4_11.png``, ``fig4_12.png`` and
``fig4_13.png``.
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sitl.study.sweep import mean_interval
from utility_specs.evaluate import evaluate
from utility_specs.message import Message
from utility_specs.spec import MissionSpec, parse_spec

__all__ = ["DIRECT_DELAY_S", "break_even_delay_s", "main", "mission_utility"]

T_END_S = 100.0
PERIOD_S = 1.0
DEPLETION_PER_S = 0.01
"""The pessimistic depletion rate ρ of eq. 4.9: 1 % of full capacity per second."""
LEVEL_START, LEVEL_END = 1.0, 0.88
DIRECT_DELAY_S = 0.010

SPEC: MissionSpec = parse_spec({
    "mission": {"name": "model_application", "t_end": T_END_S},
    "types": {"battery": {"utility": "battery", "aggregation": "max", "weight": 1.0,
                          "per_sender": True, "markovian": True,
                          "params": {"depletion_rate": DEPLETION_PER_S}}},
}, source="<thesis ch. 4.5>")


def break_even_delay_s(loss: float) -> float:
    """The Internet delay at which both links are worth the same for a direct loss ``loss``,
    in expectation: each link shifts a stream's first report and the age of its newest one by
    the same amount, d for the Internet, 10 ms + p / (1 − p) for the direct link (eq. 4.9 is
    linear in the age while it is positive)."""
    return DIRECT_DELAY_S + loss / (1.0 - loss)


def mission_utility(*, agents: int, delay_s: float, loss: float, seed: int,
                    jitter: float = 0.0) -> float:
    """Total utility U(M) of one simulated mission (every agent's reports at every other).

    The same ``seed`` draws the same report phases and the same per-copy uniforms whatever
    the link, so two links, or two loss rates, are compared on common random numbers (a copy
    lost at p is lost at every larger p)."""
    phases = np.random.default_rng([seed, 0]).uniform(0.0, PERIOD_S, agents)
    fate = np.random.default_rng([seed, 1])
    messages: list[Message] = []
    for a in range(agents):
        t_gen = np.arange(float(phases[a]), T_END_S, PERIOD_S)
        level = LEVEL_START + (LEVEL_END - LEVEL_START) * t_gen / T_END_S
        for r in range(agents):
            if r == a:
                continue
            lost = fate.random(len(t_gen)) < loss
            spread = fate.uniform(-1.0, 1.0, len(t_gen))
            delay = np.maximum(0.0, delay_s * (1.0 + jitter * spread))
            messages += [
                Message(sender=f"uav{a}", seq=k, type="battery", t_gen=float(t), size=1,
                        receiver=f"uav{r}", t_rcv=float(t + d), data={"level": float(v)})
                for k, (t, v, d, gone) in enumerate(zip(t_gen, level, delay, lost,
                                                         strict=True)) if not gone]
    return float(evaluate(messages, SPEC, t_end=T_END_S).total)


def _sweep(args: argparse.Namespace) -> list[dict[str, Any]]:
    delays = np.round(np.linspace(0.0, 1.0, 11 if args.quick else 21), 3)
    losses = np.round(np.linspace(0.0, 0.3, 7 if args.quick else 16), 3)
    rows: list[dict[str, Any]] = []
    for link, grid in (("internet", delays), ("direct", losses)):
        for x in grid:
            delay, loss = (float(x), 0.0) if link == "internet" else (DIRECT_DELAY_S, float(x))
            for run in range(args.runs):
                u = mission_utility(agents=args.agents, delay_s=delay, loss=loss, seed=run,
                                    jitter=args.jitter if link == "internet" else 0.0)
                rows.append({"link": link, "delay_s": delay, "loss": loss, "run": run,
                             "agents": args.agents, "utility": round(u, 4)})
        print(f"fig4.11-4.13: {link} link, {len(grid)} points x {args.runs} run(s) done",
              flush=True)
    return rows


def _curve(rows: Sequence[dict[str, Any]], link: str, key: str
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    xs = sorted({float(r[key]) for r in rows if r["link"] == link})
    stats = [mean_interval([r["utility"] for r in rows if r["link"] == link and r[key] == x])
             for x in xs]
    # half-widths; one run has no interval (nan), drawn and printed as 0
    return (np.array(xs), np.array([m for m, _, _ in stats]),
            np.nan_to_num(np.array([hi - m for m, _, hi in stats])))


def _plots(out: Path, rows: Sequence[dict[str, Any]], agents: int) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ideal = float(_curve(rows, "internet", "delay_s")[1][0])  # the same runs at d = 0
    for name, link, key, label in (("fig4_11", "internet", "delay_s", "delay (s)"),
                                   ("fig4_12", "direct", "loss", "loss rate")):
        x, mean, half = _curve(rows, link, key)
        fig, ax = plt.subplots(figsize=(6.4, 4.0))
        ax.errorbar(x, mean, yerr=half, fmt="o-", ms=4, capsize=3,
                    label=f"{agents} agents, model (95 % interval)")
        ax.axhline(ideal, color="grey", lw=0.8, ls="--", label="no delay, no loss")
        ax.set_xlabel(label)
        ax.set_ylabel("total utility U(M)")
        which = "Internet: reliable, delayed" if link == "internet" else \
            f"direct radio: {DIRECT_DELAY_S * 1e3:g} ms, lossy"
        ax.set_title(f"thesis fig. {name[3]}.{name[5:]}: battery reports, {which}", fontsize=9)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(out / f"{name}.png", dpi=110)
        plt.close(fig)
    d, u_net, _ = _curve(rows, "internet", "delay_s")
    p, u_dir, _ = _curve(rows, "direct", "loss")
    diff = u_dir[:, None] - u_net[None, :]  # rows: loss, columns: delay
    fig, ax = plt.subplots(figsize=(6.4, 4.6))
    lim = float(np.abs(diff).max()) or 1.0
    mesh = ax.pcolormesh(d, p, diff, cmap="RdBu", vmin=-lim, vmax=lim, shading="nearest")
    fig.colorbar(mesh, ax=ax, label="U(direct) − U(Internet)")
    fine = np.linspace(0.0, float(p.max()), 100)
    ax.plot([break_even_delay_s(float(x)) for x in fine], fine, "k--", lw=1,
            label="break-even (closed form)")
    ax.set_xlim(float(d.min()), float(d.max()))
    ax.set_xlabel("Internet delay (s)")
    ax.set_ylabel("direct link loss rate")
    ax.set_title("thesis fig. 4.13: blue, the direct link is worth more; red, the Internet",
                 fontsize=9)
    ax.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    fig.savefig(out / "fig4_13.png", dpi=110)
    plt.close(fig)


def _table(rows: Sequence[dict[str, Any]], agents: int, runs: int) -> str:
    d, u_net, _ = _curve(rows, "internet", "delay_s")
    p, u_dir, h_dir = _curve(rows, "direct", "loss")
    lines = [f"fig. 4.11-4.13 (the model, {agents} agents, {T_END_S:g} s, {runs} run(s) a "
             f"point; mean ± 95 %)",
             f"{'direct loss':>11} | {'U(direct)':>16} | {'break-even delay (sim)':>22} | "
             f"{'(closed form)':>13}"]
    for x, m, h in zip(p, u_dir, h_dir, strict=True):
        # the delay where the Internet curve (falling with d) meets this direct utility
        crossing = float(np.interp(-m, -u_net, d)) if u_net.min() <= m <= u_net.max() \
            else math.nan
        lines.append(f"{x:11.2f} | {m:9.2f} ± {h:4.2f} | {crossing:20.3f} s | "
                     f"{break_even_delay_s(float(x)):11.3f} s")
    lines.append(f"Internet: U = {u_net[0]:.2f} at 0 s, {u_net[-1]:.2f} at {d[-1]:g} s")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="uav-sitl study fig4.13",
        description="Thesis figures 4.11-4.13 (ch. 4.5): battery reports over a lossy direct "
                    "radio link or a reliable, delayed Internet link, evaluated by the model.")
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    parser.add_argument("--agents", type=int, default=4,
                        help="UAVs, each receiving every other's reports (default 4)")
    parser.add_argument("--runs", type=int, default=50,
                        help="missions per point (default 50, as the thesis ran at least)")
    parser.add_argument("--jitter", type=float, default=0.0,
                        help="Internet delay uniform in d·(1 ± JITTER) (default 0: constant)")
    parser.add_argument("--quick", action="store_true",
                        help="a coarser grid and 5 runs a point (a few seconds)")
    args = parser.parse_args(argv)
    if args.quick:
        args.runs = min(args.runs, 5)
    if not 2 <= args.agents <= 50 or args.runs < 1 or not 0.0 <= args.jitter <= 1.0:
        parser.error("--agents must be in 2..50, --runs >= 1 and --jitter in 0..1")
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    rows = _sweep(args)
    with (out / "fig4_11_13.csv").open("w", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    _plots(out, rows, args.agents)
    print(_table(rows, args.agents, args.runs))
    print(f"\n{len(rows)} missions in {time.perf_counter() - started:.0f} s; wrote "
          f"{out}/fig4_11_13.csv, fig4_11.png, fig4_12.png, fig4_13.png")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
