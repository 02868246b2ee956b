"""The mission log: JSON Lines written by the companion and the ground station.

One record per line, three kinds::

    {"sender": "drone1", "receiver": "gs", "seq": 7, "type": "image", "t_gen": 12.0,
     "t_sent": 12.01, "t_rcv": 12.2, "size": 31000, "data": {"red": 0.12},
     "version": 0, "versions": [{"name": "full", "size": 31000, "quality": 1.0}]}
    {"state": {"agent": "gs", "t": 10.0, "objectives": ["o1"]}}
    {"mission": {"t_start": 0.0, "t_end": 100.0}}

A message record with ``t_rcv`` null was generated (and maybe sent) but not received. The
same message may appear in several logs (the sender's record without ``t_rcv``, the
receiver's with it); :func:`merge_copies` keeps the received copy. Extra keys (``decision``,
``note``...) are allowed and ignored by the model.
"""

from __future__ import annotations

import json
import math
from collections.abc import Collection, Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import IO, Any

from utility_specs.errors import LogError, MessageError
from utility_specs.message import Message, MessageKey, StateHistory, Version

__all__ = [
    "MissionLog",
    "merge_copies",
    "message_from_record",
    "message_to_record",
    "parse_log",
    "write_record",
]


@dataclass(slots=True, kw_only=True)
class MissionLog:
    """Everything a log says: messages, agents' state histories, mission bounds."""

    messages: list[Message] = field(default_factory=list)
    states: dict[str, StateHistory] = field(default_factory=dict)
    t_start: float | None = None
    t_end: float | None = None
    torn_last_line: int | None = None
    """Number of an incomplete last line that was skipped: its writer stopped mid-line (a
    crash or power loss); every complete record before it counts."""
    bounds: list[tuple[float | None, float | None]] = field(default_factory=list)
    """Every mission record's (t_start, t_end) in file order (see ``utility_specs.intervals``)."""
    bound_kinds: list[str | None] = field(default_factory=list)
    """Each of ``bounds``' ``kind``: the ground station's ``open`` (its first message),
    ``start``/``end`` (an operator's), ``stop`` (its shutdown), ``cancelled`` (a scheduled
    start called off before it ran: ``(its t_start, None)``); None where a log has none."""
    extras: dict[int, dict[str, Any]] = field(default_factory=dict)
    """Index in ``messages`` -> the extra keys :func:`parse_log` was asked to ``keep``
    (``decision``...: not the model's, but a run summary counts them)."""


def message_to_record(m: Message, **extra: Any) -> dict[str, Any]:
    record: dict[str, Any] = {
        "sender": m.sender,
        "receiver": m.receiver,
        "seq": m.seq,
        "type": m.type,
        "t_gen": m.t_gen,
        "t_sent": m.t_sent,
        "t_rcv": m.t_rcv,
        "size": m.size,
        "data": dict(m.data),
    }
    if m.versions:
        record["version"] = m.version
        record["versions"] = [
            {"name": v.name, "size": v.size, "quality": v.quality} for v in m.versions
        ]
    record.update(extra)
    return record


def _opt_float(record: Mapping[str, Any], key: str) -> float | None:
    value = record.get(key)
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise MessageError(f"{key} must be a finite number or null, got {value!r}")
    return float(value)


