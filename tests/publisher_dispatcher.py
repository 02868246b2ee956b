"""What :class:`companion.publisher.TelemetryPublisher` asks of the dispatcher, recorded."""

from __future__ import annotations

import asyncio

__all__ = ["RecordingDispatcher"]


class RecordingDispatcher:
    """Takes every submission after ``decide_s`` (a small MCTS takes ~5 ms) and keeps the
    statuses; no constraint, link health or fallback share to report."""

    optimiser_ready = True

    def __init__(self, decide_s: float = 0.0) -> None:
        self.decide_s = decide_s
        self.statuses: list[dict[str, object]] = []

    async def submit_telemetry(self, type_name: str, data: dict[str, object]) -> bool:
        if self.decide_s:
            await asyncio.sleep(self.decide_s)
        if type_name == "status":
            self.statuses.append(data)
        return True

    def constraint_limit(self) -> None:
        return None

    def link_health(self) -> dict[str, object]:
        return {}

    def fallback_share(self) -> None:
        return None
