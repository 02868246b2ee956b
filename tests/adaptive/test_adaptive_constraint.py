"""The adaptive SGD constraint (eq. 6.7/6.8), AIMD (algorithm 4) and the registry."""

from __future__ import annotations

import ast
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.middleware.adaptive import AdaptiveConstraint
from companion.middleware.aimd import AimdConstraint
from companion.middleware.constraint import ConstantConstraint, LinkSample
from companion.middleware.constraints import CONSTRAINTS, make_constraint
from companion.middleware.linkstats import WindowStats

T0 = 1_700_000_000.0
SCALE = 125_000.0


def window(goodput: float, backlog: float) -> WindowStats:
    return WindowStats(t_end=T0, window_s=1.0, n_messages=10, goodput_bytes_per_s=goodput,
                       mean_latency_s=0.02, base_latency_s=0.01, backlog_bytes_per_s=backlog,
                       warm=True)


def feed_steady(constraint: AdaptiveConstraint | AimdConstraint, *, seconds: float,
                latency_s: float, size: int = 1000, interval_s: float = 0.05,
                start: float = 0.0, seq0: int = 0) -> float:
    """Messages every ``interval_s`` with alternating latency (base 10 ms); returns end time."""
    t = start
    seq = seq0
    while t < start + seconds:
        latency = 0.010 if seq % 2 == 0 else latency_s
        constraint.on_sample(LinkSample(t_sent=T0 + t, t_rcv=T0 + t + latency, size=size,
                                        sender="d1", seq=seq), now=T0 + t + 0.1)
        t += interval_s
        seq += 1
    return t


def test_initial_belief_sets_the_first_constraint() -> None:
    c = AdaptiveConstraint(alpha_bytes_per_s=20_000.0, initial_coef=0.5,
                           initial_intercept_bytes_per_s=50_000.0)
    assert c.limit_bytes_per_s(now=T0) == pytest.approx(50_000.0 + 0.5 * 20_000.0)
    assert c.budget_bytes(now=T0) == pytest.approx(60_000.0 * 2.5)


def test_one_report_sample_is_one_exact_sgd_step() -> None:
    """Squared loss, constant rate η: w += η(y − ŷ)x, b += η(y − ŷ), in scaled units."""
    c = AdaptiveConstraint(alpha_bytes_per_s=12_500.0, learning_rate=0.1, initial_coef=1.0,
                           initial_intercept_bytes_per_s=62_500.0, min_coef=0.0)
    c._learn([window(goodput=112_500.0, backlog=25_000.0)])
    x, y = 25_000.0 / SCALE, 112_500.0 / SCALE
    residual = y - (0.5 + 1.0 * x)
    assert c.coef == pytest.approx(1.0 + 0.1 * residual * x)
    assert c.intercept_bytes_per_s == pytest.approx((0.5 + 0.1 * residual) * SCALE)
    assert c.limit_bytes_per_s(now=T0) == pytest.approx(
        c.intercept_bytes_per_s + c.coef * 12_500.0)


def test_a_batch_is_one_step_per_sample_in_order() -> None:
    """on_samples (a whole report) gives the same model as one on_sample per message."""
    one, batch = AdaptiveConstraint(window_s=1.0), AdaptiveConstraint(window_s=1.0)
    rng = np.random.default_rng(3)
    samples = []
    for i in range(80):
        t = i * 0.03
        samples.append(LinkSample(t_sent=T0 + t, t_rcv=T0 + t + 0.01 + rng.exponential(0.01),
                                  size=1200, sender="d1", seq=i))
    for s in samples:
        one.on_sample(s, now=T0 + 3.0)
    for k in range(0, 80, 7):
        batch.on_samples(samples[k : k + 7], now=T0 + 3.0)
    assert one.n_updates == batch.n_updates == sum(1 for s in samples if s.t_rcv - T0 >= 1.01)
    assert batch.coef == pytest.approx(one.coef, rel=1e-12)
    assert batch.intercept_bytes_per_s == pytest.approx(one.intercept_bytes_per_s, rel=1e-12)


def test_nothing_is_learned_before_one_whole_window() -> None:
    c = AdaptiveConstraint(window_s=2.0)
    feed_steady(c, seconds=1.9, latency_s=0.05)
    assert c.n_updates == 0
    assert c.limit_bytes_per_s(now=T0 + 2) == pytest.approx(75_000.0)


