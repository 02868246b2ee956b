"""Thesis fig. 7.3 in the discrete-event simulator: a drone seeing red gets more through."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from companion.middleware import ConstantConstraint, Middleware, MiddlewareConfig
from sitl.netsim import ChannelConfig, SimAgent, StreamConfig, simulate
from utility_specs.evaluate import evaluate
from utility_specs.files import builtin_spec
from utility_specs.message import Version

FULL = Version(name="full", size=24_000, quality=1.0)
HALF = Version(name="half", size=7_000, quality=0.5)
QUARTER = Version(name="quarter", size=2_500, quality=0.25)


def _run(versions: tuple[Version, ...], seed: int) -> dict[str, Any]:
    spec = builtin_spec("image_streaming")
    agents = []
    for i, (name, red) in enumerate((("red", 0.3), ("plain", 0.0))):
        mw = Middleware(MiddlewareConfig(spec=spec, agent=name, max_iterations=300),
                        rng=np.random.default_rng(seed),
                        constraint=ConstantConstraint(limit_bytes_per_s=8000.0, window_s=2.0))

        def data(k: int, g: np.random.Generator, red: float = red) -> dict[str, float]:
            return {"red": red}

        agents.append(SimAgent(name=name, policy=mw, streams=[
            StreamConfig(type="image", period_s=1 / 3, size=versions[0].size,
                         phase_s=0.05 * i + 0.01 * seed, versions=versions, data=data,
                         jitter_s=0.01),
            StreamConfig(type="position", period_s=1.0, size=64, phase_s=0.3 + 0.01 * i),
        ]))
    result = simulate(agents, channel=ChannelConfig(capacity_bytes_per_s=250_000), t_end=25.0,
                      rng=np.random.default_rng(seed))
    out: dict[str, Any] = {}
    for name in ("red", "plain"):
        images = [m for m in result.delivered
                  if m.sender == name and m.type == "image" and m.t_gen > 5.0]
        out[name] = len(images)
        out[f"{name}_u"] = evaluate(images, spec, t_start=5.0, t_end=25.0).total
    return out


@pytest.mark.parametrize("seed", [1, 2])
def test_one_version_red_gets_about_alpha_times_the_frame_rate(seed: int) -> None:
    """Eq. 4.28 is logarithmic in the frame rate, eq. 7.1 scales it by 1 + α·red = 4: the
    optimum shares frames about 4 : 1, and neither stream starves."""
    got = _run((QUARTER,), seed)
    assert got["red"] > 2.5 * got["plain"] > 0


def test_with_versions_red_gets_more_utility_and_quality_not_frames() -> None:
    """With full/half/quarter offered, eq. 4.33 scales the whole curve by the quality while
    a doubled frame rate adds only S: the red stream's extra worth goes into half-size
    versions, so its frame rate is not much higher, but its delivered utility is."""
    got = _run((FULL, HALF, QUARTER), 1)
    assert got["red_u"] > 2.0 * got["plain_u"]
    assert got["red"] >= got["plain"] > 0
