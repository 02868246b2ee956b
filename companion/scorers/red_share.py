"""``red_share``: the share of red pixels in a frame, ``m.red`` of eq. 7.1.

Red wraps around hue 0 in OpenCV's HSV (H in 0..179), so two hue ranges are thresholded and
OR-ed; a morphological opening removes speckle noise. Runs on a downscaled copy (``scale``)
to stay well under 5 ms per 640x480.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from companion.scorers.base import Image, ScorerPlugin, SettingsTable, is_number

__all__ = ["PLUGIN", "RedShareScorer", "RedShareSettings", "read_settings"]

HSV = tuple[int, int, int]


@dataclass(frozen=True, slots=True, kw_only=True)
class RedShareSettings:
    """HSV thresholds (OpenCV ranges: H 0..179, S and V 0..255) of the two red hue bands."""

    lower1: HSV = (0, 100, 70)
    upper1: HSV = (10, 255, 255)
    lower2: HSV = (170, 100, 70)
    upper2: HSV = (179, 255, 255)
    kernel_px: int = 3
    """Side of the square opening kernel (pixels of the scaled image); 0 or 1 disables it."""
    scale: float = 0.5
    """Downscale factor before thresholding (1.0 = full resolution)."""

    def __post_init__(self) -> None:
        for name in ("lower1", "upper1", "lower2", "upper2"):
            value = getattr(self, name)
            if len(value) != 3 or not (0 <= value[0] <= 179) or not all(
                    0 <= v <= 255 for v in value[1:]):
                raise ValueError(f"{name} must be (H 0..179, S 0..255, V 0..255), got {value}")
        if not 0 < self.scale <= 1:
            raise ValueError(f"scale must be in (0, 1], got {self.scale}")
        if self.kernel_px < 0:
            raise ValueError(f"kernel_px must be >= 0, got {self.kernel_px}")


class RedShareScorer:
    """``red``: fraction of pixels in either red hue band after a morphological opening."""

    name = "red_share"

    def __init__(self, settings: RedShareSettings | None = None) -> None:
        self.settings = settings or RedShareSettings()
        s = self.settings
        self._bounds = [
            (np.array(s.lower1, np.uint8), np.array(s.upper1, np.uint8)),
            (np.array(s.lower2, np.uint8), np.array(s.upper2, np.uint8)),
        ]
        self._kernel = (np.ones((s.kernel_px, s.kernel_px), np.uint8)
                        if s.kernel_px > 1 else None)

    def mask(self, image: Image) -> Image:
        """The cleaned red mask (255 = red) at the scaled resolution."""
        if self.settings.scale != 1.0:
            image = cv2.resize(image, None, fx=self.settings.scale, fy=self.settings.scale,
                               interpolation=cv2.INTER_NEAREST)
        hsv = cv2.cvtColor(image, cv2.COLOR_BGR2HSV)
        (lo1, hi1), (lo2, hi2) = self._bounds
        mask = cv2.bitwise_or(cv2.inRange(hsv, lo1, hi1), cv2.inRange(hsv, lo2, hi2))
        if self._kernel is not None:
            mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, self._kernel)
        return mask

    def score(self, image: Image) -> dict[str, Any]:
        mask = self.mask(image)
        return {"red": float(cv2.countNonZero(mask)) / float(mask.size)}


def _hsv(t: SettingsTable, name: str, default: HSV) -> HSV:
    value = t.get(name, default, "[H 0..179, S 0..255, V 0..255]",
                  lambda v: isinstance(v, list | tuple) and len(v) == 3
                  and all(isinstance(x, int) and not isinstance(x, bool) for x in v)
                  and 0 <= v[0] <= 179 and all(0 <= x <= 255 for x in v[1:]))
    return (int(value[0]), int(value[1]), int(value[2]))


def read_settings(t: SettingsTable) -> RedShareSettings:
    """``[scoring.red_share]``: the two HSV bands, ``kernel_px`` and ``scale``."""
    return RedShareSettings(
        lower1=_hsv(t, "lower1", (0, 100, 70)), upper1=_hsv(t, "upper1", (10, 255, 255)),
        lower2=_hsv(t, "lower2", (170, 100, 70)), upper2=_hsv(t, "upper2", (179, 255, 255)),
        kernel_px=t.integer("kernel_px", 3, low=0, high=51),
        scale=t.get("scale", 0.5, "a number in (0, 1]", lambda v: is_number(v) and 0 < v <= 1),
    )


PLUGIN = ScorerPlugin(RedShareScorer, read_settings)
