"""The relay fleet's opt-in ``price_rate_s`` (docs/adaptive.md, "The decider's lag"): the
price per byte counts the other drones' frames only as many as they were heard to send."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from companion.middleware import ConstantConstraint, Middleware, MiddlewareConfig
from companion.middleware.errors import MiddlewareError
from utility_specs.files import builtin_spec
from utility_specs.message import Message, Version


def _frame(sender: str, k: int, t: float, *, sent: bool = False) -> Message:
    versions = (Version(name="full", size=28_000, quality=1.0),
                Version(name="half", size=8_400, quality=0.5),
                Version(name="quarter", size=2_800, quality=0.25))
    m = Message(sender=sender, seq=k, type="image", t_gen=t, size=28_000,
                data={"red": 0.0, "frame": k}, versions=versions, version=0)
    if not sent:
        return m
    return dataclasses.replace(m.with_version(1), t_sent=t + 0.01, t_rcv=t + 0.21)


def _sends_while_the_peers_are_silent(price_rate_s: float | None, quiet_s: float,
                                      dp_seed: int | None = None) -> int:
    """Agent ``a`` and three peers at 5 frames/s, each sending a half frame a second for
    6 s, ξ·T = 15 kB over T = 0.5 s (the demo's); then the peers fall silent: how many of
    ``a``'s frames of the next ``quiet_s`` go out. The unseeded search by default, the one
    the price kept silent."""
    mw = Middleware(MiddlewareConfig(spec=builtin_spec("image_streaming"), agent="a",
                                     max_iterations=300, price_rate_s=price_rate_s,
                                     dp_seed=dp_seed),
                    rng=np.random.default_rng(1),
                    constraint=ConstantConstraint(limit_bytes_per_s=30_000.0, window_s=0.5))
    for k in range(30):
        t = 0.2 * k
        if k % 5 == 0:
            mw.decide(_frame("a", k, t + 0.01), t + 0.01)
        for j, peer in enumerate("bcd"):
            if k % 5 == j + 1:
                mw.on_delivered([_frame(peer, k, t + 0.02, sent=True)], now=t + 0.3)
    sent = 0
    for k in range(30, 30 + round(quiet_s / 0.2)):
        t = 0.2 * k + 0.01
        sent += mw.decide(_frame("a", k, t), t).send
    return sent


def test_a_drone_whose_peers_fell_silent_sends_where_every_forecast_frame_kept_it_silent(
        ) -> None:
    """Counting the silent peers' 45 forecast frames as sends, the agent sent one frame in
    2 s with the link empty (the demo fleet: no image for 8-18 s); counting only what
    they were heard to send over the last 3 s, it sends a second one 1.6 s after the
    first."""
    assert _sends_while_the_peers_are_silent(None, 2.0) == 1
    assert _sends_while_the_peers_are_silent(3.0, 2.0) == 2
    # seeded by the dynamic programme (the default since round 13) it sends the second
    # frame with either price
    assert _sends_while_the_peers_are_silent(None, 2.0, 128) == 2
    assert _sends_while_the_peers_are_silent(3.0, 2.0, 128) == 2


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan")])
def test_price_rate_s_must_be_positive(bad: float) -> None:
    with pytest.raises(MiddlewareError, match="price_rate_s"):
        MiddlewareConfig(spec=builtin_spec("image_streaming"), agent="a", price_rate_s=bad)

