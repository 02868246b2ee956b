"""U(m, t) of one received message as a function of time alone, with the calculus attached.

A time-only utility function turns each message into a :class:`Curve` once (reading and
checking its data a single time); the exact evaluator then works on curves: closed-form
integrals, knots where a curve is not smooth, and exact crossings between two curves.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod

import numpy as np
from numpy.typing import NDArray

from utility_specs import _envelope

# The root finder's steps as plain Python (the same source the compiled kernels use): called
# from Python, numba's dispatch would cost more than the step itself.
falsi_point = getattr(_envelope.falsi_point, "py_func", _envelope.falsi_point)
falsi_update = getattr(_envelope.falsi_update, "py_func", _envelope.falsi_update)

FloatArray = NDArray[np.float64]

__all__ = ["Curve", "EndedCurve", "LineCurve", "Shape", "ShapeCurve", "StepCurve"]

INF = math.inf


class Curve(ABC):
    """One message's utility over time (valid from its reception on), non-increasing."""

    __slots__ = ("expiry", "t_gen")

    t_gen: float
    expiry: float
    """From this time on the value is 0 for good (inf if never)."""
    evict_bounded: bool = False
    """Worth proving, at admission, that a newer curve stays above an older one until the
    older expires (so the older can go). Lines need it: a newer, steeper battery line never
    dominates outright. Shapes do not: equal scales dominate outright, and the scales left
    form a short staircase."""

    @abstractmethod
    def value(self, t: float) -> float: ...

    @abstractmethod
    def integral(self, a: float, b: float) -> float:
        """Exact ∫_a^b value(t) dt (0 when b <= a)."""

    def knots(self) -> tuple[float, ...]:
        """Times where the value is not smooth."""
        return ()

    def critical_points(self, other: Curve) -> tuple[float, ...]:
        """Times where d/dt (self - other) may vanish; between these and the knots of both,
        the difference is monotone."""
        return ()

    def dominates(self, other: Curve) -> bool:
        """A cheap sufficient test: self >= other at every time both are defined."""
        return False

    def first_above(
        self,
        other: Curve,
        lo: float,
        hi: float,
        *,
        self_lo: float | None = None,
        self_hi: float | None = None,
    ) -> float | None:
        """First time in [lo, hi] at which ``other`` is strictly above ``self``, or None.

        The difference is monotone between knots and critical points, so a sign change on a
        segment is its only root; :meth:`_root` finds it. ``self_lo``/``self_hi`` are
        self's values at ``lo``/``hi`` when the caller already has them (hot loops).
        """
        mine_lo = self.value(lo) if self_lo is None else self_lo
        other_lo = other.value(lo)
        if other_lo - mine_lo > 1e-12 * (1.0 + abs(mine_lo)):
            return lo
        # Every curve here is non-increasing in time: if ``other`` starts at or below where
        # ``self`` ends, it cannot rise above it in between.
        if other_lo <= (self.value(hi) if self_hi is None else self_hi):
            return None
        splits = [
            p for p in (*self.knots(), *other.knots(), *self.critical_points(other)) if lo < p < hi
        ]
        splits.sort()
        previous = lo
        for t in (*splits, hi):
            if self._gap(other, t) > 0:
                return self._root(other, previous, t)
            previous = t
        return None

    def _gap(self, other: Curve, t: float) -> float:
        mine = self.value(t)
        return other.value(t) - mine - 1e-12 * (1.0 + abs(mine))

    def _root(self, other: Curve, left: float, right: float) -> float:
        """Smallest t in (left, right] with gap > 0, given gap(left) <= 0 < gap(right):
        the package's one root finder (:func:`utility_specs._envelope.falsi_point`)."""
        g_left, g_right = self._gap(other, left), self._gap(other, right)
        side = 0
        for _ in range(200):
            t = falsi_point(left, right, g_left, g_right)
            if t != t:
                break
            left, right, g_left, g_right, side = falsi_update(
                left, right, g_left, g_right, side, t, self._gap(other, t)
            )
        return right


class LineCurve(Curve):
    """max(0, u0 - c·(t - t_gen)): battery (eq. 4.9) and the study's linear utility."""

    __slots__ = ("c", "u0")
    evict_bounded = True

    def __init__(self, t_gen: float, u0: float, c: float) -> None:
        self.t_gen, self.u0, self.c = t_gen, u0, c
        if u0 <= 0:
            self.expiry = t_gen
        else:
            self.expiry = t_gen + u0 / c if c > 0 else INF

    def value(self, t: float) -> float:
        v = self.u0 - self.c * (t - self.t_gen)
        return v if v > 0.0 else 0.0

    def integral(self, a: float, b: float) -> float:
        if b > self.expiry:
            b = self.expiry
        if b <= a:
            return 0.0
        xa, xb = a - self.t_gen, b - self.t_gen
        return self.u0 * (xb - xa) - 0.5 * self.c * (xb * xb - xa * xa)

    def knots(self) -> tuple[float, ...]:
        return (self.expiry,) if self.expiry < INF else ()

    def first_above(
        self,
        other: Curve,
        lo: float,
        hi: float,
        *,
        self_lo: float | None = None,
        self_hi: float | None = None,
    ) -> float | None:
        """Closed form for two lines: linear until the first expiry, then one of them is 0."""
        if not isinstance(other, LineCurve):
            return super().first_above(other, lo, hi, self_lo=self_lo, self_hi=self_hi)
        mine_lo = self.value(lo) if self_lo is None else self_lo
        gap_lo = other.value(lo) - mine_lo
        if gap_lo > 1e-12 * (1.0 + abs(mine_lo)):
            return lo
        first_expiry = min(self.expiry, other.expiry)
        end = min(first_expiry, hi)
        if end > lo:
            mine_end = self.u0 - self.c * (end - self.t_gen)
            gap_end = other.u0 - other.c * (end - other.t_gen) - mine_end
            if gap_end > 1e-12 * (1.0 + abs(mine_end)):
                return lo + (end - lo) * (-gap_lo) / (gap_end - gap_lo)
        if first_expiry < hi and self.expiry < other.expiry:
            return max(lo, first_expiry)  # self reached 0, other is still above it
        return None

    def dominates(self, other: Curve) -> bool:
        if not isinstance(other, LineCurve):
            return False
        t0 = max(self.t_gen, other.t_gen)
        return self.c <= other.c and self.u0 - self.c * (t0 - self.t_gen) >= other.u0 - other.c * (
            t0 - other.t_gen
        )


