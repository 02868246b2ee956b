"""The mission log: one JSON Lines file of ``utility_specs.log`` records plus ``decision``.

Three record shapes go in: ``mission`` (start, end), ``state`` (autopilot link, mission
commands) and messages with the decision that was taken about them (sent or not, and why).
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Mapping
from pathlib import Path
from typing import IO, Any

from utility_specs.log import message_to_record, write_record
from utility_specs.message import Message

__all__ = ["MissionLogWriter", "log_problem"]

log = logging.getLogger(__name__)


def log_problem(path: str | Path) -> str | None:
    """Why the mission log cannot be appended to at ``path`` (None: it can; the file and its
    folders are made). A log that could not be opened stopped ``run`` with a traceback,
    and ``check`` had said ok."""
    target = Path(path)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        with open(target, "a", encoding="utf-8"):
            pass
    except OSError as exc:
        return f"cannot write {target}: {exc.strerror or exc}"
    return None


class MissionLogWriter:
    """Appends JSON Lines records; flushed by the app's housekeeping and at close.

    A full SD card must not stop the drone from streaming: write errors (OSError) are counted
    in ``errors`` and logged now and then, never raised. The file buffer keeps what it could
    not write and tries again at the next flush.
    """

    def __init__(self, path: str | Path | None) -> None:
        self._stream: IO[str] | None = None
        self.errors = 0
        if path is not None:
            Path(path).parent.mkdir(parents=True, exist_ok=True)
            self._stream = open(path, "a", encoding="utf-8")  # noqa: SIM115 - closed in close()

    def write(self, record: Mapping[str, Any]) -> bool:
        """Append one record; False if it cannot be JSON (NaN, odd types) or written."""
        if self._stream is None:
            return True
        try:  # write_record serialises the whole line before writing any of it
            write_record(self._stream, record)
        except (ValueError, TypeError) as exc:
            log.warning("mission log: record skipped: %s", exc)
            return False
        except OSError as exc:
            self._failed(exc)
            return False
        return True

    def write_message(self, message: Message, *, sent: bool, decision: Mapping[str, Any]
                      ) -> bool:
        """A message and the decision about it; a message not sent has no ``t_sent``."""
        if not sent:
            message = dataclasses.replace(message, t_sent=None)
        return self.write(message_to_record(message, decision=dict(decision)))

    def write_state(self, agent: str, t: float, **state: Any) -> bool:
        """A state change of this drone (autopilot link, mission window) at ``t``."""
        return self.write({"state": {"agent": agent, "t": t, **state}})

    def flush(self) -> None:
        if self._stream is not None:
            try:
                self._stream.flush()
            except OSError as exc:
                self._failed(exc)

    def close(self) -> None:
        if self._stream is not None:
            stream, self._stream = self._stream, None
            try:
                stream.close()
            except OSError as exc:
                self._failed(exc)

    def _failed(self, exc: OSError) -> None:
        self.errors += 1
        if self.errors == 1 or self.errors % 100 == 0:
            log.error("mission log: write failed (%s), %d times so far; streaming goes on",
                      exc, self.errors)
