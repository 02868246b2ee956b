"""Messages, their versions and agents' state histories: the data the model evaluates.

All timestamps are float seconds on the fleet's synchronised clock (ARCHITECTURE.md).
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

from utility_specs.errors import MessageError

__all__ = ["Message", "MessageKey", "StateHistory", "Version"]

MessageKey = tuple[str, int, float]
"""(sender, seq, t_gen): a message's identity. A drone counts ``seq`` from 0 again each time
its companion starts, so within one mission (sender, seq) names several messages; their
``t_gen`` tells them apart (the wire decoder's identity too, docs/protocol.md)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class Version:
    """One available version of a message (eq. 4.33), e.g. an image at half resolution."""

    name: str
    """Short label: ``full``, ``half``, ``quarter``..."""
    size: int
    """Payload size of this version in bytes."""
    quality: float
    """Information content relative to the best version, in (0, 1]; for images m.d / d."""
    payload: bytes | None = field(default=None, repr=False, compare=False)
    """The encoded bytes of this version, where the sender has them (the companion's JPEG),
    so a message carries what the transport sends; None elsewhere (reports, logs, models).
    Not compared, not logged."""

    def __post_init__(self) -> None:
        if not self.name:
            raise MessageError("version name must not be empty")
        if self.payload is not None and len(self.payload) != self.size:
            raise MessageError(f"version {self.name!r}: size {self.size} is not the "
                               f"{len(self.payload)} bytes of its payload")
        if self.size < 0:
            raise MessageError(f"version {self.name!r}: size must be >= 0 bytes, got {self.size}")
        if not (0.0 < self.quality <= 1.0):
            raise MessageError(
                f"version {self.name!r}: quality must be in (0, 1], got {self.quality}"
            )


@dataclass(frozen=True, slots=True, kw_only=True)
class Message:
    """A message as the model sees it: who generated it, when, and when (if) it arrived.

    ``t_rcv`` is ``None`` when the message was not (or not yet) received. ``data`` holds the
    few fields utilities read (``red``, ``object``, ``level``, ``objective``, ``cells``...).
    When ``versions`` is given, ``version`` is the index of the version this copy carries
    (0 is the best) and ``size`` is that version's size.
    """

    sender: str
    seq: int
    type: str
    t_gen: float
    size: int = 0
    """Payload size in bytes."""
    receiver: str | None = None
    t_sent: float | None = None
    t_rcv: float | None = None
    data: Mapping[str, Any] = field(default_factory=dict)
    versions: tuple[Version, ...] = ()
    version: int | None = None

    def __post_init__(self) -> None:
        if not self.sender:
            raise MessageError("sender must not be empty")
        if not self.type:
            raise MessageError("type must not be empty")
        if not math.isfinite(self.t_gen):
            raise MessageError(f"t_gen must be finite, got {self.t_gen}")
        for name in ("t_sent", "t_rcv"):
            value = getattr(self, name)
            if value is not None and not math.isfinite(value):
                raise MessageError(f"{name} must be finite or None, got {value}")
        if self.t_rcv is not None and self.t_rcv < self.t_gen:
            raise MessageError(
                f"message {self.sender}/{self.seq}: t_rcv {self.t_rcv} is before t_gen {self.t_gen}"
            )
        if self.size < 0:
            raise MessageError(f"size must be >= 0 bytes, got {self.size}")
        if self.version is not None:
            if not self.versions:
                raise MessageError("version given but the message has no versions")
            if not 0 <= self.version < len(self.versions):
                raise MessageError(
                    f"version index {self.version} out of range 0..{len(self.versions) - 1}"
                )

    @property
    def received(self) -> bool:
        return self.t_rcv is not None

    @property
    def key(self) -> MessageKey:
        """Identity of the message across copies, receivers and versions (:data:`MessageKey`)."""
        return (self.sender, self.seq, self.t_gen)

    @property
    def quality(self) -> float:
        """Information content of the carried version relative to the best one (eq. 4.33)."""
        if self.version is None or not self.versions:
            return 1.0
        return self.versions[self.version].quality

    @property
    def payload(self) -> bytes:
        """The encoded bytes of the version this copy carries; ``b""`` for a message without
        versions (telemetry: its ``data`` travels in the metadata). Raises MessageError when
        a version's bytes are not here (a message learned from a report or a log)."""
        if not self.versions:
            return b""
        version = self.versions[self.version or 0]
        if version.payload is None:
            raise MessageError(f"{self.sender}/{self.seq}: version {version.name!r} has no "
                               "payload here")
        return version.payload

    def with_version(self, version: int) -> Message:
        """This message carrying another of its versions (size follows the version)."""
        return replace(self, version=version, size=self.versions[version].size)

    def delivered(self, *, receiver: str | None, t_rcv: float | None) -> Message:
        return replace(self, receiver=receiver, t_rcv=t_rcv)


class StateHistory:
    """H_g of one agent (sec. 4.2): a piecewise-constant state, changing at recorded times.

    Before the first record the state is empty (``{}``).
    """

    __slots__ = ("_states", "_times")

    def __init__(self, records: Iterable[tuple[float, Mapping[str, Any]]] = ()) -> None:
        pairs = sorted(records, key=lambda r: r[0])
        self._times: list[float] = [float(t) for t, _ in pairs]
        self._states: list[Mapping[str, Any]] = [s for _, s in pairs]

    def at(self, t: float) -> Mapping[str, Any]:
        i = bisect.bisect_right(self._times, t) - 1
        return self._states[i] if i >= 0 else {}

    def change_times(self, t0: float, t1: float) -> list[float]:
        """Times in the open interval (t0, t1) where the state changes."""
        lo = bisect.bisect_right(self._times, t0)
        hi = bisect.bisect_left(self._times, t1)
        return self._times[lo:hi]

    def __len__(self) -> int:
        return len(self._times)

    def __repr__(self) -> str:
        return f"StateHistory({len(self)} records)"
