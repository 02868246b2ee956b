"""``uav-utility characteristics``: thesis figure 7.2 from a recorded mission's logs."""

from __future__ import annotations

import argparse
import csv
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

from utility_specs.characteristics import Characteristics, characteristics
from utility_specs.files import builtin_specs, read_log, spec_named
from utility_specs.log import merge_copies

DROPS = "0.1,0.3,0.5,0.7,0.9"
LOW = 0.2
"""Normalised expected utility below which the thesis calls a message's utility "low"."""


def add_parser(sub: Any) -> None:
    ch = sub.add_parser(
        "characteristics",
        help="a recorded mission's characteristics (thesis fig. 7.2): random drops replayed",
        description="Thesis sec. 5.4 / fig. 7.2: replay the generated messages of the logs "
                    "through random drops and plot the expected utility of each message "
                    "(normalised, with its eCDF) and the utility left at each drop share.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="example (after `make demo`, the drones' logs hold every generated message):\n"
               "  uav-utility characteristics --spec image_streaming --type image "
               "--out out/fig72 out/fleet/*/drones/*/mission_log.jsonl")
    ch.add_argument("log", type=Path, nargs="+",
                    help="mission log(s), JSON Lines: the senders' (drones') logs")
    ch.add_argument("--spec", required=True,
                    help=f"mission spec TOML file or built-in name ({', '.join(builtin_specs())})")
    ch.add_argument("--out", type=Path, required=True, help="output folder")
    ch.add_argument("--type", action="append", dest="types", metavar="TYPE",
                    help="only messages of this type (repeatable; default every spec type)")
    ch.add_argument("--drops", default=DROPS,
                    help=f"drop probabilities, comma separated (default {DROPS})")
    ch.add_argument("--runs", type=int, default=5, help="replays per drop (default 5)")
    ch.add_argument("--seed", type=int, default=1, help="random drops' seed (default 1)")
    ch.add_argument("--t-start", type=float, help="mission start (default: first message)")
    ch.add_argument("--t-end", type=float, help="mission end (default: last message)")


def run(args: argparse.Namespace) -> int:
    # every option is checked before a log is read or a line printed: --runs -1 printed
    # "5 drop probabilities x -1 replays" and only then failed
    try:
        drops = [float(d) for d in args.drops.split(",")]
    except ValueError:
        raise ValueError(
            f"--drops: numbers separated by commas expected, got {args.drops!r}") from None
    if not all(0.0 <= d < 1.0 for d in drops):
        raise ValueError(f"--drops: need every drop probability in [0, 1), got {args.drops!r}")
    if args.runs < 1:
        raise ValueError(f"--runs must be >= 1, got {args.runs}")
    for flag, value in (("--t-start", args.t_start), ("--t-end", args.t_end)):
        if value is not None and not math.isfinite(value):
            raise ValueError(f"{flag} must be a finite time, got {value}")
    if args.t_start is not None and args.t_end is not None and not args.t_end > args.t_start:
        raise ValueError(f"need --t-start < --t-end, got {args.t_start} and {args.t_end}")
    spec_arg: str = args.spec
    spec = spec_named(spec_arg)
    unknown = sorted(set(args.types or ()) - set(spec.types))
    if unknown:
        raise ValueError(f"--type {', '.join(unknown)}: not a type of spec {spec.name!r} "
                         f"({', '.join(spec.types)})")
    types = set(args.types or spec.types)
    records = []
    for path in args.log:
        records += read_log(path).messages
    generated = [m for m in merge_copies(records) if m.type in types]
    if not generated:
        raise ValueError(f"no message of type {', '.join(sorted(types))} in the logs")
    t_start = args.t_start if args.t_start is not None else min(m.t_gen for m in generated)
    t_end = args.t_end if args.t_end is not None else max(m.t_gen for m in generated)
    generated = [m for m in generated if t_start <= m.t_gen <= t_end]
    if not t_end > t_start:
        raise ValueError(f"need --t-start < --t-end, got {t_start} and {t_end}")
    print(f"{len(generated)} generated messages ({', '.join(sorted(types))}) over "
          f"{t_end - t_start:.1f} s; {len(drops)} drop probabilities x {args.runs} replays",
          flush=True)
    result = characteristics(generated, spec, t_start=t_start, t_end=t_end, drops=drops,
                             runs=args.runs, seed=args.seed,
                             progress=lambda text: print(text, file=sys.stderr, flush=True))
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    _write(out, result, generated)
    _plot(out / "characteristics.png", result, spec.name, sorted(types))
    values = result.normalised()
    print(f"messages: {len(values)} delivered in some replay; {100 * np.mean(values < LOW):.0f} % "
          f"of them below {LOW:g} of the most useful one (median {np.median(values):.3f})")
    for drop in drops:
        pcts = [r.utility_pct for r in result.runs if r.drop == drop]
        print(f"random drop {drop:.2f}: {np.mean(pcts):5.1f} % of the utility "
              f"(replays {min(pcts):.1f}-{max(pcts):.1f})")
    print(f"wrote {out}/characteristics.csv, drop_runs.csv, characteristics.png")
    return 0


def _write(out: Path, result: Characteristics, generated: list[Any]) -> None:
    types = {m.key: m.type for m in generated}
    top = max(result.expected.values(), default=0.0) or 1.0
    with (out / "characteristics.csv").open("w", newline="", encoding="utf-8") as f:
        writer = csv.writer(f)
        writer.writerow(["sender", "seq", "type", "expected_utility", "normalised"])
        for key, value in sorted(result.expected.items()):
            writer.writerow([key[0], key[1], types[key], f"{value:.6g}",
                             f"{value / top:.6g}"])
    with (out / "drop_runs.csv").open("w", newline="", encoding="utf-8") as f:
        writer = csv.writer(f)
        writer.writerow(["drop", "achieved_drop", "utility_pct"])
        for r in result.runs:
            writer.writerow([r.drop, f"{r.achieved_drop:.4f}", f"{r.utility_pct:.4f}"])


def _plot(path: Path, result: Characteristics, mission: str, types: list[str]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, hx) = plt.subplots(2, 1, figsize=(6.4, 6.4))
    ax.plot([100 * r.achieved_drop for r in result.runs], [r.utility_pct for r in result.runs],
            "o", color="tab:orange", ms=4, label="random drop (replays)")
    ax.plot([0, 100], [100, 0], ":", color="grey", lw=0.8, label="every message alike")
    ax.set_xlabel("dropped messages (%)")
    ax.set_ylabel("utility (% of all delivered)")
    ax.set_title(f"{mission} ({', '.join(types)}): characteristics (thesis fig. 7.2)",
                 fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    values = result.normalised()
    hx.hist(values, bins=np.linspace(0, 1, 21), color="tab:blue", alpha=0.8)
    hx.set_xlabel("expected utility of a message (normalised)")
    hx.set_ylabel("messages")
    cdf = hx.twinx()
    cdf.plot(values, np.arange(1, len(values) + 1) / max(1, len(values)), color="tab:green",
             lw=1.4)
    cdf.set_ylim(0, 1.02)
    cdf.set_ylabel("eCDF", color="tab:green")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
