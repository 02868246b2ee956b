"""Frame utility features: what in a frame makes it worth the air time (thesis eq. 7.1, 7.2).

Every scorer implements :class:`Scorer`: ``score(image_bgr) -> dict`` of the few fields the
utility functions read (``red`` in 0..1 for eq. 7.1, ``object`` for eq. 7.2). Scorers are
plain synchronous code; the app runs them in an executor, never on the event loop.

* :class:`RedShareScorer`: share of red pixels. Red wraps around hue 0 in OpenCV's HSV
  (H in 0..179), so two hue ranges are thresholded and OR-ed; a morphological opening removes
  speckle noise. Runs on a downscaled copy (``scale``) to stay well under 5 ms per 640x480.
* :class:`ArucoScorer`: the object to reconstruct (KPK demonstrator, ch. 7.4) is tagged with
  ArUco markers (``cv2.aruco``, DICT_4X4_50 by default); ``object`` is true when a target
  marker is seen.
* :class:`HogPeopleScorer`: OpenCV's built-in HOG+SVM people detector (weights compiled into
  OpenCV). OpenCV 4.x ships it; OpenCV 5 moved it to opencv-contrib, and without it the scorer
  raises :class:`ScorerUnavailable` naming the fix (an ``opencv-python-headless<5`` build).

No downloaded weights anywhere. A better detector plugs in by implementing :class:`Scorer`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import cv2
import numpy as np
import numpy.typing as npt

__all__ = [
    "ArucoScorer",
    "ArucoSettings",
    "CompositeScorer",
    "HogPeopleScorer",
    "HogSettings",
    "RedShareScorer",
    "RedShareSettings",
    "Scorer",
    "ScorerUnavailable",
    "make_scorer",
]

Image = npt.NDArray[Any]
HSV = tuple[int, int, int]


class ScorerUnavailable(RuntimeError):
    """The scorer cannot run with this OpenCV build; the text says what is missing."""


@runtime_checkable
class Scorer(Protocol):
    name: str

    def score(self, image: Image) -> dict[str, Any]:
        """Features of one BGR frame (uint8, HxWx3)."""
        ...


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


@dataclass(frozen=True, slots=True, kw_only=True)
class ArucoSettings:
    dictionary: str = "DICT_4X4_50"
    """Name of a predefined ``cv2.aruco`` dictionary."""
    target_ids: tuple[int, ...] = ()
    """Marker ids that tag the object to reconstruct; empty = any marker."""
    scale: float = 0.5
    """Detect on a downscaled copy: about 4x faster, markers of >= 40 px still found."""


class ArucoScorer:
    """``object``: a target ArUco marker is visible (eq. 7.2); ``markers``: the ids seen."""

    name = "aruco"

    def __init__(self, settings: ArucoSettings | None = None) -> None:
        self.settings = settings or ArucoSettings()
        code = getattr(cv2.aruco, self.settings.dictionary, None)
        if not isinstance(code, int):
            raise ValueError(f"unknown ArUco dictionary {self.settings.dictionary!r}")
        dictionary = cv2.aruco.getPredefinedDictionary(code)
        self._detector = cv2.aruco.ArucoDetector(dictionary, cv2.aruco.DetectorParameters())
        self._targets = frozenset(self.settings.target_ids)

    def score(self, image: Image) -> dict[str, Any]:
        gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        if self.settings.scale != 1.0:
            gray = cv2.resize(gray, None, fx=self.settings.scale, fy=self.settings.scale,
                              interpolation=cv2.INTER_AREA)
        _, ids, _ = self._detector.detectMarkers(gray)
        seen = sorted({int(i) for i in ids.ravel()}) if ids is not None else []
        hit = bool(seen) if not self._targets else any(i in self._targets for i in seen)
        return {"object": hit, "markers": seen}


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


def make_scorer(names: Sequence[str], *, red: RedShareSettings | None = None,
                aruco: ArucoSettings | None = None, hog: HogSettings | None = None,
                options: Mapping[str, Any] | None = None) -> CompositeScorer:
    """The scorers named in the configuration, in order (``red_share``, ``aruco``,
    ``hog_people``; ``options`` are HogSettings fields when ``hog`` is not given). Raises
    ValueError on an unknown name, ScorerUnavailable when this OpenCV lacks a detector."""
    built: list[Scorer] = []
    for name in names:
        if name == "red_share":
            built.append(RedShareScorer(red))
        elif name == "aruco":
            built.append(ArucoScorer(aruco))
        elif name == "hog_people":
            built.append(HogPeopleScorer(hog) if hog is not None
                         else HogPeopleScorer(**dict(options or {})))
        else:
            raise ValueError(f"unknown scorer {name!r} (known: red_share, aruco, hog_people)")
    return CompositeScorer(scorers=built)
