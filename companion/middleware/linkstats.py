"""Old import path of :mod:`companion.middleware.constraints.linkstats` (kept for importers)."""

from companion.middleware.constraints.linkstats import (
    ClockOffset,
    ClockOffsetEstimator,
    LinkSample,
    LinkStats,
    RoundTrip,
    WindowStats,
)

__all__ = ["ClockOffset", "ClockOffsetEstimator", "LinkSample", "LinkStats", "RoundTrip",
           "WindowStats"]
