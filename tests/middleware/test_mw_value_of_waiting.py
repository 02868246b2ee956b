"""The value of waiting for a better frame (issue 18, round 5): spread forecasts and the
price of bytes at the root."""

from __future__ import annotations

import random

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.middleware.forecast import StreamForecaster
from companion.middleware.gate import priced_option
from companion.middleware.incremental import PlanItem, Problem
from companion.middleware.knowledge import FleetKnowledge, PlanningView, settle_inflight
from sitl.netsim import simulate
from sitl.study import baselines as study
from sitl.study import drop_rate as dr
from tests.middleware.conftest import T0, msg
from utility_specs.files import builtin_spec

KEY = ("a", "image")


def _red_stream(reds: list[float], *, worth: bool = True) -> StreamForecaster:
    f = StreamForecaster(worth=(lambda m: 1.0 + 10.0 * m.data["red"]) if worth else None)
    for k, red in enumerate(reds):
        f.observe(msg("a", k, "image", T0 + 0.2 * k, red=red))
    return f


def test_forecasts_of_a_varied_stream_are_drawn_from_its_recent_frames() -> None:
    reds = [k / 20 for k in range(20)]
    random.Random(3).shuffle(reds)
    f = _red_stream(reds)
    now = T0 + 0.2 * 19
    predicted = f.forecast(KEY, t_from=now, t_to=now + 3.0)
    assert len(predicted) == 15
    got = [m.data["red"] for m in predicted]
    assert set(got) <= set(reds)
    # a low-discrepancy draw: any 10 consecutive forecasts fall in 7+ different deciles,
    # and the best of the 15 is near the top of the distribution (copies would all be
    # the last frame's red, reds[-1])
    for start in range(6):
        assert len({int(10 * r) for r in got[start:start + 10]}) >= 7
    assert max(got) >= 0.9
    assert len(set(got)) >= 12
    # the forecasts are otherwise the copies they were: times, seqs, versions
    assert [m.seq for m in predicted] == [-1 - i for i in range(15)]
    assert all(m.versions == predicted[0].versions and m.version == 0 for m in predicted)


def test_a_future_frame_is_forecast_the_same_at_every_decision() -> None:
    reds = [(7 * k % 20) / 20 for k in range(20)]
    f = _red_stream(reds)
    now = T0 + 0.2 * 19
    first = {round(m.t_gen, 6): m.data["red"] for m in f.forecast(KEY, t_from=now, t_to=now + 3)}
    later = {round(m.t_gen, 6): m.data["red"]
             for m in f.forecast(KEY, t_from=now + 1.0, t_to=now + 3)}
    assert later and all(first[t] == red for t, red in later.items())


def test_a_stream_of_equal_worth_is_forecast_as_copies_of_its_last_message() -> None:
    f = _red_stream([0.1 + 0.001 * (k % 2) for k in range(20)])  # worth spread < 5 %
    now = T0 + 0.2 * 19
    predicted = f.forecast(KEY, t_from=now, t_to=now + 3.0)
    assert predicted and all(m.data["red"] == 0.101 for m in predicted)
    plain = _red_stream([k / 20 for k in range(20)], worth=False)
    assert all(m.data["red"] == 0.95 for m in plain.forecast(KEY, t_from=now, t_to=now + 3))


def test_knowledge_worth_is_the_best_version_over_its_span() -> None:
    spec = builtin_spec("image_streaming")
    k = FleetKnowledge(spec, agent="a", default_latency_s=0.05)
    red = msg("a", 1, "image", T0, red=0.2)
    quarter = red.with_version(2)
    assert k.worth(quarter) == k.worth(red)  # the data is what a future frame repeats
    assert k.worth(red) > 2.9 * k.worth(msg("a", 2, "image", T0, red=0.0))
    assert FleetKnowledge(spec, agent="a", default_latency_s=0.05,
                          spread_forecasts=False).forecaster.worth is None


def test_in_flight_messages_with_versions_are_settled_not_searched() -> None:
    def item(sender: str, seq: int, t: float, type_: str, kind: str) -> PlanItem:
        return PlanItem(message=msg(sender, seq, type_, t, red=0.1), send_t=t, rcv_t=t + 0.1,
                        kind=kind)

    own = item("a", 9, 2.0, "image", "decide")
    frames = [item("b", i, 1.0 + 0.2 * i, "image", "inflight") for i in range(3)]
    fix = item("c", 0, 1.5, "position", "inflight")
    view = PlanningView(items=[*frames, fix, own], fixed=[], root_window=[], horizon_end=5.0)
    settled = settle_inflight(view, now=2.0, rates={}, lag_s=1.0, keep=4, settle_versions=True)
    assert [it.message.key[:2] for it in settled.items] == [("c", 0), ("a", 9)]
    kept = settle_inflight(view, now=2.0, rates={}, lag_s=1.0, keep=4)
    assert len(kept.items) == 5


