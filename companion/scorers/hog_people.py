"""``hog_people``: people in the frame, by OpenCV's built-in HOG+SVM people detector.

The weights are compiled into OpenCV: nothing to download. OpenCV 4.x ships the detector;
OpenCV 5 moved it to opencv-contrib, and without it the scorer raises
:class:`ScorerUnavailable` naming the fix (an ``opencv-python-headless<5`` build).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from companion.scorers.base import Image, ScorerPlugin, ScorerUnavailable, SettingsTable, is_number

__all__ = ["HOG_FIX", "PLUGIN", "HogPeopleScorer", "HogSettings", "read_settings"]


@dataclass(frozen=True, slots=True, kw_only=True)
class HogSettings:
    """Knobs of OpenCV's HOG+SVM people detector (Dalal & Triggs 64x128 window)."""

    scale: float = 0.5
    """Detect on a downscaled copy: ~8x faster; finds people from ~160 px tall in the frame
    (measured on silhouettes; from <= 100 px at 1.0, the 64x128 window's own limit)."""
    win_stride_px: int = 8
    """Step of the sliding window (pixels of the scaled image); a multiple of the 8 px cell."""
    pyramid_scale: float = 1.05
    """Ratio between image-pyramid levels (OpenCV's default); larger is faster, coarser."""
    min_weight: float = 0.5
    """SVM margin a detection needs to count as a person (0 keeps every window OpenCV keeps)."""

    def __post_init__(self) -> None:
        if not 0 < self.scale <= 1:
            raise ValueError(f"scale must be in (0, 1], got {self.scale}")
        if self.win_stride_px < 1 or self.win_stride_px % 8:
            raise ValueError(f"win_stride_px must be a positive multiple of 8 (the HOG cell), "
                             f"got {self.win_stride_px}")
        if not self.pyramid_scale > 1:
            raise ValueError(f"pyramid_scale must be > 1, got {self.pyramid_scale}")
        if self.min_weight < 0:
            raise ValueError(f"min_weight must be >= 0, got {self.min_weight}")


HOG_FIX = ('install an OpenCV 4 build: pip install "opencv-python-headless>=4.10,<5" '
           "(OpenCV 5 moved HOGDescriptor to opencv-contrib's xobjdetect), "
           "or use the 'aruco' or 'red_share' scorer")


def _hog_class() -> Any:
    """``cv2.HOGDescriptor`` (OpenCV 4), else the contrib build's ``cv2.xobjdetect`` one."""
    found = getattr(cv2, "HOGDescriptor", None)
    if found is None:
        found = getattr(getattr(cv2, "xobjdetect", None), "HOGDescriptor", None)
    return found


class HogPeopleScorer:
    """``people``: persons found by OpenCV's default HOG+SVM people detector; ``object``: any;
    ``people_score``: the largest SVM margin (0.0 when none), a confidence for eq. 7.2-style
    utilities. Needs an OpenCV build with ``HOGDescriptor`` (4.x, or 5.x with contrib)."""

    name = "hog_people"

    def __init__(self, settings: HogSettings | None = None, **options: Any) -> None:
        if settings is not None and options:
            raise TypeError("give HogSettings or keyword options, not both")
        self.settings = settings or HogSettings(**options)
        hog_class = _hog_class()
        if hog_class is None:
            raise ScorerUnavailable(
                f"the HOG people detector is not in OpenCV {cv2.__version__}: {HOG_FIX}")
        self._hog = hog_class()
        self._hog.setSVMDetector(hog_class.getDefaultPeopleDetector())
        s = self.settings
        self._stride = (s.win_stride_px, s.win_stride_px)

    def score(self, image: Image) -> dict[str, Any]:
        s = self.settings
        if s.scale != 1.0:
            image = cv2.resize(image, None, fx=s.scale, fy=s.scale, interpolation=cv2.INTER_AREA)
        _, weights = self._hog.detectMultiScale(image, winStride=self._stride,
                                                scale=s.pyramid_scale)
        margins = [float(w) for w in np.ravel(weights) if float(w) >= s.min_weight]
        return {"people": len(margins), "people_score": max(margins, default=0.0),
                "object": bool(margins)}


def read_settings(t: SettingsTable) -> HogSettings:
    """``[scoring.hog_people]``: ``scale``, ``win_stride_px``, ``pyramid_scale``, ``min_weight``."""
    return HogSettings(
        scale=t.get("scale", 0.5, "a number in (0, 1]", lambda v: is_number(v) and 0 < v <= 1),
        win_stride_px=t.get("win_stride_px", 8, "a positive multiple of 8",
                            lambda v: isinstance(v, int) and not isinstance(v, bool)
                            and v > 0 and v % 8 == 0),
        pyramid_scale=t.get("pyramid_scale", 1.05, "a number > 1",
                            lambda v: is_number(v) and v > 1),
        min_weight=t.get("min_weight", 0.5, "a number >= 0",
                         lambda v: is_number(v) and v >= 0),
    )


PLUGIN = ScorerPlugin(HogPeopleScorer, read_settings)
