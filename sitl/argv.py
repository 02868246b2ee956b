"""Command-line values that start with a minus sign (``--home -35.36,149.16``)."""

from __future__ import annotations

import re

__all__ = ["attach_negative_values"]

_NUMBERS = re.compile(r"-\d[\d.,eE+-]*")


def attach_negative_values(argv: list[str], flags: tuple[str, ...]) -> list[str]:
    """``FLAG -1.5,2`` as ``FLAG=-1.5,2``: argparse takes a value like ``-35.36,149.16``
    (it has commas, so it is no negative number to argparse) for an unknown option and fails
    with "expected one argument", though the southern and western hemispheres need it
    (ArduPilot's own SITL home, ``-35.363261,149.165230,584,353``, is one)."""
    out: list[str] = []
    i = 0
    while i < len(argv):
        if argv[i] in flags and i + 1 < len(argv) and _NUMBERS.fullmatch(argv[i + 1]):
            out.append(f"{argv[i]}={argv[i + 1]}")
            i += 2
            continue
        out.append(argv[i])
        i += 1
    return out