def test_more_delay_at_the_same_low_goodput_lowers_xi() -> None:
    """Figure 6.5, 65-75 s: the app sends far below ξ, yet ξ follows the link."""
    c = AdaptiveConstraint(window_s=1.0, learning_rate=0.05,
                           initial_intercept_bytes_per_s=100_000.0)
    t = feed_steady(c, seconds=20.0, latency_s=0.011)  # 20 kB/s ≪ ξ, almost no queueing
    quiet = c.limit_bytes_per_s(now=T0 + t)
    feed_steady(c, seconds=20.0, latency_s=0.060, start=t, seq0=10_000)  # background: delay
    loaded = c.limit_bytes_per_s(now=T0 + t + 20)
    assert quiet > 20_000.0 * 1.5  # well above what the app sends
    assert loaded < 0.8 * quiet


def test_xi_stays_in_bounds_and_slope_is_projected() -> None:
    c = AdaptiveConstraint(min_bytes_per_s=5_000.0, max_bytes_per_s=200_000.0, min_coef=0.1,
                           learning_rate=0.5)
    c._learn([window(goodput=0.0, backlog=10 * SCALE)] * 50)  # hopelessly congested
    assert c.coef >= 0.1
    assert c.limit_bytes_per_s(now=T0) == 5_000.0
    c._learn([window(goodput=100 * SCALE, backlog=0.0)] * 50)
    assert c.limit_bytes_per_s(now=T0) == 200_000.0


def test_backlog_is_clipped_before_fitting() -> None:
    """A 50x-goodput backlog sample counts as backlog_clip·α: SGD stays stable."""
    a = AdaptiveConstraint(alpha_bytes_per_s=10_000.0, backlog_clip=4.0, learning_rate=0.2)
    b = AdaptiveConstraint(alpha_bytes_per_s=10_000.0, backlog_clip=4.0, learning_rate=0.2)
    a._learn([window(goodput=50_000.0, backlog=2_500_000.0)])
    b._learn([window(goodput=50_000.0, backlog=40_000.0)])
    assert a.coef == b.coef and a.intercept_bytes_per_s == b.intercept_bytes_per_s


@settings(max_examples=50, deadline=None)
@given(st.lists(st.tuples(st.floats(0, 1e7), st.floats(0, 1e8)), min_size=1, max_size=30),
       st.floats(1e-4, 1.0))
def test_xi_is_always_finite_and_within_bounds(
    observations: list[tuple[float, float]], learning_rate: float,
) -> None:
    c = AdaptiveConstraint(learning_rate=learning_rate, min_bytes_per_s=1_000.0,
                           max_bytes_per_s=1_000_000.0)
    c._learn([window(goodput=g, backlog=d) for g, d in observations])
    xi = c.limit_bytes_per_s(now=T0)
    assert math.isfinite(xi) and 1_000.0 <= xi <= 1_000_000.0
    assert math.isfinite(c.coef) and math.isfinite(c.intercept_bytes_per_s)


def test_aimd_follows_algorithm_4_exactly() -> None:
    c = AimdConstraint(alpha_bytes_per_s=10_000.0, increase_bytes_per_s=2048.0,
                       decrease_factor=0.998, beta_bytes_per_s=6250.0,
                       initial_bytes_per_s=50_000.0)
    c._learn([window(goodput=48_000.0, backlog=20_000.0)])  # Δ > α: ξ·b
    assert c.limit_bytes_per_s(now=T0) == pytest.approx(50_000.0 * 0.998)
    c._learn([window(goodput=48_000.0, backlog=5_000.0)])  # ξ − G < β: ξ + a
    assert c.limit_bytes_per_s(now=T0) == pytest.approx(50_000.0 * 0.998 + 2048.0)
    before = c.limit_bytes_per_s(now=T0)
    c._learn([window(goodput=1_000.0, backlog=5_000.0)])  # far below ξ: unchanged
    assert c.limit_bytes_per_s(now=T0) == before
    c._learn([window(goodput=48_000.0, backlog=20_000.0)] * 100)
    assert c.limit_bytes_per_s(now=T0) == pytest.approx(before * 0.998**100)


def test_aimd_keeps_units_consistent_thesis_defaults() -> None:
    c = AimdConstraint()
    assert c.increase_bytes_per_s == 2048.0
    assert c.decrease_factor == 0.998
    assert c.beta_bytes_per_s == 0.05e6 / 8  # 0.05 Mbit/s in bytes per second


def test_aimd_does_not_adapt_while_the_app_sends_far_less() -> None:
    """The weakness of figure 6.5 (~90 s): ξ_AIMD freezes at an arbitrary value."""
    c = AimdConstraint(window_s=1.0, initial_bytes_per_s=100_000.0)
    t = feed_steady(c, seconds=10.0, latency_s=0.011)
    xi = c.limit_bytes_per_s(now=T0 + t)
    assert xi == 100_000.0  # 20 kB/s sent, ξ − G > β: never changes


