"""Roles and replays (issue 13 items 4, 5): only the ground station's Ed25519 key makes a
command a companion obeys; a companion obeys a command of its own boot only; a restarted
receiver refuses what a sender sent before the restart."""

from __future__ import annotations

import json
import secrets

from hypothesis import given, settings
from hypothesis import strategies as st
from protocol_helpers import ADDR, FLEET, KEY, T0, drain, make_encoder, transfer

from companion.protocol import (
    Command,
    CommandReceived,
    Decoder,
    Encoder,
    MessageReassembled,
    PacketDropped,
    Report,
)
from companion.protocol.wire import HEADER, TAG_BYTES, tag
from tests.keys import TEST_COMMAND_PUB
from utility_specs.message import Message

START = Command(command_id=3, name="start", t_exec=T0 + 5.0)


def drone_decoder(epoch: int | None = 77) -> Decoder:
    """A companion's decoder: the station's public key and this boot's epoch."""
    return Decoder(FLEET, KEY, local_id="drone1", command_key=TEST_COMMAND_PUB, epoch=epoch)


def reasons(events: list) -> list[str]:
    return [e.reason if isinstance(e, PacketDropped) else type(e).__name__ for e in events]


def test_the_station_command_is_obeyed() -> None:
    datagram = make_encoder("ground").encode_command(START, T0, epoch=77)
    events = transfer([datagram], drone_decoder(), now=T0)
    assert events == [CommandReceived(command=START, sender="ground", t_sent=T0, t_rcv=T0,
                                      addr=ADDR)]


def test_a_drone_with_the_fleet_key_cannot_command() -> None:
    """drone9 holds the fleet HMAC key and signs with its own Ed25519 key: not obeyed, under
    its own id or the station's."""
    forged = [
        Encoder(FLEET, sender, KEY, command_key=secrets.token_bytes(32)).encode_command(
            START, T0, epoch=77)
        for sender in ("drone9", "ground")
    ]
    decoder = drone_decoder()
    assert reasons(transfer(forged, decoder, now=T0)) == ["bad_signature", "bad_signature"]
    assert decoder.counters["bad_signature"] == 2 and decoder.counters["commands"] == 0


def test_a_command_without_signature_is_refused() -> None:
    """Version 1 layout (no signature) under a valid fleet tag."""
    body = b"\x00" * 8 + b"\x00\x00\x00\x03" + b"\x41\xd9\x54\xfc\x41\x40\x00\x00\x05start\x00{}"
    head = HEADER.pack(b"UV", 2, 3, FLEET, 5 << 32, T0, len(body), 6) + b"drone9" + body
    assert reasons(transfer([head + tag(KEY, head)], drone_decoder(), now=T0)) == [
        "bad_signature"]


def test_rewrapping_a_signed_command_breaks_the_signature() -> None:
    """A captured command with a fresh packet number and t_sent, re-tagged with the fleet key
    (what a compromised drone could do): the signature covers the header."""
    original = make_encoder("ground").encode_command(START, T0, epoch=77)
    magic, version, kind, fleet, pn, t_sent, body_len, n = HEADER.unpack_from(original)
    header = HEADER.pack(magic, version, kind, fleet, pn + 1000, t_sent + 100, body_len, n)
    signed = header + original[HEADER.size : -TAG_BYTES]
    rewrapped = signed + tag(KEY, signed)
    assert reasons(transfer([rewrapped], drone_decoder(), now=T0 + 100)) == ["bad_signature"]


def test_the_ground_station_obeys_no_command() -> None:
    station = Decoder(FLEET, KEY, local_id="ground")  # no command key
    datagram = make_encoder("ground").encode_command(START, T0, epoch=0)
    assert reasons(transfer([datagram], station, now=T0)) == ["bad_signature"]


def test_a_command_for_another_boot_is_refused() -> None:
    ground = make_encoder("ground")
    decoder = drone_decoder(epoch=77)
    old = ground.encode_command(START, T0, epoch=76)
    unknown = ground.encode_command(START, T0, epoch=0)
    current = ground.encode_command(START, T0, epoch=77)
    assert reasons(transfer([old, unknown, current], decoder, now=T0)) == [
        "wrong_epoch", "wrong_epoch", "CommandReceived"]


def test_fleet_key_traffic_cannot_push_the_command_window() -> None:
    """A report forged as 'ground' with a huge packet number (fleet key only) must not make
    the station's next signed command look old."""
    decoder = drone_decoder()
    forger = Encoder(FLEET, "ground", KEY)
    forger._next_packet_number = (1 << 63)  # far ahead of the station's numbers
    forged = forger.encode_report(Report(entries=(), echoes=()), T0)
    command = make_encoder("ground").encode_command(START, T0, epoch=77)
    assert reasons(transfer([*forged, command], decoder, now=T0)) == [
        "ReportReceived", "CommandReceived"]


# -- replay across a receiver restart --------------------------------------------------------


def _telemetry_stream(encoder: Encoder, start: float, seconds: float, rate_hz: float,
                      offset: float) -> list[tuple[float, bytes]]:
    """(receive time, datagram) of a drone whose clock is ``offset`` ahead of the receiver."""
    out = []
    n = int(seconds * rate_hz)
    for i in range(n):
        t = start + i / rate_hz
        message = Message(sender=encoder.sender, seq=i, type="battery", t_gen=t + offset,
                          data={"level": 0.5})
        (datagram,) = encoder.fragment(message, b"", now=t + offset)
        out.append((t + 0.01, datagram))
    return out


