"""The red drone's precedence under ``price_rate_s`` (docs/adaptive.md, "The red drone's
precedence"): the others forecast its frames from its recent worths, and count them all in
the price while they are worth twice their own."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from companion.middleware import ConstantConstraint, Middleware, MiddlewareConfig
from companion.middleware import middleware as mw_module
from companion.middleware.forecast import StreamForecaster
from utility_specs.files import builtin_spec
from utility_specs.message import Message, Version

VERSIONS = (Version(name="full", size=28_000, quality=1.0),
            Version(name="half", size=8_400, quality=0.5),
            Version(name="quarter", size=2_800, quality=0.25))


def _frame(sender: str, k: int, t: float, *, red: float = 0.0, sent: bool = False) -> Message:
    m = Message(sender=sender, seq=k, type="image", t_gen=t, size=28_000,
                data={"red": red, "frame": k}, versions=VERSIONS, version=0)
    if not sent:
        return m
    return dataclasses.replace(m.with_version(1), t_sent=t + 0.01, t_rcv=t + 0.21)


def test_a_span_keeps_a_rarely_heard_stream_s_forecasts_to_its_recent_worths() -> None:
    """Heard a frame a second, 24 plain frames then 8 red ones: its 32 observations span
    the mission, and most forecasts carried plain data; within 3 s of the newest only
    red frames count (too few to spread: copies of the newest, red)."""
    f = StreamForecaster(worth=lambda m: 1.0 + 10.0 * m.data["red"])
    for k in range(32):
        f.observe(_frame("r", k, float(k), red=0.3 if k >= 24 else 0.0))
    reds = [m.data["red"] for m in f.forecast(("r", "image"), t_from=31.0, t_to=34.0)]
    assert len(reds) == 3 and reds.count(0.0) >= 2
    assert f.risen(("r", "image")) == pytest.approx(1.75)
    f.pool_span_s = 3.0
    f.observe(_frame("r", 32, 32.0, red=0.3))
    reds = [m.data["red"] for m in f.forecast(("r", "image"), t_from=32.0, t_to=35.0)]
    assert reds == [0.3, 0.3, 0.3]
    assert f.risen(("r", "image")) == pytest.approx(4.0)


def _plain_sends_while_the_peer_is_red(*, risen: float) -> int:
    """Agent ``a`` (plain) and peer ``r`` at 5 frames/s over a 15 kB window of 0.5 s; ``r``
    is heard sending a half frame a second, plain for 10 s, then red (0.3): how many of
    ``a``'s frames of the next 3 s go out."""
    mw = Middleware(MiddlewareConfig(spec=builtin_spec("image_streaming"), agent="a",
                                     max_iterations=300, price_rate_s=3.0),
                    rng=np.random.default_rng(1),
                    constraint=ConstantConstraint(limit_bytes_per_s=30_000.0, window_s=0.5))
    red_from = 50
    sent = 0
    for k in range(65):
        t = 0.2 * k
        red = 0.3 if k >= red_from else 0.0
        if k % 5 == 2:
            mw.on_delivered([_frame("r", k, t + 0.02, red=red, sent=True)], now=t + 0.12)
        mw_module.RISEN_WORTH = risen
        decision = mw.decide(_frame("a", k, t + 0.01), t + 0.01)
        sent += decision.send and k >= red_from
    return sent


def test_a_plain_drone_leaves_the_red_drone_its_windows(monkeypatch: pytest.MonkeyPatch
                                                        ) -> None:
    """Counted at its heard rate (a half frame a second), the red peer's frames left the
    plain agent's price to its own: it sent 3 of its 15 frames while the peer was red (3
    with the unseeded search, 2 with the unpriced beam of round 13); counted all while its
    worth is 1.25x its history or more, they price every one out (1 before round 14)."""
    monkeypatch.setattr(mw_module, "RISEN_WORTH", mw_module.RISEN_WORTH)
    capped = _plain_sends_while_the_peer_is_red(risen=float("inf"))
    counted = _plain_sends_while_the_peer_is_red(risen=1.25)
    assert (capped, counted) == (3, 0)


def test_the_fit_sends_the_most_valuable_option_that_earns_the_price_and_fits() -> None:
    """``_fitting_option``: of the options earning the price, the most valuable that adds
    no violated window to the known sends (the red drone's half frame, where its tree
    chose the worthless quarter); none when the window is full."""
    mw = Middleware(MiddlewareConfig(spec=builtin_spec("image_streaming"), agent="a",
                                     max_iterations=100, price_rate_s=3.0),
                    rng=np.random.default_rng(1),
                    constraint=ConstantConstraint(limit_bytes_per_s=30_000.0, window_s=0.5))
    mw.decide(_frame("a", 0, 0.0, red=0.3), 0.0)
    frame = _frame("a", 10, 2.0, red=0.3)
    mw.decide(frame, 2.0)
    problem = mw.last_problem
    assert problem is not None
    level = problem.decided_level
    gain = [float(problem.gain[level, o, 0]) for o in (1, 2, 3)]
    assert gain[0] > gain[1] > gain[2] > 0
    args = {"now": 2.0, "budget": 15_000.0, "window_s": 0.5}
    assert mw._fitting_option(problem, level, 0.0, **args) == 2  # the full frame does not fit
    half_density = gain[1] / 8_400
    assert mw._fitting_option(problem, level, 0.99 * half_density, **args) == 2
    assert mw._fitting_option(problem, level, 1.01 * half_density, **args) == 0  # quarter: 5 µ/B
    mw.knowledge.on_sent(_frame("b", 5, 1.9).with_version(1), now=1.9)  # 8.4 kB in window
    assert mw._fitting_option(problem, level, 0.0, **args) == 3
