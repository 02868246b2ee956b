"""Old import path of :mod:`companion.middleware.constraints.base` (kept for importers)."""

from companion.middleware.constraints.base import ConstantConstraint, GoodputConstraint
from companion.middleware.constraints.linkstats import LinkSample

__all__ = ["ConstantConstraint", "GoodputConstraint", "LinkSample"]