def _accepts(decoder: Decoder, stream: list[tuple[float, bytes]], now: float | None = None,
             ) -> list[bool]:
    result = []
    for t_rcv, datagram in stream:
        decoder.receive_datagram(datagram, ADDR, t_rcv if now is None else now)
        events = drain(decoder)
        result.append(any(isinstance(e, MessageReassembled) for e in events))
    return result


@settings(max_examples=30, deadline=None)
@given(offset=st.floats(-20.0, 20.0), downtime=st.floats(0.0, 8.0),
       saved_after=st.floats(0.5, 22.9))
def test_a_restarted_receiver_refuses_everything_sent_before_it(
    offset: float, downtime: float, saved_after: float
) -> None:
    """Captures 11-23 s old at the restart are all refused, whatever the drone's clock offset
    and however stale the saved state (a crash between two writes); datagrams the drone sends
    from 1.1 s after the restart on are accepted."""
    encoder = Encoder(FLEET, "drone1", KEY)
    before = Decoder(FLEET, KEY, local_id="ground")
    captured = _telemetry_stream(encoder, T0, 23.0, 10.0, offset)
    assert all(_accepts(before, captured))
    # the state file as last written, at some moment of the run (a crash loses the rest)
    saved_at = T0 + saved_after
    state_before = Decoder(FLEET, KEY, local_id="ground")
    _accepts(state_before, [c for c in captured if c[0] <= saved_at])
    saved = json.loads(json.dumps(state_before.replay_state(saved_at)))
    restart = T0 + 23.0 + downtime
    after = Decoder(FLEET, KEY, local_id="ground")
    assert after.restore_replay_state(saved, restart) == 1
    replay = [c for c in captured if restart - 23.0 <= c[0] - 0.01 <= restart - 11.0]
    assert replay and not any(_accepts(after, replay, now=restart + 0.5))
    assert after.counters["replayed"] == len(replay)
    fresh = _telemetry_stream(encoder, restart + 1.1, 2.0, 10.0, offset)
    assert all(_accepts(after, fresh))


def test_after_a_clean_shutdown_only_what_was_accepted_is_refused() -> None:
    """A state saved as the receiver stopped (``closed``) is exact: every capture of what it
    accepted is still refused, and what the drone sent while it was down, or in its first
    second back, is accepted (the crash rule refused that second: real data lost and
    ``replayed`` alerts after every ordinary restart)."""
    encoder = Encoder(FLEET, "drone1", KEY)
    offset = -3.0
    before = Decoder(FLEET, KEY, local_id="ground")
    captured = _telemetry_stream(encoder, T0, 5.0, 10.0, offset)
    assert all(_accepts(before, captured))
    saved = json.loads(json.dumps(before.replay_state(T0 + 5.0)))
    after = Decoder(FLEET, KEY, local_id="ground")
    assert after.restore_replay_state(saved, T0 + 5.2, closed=True) == 1
    assert not any(_accepts(after, captured, now=T0 + 5.3))
    assert after.counters["replayed"] == len(captured)
    down_and_back = _telemetry_stream(encoder, T0 + 5.1, 1.0, 10.0, offset)  # from 5.11 s
    assert all(_accepts(after, down_and_back))
    crashed = Decoder(FLEET, KEY, local_id="ground")  # the same file, not closed: refused
    crashed.restore_replay_state(saved, T0 + 5.2)
    assert not any(_accepts(crashed, down_and_back))


def test_a_second_restart_after_a_quiet_spell_still_refuses_the_last_burst() -> None:
    """Restart, the drone is heard, goes quiet for 40 s, the state is saved, the drone sends
    a burst, the station crashes before the next save: the burst is refused after the
    second restart (the saved offset, not the save's age, decides)."""
    encoder = Encoder(FLEET, "drone1", KEY)
    offset = 7.5
    first = Decoder(FLEET, KEY, local_id="ground")
    assert all(_accepts(first, _telemetry_stream(encoder, T0, 5.0, 10.0, offset)))
    second = Decoder(FLEET, KEY, local_id="ground")
    second.restore_replay_state(first.replay_state(T0 + 5.0), T0 + 6.0)
    assert all(_accepts(second, _telemetry_stream(encoder, T0 + 7.5, 2.0, 10.0, offset)))
    saved = json.loads(json.dumps(second.replay_state(T0 + 49.5)))  # after 40 s of quiet
    burst = _telemetry_stream(encoder, T0 + 49.6, 0.5, 10.0, offset)
    assert all(_accepts(second, burst))
    third = Decoder(FLEET, KEY, local_id="ground")
    third.restore_replay_state(saved, T0 + 50.5)  # crashed at 50.2, before the next save
    assert not any(_accepts(third, burst, now=T0 + 51.0))
    assert all(_accepts(third, _telemetry_stream(encoder, T0 + 51.6, 1.0, 10.0, offset)))


def test_restore_ignores_damaged_entries_and_old_senders() -> None:
    decoder = Decoder(FLEET, KEY, local_id="ground")
    state = {
        "drone1": [5 << 32, T0, T0],
        "old": [5 << 32, T0 - 100, T0 - 100],   # heard 100 s ago: stale anyway
        "nan": [1, float("nan"), T0],
        "short": [1, 2],
        "text": ["1", T0, T0],
        "bool": [True, T0, T0],
    }
    assert decoder.restore_replay_state(state, T0 + 5) == 1
