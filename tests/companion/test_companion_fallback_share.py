"""Issue 18: the share of decisions the optimiser did not make itself rides on the status."""

from __future__ import annotations

import asyncio
from typing import Any

from companion_fake_vehicle import FakeVehicle
from test_companion_app import FakeDecider, FakeDecision, _config, _make, _until

from utility_specs.message import Message


class HalfFallback(FakeDecider):
    """Every other image decision comes from the greedy fallback (drop)."""

    def __init__(self) -> None:
        super().__init__()
        self.images = 0

    def decide(self, message: Message, now: float) -> FakeDecision:
        self.decided.append(message)
        if message.type != "image":
            return FakeDecision(True, None, "mcts", 1.0)
        self.images += 1
        if self.images % 2:
            return FakeDecision(False, None, "fallback-greedy", 0.0)
        return FakeDecision(True, 0, "mcts", 1.0)


async def test_status_reports_the_fallback_share(vehicle: FakeVehicle, tmp_path: Any) -> None:
    decider = HalfFallback()
    app, transports = _make(_config(vehicle, tmp_path), decider)
    assert app.fallback_share() is None  # nothing decided yet: no share to show
    task = asyncio.create_task(app.run())
    try:
        await _until(lambda: decider.images >= 10, timeout_s=10.0)
        await _until(lambda: any(0 < m.data.get("fallback_share", 0) < 1
                                 for m, _ in transports[0].sent if m.type == "status"),
                     timeout_s=10.0)
    finally:
        app.stop()
        await asyncio.wait_for(task, 10)
    fallbacks = (decider.images + 1) // 2
    assert app.counters["fallback"] == fallbacks
    assert app.counters["decided"] == len(decider.decided)
    assert app.fallback_share() == fallbacks / len(decider.decided)
    shares = [m.data["fallback_share"] for m, _ in transports[0].sent
              if m.type == "status" and "fallback_share" in m.data]
    assert shares and all(0.0 <= s < 1.0 for s in shares)
