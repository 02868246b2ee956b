"""Old import path of :mod:`companion.middleware.constraints.adaptive` (kept for importers)."""

from companion.middleware.constraints.adaptive import AdaptiveConstraint, LinkStatsConstraint

__all__ = ["AdaptiveConstraint", "LinkStatsConstraint"]