def message_from_record(record: Mapping[str, Any]) -> Message:
    """A :class:`Message` from one log record; raises MessageError naming the bad key."""
    for key in ("sender", "seq", "type", "t_gen"):
        if key not in record:
            raise MessageError(f"missing key {key!r}")
    sender, seq, type_name = record["sender"], record["seq"], record["type"]
    if not isinstance(sender, str) or not isinstance(type_name, str):
        raise MessageError("sender and type must be strings")
    if isinstance(seq, bool) or not isinstance(seq, int):
        raise MessageError(f"seq must be an integer, got {seq!r}")
    receiver = record.get("receiver")
    if receiver is not None and not isinstance(receiver, str):
        raise MessageError(f"receiver must be a string or null, got {receiver!r}")
    data = record.get("data", {})
    if not isinstance(data, Mapping):
        raise MessageError(f"data must be an object, got {data!r}")
    size = record.get("size", 0)
    if isinstance(size, bool) or not isinstance(size, int):
        raise MessageError(f"size must be an integer number of bytes, got {size!r}")
    versions_raw = record.get("versions") or []
    try:
        versions = tuple(
            Version(name=str(v["name"]), size=int(v["size"]), quality=float(v["quality"]))
            for v in versions_raw
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise MessageError(f"versions must be a list of {{name, size, quality}} ({exc})") from None
    version = record.get("version")
    if version is not None and (isinstance(version, bool) or not isinstance(version, int)):
        raise MessageError(f"version must be an integer index or null, got {version!r}")
    t_gen = _opt_float(record, "t_gen")
    assert t_gen is not None
    return Message(
        sender=sender,
        receiver=receiver,
        seq=seq,
        type=type_name,
        t_gen=t_gen,
        t_sent=_opt_float(record, "t_sent"),
        t_rcv=_opt_float(record, "t_rcv"),
        size=size,
        data=dict(data),
        versions=versions,
        version=version,
    )


def parse_log(
    lines: Iterable[str],
    *,
    source: str = "<log>",
    allow_torn_tail: bool = False,
    keep: Collection[str] = (),
) -> MissionLog:
    """Parse JSON Lines; errors name the source and the line number.

    With ``allow_torn_tail`` (``lines`` keep their newlines, as a file's do), a last line that
    has no newline and is not valid JSON is skipped and noted in ``torn_last_line``.
    The ``keep`` keys of a message record, where present, go to ``extras``.
    """
    log = MissionLog()
    state_records: dict[str, list[tuple[float, Mapping[str, Any]]]] = {}
    for number, raw in enumerate(lines, start=1):
        line = raw.strip()
        if not line:
            continue
        try:
            record = json.loads(line)
            if not isinstance(record, dict):
                raise MessageError("a record must be a JSON object")
            if "mission" in record:
                mission = record["mission"]
                if not isinstance(mission, Mapping):
                    raise MessageError("mission must be an object")
                t_end = _opt_float(mission, "t_end")
                t_start = _opt_float(mission, "t_start")
                cancelled = _opt_float(mission, "cancelled")
                if cancelled is not None:  # a scheduled start the operator called off
                    log.bounds.append((cancelled, None))
                    log.bound_kinds.append("cancelled")
                    continue
                if t_end is not None:
                    log.t_end = t_end
                if t_start is not None:
                    log.t_start = t_start
                if t_start is not None or t_end is not None:
                    log.bounds.append((t_start, t_end))
                    kind = mission.get("kind")
                    log.bound_kinds.append(kind if isinstance(kind, str) else None)
            elif "state" in record:
                state = record["state"]
                if not isinstance(state, Mapping) or not isinstance(state.get("agent"), str):
                    raise MessageError("state must be an object with a string 'agent'")
                t = _opt_float(state, "t")
                if t is None:
                    raise MessageError("state needs a time 't'")
                fields = {k: v for k, v in state.items() if k not in ("agent", "t")}
                state_records.setdefault(state["agent"], []).append((t, fields))
            else:
                log.messages.append(message_from_record(record))
                kept = {k: record[k] for k in keep if k in record}
                if kept:
                    log.extras[len(log.messages) - 1] = kept
        except RecursionError:
            raise LogError(f"{source}:{number}: JSON nested too deeply") from None
        except (json.JSONDecodeError, MessageError) as exc:
            if allow_torn_tail and isinstance(exc, json.JSONDecodeError) and not raw.endswith("\n"):
                log.torn_last_line = number  # only a file's last line lacks its newline
                continue
            raise LogError(f"{source}:{number}: {exc}") from None
    log.states = {agent: StateHistory(records) for agent, records in state_records.items()}
    return log


def write_record(stream: IO[str], record: Mapping[str, Any]) -> None:
    """Append one record as a line (the caller owns the file and its flushing)."""
    stream.write(json.dumps(record, separators=(",", ":"), allow_nan=False) + "\n")


def merge_copies(messages: Iterable[Message]) -> Iterator[Message]:
    """Drop a sender's not-received record when a receiver logged the same message.

    Copies are matched by identity (sender, seq, t_gen) and version; received copies are all
    kept (one per receiver), a not-received copy only when no receiver logged that message.
    """
    received: set[tuple[MessageKey, int | None]] = set()
    pending: list[Message] = []
    for m in messages:
        if m.t_rcv is not None:
            received.add((m.key, m.version))
            yield m
        else:
            pending.append(m)
    for m in pending:
        if (m.key, m.version) not in received:
            yield m
