"""What an operator types or posts for the mission manager, parsed: times ("in 5 s", "+5",
"at 14:00"), live parameters ("NAME=VALUE,..."), and the ground-station shell's lines.
Every refusal is a :class:`MissionError` whose text says what was expected.
"""

from __future__ import annotations

import datetime as dt
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

__all__ = ["HELP", "MissionError", "ShellCommand", "parse_params", "parse_shell_line",
           "parse_when"]


class MissionError(ValueError):
    """An operator command that cannot be understood; the text says what was expected."""


_IN = re.compile(r"^(?:in\s+|\+)?\s*(\d+(?:\.\d+)?)\s*(s|sec|secs|seconds?|m|min|mins|minutes?)?$")
_AT = re.compile(r"^(?:at\s+|@\s*)?(\d{1,2}):(\d{2})(?::(\d{2}(?:\.\d+)?))?$")


def parse_when(text: str | None, *, now: float, tz: dt.tzinfo | None = None) -> float:
    """Absolute fleet time for ``now``/``in 5 s``/``+5``/``5s``/``in 2 min``/``at 14:00[:30]``.

    ``at HH:MM`` is the next such wall-clock time in ``tz`` (local time when ``None``); if it
    has already passed today it means tomorrow, like the thesis' "finish a mission at 14:00".
    """
    spec = (text or "").strip().lower()
    if spec in ("", "now", "+0"):
        return now
    match = _IN.match(spec)
    if match:
        amount = float(match.group(1))
        unit = match.group(2) or "s"
        return now + (amount * 60.0 if unit.startswith("m") else amount)
    match = _AT.match(spec)
    if match:
        hour, minute = int(match.group(1)), int(match.group(2))
        second = float(match.group(3)) if match.group(3) else 0.0
        if hour > 23 or minute > 59 or second >= 60:
            raise MissionError(f"time {text!r}: expected HH:MM[:SS] with a valid clock time")
        local_now = dt.datetime.fromtimestamp(now, tz=tz)
        target = local_now.replace(
            hour=hour, minute=minute, second=int(second), microsecond=round(second % 1 * 1e6)
        )
        if target.timestamp() < now:
            target += dt.timedelta(days=1)
        return target.timestamp()
    raise MissionError(
        f"time {text!r}: expected 'now', 'in 5 s', '+5', '5s', 'in 2 min' or 'at 14:00[:SS]'"
    )


def _value(text: str) -> Any:
    low = text.lower()
    if low in ("true", "false"):
        return low == "true"
    try:
        return int(text)
    except ValueError:
        pass
    try:
        value = float(text)
    except ValueError:
        return text.strip("\"'")
    if not math.isfinite(value):
        raise MissionError(f"parameter value {text!r}: expected a finite number")
    return value


def check_params(params: Mapping[str, Any]) -> dict[str, Any]:
    """The API's ``{"params": {...}}`` held to the shell's rules: names as in
    :func:`parse_params`, values a bool, an integer, a finite number or text. A JSON object
    let 1e400 (Infinity, which breaks every dashboard's JSON.parse) and nested values in."""
    if not params:
        raise MissionError("expected at least one NAME=VALUE parameter")
    for name, value in params.items():
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_.]{0,63}", name):
            raise MissionError(f"parameter name {name[:40]!r}: expected up to 64 letters, "
                               "digits, '_' or '.'")
        if isinstance(value, float) and not math.isfinite(value):
            raise MissionError(f"parameter {name}: expected a finite number")
        if not isinstance(value, bool | int | float | str):
            raise MissionError(f"parameter {name}: expected a number, true/false or text")
    return dict(params)


def parse_params(text: str) -> dict[str, Any]:
    """``"alpha=10, mcts_iterations=300"`` -> ``{"alpha": 10, "mcts_iterations": 300}``."""
    params: dict[str, Any] = {}
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        name, sep, raw = part.partition("=")
        name = name.strip()
        if not sep or not name or not raw.strip():
            raise MissionError(f"parameter {part!r}: expected NAME=VALUE, e.g. alpha=10")
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_.]*", name):
            raise MissionError(f"parameter name {name!r}: expected letters, digits, '_' or '.'")
        if "=" in raw:  # "alpha=12 mcts_iterations=300" would send alpha the text "12 mcts..."
            raise MissionError(f"parameter {part!r}: separate parameters with commas, "
                               "e.g. alpha=10, mcts_iterations=300")
        params[name] = _value(raw.strip())
    if not params:
        raise MissionError("expected at least one NAME=VALUE parameter")
    return params


