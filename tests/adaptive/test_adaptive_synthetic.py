"""Evidence 1 of issue 4 on seeded synthetic traces (thesis figures 6.1/6.2 link model).

The link (sitl.study.adaptive.simulate) is a FIFO bottleneck of 1 Mbit/s with a bounded
queue and 20 ms propagation, fed by Poisson application and background packets, so queueing
delay and ‖W‖_Δ grow with load and background. r* is the publishing rate at which the mean
‖W‖_Δ equals α, found by bisection over open-loop runs (a figure 6.2 curve).
Run with ``-s`` to see the measured numbers.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

from companion.middleware.adaptive import AdaptiveConstraint
from companion.middleware.aimd import AimdConstraint
from sitl.study.adaptive import SimTrace, equilibrium_rate, simulate, steps

C = 125_000.0  # link capacity, bytes/s (1 Mbit/s)
ALPHA = 0.5 * C  # the thesis' figure 6.2 example: α = 0.5 Mbit/s
DEMAND = steps((0.0, 2 * C))  # the application always wants more than the link carries


def adaptive() -> AdaptiveConstraint:
    return AdaptiveConstraint(alpha_bytes_per_s=ALPHA, learning_rate=0.01,
                              initial_intercept_bytes_per_s=0.3 * C)


@functools.cache
def r_star_for(background_share: float) -> float:
    """r* for a background share of C (bisection to (C − S)/512), computed once per run."""
    return equilibrium_rate(ALPHA, background_bytes_per_s=background_share * C, iterations=9)


def rolling_mean(trace: SimTrace, width_s: float) -> tuple[np.ndarray, np.ndarray]:
    t, xi = np.asarray(trace.t), np.asarray(trace.xi_bytes_per_s)
    out = np.array([xi[(t > s - width_s) & (t <= s)].mean() for s in t])
    return t, out


@pytest.mark.parametrize("background_share", [0.0, 0.25, 0.5])
def test_xi_converges_near_the_rate_where_backlog_equals_alpha(background_share: float) -> None:
    background = background_share * C
    r_star = r_star_for(background_share)
    # the figure 6.2 shape: more background, lower r* (thesis: 0.9, 0.65, 0.42 Mbit/s)
    assert r_star < C - background
    trace = simulate(adaptive(), duration_s=200.0, rng=np.random.default_rng(7),
                     demand_bytes_per_s=DEMAND,
                     background_bytes_per_s=steps((0.0, background)))
    settled = trace.xi_between(120.0, 200.0)
    print(f"\nS={background_share:.2f}C: r*={r_star / C:.3f}C, "
          f"mean ξ(120..200 s)={settled.mean() / C:.3f}C")
    assert settled.mean() == pytest.approx(r_star, rel=0.12)


def test_r_star_falls_with_background_like_figure_6_2() -> None:
    rates = [r_star_for(share) for share in (0.0, 0.25, 0.5)]
    assert rates[0] > rates[1] > rates[2] > 0


def test_xi_settles_after_a_background_step() -> None:
    """Background 0 -> 0.5 C at 120 s: ξ's 10 s mean reaches ±20% of the new r* within 30 s
    and its mean afterwards is within ±15% of r*."""
    r_star = r_star_for(0.5)
    settle, after = [], []
    for seed in (1, 2, 3):
        trace = simulate(adaptive(), duration_s=240.0, rng=np.random.default_rng(seed),
                         demand_bytes_per_s=DEMAND,
                         background_bytes_per_s=steps((0.0, 0.0), (120.0, 0.5 * C)))
        t, mean10 = rolling_mean(trace, 10.0)
        inside = (t >= 120.0) & (np.abs(mean10 - r_star) <= 0.2 * r_star)
        t_in = float(t[inside].min()) if inside.any() else np.inf
        settle.append(t_in - 120.0)
        after.append(float(trace.xi_between(t_in, 240.0).mean()) if inside.any() else np.inf)
    print(f"\nsettling times after the step: {[round(s, 1) for s in settle]} s; mean ξ after: "
          f"{[round(a / C, 3) for a in after]} C (r*={r_star / C:.3f}C)")
    assert max(settle) <= 30.0
    for mean_after in after:
        assert mean_after == pytest.approx(r_star, rel=0.15)


def test_adaptive_varies_far_less_than_aimd_under_noise() -> None:
    """Steady link, background 0.25 C: coefficient of variation of ξ over 100-200 s."""
    cv = {"adaptive": [], "aimd": []}
    for seed in (1, 2, 3):
        for name, constraint in (
            ("adaptive", adaptive()),
            ("aimd", AimdConstraint(alpha_bytes_per_s=ALPHA, initial_bytes_per_s=0.3 * C)),
        ):
            trace = simulate(constraint, duration_s=200.0, rng=np.random.default_rng(seed),
                             demand_bytes_per_s=DEMAND,
                             background_bytes_per_s=steps((0.0, 0.25 * C)))
            xi = trace.xi_between(100.0, 200.0)
            cv[name].append(float(xi.std() / xi.mean()))
    mean_cv = {k: float(np.mean(v)) for k, v in cv.items()}
    print(f"\ncoefficient of variation of ξ: adaptive {mean_cv['adaptive']:.3f} "
          f"{[round(v, 3) for v in cv['adaptive']]}, AIMD {mean_cv['aimd']:.3f} "
          f"{[round(v, 3) for v in cv['aimd']]}")
    assert mean_cv["adaptive"] < 0.6 * mean_cv["aimd"]
    assert max(cv["adaptive"]) < min(cv["aimd"])
