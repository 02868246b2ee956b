"""Utility weight of a received image, for the dashboard's red border and gallery order.

The weight is the per-message scale of the mission spec's own video utility function
(``Video.scale`` in :mod:`utility_specs.functions`): the factor eq. 7.1 / 7.2 / 4.33 multiply
U_vid (eq. 4.28) with. U_vid depends on the stream's frame times, not on the image, so the
factor alone ranks images. There is no second copy of the equations here: a spec type whose
function is any :class:`~utility_specs.functions.Video` (``video``, ``video_versions``,
``red_image``, ``object_image``, or a new one) is weighed by that function.

Without a spec (or for a type the spec does not make a video), the ``object`` flag selects
``object_image`` and a ``red`` share ``red_image``, both with α from the ground-station
config. The dashboard never rejects an image: one its function refuses (a flag missing or
out of range) weighs its version quality alone, as a plain frame.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from utility_specs.errors import MessageError
from utility_specs.functions import ObjectImage, RedImage, Video
from utility_specs.message import Message

__all__ = ["ImageUtility", "image_utility_from_spec"]


def _gain(function: Video) -> float:
    """What the function can add over a plain frame (its α; 0 for plain video)."""
    return float(function.params().get("alpha", 0.0))


@dataclass(frozen=True, slots=True, kw_only=True)
class ImageUtility:
    """Scores images with the spec's video utility functions (eq. 7.1, 7.2, 4.33)."""

    alpha: float = 10.0
    """α of the fallback rules (no spec, or a type it does not know)."""
    by_type: Mapping[str, Video] = field(default_factory=dict)
    """Per message type, the spec's utility function (video kinds only)."""
    _red: RedImage = field(init=False, repr=False, compare=False)
    _object: ObjectImage = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_red", RedImage(alpha=self.alpha))
        object.__setattr__(self, "_object", ObjectImage(alpha=self.alpha))

    def function_for(self, message: Message) -> Video | None:
        function = self.by_type.get(message.type)
        if function is not None:
            return function
        data = message.data
        if data.get("object") is True:
            return self._object
        red = data.get("red")
        if isinstance(red, int | float) and not isinstance(red, bool) and math.isfinite(red):
            return self._red
        return None

    def weight(self, message: Message) -> float:
        """The image's weight: its function's scale, or its quality when it has none."""
        function = self.function_for(message)
        if function is None:
            return message.quality
        try:
            return function.scale(message)
        except MessageError:  # the dashboard never rejects an image: weigh it plain
            return message.quality

    def max_gain(self) -> float:
        """Largest α any image type can add over a plain image (1 + α is its top weight).

        With a spec, over its video types (0 when it has only plain video); without one,
        the configured α."""
        if not self.by_type:
            return self.alpha
        return max((_gain(function) for function in self.by_type.values()), default=0.0)

    def high_threshold(self, fraction: float) -> float | None:
        """Weight from which an image counts as high utility (red border): a plain image
        plus ``fraction`` of the largest gain, e.g. 1 + 0.1·10 = 2.0 for α = 10, the weight
        of a 10 % red share. None when no image type can gain (nothing is ever high)."""
        gain = self.max_gain()
        return 1.0 + fraction * gain if gain > 0 else None


def image_utility_from_spec(spec_path: Path | None, *, alpha: float) -> ImageUtility:
    """The spec's video utility function per type (α comes from each function)."""
    if spec_path is None:
        return ImageUtility(alpha=alpha)
    from utility_specs.files import load_spec

    spec = load_spec(spec_path)
    functions = {
        name: info_type.utility
        for name, info_type in spec.types.items()
        if isinstance(info_type.utility, Video)
    }
    return ImageUtility(alpha=alpha, by_type=functions)
