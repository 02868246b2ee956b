"""Image streaming at tight budgets (issue 18, round 6): telemetry is not starved by windows
the others' frames already broke, and the price on bytes counts each message's bytes in the
version its density is of."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from companion.middleware import ConstantConstraint, Middleware, MiddlewareConfig
from companion.middleware.gate import creates_violation, price_per_byte
from companion.middleware.incremental import FixedItem, PlanItem, build_problem
from companion.middleware.mcts import rollout_threshold
from utility_specs.files import builtin_spec
from utility_specs.message import Message, Version

FULL = Version(name="full", size=24_000, quality=1.0)
HALF = Version(name="half", size=7_000, quality=0.5)
QUARTER = Version(name="quarter", size=2_500, quality=0.25)


@pytest.mark.parametrize(("sends", "now", "size", "created"), [
    ([(0.0, 600), (1.0, 300)], 2.0, 100, False),     # 1000 of 1000: still within
    ([(0.0, 600), (1.0, 300)], 2.0, 101, True),      # the window from 0.0 breaks
    ([(0.0, 1200)], 1.0, 64, False),                 # already broken by the others: no new one
    ([(0.0, 1200), (1.0, 500)], 1.5, 400, False),    # the window from 1.0 holds 900
    ([(0.0, 1200), (1.0, 500)], 1.5, 600, True),     # ... and now 1100: a new violation
    ([(-3.0, 5000)], 0.0, 1000, False),              # older than T: in no window with now
    ([], 0.0, 1001, True),                           # alone over the budget
])
def test_a_send_creates_a_violation_only_if_it_breaks_a_window_that_was_within(
        sends: list[tuple[float, int]], now: float, size: int, created: bool) -> None:
    """Eq. 5.5/5.7: windows [t, t + T] from each send instant; budget 1000 B, T = 2.5 s."""
    assert creates_violation(sends, now=now, size=size, window_s=2.5,
                             budget_bytes=1000.0) is created


def _agent(**config: Any) -> Middleware:
    spec = builtin_spec("image_streaming")
    return Middleware(MiddlewareConfig(spec=spec, agent="a", max_iterations=300, **config),
                      rng=np.random.default_rng(1),
                      constraint=ConstantConstraint(limit_bytes_per_s=10_000.0, window_s=2.5))


def _peer_frame(t_sent: float, size: int) -> Message:
    return Message(sender="b", seq=1, type="image", t_gen=t_sent, t_sent=t_sent,
                   t_rcv=t_sent + 0.2, size=size, data={"red": 0.1},
                   versions=(Version(name="full", size=size, quality=1.0),), version=0)


def _position(seq: int, t: float) -> Message:
    return Message(sender="a", seq=seq, type="position", t_gen=t, size=64,
                   data={"lat_deg": 47.0, "lon_deg": 8.0, "alt_m": 30.0})


def test_a_position_goes_out_in_a_window_the_others_already_broke() -> None:
    """The peer's 30 kB frame, delivered, puts the 25 kB window over the budget: the tree
    prunes every send there, but a 64-byte position adds no violated window, so it goes out
    on its gain per byte with the opt-in ``small_share`` (round 6). The counter of planned
    violations still counts it: the window it joins is over the budget as this agent knows it."""
    mw = _agent(small_share=0.01)
    mw.on_delivered([_peer_frame(0.5, 30_000)], now=0.8)
    decision = mw.decide(_position(0, 1.0), 1.0)
    assert decision.send and decision.reason == "mcts-rescue"
    assert mw.counters["over_budget"] == 1 and mw.counters["rescue"] == 1
    off = _agent()  # the default: off
    off.on_delivered([_peer_frame(0.5, 30_000)], now=0.8)
    assert not off.decide(_position(0, 1.0), 1.0).send


def test_a_position_that_would_break_a_window_within_the_budget_stays_dropped() -> None:
    """24 990 of 25 000 bytes known: 64 more would make a violation of this agent's own."""
    mw = _agent(small_share=0.01)
    mw.on_delivered([_peer_frame(0.5, 24_990)], now=0.8)
    decision = mw.decide(_position(0, 1.0), 1.0)
    assert not decision.send and mw.counters["rescue"] == 0