def test_registry_builds_every_constraint_by_name() -> None:
    assert set(CONSTRAINTS) == {"constant", "adaptive", "adaptive-thesis", "adaptive-smooth",
                                "aimd"}
    assert isinstance(make_constraint("constant", limit_bytes_per_s=5.0), ConstantConstraint)
    for name in ("adaptive", "adaptive-thesis", "adaptive-smooth"):
        adaptive = make_constraint(name, alpha_bytes_per_s=1000.0, window_s=0.5)
        assert isinstance(adaptive, AdaptiveConstraint) and adaptive.window_s == 0.5
        # the default is the thesis' SGD; the smooth one has use-weighted steps and the knee
        smooth = name == "adaptive-smooth"
        assert adaptive.use_weighted is smooth and (adaptive.knee_band == 0.05) is smooth
    assert isinstance(make_constraint("aimd", decrease_factor=0.9), AimdConstraint)


def test_registry_errors_name_the_problem() -> None:
    with pytest.raises(ValueError, match=r"unknown goodput constraint 'sgd'.*'adaptive'"):
        make_constraint("sgd")
    with pytest.raises(ValueError, match=r"'aimd'.*learning_rate"):
        make_constraint("aimd", learning_rate=0.1)
    with pytest.raises(ValueError, match="decrease_factor"):
        make_constraint("aimd", decrease_factor=1.5)


@pytest.mark.parametrize("module", ["constraints/linkstats", "constraints/adaptive",
                                    "constraints/aimd", "constraints/base",
                                    "constraints/registry", "constraints/__init__"])
def test_cores_do_no_io(module: str) -> None:
    """Sans-I/O: no clock, socket, thread or file machinery in the constraint cores."""
    path = Path(__file__).resolve().parents[2] / "companion" / "middleware" / f"{module}.py"
    forbidden = {"asyncio", "socket", "threading", "time", "os", "subprocess", "random"}
    for node in ast.walk(ast.parse(path.read_text())):
        names = []
        if isinstance(node, ast.Import):
            names = [a.name.split(".")[0] for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module:
            names = [node.module.split(".")[0]]
        assert not forbidden & set(names), f"{module} imports {forbidden & set(names)}"
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name):
            assert node.func.id != "open", f"{module} opens a file"


def test_the_send_log_stays_one_window_long_when_nobody_asks() -> None:
    """The optimiser records every send but never asks admits(): memory must not grow."""
    c = ConstantConstraint(limit_bytes_per_s=1000.0, window_s=2.0)
    for i in range(10_000):
        c.on_sent(100, now=i * 0.01)  # 100 s of sends at 100 Hz
    assert len(c._sent) <= 201
    assert c.sent_in_window(now=99.99) == 200 * 100


def test_live_parameters_are_settings_not_the_state_the_constraint_recomputes() -> None:
    """α of the last window is recomputed at every learned window: offering it to
    ``set_params`` would accept a number the next window overwrites."""
    from companion.middleware.errors import UnknownParamError

    c = AdaptiveConstraint()
    assert "alpha_now_bytes_per_s" not in c.tunable()
    assert {"alpha_bytes_per_s", "min_bytes_per_s", "max_bytes_per_s"} <= set(c.tunable())
    with pytest.raises(UnknownParamError) as err:
        c.check_params({"alpha_now_bytes_per_s": 1000.0})
    assert "alpha_now" not in ", ".join(err.value.known)
    assert "constraint.alpha_bytes_per_s" in err.value.known  # the name a user types
    assert sorted(AimdConstraint().tunable()) == [
        "alpha_bytes_per_s", "beta_bytes_per_s", "decrease_factor", "increase_bytes_per_s",
        "max_bytes_per_s", "min_bytes_per_s"]


def test_a_new_alpha_moves_xi_at_once_without_waiting_for_a_window() -> None:
    """ξ = R(α) (eq. 6.8): a changed α is the operator's new tolerance for queueing, on the
    dashboard at the next status, even on a link that carries nothing to learn from."""
    c = AdaptiveConstraint()
    c.apply_params(c.check_params({"alpha_bytes_per_s": 5_000.0}))
    assert c.limit_bytes_per_s(now=T0) == pytest.approx(c.predict_bytes_per_s(5_000.0))
    assert c.limit_bytes_per_s(now=T0) < AdaptiveConstraint().limit_bytes_per_s(now=T0)
