"""The library of message utility functions (thesis ch. 4.3, 4.4, 5.4 and 7).

A utility function gives the utility U_p(m, t, s) of one received message ``m`` at time ``t``
(``t >= m.t_rcv``; the aggregator never asks earlier, because a message brings nothing before it
arrives). Besides the value, each function tells the exact evaluator what it needs to integrate
without a fixed time step:

* :meth:`UtilityFunction.integral` - the closed-form integral over an interval,
* :meth:`UtilityFunction.knots` - the times where the value is not smooth (a cap ends, it hits 0),
* :meth:`UtilityFunction.expiry` - from when on the value is 0 for good,
* :meth:`UtilityFunction.critical_points` - where the difference of two messages' values may turn,
  so that between knots and critical points the difference is monotone and a crossing is found
  exactly by bisection,
* :meth:`UtilityFunction.dominates` - a cheap proof that one message is never worse than another,
  which keeps the `max` envelope small.

State-dependent functions (``objective``, ``localization``) are piecewise constant between
state changes and receptions; the evaluator integrates them piece by piece.
"""

from __future__ import annotations

import bisect
import math
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from typing import Any, ClassVar

import numpy as np

from utility_specs._envelope import CAPPED_LOG, EXPONENTIAL, LINE, QUADRATIC, STEP, Family
from utility_specs.curves import (
    Curve,
    EndedCurve,
    FloatArray,
    LineCurve,
    Shape,
    ShapeCurve,
    StepCurve,
)
from utility_specs.errors import MessageError, SpecError
from utility_specs.message import Message, MessageKey

__all__ = [
    "FUNCTIONS",
    "Battery",
    "External",
    "Linear",
    "Localization",
    "ObjectImage",
    "Objective",
    "Position",
    "RedImage",
    "Status",
    "StatusChange",
    "StatusPoisson",
    "UtilityFunction",
    "Video",
    "VideoVersions",
    "make_function",
    "video_coefficients",
]

INF = math.inf
LN2 = math.log(2.0)
EMPTY_STATE: Mapping[str, Any] = {}