class Shape(ABC):
    """φ(x) of a family whose messages differ only by generation time and a scale."""

    @abstractmethod
    def phi(self, x: float) -> float: ...

    @abstractmethod
    def phi_integral(self, xa: float, xb: float) -> float: ...

    x_knots: tuple[float, ...] = ()
    x_zero: float = INF
    kernel: tuple[int, tuple[float, ...]] | None = None
    """The family kind and shape parameters of :mod:`utility_specs._envelope`'s compiled
    kernels (None: only the general curve path knows this shape)."""

    @abstractmethod
    def phi_integral_array(self, xa: FloatArray, xb: FloatArray) -> FloatArray:
        """:meth:`phi_integral` over arrays of intervals (xa <= xb elementwise)."""

    @abstractmethod
    def phi_array(self, x: FloatArray) -> FloatArray:
        """:meth:`phi` over an array of ages."""

    def critical(self, s1: float, g1: float, s2: float, g2: float) -> tuple[float, ...]:
        return ()


class ShapeCurve(Curve):
    """scale · φ(t - t_gen): position, status_poisson and the video family."""

    __slots__ = ("phi", "scale", "shape")

    def __init__(self, t_gen: float, scale: float, shape: Shape) -> None:
        self.t_gen, self.scale, self.shape = t_gen, scale, shape
        self.phi = shape.phi
        self.expiry = t_gen + shape.x_zero if scale > 0 else t_gen

    def value(self, t: float) -> float:
        return self.scale * self.phi(t - self.t_gen)

    def same_family(self, other: ShapeCurve) -> bool:
        return other.shape is self.shape and other.scale == self.scale

    def integral(self, a: float, b: float) -> float:
        if b > self.expiry:
            b = self.expiry
        if b <= a:
            return 0.0
        return self.scale * self.shape.phi_integral(a - self.t_gen, b - self.t_gen)

    def knots(self) -> tuple[float, ...]:
        g = self.t_gen
        return tuple([g + x for x in self.shape.x_knots])

    def critical_points(self, other: Curve) -> tuple[float, ...]:
        if not isinstance(other, ShapeCurve) or other.shape is not self.shape:
            return ()
        return self.shape.critical(self.scale, self.t_gen, other.scale, other.t_gen)

    def dominates(self, other: Curve) -> bool:
        if isinstance(other, EndedCurve):  # an ended curve is never above its inner one
            return other.expiry <= self.t_gen or self.dominates(other.inner)
        # φ is non-increasing, so the newer of two equally shaped curves is never lower.
        return (
            isinstance(other, ShapeCurve)
            and other.shape is self.shape
            and self.t_gen >= other.t_gen
            and self.scale >= other.scale
        )


class StepCurve(Curve):
    """1 once received (eq. 4.14)."""

    __slots__ = ()

    def __init__(self, t_gen: float) -> None:
        self.t_gen, self.expiry = t_gen, INF

    def value(self, t: float) -> float:
        return 1.0

    def integral(self, a: float, b: float) -> float:
        return b - a if b > a else 0.0

    def dominates(self, other: Curve) -> bool:
        if isinstance(other, EndedCurve):
            return other.expiry <= self.t_gen or self.dominates(other.inner)
        return isinstance(other, StepCurve)


class EndedCurve(Curve):
    """``inner`` until ``until``, 0 from then on: a status whose state has ended."""

    __slots__ = ("inner", "until")

    def __init__(self, inner: Curve, until: float) -> None:
        self.inner, self.until, self.t_gen = inner, until, inner.t_gen
        self.expiry = min(inner.expiry, until)

    def value(self, t: float) -> float:
        return self.inner.value(t) if t < self.until else 0.0

    def integral(self, a: float, b: float) -> float:
        return self.inner.integral(a, min(b, self.until))

    def knots(self) -> tuple[float, ...]:
        return (*self.inner.knots(), self.until)

    def critical_points(self, other: Curve) -> tuple[float, ...]:
        return self.inner.critical_points(other.inner if isinstance(other, EndedCurve) else other)

    def dominates(self, other: Curve) -> bool:
        if other.expiry <= self.t_gen:  # other is 0 before self can have arrived
            return True
        if isinstance(other, EndedCurve):
            return self.until >= other.until and self.inner.dominates(other.inner)
        return False
