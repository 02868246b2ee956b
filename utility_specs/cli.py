"""``uav-utility``: score a recorded mission, draw the model's figures, list specs."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from utility_specs.errors import UtilitySpecsError
from utility_specs.evaluate import evaluate
from utility_specs.files import builtin_spec, builtin_specs, load_spec, read_log
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

    sub.add_parser("specs", help="list the built-in mission specs")
    return parser


def _evaluate(args: argparse.Namespace) -> int:
    spec_arg: str = args.spec
    spec = load_spec(spec_arg) if Path(spec_arg).suffix == ".toml" else builtin_spec(spec_arg)
    messages = []
    states = {}
    t_end = args.t_end
    t_start = args.t_start
    log_t_end = None
    log_t_start = None
    for path in args.log:
        log = read_log(path)
        if log.torn_last_line is not None:
            print(f"uav-utility: warning: {path}:{log.torn_last_line}: incomplete last line "
                  "ignored (its writer stopped mid-line)", file=sys.stderr)
        messages.extend(log.messages)
        states.update(log.states)
        log_t_end = log.t_end if log.t_end is not None else log_t_end
        log_t_start = log.t_start if log.t_start is not None else log_t_start
    t_end = t_end if t_end is not None else log_t_end if log_t_end is not None else spec.t_end
    if t_end is None:
        print("uav-utility: no mission end: give --t-end, a {\"mission\": {\"t_end\": ...}} "
              "record, or mission.t_end in the spec", file=sys.stderr)
        return 2
    t_start = t_start if t_start is not None else log_t_start if log_t_start is not None else 0.0
    result = evaluate(
        merge_copies(messages), spec, t_end=t_end, t_start=t_start, states=states,
        ignore_unknown_types=args.ignore_unknown_types,
    )
    if args.json:
        print(json.dumps(result.as_dict(), sort_keys=True))
        return 0
    received = sum(1 for m in messages if m.t_rcv is not None)
    print(f"mission {spec.name!r}: [{t_start:.3f}, {t_end:.3f}] s ({t_end - t_start:.1f} s), "
          f"{len(messages)} records, {received} received")
    print(f"total utility  {result.total:14.6f}")
    print("per type:")
    for name, value in result.per_type.items():
        print(f"  {name:<20} {value:14.6f}")
    print("per receiver:")
    for name, value in sorted(result.per_receiver.items()):
        print(f"  {name:<20} {value:14.6f}")
    return 0


def _plot(args: argparse.Namespace) -> int:
    from utility_specs.plots import KINDS, plot

    if args.kind == "all":
        for kind in KINDS:
            print(plot(kind, args.out / f"{kind}.png"))
        return 0
    print(plot(args.kind, args.out))
    return 0


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        if args.command == "evaluate":
            return _evaluate(args)
        if args.command == "plot":
            return _plot(args)
        for name in builtin_specs():
            spec = builtin_spec(name)
            print(f"{name:<20} {', '.join(spec.types)}")
        return 0
    except (UtilitySpecsError, ValueError) as exc:
        print(f"uav-utility: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
