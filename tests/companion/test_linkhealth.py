"""Δ and loss a drone reports in its status (companion.linkhealth)."""

from __future__ import annotations

from types import SimpleNamespace

from companion.linkhealth import LinkHealth


def test_loss_counts_messages_no_report_mentioned_within_the_grace() -> None:
    h = LinkHealth(grace_s=3.0)
    assert h.loss(0.0) is None
    for seq in range(4):
        h.on_sent(seq, float(seq))
    h.on_delivered(0)
    h.on_delivered(2)
    h.on_delivered(2)  # a repeated report entry counts once
    assert h.loss(3.5) == 0.0  # 1 and 3 are still within their grace
    assert h.loss(4.0) == 1 / 3  # 1 (sent at 1.0) is now lost
    assert h.loss(10.0) == 2 / 4  # 3 as well
    h.on_delivered(1)  # late (the drone or the station stalled): delivered after all
    assert h.loss(10.0) == 1 / 4
    h.on_delivered(1)
    assert h.loss(10.0) == 1 / 4


def test_a_late_report_undoes_only_a_loss_still_in_the_window() -> None:
    h = LinkHealth(grace_s=1.0, window=3)
    for seq in range(3):
        h.on_sent(seq, 0.0)
    assert h.loss(2.0) == 1.0
    h.on_sent(3, 2.0)
    h.on_delivered(3)  # the window is now 1, 2 (lost) and 3 (delivered)
    h.on_delivered(0)  # 0 left the window: nothing changes
    assert h.loss(2.0) == 2 / 3
    h.on_delivered(2)
    assert h.loss(2.0) == 1 / 3
    h.on_delivered(99)  # never sent (another drone's, a stale report)
    assert h.loss(2.0) == 1 / 3


def test_loss_is_over_the_last_window_of_settled_messages() -> None:
    h = LinkHealth(grace_s=1.0, window=4)
    for seq in range(4):
        h.on_sent(seq, 0.0)
    assert h.loss(5.0) == 1.0
    for seq in range(4, 8):
        h.on_sent(seq, 5.0)
        h.on_delivered(seq)
    assert h.loss(5.0) == 0.0


def test_delta_is_the_queueing_delay_of_the_last_window() -> None:
    stats = SimpleNamespace(queueing_delay_s=0.25)
    assert LinkHealth.delta_s(SimpleNamespace(last_stats=stats)) == 0.25
    assert LinkHealth.delta_s(SimpleNamespace(last_stats=SimpleNamespace(
        queueing_delay_s=-0.001))) == 0.0
    assert LinkHealth.delta_s(SimpleNamespace(last_stats=None)) is None
    assert LinkHealth.delta_s(object()) is None  # a constant constraint keeps no stats


def test_a_status_always_goes_and_counts_in_the_window() -> None:
    """The heartbeat: even when the window is full the status goes out, its bytes are
    counted, and the drone's status then carries the loss of what it sent."""
    from companion.app import build_decider
    from companion.config import parse_config
    from utility_specs.message import Message

    t0 = 1_700_000_000.0
    decider = build_decider(parse_config({
        "drone": {"id": "d1"}, "budgets": {"mcts_iterations": 30},
        "constraint": {"name": "constant",
                       "params": {"limit_bytes_per_s": 100.0, "window_s": 1.0}}}))
    status = Message(sender="d1", seq=0, type="status", t_gen=t0, size=300,
                     data={"mode": "AUTO", "armed": True, "since": t0 - 60.0})
    decision = decider.decide(status, t0)  # 300 B over a 100 B window: the tree drops it
    assert decision.send and decision.reason == "status-heartbeat"
    assert decider.knowledge.sent_in_window(now=t0, window_s=1.0) == 300
    image = Message(sender="d1", seq=1, type="position", t_gen=t0, size=300,
                    data={"lat_deg": 50.0, "lon_deg": 19.0, "alt_rel_m": 30.0})
    assert not decider.decide(image, t0).send  # other types stay the optimiser's choice
