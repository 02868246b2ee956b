"""The camera pipeline: frame -> score -> encode (JPEG versions) -> the dispatcher.

Scoring and encoding are blocking CPU work and run in the pipeline's own one-thread executor.
A frame that arrives while the previous one is still being scored is skipped (the camera
always has a fresher one), and outside the mission window no frame is scored at all.
"""

from __future__ import annotations

import asyncio
import logging
from concurrent.futures import ThreadPoolExecutor

from companion.camera import Frame
from companion.config import CameraConfig
from companion.dispatch import Dispatcher
from companion.imaging import DEFAULT_SCALES, EncodedImage, image_message
from companion.mission import MissionWindow
from companion.scoring import Scorer

__all__ = ["CameraPipeline"]

log = logging.getLogger(__name__)


class CameraPipeline:
    """The camera service's sink: ``await pipeline.on_frame(frame)``."""

    def __init__(self, settings: CameraConfig, *, drone_id: str, scorer: Scorer,
                 dispatcher: Dispatcher, mission: MissionWindow) -> None:
        self._settings = settings
        self._drone_id = drone_id
        self._scorer = scorer
        self._dispatcher = dispatcher
        self._mission = mission
        self._counters = dispatcher.counters
        self._scales = [(n, s) for n, s in DEFAULT_SCALES if n in settings.versions]
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="frame")
        self._busy = False

    def close(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)

    async def on_frame(self, frame: Frame) -> None:
        """Score and encode off the loop, then submit; a busy pipeline skips the frame, and
        outside the mission window (before start, after end) no frame is scored at all."""
        if not self._mission.running:
            self._counters["not_running"] += 1
            return
        if self._busy:
            self._counters["frames_skipped"] += 1
            return
        self._busy = True
        try:
            loop = asyncio.get_running_loop()
            seq = self._dispatcher.next_seq()
            encoded = await loop.run_in_executor(self._pool, self.encode, frame, seq)
        except (ValueError, RuntimeError) as exc:
            self._counters["frame_errors"] += 1
            log.warning("frame %d: %s", frame.index, exc)
            return
        finally:
            self._busy = False
        await self._dispatcher.submit(encoded.message)

    def encode(self, frame: Frame, seq: int) -> EncodedImage:
        """The frame as an ``image`` message: the scorer's features, geotag, JPEG versions."""
        features = self._scorer.score(frame.image)
        geotag = (frame.telemetry.geotag(at=frame.t_capture) if frame.telemetry is not None
                  else {"position": "none"})
        return image_message(frame.image, sender=self._drone_id, seq=seq,
                             t_gen=frame.t_capture, features=features, geotag=geotag,
                             jpeg_quality=self._settings.jpeg_quality, scales=self._scales,
                             frame_index=frame.index)
