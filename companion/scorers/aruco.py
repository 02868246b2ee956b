"""``aruco``: is the object to reconstruct in view (eq. 7.2)?

The object (KPK demonstrator, ch. 7.4) is tagged with ArUco markers (``cv2.aruco``,
DICT_4X4_50 by default); ``object`` is true when a target marker is seen.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2

from companion.scorers.base import Image, ScorerPlugin, SettingsTable, is_number

__all__ = ["PLUGIN", "ArucoScorer", "ArucoSettings", "read_settings"]


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


def read_settings(t: SettingsTable) -> ArucoSettings:
    """``[scoring.aruco]``: ``dictionary``, ``target_ids`` and ``scale``."""
    return ArucoSettings(
        dictionary=t.get("dictionary", "DICT_4X4_50", "an OpenCV ArUco dictionary name "
                         "like DICT_4X4_50", lambda v: isinstance(v, str) and v.startswith(
                             "DICT_")),
        target_ids=tuple(t.get("target_ids", [], "a list of marker ids >= 0",
                               lambda v: isinstance(v, list) and all(
                                   isinstance(x, int) and x >= 0 for x in v))),
        scale=t.get("scale", 0.5, "a number in (0, 1]", lambda v: is_number(v) and 0 < v <= 1),
    )


PLUGIN = ScorerPlugin(ArucoScorer, read_settings)
