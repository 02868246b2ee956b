"""Utility weight of a received image, for the dashboard's red border and gallery order.

The weight is the factor eq. 7.1 / 7.2 multiply the video utility U_vid (eq. 4.28) with,
times the carried version's quality (eq. 4.33): ``q·(1 + α·red)`` for red-share images
(eq. 7.1) and ``q·(1 + α)`` for images showing the object to reconstruct (eq. 7.2, ``q``
otherwise). U_vid depends on the stream's frame times, not on the image, so the factor alone
ranks images. With a mission spec, each message type follows its own utility function
(``red_image`` or ``object_image``) and α, and the plain video types (``video``,
``video_versions``) weigh only their quality; without a spec (or for a type it does not
know), an ``object`` flag selects eq. 7.2, else a ``red`` share eq. 7.1, with α from the
ground-station config. The flags are read leniently here (the dashboard never rejects an
image); the evaluator's functions check them strictly.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

__all__ = ["ImageUtility", "image_utility_from_spec"]

Kind = Literal["red", "object", "plain"]


def _red_share(data: Mapping[str, Any]) -> float | None:
    red = data.get("red")
    if isinstance(red, int | float) and not isinstance(red, bool) and math.isfinite(red):
        return min(max(float(red), 0.0), 1.0)
    return None


def _has_object(data: Mapping[str, Any]) -> bool:
    obj = data.get("object")
    return obj is True or (isinstance(obj, int | float) and not isinstance(obj, bool) and obj > 0)


@dataclass(frozen=True, slots=True, kw_only=True)
class ImageUtility:
    """Scores images by eq. 7.1 (red share) or eq. 7.2 (object flag)."""

    alpha: float = 10.0
    by_type: Mapping[str, tuple[Kind, float]] = field(default_factory=dict)
    """Per message type, the spec's utility kind and its α."""

    def weight(self, message_type: str, data: Mapping[str, Any], *, quality: float = 1.0) -> float:
        rule = self.by_type.get(message_type)
        if rule is not None:
            kind, alpha = rule
            if kind == "plain":
                return quality  # eq. 4.28 / 4.33: neither red nor objects count
            if kind == "object":
                return quality * (1.0 + alpha if _has_object(data) else 1.0)  # eq. 7.2
            return quality * (1.0 + alpha * (_red_share(data) or 0.0))  # eq. 7.1
        if _has_object(data):
            return quality * (1.0 + self.alpha)  # eq. 7.2
        red = _red_share(data)
        if red is not None:
            return quality * (1.0 + self.alpha * red)  # eq. 7.1
        return quality


    def max_gain(self) -> float:
        """Largest α any image type can add over a plain image (1 + α is its top weight).

        With a spec, over its ``red_image``/``object_image`` types (0 when it has only plain
        video); without one, the configured α."""
        if not self.by_type:
            return self.alpha
        return max((alpha for kind, alpha in self.by_type.values() if kind != "plain"),
                   default=0.0)

    def high_threshold(self, fraction: float) -> float | None:
        """Weight from which an image counts as high utility (red border): a plain image
        plus ``fraction`` of the largest gain, e.g. 1 + 0.1·10 = 2.0 for α = 10, the weight
        of a 10 % red share. None when no image type can gain (nothing is ever high)."""
        gain = self.max_gain()
        return 1.0 + fraction * gain if gain > 0 else None


def image_utility_from_spec(spec_path: Path | None, *, alpha: float) -> ImageUtility:
    """α and rule per type from a mission spec's ``red_image``/``object_image`` types."""
    if spec_path is None:
        return ImageUtility(alpha=alpha)
    from utility_specs.files import load_spec

    spec = load_spec(spec_path)
    rules: dict[str, tuple[Kind, float]] = {}
    for name, info_type in spec.types.items():
        function = info_type.utility
        if function.name == "red_image":
            rules[name] = ("red", float(getattr(function, "alpha", alpha)))
        elif function.name == "object_image":
            rules[name] = ("object", float(getattr(function, "alpha", alpha)))
        elif function.name in ("video", "video_versions"):
            rules[name] = ("plain", 0.0)
    return ImageUtility(alpha=alpha, by_type=rules)
