"""Old import path of :mod:`companion.middleware.constraints.aimd` (kept for importers)."""

from companion.middleware.constraints.aimd import AimdConstraint

__all__ = ["AimdConstraint"]