def _one_level(gains: list[float], sizes: list[int]) -> Problem:
    n_opt = 1 + len(gains)
    gain = np.zeros((1, n_opt, 1))
    gain[0, 1:, 0] = gains
    size = np.zeros((1, n_opt), dtype=np.int64)
    size[0, 1:] = sizes
    item = PlanItem(message=msg("a", 1, "image", T0, red=0.1), send_t=T0, rcv_t=T0,
                    kind="decide")
    return Problem(items=[item], stream=np.array([-1]), pos=np.zeros(1, dtype=np.int64),
                   nopt=np.array([n_opt]), size=size, send_t=np.zeros(1), gain=gain,
                   nslot=np.zeros((1, n_opt, 1), dtype=np.int64), stream_keys=[],
                   stream_markov=np.zeros(0, dtype=np.bool_), root_win_t=np.zeros(0),
                   root_win_bytes=np.zeros(0, dtype=np.int64), budget_bytes=1e9, window_s=1.0,
                   max_versions=len(gains), decided_level=0, horizon_end=1.0)


def test_a_quarter_copy_that_does_not_earn_its_bytes_is_dropped() -> None:
    # a red frame: full 1.5 (40 kB), half 0.53 (10 kB), quarter 0.04 (2.5 kB); the horizon
    # pays 2.5e-5 per byte (what a plain full frame earns)
    p = _one_level([1.5, 0.53, 0.04], [40_000, 10_000, 2_500])
    assert priced_option(p, 0, 3, 2.5e-5) == 0  # the tree's quarter does not earn 62.5e-3
    assert priced_option(p, 0, 1, 2.5e-5) == 1  # the full frame does: kept
    assert priced_option(p, 0, 2, 2.5e-5) == 2
    assert priced_option(p, 0, 1, 4.0e-5) == 2  # only the half earns 4e-5: smaller, sent
    assert priced_option(p, 0, 3, 0.0) == 3  # no price: the tree's option


@settings(max_examples=100, deadline=None)
@given(st.lists(st.tuples(st.floats(0, 2), st.integers(1, 50_000)), min_size=1, max_size=4),
       st.integers(0, 4), st.floats(0, 1e-4))
def test_priced_option_earns_its_bytes_and_never_grows(
        options: list[tuple[float, int]], tree: int, lam: float) -> None:
    p = _one_level([g for g, _ in options], [s for _, s in options])
    tree = min(tree, len(options))
    got = priced_option(p, 0, tree, lam)
    if tree == 0:
        assert got == 0
        return
    earns = [o for o in range(1, len(options) + 1)
             if p.gain[0, o, 0] >= lam * max(1, p.size[0, o])]
    if tree in earns:
        assert got == tree
    elif got:
        assert got in earns and p.size[0, got] <= p.size[0, tree]
        assert all(p.gain[0, got, 0] >= p.gain[0, o, 0] for o in earns
                   if p.size[0, o] <= p.size[0, tree])
    else:
        assert not [o for o in earns if p.size[0, o] <= p.size[0, tree]]


def _fleet(policy: str, budget: float) -> tuple[float, float, int]:
    """Two drones of the study's image fleet, 12 s: (utility %, mean percentile of the sent
    frames' red content within their drone's frames, frames sent)."""
    spec = builtin_spec("image_streaming")
    agents = study.image_fleet(lambda a, i: study._policy(
        policy, budget, spec=spec, agent=a, index=i, seed=1,
        budget_bytes=budget * study.IMAGE_WINDOW_S, window_s=study.IMAGE_WINDOW_S,
        horizon_s=3.0), n=2, seed=1)
    result = simulate(agents, channel=study.IMAGE_CHANNEL, t_end=8.0,
                      rng=np.random.default_rng([1, 3]))
    ranks = []
    for a in agents:
        reds = np.array([m.data["red"] for m in result.generated
                         if m.sender == a.name and m.type == "image"])
        ranks += [float((reds < m.data["red"]).mean()) for m in result.delivered
                  if m.sender == a.name and m.type == "image"]
    return dr.utility_pct(spec, result.generated, 8.0), float(np.mean(ranks)), len(ranks)


def test_the_optimiser_waits_for_redder_frames() -> None:
    """Two drones at 40 kB/s, 8 s: the frames the default optimiser sends are the redder ones
    of each stream. Measured: 6 frames at mean percentile 0.71, 69.9 % (knapsack-greedy 11
    frames, 0.66, 67.4 %); the round-4 model (forecasts copying the last frame, no price on
    bytes) sent 25 frames of average red (percentile 0.52) whenever its plan had room, 63.5 %."""
    utility, rank, frames = _fleet("mcts300", 40_000.0)
    assert rank >= 0.6
    assert frames <= 15
    knapsack, _, _ = _fleet("knapsack", 40_000.0)
    assert utility >= knapsack - 3.0
