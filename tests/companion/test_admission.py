"""ConnectionGate: per-client and total bounds, counted exactly, released exactly; the
dashboard's WebSocket refusals built on it."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from companion.admission import ConnectionGate, Refusal, worth_logging
from ground_station.ws_guard import refusal, refusal_text, websocket_gate


def test_per_client_then_total_bounds() -> None:
    gate = websocket_gate(10, max_per_client=3)  # 5 in all
    assert [gate.admit("a") for _ in range(3)] == [None] * 3
    refused = gate.admit("a")
    assert refused == Refusal("client", "a", 3, 1)
    assert refusal_text(refused) == "WebSocket refused: a has 3 open (ws_max_per_client)"
    assert refusal(refused).status == 429
    assert [gate.admit("b") for _ in range(2)] == [None] * 2
    refused = gate.admit("c")
    assert refused == Refusal("total", "c", 5, 1)
    assert refusal(refused).status == 503
    gate.release("a")
    assert gate.admit("c") is None
    assert gate.open == 5 and gate.refused == {"client": 1, "total": 1}


def test_at_least_one_websocket() -> None:
    gate = websocket_gate(1, max_per_client=8)
    assert gate.admit("a") is None
    assert gate.admit("b") is not None


def test_release_of_a_connection_not_held_is_a_bug_not_a_negative_count() -> None:
    gate = ConnectionGate(max_total=2, max_per_client=1)
    with pytest.raises(ValueError, match="did not hold"):
        gate.release("a")
    assert gate.admit("a") is None
    assert gate.admit("a") is not None  # the failed release did not make room


@pytest.mark.parametrize("caps", [(0, 1), (1, 0)])
def test_a_gate_that_admits_nothing_is_refused(caps: tuple[int, int]) -> None:
    with pytest.raises(ValueError, match="at least one"):
        ConnectionGate(*caps)


def test_refusals_are_logged_sparsely() -> None:
    assert [n for n in range(1, 3001) if worth_logging(n)] == [1, 10, 100, 1000, 2000, 3000]


@given(st.lists(st.tuples(st.sampled_from("abc"), st.booleans()), max_size=60))
def test_open_never_exceeds_the_bounds(steps: list[tuple[str, bool]]) -> None:
    gate = ConnectionGate(max_total=4, max_per_client=2)
    held: list[str] = []
    for client, opening in steps:
        if opening:
            refused = gate.admit(client)
            if refused is None:
                held.append(client)
            else:  # refused only when a bound is reached, and for the right reason
                assert (held.count(client) == 2) == (refused.reason == "client")
                assert len(held) == 4 or refused.reason == "client"
        elif client in held:
            held.remove(client)
            gate.release(client)
        assert gate.open == len(held) <= 4
        assert all(n <= 2 for n in gate.open_by_client.values())
    for client in held:
        gate.release(client)
    assert gate.open == 0 and not gate.open_by_client
