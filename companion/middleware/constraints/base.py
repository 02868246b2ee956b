"""The goodput constraint interface shared by the optimiser and the constraint strategies.

The optimiser (ch. 5, eq. 5.5/5.7) prunes every plan whose sent bytes exceed
``limit_bytes_per_s(now) * window_s`` in any window of length ``window_s``. A strategy
decides that limit: a constant, the adaptive SGD model of ch. 6 (eq. 6.7/6.8), or AIMD
(algorithm 4). Time always comes in as ``now`` (fleet clock, seconds); nothing here reads a
clock.
"""

from __future__ import annotations

import inspect
import math
from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Iterable, Mapping

from companion.middleware.constraints.linkstats import LinkSample, RoundTrip
from companion.middleware.errors import ConstraintError, ParamError, UnknownParamError

__all__ = ["ConstantConstraint", "GoodputConstraint", "LinkSample"]


class GoodputConstraint(ABC):
    """ξ: how many bytes per second the application may send, averaged over ``window_s``."""

    window_s: float

    def __init__(self, *, window_s: float) -> None:
        if not window_s > 0:
            raise ConstraintError(f"window_s must be > 0, got {window_s}")
        self.window_s = window_s
        self._sent: deque[tuple[float, int]] = deque()
        self._sent_bytes = 0

    @abstractmethod
    def limit_bytes_per_s(self, *, now: float) -> float:
        """ξ(now) in bytes per second."""

    def budget_bytes(self, *, now: float) -> float:
        """Bytes that may be sent in one window of length ``window_s`` (ξ·T)."""
        return self.limit_bytes_per_s(now=now) * self.window_s

    def on_sample(self, sample: LinkSample, *, now: float) -> None:  # noqa: B027
        """Learn from one delivered message (default: nothing to learn)."""

    def on_samples(self, samples: Iterable[LinkSample], *, now: float) -> None:
        """Learn from all messages of one receiver report (default: one by one)."""
        for sample in samples:
            self.on_sample(sample, now=now)

    def on_round_trip(self, round_trip: RoundTrip, *, now: float) -> None:  # noqa: B027
        """A report round trip (clock offset and delay); default: not used."""

    def on_stall(self, t_from: float, t_to: float, *, now: float) -> None:  # noqa: B027
        """This agent did not run in [t_from, t_to] (its clock); default: nothing to undo."""

    @property
    def fleet_goodput(self) -> bool:
        """Whether :meth:`on_samples` wants the other agents' report entries too (marked
        ``own=False``, for the fleet's goodput); default: only this agent's."""
        return False

    def on_sent(self, size_bytes: int, *, now: float) -> None:
        """Record that ``size_bytes`` went on the link at ``now``."""
        self._sent.append((now, size_bytes))
        self._sent_bytes += size_bytes
        self._forget_before(now - self.window_s)  # bounded even when nobody asks

    def sent_in_window(self, *, now: float) -> int:
        """Bytes recorded by :meth:`on_sent` in (now - window_s, now]."""
        self._forget_before(now - self.window_s)
        return self._sent_bytes

    def _forget_before(self, horizon: float) -> None:
        while self._sent and self._sent[0][0] <= horizon:
            self._sent_bytes -= self._sent.popleft()[1]

    def admits(self, size_bytes: int, *, now: float) -> bool:
        """Whether sending ``size_bytes`` now keeps the last window within budget."""
        return self.sent_in_window(now=now) + size_bytes <= self.budget_bytes(now=now)

    # -- live parameters (``set_params`` with ``constraint.NAME`` keys) ---------------------

    def tunable(self) -> dict[str, str]:
        """The numbers a live ``set_params`` may change: parameter name -> attribute.

        By default every public numeric attribute that is also a constructor parameter (a
        setting, not state the constraint recomputes, such as the adaptive α of the last
        window), except the window (its length shapes the statistics already gathered).
        """
        settings = inspect.signature(type(self)).parameters
        return {k: k for k, v in sorted(vars(self).items())
                if not k.startswith("_") and k in settings and k != "window_s"
                and isinstance(v, int | float) and not isinstance(v, bool)}

    def check_params(self, changes: Mapping[str, object]) -> dict[str, float]:
        """Validate ``{name: value}`` without changing anything; returns them as floats.

        A throwaway constraint of the same kind is built with the new numbers, so its own
        checks (ranges, min <= max) reject what the running one must not get.
        """
        tunable = self.tunable()
        checked: dict[str, float] = {}
        for name, value in changes.items():
            if name not in tunable:
                raise UnknownParamError(f"constraint.{name}",
                                        [f"constraint.{k}" for k in sorted(tunable)],
                                        owner=f"the {type(self).__name__}")
            if (isinstance(value, bool) or not isinstance(value, int | float)
                    or not math.isfinite(value) or value < 0):
                raise ParamError(f"constraint.{name} must be a number >= 0, got {value!r}")
            checked[name] = float(value)
        kind = type(self)
        current = {name: getattr(self, tunable.get(name, name), None)
                   for name in inspect.signature(kind).parameters}
        kwargs = {k: v for k, v in current.items()
                  if isinstance(v, int | float) and not isinstance(v, bool)}
        kwargs.update(checked)
        try:
            kind(**kwargs)
        except (ValueError, TypeError) as exc:
            raise ParamError(f"constraint: {exc}") from None
        return checked

    def apply_params(self, checked: Mapping[str, float]) -> None:
        """Set numbers :meth:`check_params` accepted."""
        tunable = self.tunable()
        for name, value in checked.items():
            setattr(self, tunable[name], value)


class ConstantConstraint(GoodputConstraint):
    """A fixed ξ (eq. 5.7 with a constant A)."""

    def __init__(self, *, limit_bytes_per_s: float, window_s: float = 2.5) -> None:
        super().__init__(window_s=window_s)
        if not limit_bytes_per_s >= 0:
            raise ConstraintError(f"limit_bytes_per_s must be >= 0, got {limit_bytes_per_s}")
        self._limit = float(limit_bytes_per_s)

    def limit_bytes_per_s(self, *, now: float) -> float:
        return self._limit

    def tunable(self) -> dict[str, str]:
        return {**super().tunable(), "limit_bytes_per_s": "_limit"}
