"""``uav-utility``: score a recorded mission, draw the model's figures, list specs."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from utility_specs.errors import UtilitySpecsError
from utility_specs.evaluate import evaluate
from utility_specs.files import builtin_spec, builtin_specs, read_log, spec_named
from utility_specs.intervals import MissionInterval, intervals_of, select_intervals
from utility_specs.log import merge_copies


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="uav-utility",
        description="The utility evaluation model (thesis ch. 4): evaluate mission logs, plot.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    ev = sub.add_parser(
        "evaluate",
        help="total utility of a recorded mission (JSON Lines log)",
        description="Total utility U(M) of a mission log (eq. 4.1/4.2) with its breakdown.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="examples (after `make demo`, its run folder's logs):\n"
               "  uav-utility evaluate --spec image_streaming "
               "out/fleet/*/gs-data/missions/fleet/mission_log.jsonl\n"
               "  uav-utility evaluate --spec my_mission.toml drone1.jsonl gs.jsonl --json",
    )
    ev.add_argument("log", type=Path, nargs="+", help="mission log(s), JSON Lines; merged")
    ev.add_argument(
        "--spec", required=True,
        help="mission spec TOML file, or the name of a built-in spec "
        f"({', '.join(builtin_specs())})",
    )
    ev.add_argument("--t-end", type=float, help="mission end (default: the log's, then the spec's)")
    ev.add_argument("--t-start", type=float, help="mission start (default: the log's, else 0)")
    ev.add_argument("--json", action="store_true", help="print one JSON object")
    ev.add_argument(
        "--mission", type=_mission_choice, default=None, metavar="N|last|all",
        help="which mission interval of the logs to evaluate (numbered by start time; "
        "default: the only one, else the last complete one, and it says so); the ground "
        "station's log marks the mission, a drone's log only its process's lifetime",
    )
    ev.add_argument(
        "--ignore-unknown-types", action="store_true",
        help="skip messages whose type the spec does not define (default: error)",
    )

    pl = sub.add_parser(
        "plot",
        help="draw a thesis figure (4.2-4.10) for an example mission",
        description="Figures of thesis ch. 4: KIND is a name or a figure number (4.2 ... 4.10), "
        "or 'all' with --out naming a folder.",
    )
    from utility_specs.plots import KINDS

    pl.add_argument("kind", metavar="KIND", help=f"one of: {', '.join(KINDS)}, 4.2-4.10, all")
    pl.add_argument("--out", type=Path, required=True, help="output PNG (a folder with 'all')")

    from utility_specs import cli_characteristics

    cli_characteristics.add_parser(sub)

    sub.add_parser("specs", help="list the built-in mission specs",
                   description="List the built-in mission specs: each name works as "
                               "`evaluate --spec NAME` and as a companion's mission.spec = "
                               "\"builtin:NAME\".")
    return parser


def _evaluate(args: argparse.Namespace) -> int:
    spec_arg: str = args.spec
    spec = spec_named(spec_arg)
    messages = []
    states = {}
    receiver_logs: list[list[MissionInterval]] = []
    sender_logs: list[list[MissionInterval]] = []
    for path in args.log:
        log = read_log(path)
        if log.torn_last_line is not None:
            print(f"uav-utility: warning: {path}:{log.torn_last_line}: incomplete last line "
                  "ignored (its writer stopped mid-line)", file=sys.stderr)
        messages.extend(log.messages)
        states.update(log.states)
        received_here = any(m.t_rcv is not None for m in log.messages)
        (receiver_logs if received_here else sender_logs).append(
            intervals_of(log.bounds, str(path), log.bound_kinds))
    try:
        selection = select_intervals(receiver_logs, sender_logs, args.mission)
    except ValueError as exc:
        print(f"uav-utility: error: {exc}", file=sys.stderr)
        return 2
    note = sys.stderr if args.json else sys.stdout
    if len(selection.candidates) > 1:
        for number, interval in enumerate(selection.candidates, start=1):
            print(f"  mission interval {number}: {interval.describe()}", file=note)
    received = sum(1 for m in messages if m.t_rcv is not None)
    if received == 0 and messages:
        print("uav-utility: warning: no record in these logs was received (no t_rcv): they "
              "hold only senders' records, so nothing counts as delivered and the total is 0; "
              "add the receiver's log (the ground station's "
              "gs-data/missions/MISSION/mission_log.jsonl)", file=sys.stderr)
    chosen = selection.chosen or [MissionInterval(None, None, "")]
    results = []
    merged = list(merge_copies(messages))
    for interval in chosen:
        t_end = args.t_end if args.t_end is not None else interval.t_end \
            if interval.t_end is not None else spec.t_end
        if t_end is None:
            print("uav-utility: no mission end: give --t-end, a {\"mission\": {\"t_end\": ...}} "
                  "record, or mission.t_end in the spec", file=sys.stderr)
            return 2
        t_start = args.t_start if args.t_start is not None else interval.t_start \
            if interval.t_start is not None else 0.0
        why = selection.why if selection.chosen else "no mission records: spec and defaults"
        if args.t_start is not None or args.t_end is not None:
            why = "bounds given by --t-start/--t-end" + (
                f" (the logs' choice was {interval.describe()})" if interval.source else "")
        result = evaluate(merged, spec, t_end=t_end, t_start=t_start, states=states,
                          ignore_unknown_types=args.ignore_unknown_types)
        results.append((t_start, t_end, why, result))
    if args.json:
        objects = [{**r.as_dict(), "t_start": a, "t_end": b, "interval": why}
                   for a, b, why, r in results]
        print(json.dumps(objects[0] if args.mission != "all" else {"missions": objects},
                         sort_keys=True))
        return 0
    for t_start, t_end, why, result in results:
        print(f"mission {spec.name!r}: [{t_start:.3f}, {t_end:.3f}] s "
              f"({t_end - t_start:.1f} s), {len(messages)} records, {received} received")
        print(f"interval: {why}")
        print(f"total utility  {result.total:14.6f}")
        print("per type:")
        for name, value in result.per_type.items():
            print(f"  {name:<20} {value:14.6f}")
        print("per receiver:")
        for name, value in sorted(result.per_receiver.items()):
            print(f"  {name:<20} {value:14.6f}")
    return 0


def _mission_choice(text: str) -> str:
    if text in ("last", "all") or (text.isdigit() and int(text) >= 1):
        return text
    raise argparse.ArgumentTypeError(f"expected a number >= 1, last or all, got {text!r}")


def _plot(args: argparse.Namespace) -> int:
    from utility_specs.plots import KINDS, plot

    try:
        if args.kind == "all":
            for kind in KINDS:
                print(plot(kind, args.out / f"{kind}.png"))
            return 0
        print(plot(args.kind, args.out))
    except OSError as exc:  # an unwritable or missing --out folder
        print(f"uav-utility: error: cannot write {args.out}: {exc.strerror or exc}",
              file=sys.stderr)
        return 1
    return 0


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        if args.command == "evaluate":
            return _evaluate(args)
        if args.command == "plot":
            return _plot(args)
        if args.command == "characteristics":
            from utility_specs import cli_characteristics

            return cli_characteristics.run(args)
        for name in builtin_specs():
            spec = builtin_spec(name)
            print(f"{name:<20} {', '.join(spec.types)}")
        return 0
    except (UtilitySpecsError, ValueError) as exc:
        print(f"uav-utility: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
