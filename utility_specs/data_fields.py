"""Reading numbers out of a message's ``data`` (telemetry and status maps from JSON).

Senders spell a field several ways (``lat_deg`` or ``lat``) and JSON carries booleans,
NaN and strings where a number is expected; every reader of telemetry (the peer table,
the dashboard, the MAVLink mirror) wants the first finite number among the spellings.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, TypeGuard

__all__ = ["first_number", "is_number"]


def is_number(value: object) -> TypeGuard[int | float]:
    """A finite int or float; ``True``/``False`` are not numbers here."""
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(
        value)


def first_number(data: Mapping[str, Any], *keys: str) -> float | None:
    """The first of ``keys`` whose value is a finite number, as a float; None if none is."""
    for key in keys:
        value = data.get(key)
        if is_number(value):
            return float(value)
    return None