def _number(name: str, value: object, *, positive: bool = True, allow_zero: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise SpecError(f"param {name!r}: expected a number, got {value!r}")
    number = float(value)
    if not math.isfinite(number):
        raise SpecError(f"param {name!r}: expected a finite number, got {value!r}")
    if positive and (number < 0 or (number == 0 and not allow_zero)):
        bound = ">= 0" if allow_zero else "> 0"
        raise SpecError(f"param {name!r}: expected a number {bound}, got {value!r}")
    return number


def _field(m: Message, name: str) -> Any:
    try:
        return m.data[name]
    except KeyError:
        raise MessageError(
            f"message {m.sender}/{m.seq} of type {m.type!r} has no data field {name!r}"
        ) from None


def _float_field(m: Message, name: str, default: float | None = None) -> float:
    value = m.data.get(name, default) if default is not None else _field(m, name)
    if type(value) is float and -INF < value < INF:  # the common case, checked cheaply
        return value
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise MessageError(
            f"message {m.sender}/{m.seq}: data field {name!r} must be a finite number, "
            f"got {value!r}"
        )
    return float(value)


class UtilityFunction(ABC):
    """U_p(m, t, s): utility of message ``m`` at time ``t`` for a receiver in state ``s``.

    Time-only functions implement :meth:`curve`; everything else follows from it.
    State-dependent ones implement :meth:`value` and are integrated piecewise.
    """

    name: ClassVar[str]
    state_dependent: ClassVar[bool] = False
    """Value depends on the receiver's state; integrated piecewise between state changes."""
    impulse: ClassVar[bool] = False
    """Utility is a Dirac impulse at reception (eq. 4.34); only ``sum`` aggregates it."""
    aggregations: ClassVar[frozenset[str]] = frozenset({"sum", "max", "last"})

    def curve(self, m: Message) -> Curve:
        """The message's utility as a function of time (reads and checks its data once)."""
        raise NotImplementedError(f"{self.name} depends on the receiver's state")

    def value(self, m: Message, t: float, state: Mapping[str, Any] = EMPTY_STATE) -> float:
        """U(m, t, s) for ``t >= m.t_rcv``."""
        return self.curve(m).value(t)

    def integral(self, m: Message, a: float, b: float) -> float:
        """Exact integral of :meth:`value` over [a, b] (``a >= m.t_rcv``)."""
        return self.curve(m).integral(a, b)

    def values(
        self, messages: Sequence[Message], t: float, state: Mapping[str, Any] = EMPTY_STATE
    ) -> list[float]:
        """:meth:`value` of several messages at one instant and state."""
        value = self.value
        return [value(m, t, state) for m in messages]

    def knots(self, m: Message) -> tuple[float, ...]:
        return self.curve(m).knots()

    def expiry(self, m: Message) -> float:
        return self.curve(m).expiry

    def critical_points(self, m1: Message, m2: Message) -> tuple[float, ...]:
        return self.curve(m1).critical_points(self.curve(m2))

    def dominates(self, a: Message, b: Message) -> bool:
        """True only if U(a, t) >= U(b, t) for every t at which both have arrived."""
        return self.curve(a).dominates(self.curve(b))

    def family(self, messages: Sequence[Message]) -> Family | None:
        """The messages' curves as one family on flat arrays (reads and checks their data).

        Lets the evaluator integrate a whole stream in compiled code without a curve object
        per message; None when the function has no such form. A function with a family must
        derive nothing in :meth:`prepare` (the compiled path skips it).
        """
        return None

    def prepare(self, received: Sequence[Message]) -> list[Message] | None:
        """Derive per-message data that depends on the other received messages (eq. 4.20).

        Returns the messages with that data added, or None when there is nothing to derive.
        """
        return None

    def superseded(self, old: Message, newer: Message) -> Message | None:
        """``old`` as known once ``newer`` of its stream was generated, or None (unchanged).

        A function whose value ends when the world changes (:class:`StatusChange`) marks the
        end on the older message; the optimiser applies it to what it has already sent.
        """
        return None

    def params(self) -> dict[str, float]:
        return {}

    def __repr__(self) -> str:
        inner = ", ".join(f"{k}={v!r}" for k, v in self.params().items())
        return f"{type(self).__name__}({inner})"


class _LinearDecay(UtilityFunction):
    """U = max(0, u0 - c·(t - t_gen)): shared by ``battery`` (eq. 4.9) and ``linear`` (ch. 5.4)."""

    @abstractmethod
    def line(self, m: Message) -> tuple[float, float]:
        """(u0, c): value at generation and decrease per second."""

    def curve(self, m: Message) -> Curve:
        u0, c = self.line(m)
        return LineCurve(m.t_gen, u0, c)

    def family(self, messages: Sequence[Message]) -> Family:
        line = self.line
        lines = [line(m) for m in messages]
        return Family(LINE, (), [u0 for u0, _ in lines], [c for _, c in lines])


class Battery(_LinearDecay):
    """Eq. 4.9: U = max(0, 1 - ρ·(t - t_gen) / level); ``max`` aggregation (eq. 4.10).

    ``level`` (0..1] comes from the message data; ``depletion_rate`` ρ (1/s) may be
    overridden per message by a data field of the same name (the ch. 5.4 study draws it).
    """

    name = "battery"

    def __init__(self, *, depletion_rate: float) -> None:
        self.depletion_rate = _number("depletion_rate", depletion_rate)

    def line(self, m: Message) -> tuple[float, float]:
        level = _float_field(m, "level")
        rho = _float_field(m, "depletion_rate", self.depletion_rate)
        if level <= 0:
            return (0.0, 0.0)
        return (1.0, rho / level)

    def params(self) -> dict[str, float]:
        return {"depletion_rate": self.depletion_rate}


class Linear(_LinearDecay):
    """U = max(0, initial - slope·(t - t_gen)), the decreasing line of the ch. 5.4 study.

    ``initial`` and ``slope`` may be overridden per message by data fields of the same name.
    """

    name = "linear"

    def __init__(self, *, initial: float = 1.0, slope: float = 0.1) -> None:
        self.initial = _number("initial", initial, allow_zero=True)
        self.slope = _number("slope", slope, allow_zero=True)

    def line(self, m: Message) -> tuple[float, float]:
        return (
            _float_field(m, "initial", self.initial),
            _float_field(m, "slope", self.slope),
        )

    def params(self) -> dict[str, float]:
        return {"initial": self.initial, "slope": self.slope}


class _Quadratic(Shape):
    def __init__(self, c: float) -> None:
        self.c = c
        self.x_zero = 1.0 / math.sqrt(c)
        self.x_knots = (self.x_zero,)
        self.kernel = (QUADRATIC, (c,))

    def phi(self, x: float) -> float:
        v = 1.0 - self.c * x * x
        return v if v > 0.0 else 0.0

    def phi_array(self, x: FloatArray) -> FloatArray:
        return np.maximum(1.0 - self.c * x * x, 0.0)

    def phi_integral(self, xa: float, xb: float) -> float:
        xb = min(xb, self.x_zero)
        if xb <= xa:
            return 0.0
        return (xb - xa) - self.c * (xb**3 - xa**3) / 3.0

    def phi_integral_array(self, xa: FloatArray, xb: FloatArray) -> FloatArray:
        xb = np.minimum(xb, self.x_zero)
        xa = np.minimum(xa, xb)
        return (xb - xa) - self.c * (xb**3 - xa**3) / 3.0


class Position(UtilityFunction):
    """Eq. 4.11-4.12: U = max(0, 1 - π·v_max²·(t - t_gen)² / A); ``max`` (eq. 4.13)."""

    name = "position"

    def __init__(self, *, v_max: float, area: float) -> None:
        self.v_max = _number("v_max", v_max)
        self.area = _number("area", area)
        self._shape = _Quadratic(math.pi * self.v_max**2 / self.area)

    def curve(self, m: Message) -> Curve:
        return ShapeCurve(m.t_gen, 1.0, self._shape)

    def family(self, messages: Sequence[Message]) -> Family:
        n = len(messages)
        return Family(QUADRATIC, (self._shape.c,), [1.0] * n, [0.0] * n)

    def params(self) -> dict[str, float]:
        return {"v_max": self.v_max, "area": self.area}


class Status(UtilityFunction):
    """Eq. 4.14: U = 1 once received; meant for ``last`` aggregation (eq. 4.15)."""

    name = "status"

    def curve(self, m: Message) -> Curve:
        return StepCurve(m.t_gen)

    def family(self, messages: Sequence[Message]) -> Family:
        n = len(messages)
        return Family(STEP, (), [1.0] * n, [0.0] * n)

    def value(self, m: Message, t: float, state: Mapping[str, Any] = EMPTY_STATE) -> float:
        return 1.0 if m.t_rcv is not None and t > m.t_rcv else 0.0


class _Exponential(Shape):
    def __init__(self, rate: float) -> None:
        self.rate = rate
        self.kernel = (EXPONENTIAL, (rate,))

    def phi(self, x: float) -> float:
        return math.exp(-self.rate * x)

    def phi_array(self, x: FloatArray) -> FloatArray:
        result: FloatArray = np.exp(-self.rate * x)
        return result

    def phi_integral(self, xa: float, xb: float) -> float:
        return (math.exp(-self.rate * xa) - math.exp(-self.rate * xb)) / self.rate

    def phi_integral_array(self, xa: FloatArray, xb: FloatArray) -> FloatArray:
        result: FloatArray = (np.exp(-self.rate * xa) - np.exp(-self.rate * xb)) / self.rate
        return result


class StatusPoisson(UtilityFunction):
    """Eq. 4.16: U = exp(-λ·(t - t_gen)), the chance the status has not changed; ``max``."""

    name = "status_poisson"

    def __init__(self, *, rate: float) -> None:
        self.rate = _number("rate", rate)
        self._shape = _Exponential(self.rate)

    def curve(self, m: Message) -> Curve:
        return ShapeCurve(m.t_gen, 1.0, self._shape)

    def family(self, messages: Sequence[Message]) -> Family:
        n = len(messages)
        return Family(EXPONENTIAL, (self.rate,), [1.0] * n, [0.0] * n)

    def params(self) -> dict[str, float]:
        return {"rate": self.rate}


class StatusChange(UtilityFunction):
    """Eq. 4.14 and 4.16 for a periodically repeated state: true until the state changes.

    Eq. 4.14 assumes one message per status change: a new status makes every older one
    worthless (``last``, eq. 4.15), so a delayed new status costs utility. A vehicle status
    repeated every few seconds breaks that premise: a repeat of an unchanged state is not a
    new status, and under ``last`` a newer copy only loses its own delay. Here each message
    carries ``since``, when the state it reports began (data; its ``t_gen`` when absent, so
    that every message is a new state as in eq. 4.14). A message is worth
    ``exp(-λ·(t - t_gen))`` after reception (eq. 4.16: the chance the state has not changed
    since it was observed; λ = 0 gives eq. 4.14's constant 1) and 0 from ``until`` on, the
    time the state it reports ended: data ``until``, or derived from a received message
    whose ``since`` is after its generation (:meth:`prepare`; the optimiser learns it from
    the newer state it generated, :meth:`superseded`). So a repeat of the known state adds
    only eq. 4.16's refresh, while the first message of a new state replaces a value of 0:
    the optimiser sends state changes at once and repeats when the link has room. ``max``.
    """

    name = "status_change"
    UNTIL = "until"

    def __init__(self, *, rate: float = 0.0) -> None:
        self.rate = _number("rate", rate, allow_zero=True)
        self._shape = _Exponential(self.rate) if self.rate > 0 else None

    def since(self, m: Message) -> float:
        since = _float_field(m, "since", m.t_gen)
        if since > m.t_gen:
            raise MessageError(
                f"message {m.sender}/{m.seq}: since {since} is after its t_gen {m.t_gen}"
            )
        return since

    def curve(self, m: Message) -> Curve:
        self.since(m)
        inner: Curve = (
            StepCurve(m.t_gen) if self._shape is None else ShapeCurve(m.t_gen, 1.0, self._shape)
        )
        until = _float_field(m, self.UNTIL, INF) if self.UNTIL in m.data else INF
        return inner if until == INF else EndedCurve(inner, until)

    def superseded(self, old: Message, newer: Message) -> Message | None:
        since = self.since(newer)
        if since <= old.t_gen or newer.t_gen <= old.t_gen:
            return None  # the same state (or an older message): old stays true
        until = old.data.get(self.UNTIL)
        if isinstance(until, int | float) and until <= since:
            return None
        return replace(old, data={**old.data, self.UNTIL: since})

    def prepare(self, received: Sequence[Message]) -> list[Message] | None:
        # As everywhere in the evaluator, a message never received does not exist for the
        # receiver: a change whose every message was lost does not end the older state.
        starts = sorted({self.since(m) for m in received if m.t_rcv is not None})
        if not starts:
            return None
        out = []
        for m in received:
            i = bisect.bisect_right(starts, m.t_gen)  # the first state begun after m
            if i < len(starts) and self.UNTIL not in m.data:
                m = replace(m, data={**m.data, self.UNTIL: starts[i]})
            out.append(m)
        return out

    def params(self) -> dict[str, float]:
        return {"rate": self.rate}


class Objective(UtilityFunction):
    """Eq. 4.18: 1 while the receiver pursues the message's objective; ``sum`` (eq. 4.19).

    Message data ``objective``; receiver state ``objectives`` (the pursued set O_pursued).
    """

    name = "objective"
    state_dependent = True

    def value(self, m: Message, t: float, state: Mapping[str, Any] = EMPTY_STATE) -> float:
        objective = _field(m, "objective")
        return 1.0 if objective in state.get("objectives", ()) else 0.0


class Localization(UtilityFunction):
    """Eq. 4.20-4.22: share of the observed area covered by the message's *new* map area.

    Areas are either grid cells (data ``cells``: [[i, j], ...]; state ``observed_cells``) or
    2-D polygons (data ``area``: [[x, y], ...]; state ``observed_area``). N_m removes what
    earlier receptions already covered (ties in t_rcv are broken by sender, then seq, so two
    copies of the same area received at once do not cancel each other out).
    """

    name = "localization"
    state_dependent = True
    NEW_CELLS = "_new_cells"
    NEW_AREA = "_new_area"

    def prepare(self, received: Sequence[Message]) -> list[Message]:
        order = sorted(received, key=lambda m: (m.t_rcv or 0.0, m.sender, m.seq))
        known_cells: set[tuple[int, int]] = set()
        known_area: Any = None
        new_of: dict[MessageKey, tuple[str, Any]] = {}  # a message's N_m, by its key
        out: list[Message] = []
        for m in order:
            data = dict(m.data)
            if m.key in new_of:  # another version of a message seen already: the same N_m
                field, new_part = new_of[m.key]
                data[field] = new_part
                out.append(replace(m, data=data))
                continue
            if "cells" in m.data:
                cells = _cells(m.data["cells"], m)
                data[self.NEW_CELLS] = frozenset(cells - known_cells)
                known_cells |= cells
            elif "area" in m.data:
                polygon = _polygon(m.data["area"], m)
                new = polygon if known_area is None else polygon.difference(known_area)
                data[self.NEW_AREA] = new
                known_area = polygon if known_area is None else known_area.union(polygon)
            else:
                raise MessageError(
                    f"message {m.sender}/{m.seq}: localization needs data 'cells' or 'area'"
                )
            field = self.NEW_CELLS if self.NEW_CELLS in data else self.NEW_AREA
            new_of[m.key] = (field, data[field])
            out.append(replace(m, data=data))
        return out

    def __init__(self) -> None:
        self._observed: tuple[int, Any] = (0, None)  # (id of the state's raw area, parsed)

    def _parsed_observation(
        self, raw: Any, m: Message, parse: Callable[[Any, Message], Any]
    ) -> Any:
        # States repeat for every message in a piece: parse each observation once.
        if self._observed[0] != id(raw) or self._observed[1] is None:
            self._observed = (id(raw), (raw, parse(raw, m)))
        return self._observed[1][1]

    def values(
        self, messages: Sequence[Message], t: float, state: Mapping[str, Any] = EMPTY_STATE
    ) -> list[float]:
        observed_raw = state.get("observed_cells")
        if messages and observed_raw:
            try:
                new_cells = [m.data[self.NEW_CELLS] for m in messages]
            except KeyError:  # not prepared, or polygons
                return super().values(messages, t, state)
            observed = self._parsed_observation(observed_raw, messages[0], _cells)
            share = 1.0 / len(observed)
            return [len(new & observed) * share for new in new_cells]
        return super().values(messages, t, state)

    def value(self, m: Message, t: float, state: Mapping[str, Any] = EMPTY_STATE) -> float:
        if self.NEW_CELLS in m.data:
            observed_raw = state.get("observed_cells")
            if not observed_raw:
                return 0.0
            observed = self._parsed_observation(observed_raw, m, _cells)
            new: frozenset[tuple[int, int]] = m.data[self.NEW_CELLS]
            return len(new & observed) / len(observed)
        if self.NEW_AREA in m.data:
            area_raw = state.get("observed_area")
            if not area_raw:
                return 0.0
            observed_polygon = self._parsed_observation(area_raw, m, _polygon)
            if observed_polygon.area <= 0:
                return 0.0
            return float(m.data[self.NEW_AREA].intersection(observed_polygon).area) / float(
                observed_polygon.area
            )
        # Not prepared: the message alone (no redundancy to remove).
        return self.value(self.prepare([m])[0], t, state)


def _cells(raw: Any, m: Message) -> set[tuple[int, int]]:
    try:
        return {(int(c[0]), int(c[1])) for c in raw}
    except (TypeError, ValueError, IndexError):
        raise MessageError(
            f"message {m.sender}/{m.seq}: cells must be a list of [i, j] pairs"
        ) from None


def _polygon(raw: Any, m: Message) -> Any:
    from shapely.geometry import Polygon  # geometry only where polygons are used

    try:
        polygon = Polygon([(float(p[0]), float(p[1])) for p in raw])
    except (TypeError, ValueError, IndexError):
        raise MessageError(
            f"message {m.sender}/{m.seq}: area must be a list of [x, y] points"
        ) from None
    return polygon if polygon.is_valid else polygon.buffer(0)


def video_coefficients(s: float, f_max: float, f_1: float) -> tuple[float, float]:
    """(k, l) of eq. 4.28 from eq. 4.32 and 4.31."""
    denominator = 1.0 - f_1 / (2.0 * f_max * LN2)
    if denominator <= 0:
        raise SpecError(
            f"params f_1={f_1} and f_max={f_max}: expected f_1 < 2·f_max·ln 2 so that k > 0"
        )
    k = s / denominator
    l = 1.0 + math.log2(1.0 / f_max) * k  # noqa: E741 (thesis notation)
    return k, l


class _CappedLog(Shape):
    """φ(x) = max(0, min(1, l - k·log2 x)) of eq. 4.28."""

    def __init__(self, k: float, l: float) -> None:  # noqa: E741 (thesis notation)
        self.k, self.l = k, l
        self.x_cap = 2.0 ** ((l - 1.0) / k)  # = 1/f_max: younger frames are worth 1
        self.x_zero = 2.0 ** (l / k)  # age at which a frame is worth nothing
        self.x_knots = (self.x_cap, self.x_zero)
        self.kernel = (CAPPED_LOG, (k, l, self.x_cap, self.x_zero))

    def phi(self, x: float) -> float:
        if x <= self.x_cap:
            return 1.0
        if x >= self.x_zero:
            return 0.0
        return self.l - self.k * math.log2(x)

    def phi_array(self, x: FloatArray) -> FloatArray:
        with np.errstate(divide="ignore", invalid="ignore"):
            logarithmic = self.l - self.k * np.log2(np.maximum(x, self.x_cap))
        result: FloatArray = np.clip(logarithmic, 0.0, 1.0)
        return result

    def phi_integral(self, xa: float, xb: float) -> float:
        total = 0.0
        if xa < self.x_cap:
            end = min(xb, self.x_cap)
            total += end - xa
            xa = end
        xb = min(xb, self.x_zero)
        if xb > xa:
            total += self.l * (xb - xa) - (self.k / LN2) * (
                (xb * math.log(xb) - xb) - (xa * math.log(xa) - xa)
            )
        return total

    def phi_integral_array(self, xa: FloatArray, xb: FloatArray) -> FloatArray:
        capped = np.clip(np.minimum(xb, self.x_cap) - xa, 0.0, None)
        lo = np.maximum(xa, self.x_cap)
        hi = np.maximum(np.minimum(xb, self.x_zero), lo)
        with np.errstate(divide="ignore", invalid="ignore"):
            antiderivative_hi = hi * np.log(hi) - hi
            antiderivative_lo = lo * np.log(lo) - lo
        logarithmic = self.l * (hi - lo) - (self.k / LN2) * (antiderivative_hi - antiderivative_lo)
        result: FloatArray = capped + np.where(hi > lo, logarithmic, 0.0)
        return result

    def critical(self, s1: float, g1: float, s2: float, g2: float) -> tuple[float, ...]:
        # In the logarithmic part d/dt (s1·φ1 - s2·φ2) = 0 where s1/x1 = s2/x2.
        if s1 == s2:
            return ()
        return ((s1 * g2 - s2 * g1) / (s1 - s2),)


class Video(UtilityFunction):
    """Eq. 4.28: U = max(0, min(1, l - k·log2(t - t_gen))), scaled per message; ``max``.

    ``S`` is the utility lost per halving of the frame rate at ``f_1`` (Hz); ``f_max`` (Hz)
    is the rate that earns the full 1 per second. k and l follow from eq. 4.31/4.32.
    Subclasses multiply by a per-message :meth:`scale` (eq. 4.33, 7.1, 7.2); the base
    scales by the carried version's quality.
    """

    name = "video"

    def __init__(self, *, S: float = 0.1, f_max: float = 24.0, f_1: float = 12.0) -> None:
        self.S = _number("S", S)
        self.f_max = _number("f_max", f_max)
        self.f_1 = _number("f_1", f_1)
        self.k, self.l = video_coefficients(self.S, self.f_max, self.f_1)
        self._shape = _CappedLog(self.k, self.l)
        self.x_cap: float = self._shape.x_cap
        self.x_zero: float = self._shape.x_zero

    def scale(self, m: Message) -> float:
        return m.quality

    def shape(self, x: float) -> float:
        """The unscaled eq. 4.28 as a function of the age x = t - t_gen."""
        return self._shape.phi(x)

    def curve(self, m: Message) -> Curve:
        return ShapeCurve(m.t_gen, self.scale(m), self._shape)

    def family(self, messages: Sequence[Message]) -> Family:
        shape, scale = self._shape, self.scale
        return Family(
            CAPPED_LOG, (shape.k, shape.l, shape.x_cap, shape.x_zero),
            [scale(m) for m in messages], [0.0] * len(messages),
        )

    def params(self) -> dict[str, float]:
        return {"S": self.S, "f_max": self.f_max, "f_1": self.f_1}


class VideoVersions(Video):
    """Eq. 4.33: U_vid scaled by m.d / d, the carried image diagonal over the best one.

    The ratio is read from data ``diagonal`` and ``full_diagonal`` when both are present,
    otherwise from the carried version's ``quality``.
    """

    name = "video_versions"

    def scale(self, m: Message) -> float:
        if "diagonal" in m.data and "full_diagonal" in m.data:
            d = _float_field(m, "diagonal")
            full = _float_field(m, "full_diagonal")
            if full <= 0 or not 0 <= d <= full:
                raise MessageError(
                    f"message {m.sender}/{m.seq}: expected 0 <= diagonal <= full_diagonal"
                )
            return d / full
        return m.quality


class RedImage(Video):
    """Eq. 7.1: U_vid·(1 + α·red), red = share of red pixels (0..1); times the version quality."""

    name = "red_image"

    def __init__(
        self,
        *,
        alpha: float = 10.0,
        S: float = 0.1,
        f_max: float = 24.0,
        f_1: float = 12.0,
    ) -> None:
        super().__init__(S=S, f_max=f_max, f_1=f_1)
        self.alpha = _number("alpha", alpha, allow_zero=True)

    def scale(self, m: Message) -> float:
        red = _float_field(m, "red")
        if not 0.0 <= red <= 1.0:
            raise MessageError(f"message {m.sender}/{m.seq}: red must be in [0, 1], got {red}")
        return m.quality * (1.0 + self.alpha * red)

    def params(self) -> dict[str, float]:
        return {"alpha": self.alpha, **super().params()}


class ObjectImage(RedImage):
    """Eq. 7.2: U_vid·(1 + α) if the image shows the object to reconstruct, else U_vid."""

    name = "object_image"

    def scale(self, m: Message) -> float:
        seen = _field(m, "object")
        if not isinstance(seen, bool):
            raise MessageError(f"message {m.sender}/{m.seq}: object must be true or false")
        return m.quality * (1.0 + self.alpha if seen else 1.0)


class External(UtilityFunction):
    """Eq. 4.34: U = V(m)·δ(t - t_rcv), a value per message counted once at reception.

    V(m) is the data field ``value`` (times the version quality); only ``sum`` aggregates it.
    """

    name = "external"
    impulse = True
    aggregations = frozenset({"sum"})

    def value(self, m: Message, t: float, state: Mapping[str, Any] = EMPTY_STATE) -> float:
        return 0.0  # the impulse has no finite value; see impulse_value

    def integral(self, m: Message, a: float, b: float) -> float:
        return 0.0

    def impulse_value(self, m: Message) -> float:
        return _float_field(m, "value") * m.quality


FUNCTIONS: dict[str, Callable[..., UtilityFunction]] = {
    cls.name: cls
    for cls in (
        Battery,
        Position,
        Status,
        StatusPoisson,
        StatusChange,
        Objective,
        Localization,
        Video,
        VideoVersions,
        External,
        RedImage,
        ObjectImage,
        Linear,
    )
}


def make_function(name: str, params: Mapping[str, Any]) -> UtilityFunction:
    """Build a utility function by its spec name; errors name the offending parameter."""
    try:
        factory = FUNCTIONS[name]
    except KeyError:
        raise SpecError(
            f"unknown utility {name!r}; expected one of {', '.join(sorted(FUNCTIONS))}"
        ) from None
    try:
        return factory(**params)
    except TypeError as exc:
        raise SpecError(f"utility {name!r}: bad params {dict(params)!r} ({exc})") from None
