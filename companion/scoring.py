"""Frame utility features: what in a frame makes it worth the air time (thesis eq. 7.1, 7.2).

Every scorer implements :class:`Scorer`: ``score(image_bgr) -> dict`` of the few fields the
utility functions read (``red`` in 0..1 for eq. 7.1, ``object`` for eq. 7.2). Scorers are
plain synchronous code; the app runs them in an executor, never on the event loop.

The registry :data:`SCORERS` maps the names ``[scoring] scorers`` may list to a
:class:`ScorerPlugin`; the config validates names and ``[scoring.NAME]`` tables through it.
Built in (one module each under ``companion/scorers/``, no downloaded weights):

* ``red_share`` (:class:`RedShareScorer`): share of red pixels, eq. 7.1's ``m.red``.
* ``aruco`` (:class:`ArucoScorer`): a target ArUco marker is in view, eq. 7.2's ``object``.
* ``hog_people`` (:class:`HogPeopleScorer`): OpenCV's built-in HOG+SVM people detector.

A new scorer is one module plus one line: ``register_scorer("name", ScorerPlugin(...))``
(docs/architecture.md, "Adding a scorer").
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from companion.scorers import aruco, hog_people, red_share
from companion.scorers.aruco import ArucoScorer, ArucoSettings
from companion.scorers.base import Image, Scorer, ScorerPlugin, ScorerUnavailable, SettingsTable
from companion.scorers.hog_people import HOG_FIX, HogPeopleScorer, HogSettings
from companion.scorers.red_share import RedShareScorer, RedShareSettings

__all__ = [
    "HOG_FIX",
    "SCORERS",
    "ArucoScorer",
    "ArucoSettings",
    "CompositeScorer",
    "HogPeopleScorer",
    "HogSettings",
    "RedShareScorer",
    "RedShareSettings",
    "Scorer",
    "ScorerPlugin",
    "ScorerUnavailable",
    "SettingsTable",
    "make_scorer",
    "register_scorer",
    "scorer_names",
]

SCORERS: dict[str, ScorerPlugin] = {
    "red_share": red_share.PLUGIN,
    "aruco": aruco.PLUGIN,
    "hog_people": hog_people.PLUGIN,
}
"""Scorer name -> how to build it and read its settings, in the order ``check`` lists them."""


def register_scorer(name: str, plugin: ScorerPlugin) -> None:
    """Make ``name`` a scorer the configuration may list (a second one of a name is refused)."""
    if name in SCORERS and SCORERS[name] is not plugin:
        raise ValueError(f"a scorer named {name!r} is registered already")
    SCORERS[name] = plugin


def scorer_names() -> list[str]:
    return list(SCORERS)


@dataclass(kw_only=True)
class CompositeScorer:
    """Runs several scorers; ``object`` is true when any of them says so."""

    scorers: Sequence[Scorer] = field(default_factory=list)
    name: str = "composite"

    def score(self, image: Image) -> dict[str, Any]:
        out: dict[str, Any] = {}
        found = False
        for scorer in self.scorers:
            result = scorer.score(image)
            found = found or bool(result.get("object", False))
            out.update(result)
        out["object"] = found
        return out


def make_scorer(names: Sequence[str], settings: Mapping[str, Any] | None = None
                ) -> CompositeScorer:
    """The scorers named in the configuration, in order, each built from ``settings[name]``
    (its defaults when absent). Raises ValueError on an unknown name, ScorerUnavailable when
    this OpenCV lacks a detector."""
    settings = settings or {}
    built: list[Scorer] = []
    for name in names:
        plugin = SCORERS.get(name)
        if plugin is None:
            raise ValueError(f"unknown scorer {name!r} (known: {', '.join(SCORERS)})")
        built.append(plugin.build(settings.get(name)))
    return CompositeScorer(scorers=built)