def test_the_price_counts_each_message_in_its_densest_version_with_that_versions_bytes(
        ) -> None:
    """Four drones' frames over 3 s in full/half/quarter, a 5 kB window: the quarter is the
    densest version of every frame. Counted with its own 2.5 kB, two of them fill 6 kB (the
    budget over the 3 s span); counted at full size (the rollout's threshold) the first
    frame alone fills it, and the price is the densest frame's: nothing but a drone's very
    best frame could earn it."""
    spec = builtin_spec("image_streaming")
    items = []
    for k in range(12):
        red = 0.3 * (k % 4) / 3
        frame = Message(sender=f"d{k % 4}", seq=k // 4, type="image", t_gen=0.25 * k,
                        size=FULL.size, data={"red": red}, versions=(FULL, HALF, QUARTER),
                        version=0)
        items.append(PlanItem(message=frame, send_t=frame.t_gen, rcv_t=frame.t_gen + 0.1,
                              kind="decide" if k == 0 else "forecast"))
    problem = build_problem(spec, items=items, fixed=[], horizon_end=3.0, budget_bytes=5000.0,
                            window_s=2.5)
    quarter = [float(problem.gain[i, 3, 0]) / QUARTER.size for i in range(problem.n)]
    densities = sorted(quarter, reverse=True)
    span = float(problem.send_t[-1] - problem.send_t[0])
    fits = int(5000.0 * span / 2.5 // QUARTER.size)
    assert all(q >= float(problem.gain[i, o, 0]) / problem.size[i, o]
               for i, q in enumerate(quarter) for o in (1, 2))
    assert price_per_byte(problem) == pytest.approx(densities[fits])
    assert rollout_threshold(problem) == pytest.approx(densities[0])
    assert price_per_byte(problem) < rollout_threshold(problem)


# -- round 11: the red drone on the product path ------------------------------------------------


def _frames(sender: str, reds: list[float], times: list[float], *, counted: bool,
            first: int = 0) -> list[Message]:
    """Frames of one stream; ``counted``: they carry the camera's frame index, as the
    companion's do."""
    return [Message(sender=sender, seq=first + k, type="image", t_gen=t, size=FULL.size,
                    data={"red": red, **({"frame": first + k} if counted else {})},
                    versions=(FULL, HALF, QUARTER), version=0)
            for k, (red, t) in enumerate(zip(reds, times, strict=True))]


def _fleet_problem(decided: str, *, counted: bool = True, red: float = 0.5) -> tuple[Any, int]:
    """A red drone (red 0.5) and three plain ones, 3 frames/s each over 3 s, 10 kB/s over a
    2 s window (the slow fleet test's link), every stream's last half frame a second old;
    ``decided`` is the sender of the frame decided at t = 0."""
    spec = builtin_spec("image_streaming")
    times = [k / 3 for k in range(9)]
    senders = {"red": red, "plain": 0.0, "plain2": 0.0, "plain3": 0.0}
    frames: list[Message] = []
    fixed = []
    for j, (name, red) in enumerate(senders.items()):
        ts = [t + 0.01 * j for t in times]
        frames += _frames(name, [red] * 9, ts, counted=counted, first=10)
        base = _frames(name, [red], [-1.0], counted=counted, first=7)[0].with_version(1)
        fixed.append(FixedItem(message=base, send_t=-1.0, rcv_t=-0.9))
    frames.sort(key=lambda m: m.t_gen)
    decide = next(m for m in frames if m.sender == decided)
    items = [PlanItem(message=m, send_t=m.t_gen, rcv_t=m.t_gen + 0.1,
                      kind="decide" if m is decide else "forecast") for m in frames]
    level = next(i for i, it in enumerate(items) if it.kind == "decide")
    return build_problem(spec, items=items, fixed=fixed, horizon_end=3.0,
                         budget_bytes=20_000.0, window_s=2.0), level


def _density(problem: Any, level: int, option: int) -> float:
    return float(problem.gain[level, option, 0]) / int(problem.size[level, option])


def test_own_copies_do_not_price_a_frame_out_but_a_redder_frame_to_come_does() -> None:
    """Counted each as the stream's only send, a drone's own forecast frames, worth more
    the longer after its last send, set a price its current frame never earned: the red
    drone sent a half frame per ~2 s with the window half empty. With the decided level,
    its later frames count what they add once it is sent: copies add little, a much redder
    frame to come still raises the price (the value of waiting, round 5)."""
    spec = builtin_spec("image_streaming")
    times = [k / 3 for k in range(9)]

    def alone(reds: list[float]) -> Any:
        frames = _frames("a", reds, times, counted=False)
        items = [PlanItem(message=m, send_t=m.t_gen, rcv_t=m.t_gen + 0.1,
                          kind="decide" if k == 0 else "forecast")
                 for k, m in enumerate(frames)]
        base = _frames("a", [reds[0]], [-1.0], counted=False, first=50)[0].with_version(1)
        return build_problem(spec, items=items, horizon_end=3.0, budget_bytes=20_000.0,
                             window_s=2.0,
                             fixed=[FixedItem(message=base, send_t=-1.0, rcv_t=-0.9)])

    copies = alone([0.5] * 9)
    before, now = price_per_byte(copies), price_per_byte(copies, level=0)
    half = _density(copies, 0, 2)  # the version that fits the window with room to spare
    assert half < before  # the old price: the half frame waits for its own copies
    assert half >= now  # now it earns its price
    redder = alone([0.5, 0.5, 0.5, 0.5, 1.0, 0.5, 0.5, 0.5, 0.5])
    assert price_per_byte(redder, level=0) > 3 * now


def test_in_a_fleet_the_red_frame_earns_its_price_and_a_plain_one_does_not() -> None:
    """Four drones' streams in one window, the others' frames each counted as their
    stream's only send: the red drone's half frame earns the price, a plain drone's half
    frame does not (it leaves the room to the red frames). Pricing the others' frames as
    substitutes (each what it adds after the previous one) lowered the price until plain
    drones took a third of a 2-drone link (round 11, not kept)."""
    red, red_level = _fleet_problem("red")
    plain, plain_level = _fleet_problem("plain")
    red_price = price_per_byte(red, level=red_level)
    plain_price = price_per_byte(plain, level=plain_level)
    assert red_price > 0.0 and plain_price > 0.0
    assert _density(red, red_level, 2) >= red_price
    assert _density(plain, plain_level, 2) < plain_price


# -- the relay fleet's price: the others' frames they are expected to send ---------------------

DEMO_FULL = Version(name="full", size=30_000, quality=1.0)
DEMO_HALF = Version(name="half", size=8_500, quality=0.5)
DEMO_QUARTER = Version(name="quarter", size=2_500, quality=0.25)


def _demo_problem(decided: str, reds: dict[str, float], *, age_s: float) -> tuple[Any, int]:
    """The demo fleet's numbers: every drone's camera at 5 frames/s over the 3 s horizon,
    frames of 30 / 8.5 / 2.5 kB, ξ·T = 15 kB over T = 0.5 s; each stream's last half frame
    ``age_s`` old (the fleet silent since)."""
    spec = builtin_spec("image_streaming")
    versions = (DEMO_FULL, DEMO_HALF, DEMO_QUARTER)
    frames: list[Message] = []
    fixed = []
    for j, (name, red) in enumerate(reds.items()):
        for k in range(-1, 15):
            t = -age_s if k < 0 else k / 5 + 0.01 * j
            m = Message(sender=name, seq=100 + k, type="image", t_gen=t, size=DEMO_FULL.size,
                        data={"red": red, "frame": 100 + k}, versions=versions, version=0)
            if k < 0:
                fixed.append(FixedItem(message=m.with_version(1), send_t=t, rcv_t=t + 0.15))
            else:
                frames.append(m)
    frames.sort(key=lambda m: m.t_gen)
    decide = next(m for m in frames if m.sender == decided)
    items = [PlanItem(message=m, send_t=m.t_gen, rcv_t=m.t_gen + 0.15,
                      kind="decide" if m is decide else "forecast") for m in frames]
    level = next(i for i, it in enumerate(items) if it.kind == "decide")
    return build_problem(spec, items=items, fixed=fixed, horizon_end=3.0,
                         budget_bytes=15_000.0, window_s=0.5), level


def _best_density(problem: Any, level: int) -> float:
    return max(_density(problem, level, o) for o in range(1, int(problem.nopt[level])))


def test_a_silent_fleet_prices_every_half_frame_out_unless_expected_sends_count() -> None:
    """Four plain drones silent for 2 s: counted all, the others' 45 forecast frames (each
    as its stream's only send) price the drone's half frame out, and the same holds for
    every drone: the demo fleet sent no image for 8-18 s with the link empty. Counting
    each other drone's frames only up to the bytes it is expected to send over the horizon
    (here one half frame's, less than half of their densest version, the 30 kB full
    frame: none of theirs counts), the half frame earns the price; expected to send
    without bound, they price it out again."""
    plain = {"a": 0.0, "b": 0.0, "c": 0.0, "d": 0.0}
    problem, level = _demo_problem("a", plain, age_s=2.0)
    half = _density(problem, level, 2)
    assert half < price_per_byte(problem, level=level)
    one_half_frame = {name: float(DEMO_HALF.size) for name in "bcd"}
    priced = price_per_byte(problem, level=level, expected=one_half_frame)
    assert 0.0 < priced <= 0.1 * half
    assert price_per_byte(problem, level=level, expected={}) <= priced  # nothing expected
    assert price_per_byte(problem, level=level, expected={n: 9e9 for n in "bcd"}) > half


def test_with_expected_sends_the_red_drone_keeps_its_precedence() -> None:
    """A red drone (red 0.4) heard sending two full frames' bytes per horizon, the plain
    ones one: its frames raise the plain drone's price over what it is with the red drone
    expected to send nothing, the red drone's own frame earns its price four times over
    and the plain drone's only just (within 1 %)."""
    reds = {"a": 0.0, "r": 0.4, "c": 0.0, "d": 0.0}
    plain, level = _demo_problem("a", reds, age_s=1.0)
    one = float(DEMO_FULL.size)
    expected = {"r": 2.0 * one, "c": one, "d": one}
    price = price_per_byte(plain, level=level, expected=expected)
    assert price > price_per_byte(plain, level=level, expected=expected | {"r": 0.0})
    assert price <= _best_density(plain, level) < 1.01 * price
    red, red_level = _demo_problem("r", reds, age_s=1.0)
    red_price = price_per_byte(red, level=red_level, expected={n: one for n in "acd"})
    assert _best_density(red, red_level) >= 4.0 * red_price
