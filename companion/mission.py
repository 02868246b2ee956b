"""The mission window of one drone: ``idle`` until ``start``, ``running``, ``ended`` after ``end``.

Shared by the services that send (nothing but status goes out outside the window) and changed
only by the command executor.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["MissionWindow"]


@dataclass(slots=True)
class MissionWindow:
    state: str = "running"
    """``idle``, ``running`` or ``ended``."""

    @property
    def running(self) -> bool:
        return self.state == "running"
