"""What a frame scorer is: ``score(image_bgr) -> dict`` plus, optionally, its settings table.

A scorer plugs in as a :class:`ScorerPlugin` in ``companion.scoring.SCORERS``: ``build``
makes the scorer from its settings (None: the defaults) and ``read_settings`` reads the
settings from the config's ``[scoring.NAME]`` table (a :class:`SettingsTable`, whose errors
name the file and key).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy.typing as npt

__all__ = ["Image", "Scorer", "ScorerPlugin", "ScorerUnavailable", "SettingsTable", "is_number",
           "no_settings"]

Image = npt.NDArray[Any]


class ScorerUnavailable(RuntimeError):
    """The scorer cannot run with this OpenCV build; the text says what is missing."""


@runtime_checkable
class Scorer(Protocol):
    name: str

    def score(self, image: Image) -> dict[str, Any]:
        """Features of one BGR frame (uint8, HxWx3)."""
        ...


class SettingsTable(Protocol):
    """Typed reads from one config table (``companion.config``); a bad value raises the
    config's error naming ``file: scoring.NAME.key`` and what was expected."""

    def get(self, name: str, default: Any, expected: str, ok: Callable[[Any], bool]) -> Any:
        ...

    def integer(self, name: str, default: int, *, low: int, high: int) -> int: ...

    def number(self, name: str, default: float, *, minimum: float = 0.0,
               strict: bool = True) -> float: ...

    def boolean(self, name: str, default: bool) -> bool: ...


def no_settings(table: SettingsTable) -> None:
    """For a scorer without settings: its table, if any, must be empty."""
    return None


@dataclass(frozen=True, slots=True)
class ScorerPlugin:
    """How the app makes one kind of scorer: ``build(settings or None)``, ``read_settings``."""

    build: Callable[[Any], Scorer]
    read_settings: Callable[[SettingsTable], Any] = no_settings


def is_number(value: Any) -> bool:
    """A finite int or float (not a bool): what a numeric setting may be."""
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(
        value)
