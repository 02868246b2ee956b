"""The knee memory of ``adaptive-smooth`` (issue 16): slow near the knee, full
speed away from it, and a new congestion episode stops just under the knee.

On a link with a sharp capacity the thesis' SGD limit-cycles ±15 % around the knee; these
pin the learning rule that stops it (docs/adaptive.md, "smooth and fast").
"""

from __future__ import annotations

import copy

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.middleware.constraints import make_constraint
from companion.middleware.constraints.adaptive import KNEE_FORGET_WINDOWS, AdaptiveConstraint
from companion.middleware.linkstats import WindowStats

ALPHA = 62_500.0
T = 0.5


def window(t: float, goodput: float, backlog: float) -> WindowStats:
    return WindowStats(t_end=t, window_s=T, n_messages=50, goodput_bytes_per_s=goodput,
                       mean_latency_s=0.02, base_latency_s=0.01, backlog_bytes_per_s=backlog,
                       warm=True)


def at_the_knee(knee: float = 120_000.0) -> AdaptiveConstraint:
    """The real-link constraint, just after a congestion episode at ``knee`` ended (t = 1.1)."""
    c = AdaptiveConstraint(window_s=T, alpha_bytes_per_s=ALPHA, learning_rate=0.1,
                           min_coef=0.3, backlog_clip=2.0, use_weighted=True,
                           knee_band=0.05, knee_step=0.01,
                           initial_intercept_bytes_per_s=knee - 0.3 * ALPHA)
    c._learn([window(1.0, knee, 3 * ALPHA)])  # congested: the episode's peak is the knee
    c._learn([window(1.1, knee, 0.0)])  # calm again: the episode ends, the knee is learnt
    assert c.knee_bytes_per_s == knee
    set_xi(c, knee)
    return c


def set_xi(c: AdaptiveConstraint, xi: float) -> None:
    c.model.intercept_[0] = (xi - c.coef * c.alpha_bytes_per_s) / c.scale_bytes_per_s
    assert c.limit_bytes_per_s(now=0.0) == pytest.approx(xi)


def step(c: AdaptiveConstraint, t: float, *, thesis: bool = False) -> float:
    """How much ξ moves on one calm window that used all of ξ."""
    c = copy.deepcopy(c)
    if thesis:
        c.knee_band = 0.0
    before = c.limit_bytes_per_s(now=0.0)
    c._learn([window(t, before, 0.0)])
    return c.limit_bytes_per_s(now=0.0) - before


@pytest.mark.parametrize("offset", [-0.04, -0.02, 0.0, 0.01, 0.03])
def test_steps_near_the_knee_are_slowed_quadratically(offset: float) -> None:
    knee = 120_000.0
    c = at_the_knee(knee)
    set_xi(c, knee * (1 + offset))
    distance = max(abs(offset) / c.knee_band, 0.1 / (KNEE_FORGET_WINDOWS * T))  # 0.1 s calm
    expected = c.knee_step + (1 - c.knee_step) * distance**2
    slow, full = step(c, 1.2), step(c, 1.2, thesis=True)
    assert full > 0  # uncongested: the SGD probes upwards
    assert slow / full == pytest.approx(expected, rel=1e-6)


def test_full_speed_outside_the_band_and_once_the_knee_is_forgotten() -> None:
    knee = 120_000.0
    c = at_the_knee(knee)
    assert step(c, 1.1) == pytest.approx(0.01 * step(c, 1.1, thesis=True), rel=1e-6)
    forgotten = 1.1 + KNEE_FORGET_WINDOWS * T
    assert step(c, forgotten) == pytest.approx(step(c, forgotten, thesis=True), rel=1e-9)
    far = copy.deepcopy(c)
    set_xi(far, 0.8 * knee)
    assert step(far, 1.2) == pytest.approx(step(far, 1.2, thesis=True), rel=1e-9)
    assert step(far, 1.2) > 50 * step(c, 1.2)


def test_a_new_congestion_episode_stops_just_under_the_knee() -> None:
    knee = 120_000.0
    c = at_the_knee(knee)
    set_xi(c, 1.03 * knee)  # probing 3 % over the knee
    thesis = copy.deepcopy(c)
    thesis.knee_band = 0.0
    t = 2.0
    for _ in range(7):  # 0.7 s of a full queue (< 1.5 windows): 10 windows a report
        batch = [window(t + i * 0.01, knee, 10 * ALPHA) for i in range(10)]
        c._learn(batch)
        thesis._learn(batch)
        t += 0.1
    assert c.limit_bytes_per_s(now=0.0) == pytest.approx(0.95 * knee)
    assert thesis.limit_bytes_per_s(now=0.0) < 0.87 * knee  # the thesis' SGD: ~cα under G
    for _ in range(10):  # the queue persists: the link has less now, the full SGD applies
        c._learn([window(t + i * 0.01, 0.7 * knee, 10 * ALPHA) for i in range(10)])
        t += 0.1
    assert c.limit_bytes_per_s(now=0.0) < 0.7 * knee


def test_windows_without_goodput_teach_nothing() -> None:
    """Regression: all-zero step weights made scikit-learn raise (use_weighted, G = 0)."""
    c = make_constraint("adaptive-smooth", window_s=T)
    before = c.limit_bytes_per_s(now=0.0)
    c._learn([window(1.0, 0.0, 0.0), window(1.1, 0.0, 0.0)])
    assert c.limit_bytes_per_s(now=0.0) == before


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(0.0, 300_000.0), st.floats(0.0, 20 * ALPHA)),
                min_size=1, max_size=12))
def test_a_fresh_episode_never_takes_xi_below_the_knee_band(
        windows: list[tuple[float, float]]) -> None:
    """Whatever the congested windows of a report say, within 1.5 windows of the episode's
    start ξ stays at or above 0.95 · min(ξ before, the goodput the link carried)."""
    c = at_the_knee()
    c._learn([window(1.2, 118_000.0, 0.0)])  # a calm window: the carried goodput
    before = c.limit_bytes_per_s(now=0.0)
    congested = [window(1.3 + i * 0.01, g, ALPHA * 1.001 + d) for i, (g, d) in
                 enumerate(windows)]
    c._learn(congested)
    peak = max([118_000.0] + [g for g, _ in windows])
    assert c.limit_bytes_per_s(now=0.0) >= 0.95 * min(before, peak) - 1e-6
