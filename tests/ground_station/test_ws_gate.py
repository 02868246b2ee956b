"""WebSocketGate: per-client and total bounds, counted exactly, released exactly."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from ground_station.ws_guard import WebSocketGate


def test_per_client_then_total_bounds() -> None:
    gate = WebSocketGate.for_connections(10, max_per_client=3)  # 5 in all
    assert [gate.admit("a") for _ in range(3)] == [None] * 3
    assert gate.admit("a") == (429, "WebSocket refused: a has 3 open (ws_max_per_client)")
    assert [gate.admit("b") for _ in range(2)] == [None] * 2
    refused = gate.admit("c")
    assert refused is not None and refused[0] == 503
    gate.release("a")
    assert gate.admit("c") is None
    assert (gate.open, gate.refused) == (5, 2)


def test_at_least_one_websocket() -> None:
    gate = WebSocketGate.for_connections(1, max_per_client=8)
    assert gate.admit("a") is None
    assert gate.admit("b") is not None


@given(st.lists(st.tuples(st.sampled_from("abc"), st.booleans()), max_size=60))
def test_open_never_exceeds_the_bounds(steps: list[tuple[str, bool]]) -> None:
    gate = WebSocketGate(max_total=4, max_per_client=2)
    held: list[str] = []
    for client, opening in steps:
        if opening:
            if gate.admit(client) is None:
                held.append(client)
        elif client in held:
            held.remove(client)
            gate.release(client)
        assert gate.open == len(held) <= 4
        assert all(n <= 2 for n in gate.open_by_client.values())
    for client in held:
        gate.release(client)
    assert gate.open == 0 and not gate.open_by_client
