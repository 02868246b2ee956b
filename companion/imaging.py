"""A camera frame as an image message: JPEG versions, their sizes, features and geotag.

Each frame becomes one :class:`utility_specs.message.Message` of type ``image`` whose
``versions`` are the frame at full, half and quarter resolution, JPEG-encoded, so the optimiser
can pick a cheaper version (eq. 4.33: a version's quality is its diagonal relative to the full
image, ``m.d / d``). ``data`` carries the features the utility functions read (``red``,
``object``...), the full image's diagonal, and the position and attitude at capture time.
Encoding is synchronous CPU work; the app calls it in an executor.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy.typing as npt

from utility_specs.message import Message, Version

__all__ = ["DEFAULT_SCALES", "EncodedImage", "encode_versions", "image_message"]

DEFAULT_SCALES: tuple[tuple[str, float], ...] = (("full", 1.0), ("half", 0.5), ("quarter", 0.25))


@dataclass(frozen=True, slots=True, kw_only=True)
class EncodedVersion:
    name: str
    jpeg: bytes
    width_px: int
    height_px: int


@dataclass(frozen=True, slots=True, kw_only=True)
class EncodedImage:
    """The message the optimiser sees; each of its versions carries its JPEG bytes."""

    message: Message

    @property
    def payloads(self) -> tuple[bytes, ...]:
        """The versions' bytes, best first (``message.with_version(i).payload``)."""
        return tuple(self.message.with_version(i).payload
                     for i in range(len(self.message.versions)))

    def payload(self, version: int | None) -> bytes:
        return self.message.with_version(0 if version is None else version).payload


def encode_versions(image: npt.NDArray[Any], *, jpeg_quality: int = 80,
                    scales: Sequence[tuple[str, float]] = DEFAULT_SCALES
                    ) -> list[EncodedVersion]:
    """JPEG-encode ``image`` (BGR) at each scale, best first."""
    if not 1 <= jpeg_quality <= 100:
        raise ValueError(f"jpeg_quality must be in 1..100, got {jpeg_quality}")
    height, width = image.shape[:2]
    out: list[EncodedVersion] = []
    params = [int(cv2.IMWRITE_JPEG_QUALITY), int(jpeg_quality)]
    for name, scale in scales:
        if scale == 1.0:
            scaled = image
        else:
            size = (max(1, round(width * scale)), max(1, round(height * scale)))
            scaled = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
        ok, buf = cv2.imencode(".jpg", scaled, params)
        if not ok:
            raise ValueError(f"JPEG encoding failed for version {name!r}")
        out.append(EncodedVersion(name=name, jpeg=buf.tobytes(), width_px=scaled.shape[1],
                                  height_px=scaled.shape[0]))
    return out


def image_message(image: npt.NDArray[Any], *, sender: str, seq: int, t_gen: float,
                  features: Mapping[str, Any], geotag: Mapping[str, Any],
                  jpeg_quality: int = 80,
                  scales: Sequence[tuple[str, float]] = DEFAULT_SCALES,
                  frame_index: int | None = None) -> EncodedImage:
    """One frame as an ``image`` message with full/half/quarter versions (eq. 4.33).

    ``frame_index`` (the camera's frame counter) goes into ``data["frame"]``: the stream's
    own sequence number, from which the other drones' optimisers learn its frame rate even
    when few of its frames are sent (``seq`` counts all of a drone's messages)."""
    versions = encode_versions(image, jpeg_quality=jpeg_quality, scales=scales)
    full = versions[0]
    diagonal = math.hypot(full.width_px, full.height_px)
    data: dict[str, Any] = {
        "red": 0.0,
        "object": False,
        **features,
        "width_px": full.width_px,
        "height_px": full.height_px,
        "diagonal_px": diagonal,
        **geotag,
    }
    if frame_index is not None:
        data["frame"] = frame_index
    message = Message(
        sender=sender,
        seq=seq,
        type="image",
        t_gen=t_gen,
        size=len(full.jpeg),
        data=data,
        versions=tuple(
            Version(name=v.name, size=len(v.jpeg),
                    quality=min(1.0, math.hypot(v.width_px, v.height_px) / diagonal),
                    payload=v.jpeg)
            for v in versions
        ),
        version=0,
    )
    return EncodedImage(message=message)
