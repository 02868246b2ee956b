"""``uav-sitl``: one entry point, one subcommand per tool; each lives in its own module."""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import time

# subcommand -> (module, help). Each module exposes ``main(argv: list[str]) -> int``.
COMMANDS: dict[str, tuple[str, str]] = {
    "vehicle": ("sitl.vehicle.cli", "run simulated MAVLink vehicles"),
    "fleet": ("sitl.fleet", "run a whole simulated fleet with companions and a ground station"),
    "camera": ("sitl.camera_cli", "render synthetic camera frames of a scene"),
}
STUDIES: dict[str, tuple[str, str]] = {
    "drop-rate-vs-utility": ("sitl.study.drop_rate", "thesis figure 5.7: utility vs drop share"),
    "fig4.11": ("sitl.study.fig413", "thesis figures 4.11-4.13 (same command as fig4.13)"),
    "fig4.12": ("sitl.study.fig413", "thesis figures 4.11-4.13 (same command as fig4.13)"),
    "fig4.13": ("sitl.study.fig413", "thesis figures 4.11-4.13: battery over radio vs Internet"),
    "fig5.7": ("sitl.study.fig57", "thesis figure 5.7 at 31 drop shares x 30 runs, on Dask"),
    "fig6.1": ("sitl.study.fig61", "thesis figure 6.1: reception rate and latency vs rate"),
    "fig6.2": ("sitl.study.fig62", "thesis figure 6.2: mean backlog vs publishing rate, on Dask"),
    "fig6.3": ("sitl.study.fig63", "thesis figures 6.3/6.4: the α sweep (8 agents, 6 Hz)"),
    "fig6.4": ("sitl.study.fig63", "thesis figures 6.3/6.4 (same command as fig6.3)"),
    "fig6.5": ("sitl.study.fig65", "thesis figure 6.5: ξ smoothness and step response"),
    "fig7.3": ("sitl.study.fig73", "thesis figure 7.3: image frames per robot by red content"),
    "fig7.4": ("sitl.study.fig74", "thesis figure 7.4: image streaming, background step"),
    "adaptive-vs-aimd": ("sitl.study.adaptive", "thesis figure 6.5: adaptive constraint vs AIMD"),
    "mcts-vs-baselines": ("sitl.study.baselines", "MCTS vs every baseline, equal budget and bytes"),
    "peers": ("sitl.study.peers", "peer sharing: freshness and utility at each drone, equal bytes"),
    "scaling": ("sitl.study.scaling", "fleet-size scaling: decide time, reports, memory, utility"),
}


def _written_since(argv: list[str], started: float) -> str:
    """What an interrupted study already wrote to its --out folder (files changed since it
    started), as the tail of its one line; empty if nothing (or no --out)."""
    out = next((a.split("=", 1)[1] for a in argv if a.startswith("--out=")), None)
    if out is None and "--out" in argv[:-1]:
        out = argv[argv.index("--out") + 1]
    if out is None:
        return ""
    try:
        names = sorted(e.name for e in os.scandir(out)
                       if e.is_file() and e.stat().st_mtime >= started - 1)
    except OSError:
        names = []
    if not names:
        return f" (nothing written to {out} yet)"
    shown = ", ".join(names[:6]) + (f" and {len(names) - 6} more" if len(names) > 6 else "")
    return f" (already written to {out}: {shown})"


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = argparse.ArgumentParser(
        prog="uav-sitl",
        description="Simulated vehicles, cameras, fleets and simulation studies.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="The whole demo on one machine: uav-sitl fleet --duration 120 (what `make demo` "
               "runs).\nEach command's options: uav-sitl COMMAND --help. Documentation: "
               "docs/sitl.md, docs/fleet.md.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (_, text) in COMMANDS.items():
        sub.add_parser(name, help=text, add_help=False)
    study = sub.add_parser(
        "study", help="simulation studies that reproduce thesis figures",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="studies:\n" + "\n".join(f"  {name:<21}{text}" for name, (_, text)
                                           in sorted(STUDIES.items()))
        + "\n\neach study's options: uav-sitl study NAME --help (most take --out DIR and "
          "--quick)")
    study.add_argument("name", choices=sorted(STUDIES), metavar="NAME", help="which study")
    if not argv or argv[0] in ("-h", "--help"):
        parser.print_help()
        if not argv:
            print("uav-sitl: choose a command (the demo fleet: uav-sitl fleet)", file=sys.stderr)
        return 0 if argv else 2
    command, rest = argv[0], argv[1:]
    if command == "study":
        if not rest or rest[0] in ("-h", "--help"):
            study.print_help()
            if not rest:
                print("uav-sitl study: choose a study", file=sys.stderr)
            return 0 if rest else 2
        if rest[0] not in STUDIES:
            study.error(f"unknown study {rest[0]!r}; expected one of {', '.join(sorted(STUDIES))}")
        module_name = STUDIES[rest[0]][0]
        command, rest = f"study {rest[0]}", rest[1:]
    elif command in COMMANDS:
        module_name = COMMANDS[command][0]
    else:
        parser.error(f"unknown command {command!r}")
    started = time.time()
    try:
        module = importlib.import_module(module_name)
        return int(module.main(rest))
    except KeyboardInterrupt:
        if not command.startswith("study "):
            raise  # vehicle, fleet and camera handle Ctrl-C themselves
        print(f"uav-sitl {command}: interrupted{_written_since(rest, started)}",
              file=sys.stderr)
        return 130
    except OSError as exc:  # an output folder or file the tool cannot write (--out /proc/x)
        where = f" {exc.filename}" if exc.filename else ""
        print(f"uav-sitl {command}:{where}: {exc.strerror or exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    raise SystemExit(main())