@dataclass(frozen=True, slots=True, kw_only=True)
class ShellCommand:
    """One parsed line of the interactive terminal (thesis fig. 3.7)."""

    verb: str
    """start, end, params, report, wait_drones, wait_reports, reset_reports, sleep, status,
    help, close, quit."""
    when: str | None = None
    params: Mapping[str, Any] = field(default_factory=dict)
    count: int | None = None
    report: str | None = None
    seconds: float | None = None


HELP = """Available commands:
  (the one-letter names of thesis fig. 3.7, in brackets, work too)
  start [TIME]          (s)  start the mission on every drone (TIME: now, +5, in 5 s, at 14:00)
  end [TIME]            (e)  end the mission: drones stop streaming images
  params A=1,B=2 [@ TIME]  (p)  set parameters on every drone, e.g. params mcts_iterations=300
  report                     ask every drone for its counters
  wait                  (r)  wait for every drone's result of the last command
  wait [N] NAME         (r)  wait for N reports named NAME (default N: every known drone)
  drones N              (n)  wait until N drones are heard
  reset                 (rr) forget the counted reports
  sleep N               (l)  sleep for N seconds
  status                     mission phase, drones and the last commands' results
  help                  (h)  this list
  close                 (c)  leave the interactive mode
  quit                  (q)  exit the program
Every wait gives up after the shell's timeout and names the drones that did not answer."""

ALIASES = {
    "s": "start", "e": "end", "p": "params", "set": "params", "n": "drones", "r": "wait",
    "w": "wait", "reports": "wait", "results": "wait", "rr": "reset", "l": "sleep",
    "h": "help", "?": "help", "c": "close", "q": "quit", "exit": "quit",
}
"""Old letters of thesis fig. 3.7 and other guesses -> command names."""


def parse_shell_line(line: str) -> ShellCommand | None:
    """Parse a terminal line; ``None`` for an empty line, :class:`MissionError` if unknown."""
    text = line.strip()
    if not text:
        return None
    word, _, rest = text.partition(" ")
    verb = ALIASES.get(word.lower(), word.lower())
    rest = rest.strip()
    if verb in ("start", "end"):
        return ShellCommand(verb=verb, when=rest or None)
    if verb == "params":
        params_text, _, when = rest.partition("@")
        return ShellCommand(
            verb="params", params=parse_params(params_text), when=when.strip() or None
        )
    if verb == "report":
        return ShellCommand(verb="report", when=rest or None)
    if verb == "drones":
        if not rest.isdigit():
            raise MissionError(f"{word}: expected the number of drones, e.g. {word} 4")
        return ShellCommand(verb="wait_drones", count=int(rest))
    if verb == "wait":
        count: int | None = None
        report: str | None = None
        for arg in rest.split():
            if arg.isdigit() and count is None:
                count = int(arg)
            elif report is None:
                report = arg
            else:
                raise MissionError(
                    f"{word}: expected at most a count and a report name, e.g. {word} 4 done"
                )
        return ShellCommand(verb="wait_reports", count=count, report=report)
    if verb == "reset":
        return ShellCommand(verb="reset_reports")
    if verb == "sleep":
        try:
            seconds = float(rest)
        except ValueError:
            raise MissionError(f"{word}: expected a number of seconds, e.g. {word} 5") from None
        if not (math.isfinite(seconds) and seconds >= 0):
            raise MissionError(f"{word}: expected a number of seconds >= 0")
        return ShellCommand(verb="sleep", seconds=seconds)
    if verb in ("help", "close", "quit", "status"):
        return ShellCommand(verb=verb)
    raise MissionError(f"unknown command {word!r}; help (or h) lists the commands")
