"""The MAVLink thread against a loopback vehicle: streams, commands, loss and reconnect."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Callable, Iterator

import pytest
from companion_fake_vehicle import FakeVehicle
from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.mavlink import (
    ArmCommand,
    CommandError,
    MavlinkReader,
    MavlinkSettings,
    ParamReadCommand,
    SetModeCommand,
)
from companion.telemetry import (
    HeartbeatSample,
    LinkStateSample,
    Sample,
    StatusTextSample,
    TelemetryState,
)


class Recorder:
    """Collects samples posted from the reader thread into a TelemetryState."""

    def __init__(self) -> None:
        self.state = TelemetryState()
        self.samples: list[Sample] = []
        self.lock = threading.Lock()

    def post(self, sample: Sample) -> None:
        with self.lock:
            self.samples.append(sample)
            self.state.apply(sample)

    def wait(self, predicate: Callable[[], bool], timeout_s: float = 5.0) -> bool:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with self.lock:
                if predicate():
                    return True
            time.sleep(0.02)
        return False


@pytest.fixture
def recorder() -> Recorder:
    return Recorder()


def _reader(port: int, recorder: Recorder, **kw: float) -> MavlinkReader:
    settings = MavlinkSettings(url=f"udpout:127.0.0.1:{port}", heartbeat_timeout_s=1.0,
                               reconnect_delay_s=0.1, recv_timeout_s=0.1,
                               stream_ack_timeout_s=0.5, **kw)
    return MavlinkReader(settings, clock=time.time, post=recorder.post)


@pytest.fixture
def started() -> Iterator[list[MavlinkReader]]:
    readers: list[MavlinkReader] = []
    yield readers
    for r in readers:
        r.stop()
        r.join(5)


def test_ardupilot_streams_only_after_set_message_interval(
        vehicle: FakeVehicle, recorder: Recorder, started: list[MavlinkReader]) -> None:
    reader = _reader(vehicle.port, recorder)
    started.append(reader)
    reader.start()
    # each stream's first message, not just the position's (a loaded run read the snapshot
    # between GLOBAL_POSITION_INT and GPS_RAW_INT: no satellites yet)
    assert recorder.wait(lambda: None not in (
        (s := recorder.state.snapshot()).lat_deg, s.satellites, s.battery_v, s.roll_rad))
    snap = recorder.state.snapshot()
    assert snap.connected and snap.autopilot == "ardupilot" and snap.mode == "STABILIZE"
    assert snap.battery_v == pytest.approx(12.3) and snap.battery_remaining == 0.87
    assert snap.roll_rad == pytest.approx(0.1) and snap.satellites == 12
    assert vehicle.data_stream_requests == 0  # SET_MESSAGE_INTERVAL was accepted
    assert reader.counters["stream_requests"] == 1 and reader.counters["stream_fallbacks"] == 0
    assert vehicle.rates_hz[mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT] == pytest.approx(5.0)


def _asks_once_without_fallback(vehicle: FakeVehicle, recorder: Recorder,
                                started: list[MavlinkReader], foreign: str) -> None:
    """``foreign``, the other autopilot family's estimator message, is in the reader's table;
    the reader asks for its streams once and, past the fallback's deadline, has sent no
    REQUEST_DATA_STREAM (a refusal of ``foreign`` would have set it off)."""
    reader = _reader(vehicle.port, recorder)
    started.append(reader)
    reader.start()
    assert recorder.wait(lambda: recorder.state.snapshot().lat_deg is not None)
    time.sleep(3 * reader.settings.stream_ack_timeout_s)  # past the fallback's deadline
    assert foreign in reader.settings.stream_rates_hz
    assert reader.counters["stream_requests"] == 1
    assert reader.counters["stream_fallbacks"] == 0
    assert vehicle.data_stream_requests == 0


def test_ardupilot_is_not_asked_for_a_message_it_lacks(
        vehicle: FakeVehicle, recorder: Recorder, started: list[MavlinkReader]) -> None:
    """ArduCopter 4.5 answers SET_MESSAGE_INTERVAL for ESTIMATOR_STATUS (PX4's) DENIED with
    a STATUSTEXT, which the dashboard would show as the drone's latest status; the refusal
    also set off REQUEST_DATA_STREAM, which sets every stream group to our highest rate."""
    _asks_once_without_fallback(vehicle, recorder, started, "ESTIMATOR_STATUS")
    assert not [x for x in recorder.samples if isinstance(x, StatusTextSample)]


def test_px4_is_not_asked_for_a_message_it_lacks(recorder: Recorder,
                                                 started: list[MavlinkReader]) -> None:
    """PX4 SIH answers SET_MESSAGE_INTERVAL for EKF_STATUS_REPORT (ArduPilot's) FAILED; the
    refusal would set off REQUEST_DATA_STREAM, which PX4 ignores."""
    vehicle = FakeVehicle(autopilot="px4").start()
    try:
        _asks_once_without_fallback(vehicle, recorder, started, "EKF_STATUS_REPORT")
    finally:
        vehicle.stop()


def test_own_heartbeat_is_an_onboard_controller(
        vehicle: FakeVehicle, recorder: Recorder, started: list[MavlinkReader]) -> None:
    seen: list[mav.MAVLink_message] = []
    original = vehicle.handle
    vehicle.handle = lambda msg: (seen.append(msg), original(msg))  # type: ignore[method-assign]
    reader = _reader(vehicle.port, recorder)
    started.append(reader)
    reader.start()
    assert recorder.wait(lambda: any(m.get_type() == "HEARTBEAT" for m in seen))
    hb = next(m for m in seen if m.get_type() == "HEARTBEAT")
    assert hb.type == mav.MAV_TYPE_ONBOARD_CONTROLLER
    assert hb.autopilot == mav.MAV_AUTOPILOT_INVALID
    assert hb.get_srcComponent() == mav.MAV_COMP_ID_ONBOARD_COMPUTER


def test_falls_back_to_request_data_stream() -> None:
    vehicle = FakeVehicle(autopilot="ardupilot", accept_message_interval=False).start()
    recorder = Recorder()
    reader = _reader(vehicle.port, recorder)
    try:
        reader.start()
        assert recorder.wait(lambda: recorder.state.snapshot().lat_deg is not None)
        assert vehicle.data_stream_requests == 1
        assert reader.counters["stream_fallbacks"] == 1
    finally:
        reader.stop()
        reader.join(5)
        vehicle.stop()


def test_a_gcs_acks_on_a_shared_link_are_not_the_companions() -> None:
    """A GCS on the same link (a router, one UDP port) gets ACCEPTED for its own
    SET_MESSAGE_INTERVALs, addressed to it (target 255/190) but seen by every client of the
    link: counted as the companion's, they hid that the autopilot refused the companion's
    and the REQUEST_DATA_STREAM fallback never went out (no telemetry from ArduPilot)."""
    vehicle = FakeVehicle(autopilot="ardupilot", accept_message_interval=False).start()
    recorder = Recorder()
    reader = _reader(vehicle.port, recorder)
    stop = threading.Event()

    def gcs_acks() -> None:
        while not stop.wait(0.05):
            vehicle.send(mav.MAVLink_command_ack_message(
                mav.MAV_CMD_SET_MESSAGE_INTERVAL, mav.MAV_RESULT_ACCEPTED, 0, 0, 255, 190))

    threading.Thread(target=gcs_acks, daemon=True).start()
    try:
        reader.start()
        assert recorder.wait(lambda: recorder.state.snapshot().lat_deg is not None)
        assert reader.counters["stream_fallbacks"] == 1
    finally:
        stop.set()
        reader.stop()
        reader.join(5)
        vehicle.stop()


def test_mode_change_is_confirmed_by_heartbeat(
        vehicle: FakeVehicle, recorder: Recorder, started: list[MavlinkReader]) -> None:
    reader = _reader(vehicle.port, recorder)
    started.append(reader)
    reader.start()
    assert recorder.wait(lambda: recorder.state.snapshot().connected)
    assert reader.submit(SetModeCommand(mode="GUIDED")).result(5) == "GUIDED"
    with recorder.lock:
        modes = [s.mode for s in recorder.samples if isinstance(s, HeartbeatSample)]
    assert modes[-1] == "GUIDED"
    with pytest.raises(CommandError, match="unknown"):
        reader.submit(SetModeCommand(mode="WARP")).result(5)


def test_mode_change_not_shown_in_heartbeat_times_out(
        vehicle: FakeVehicle, recorder: Recorder, started: list[MavlinkReader]) -> None:
    vehicle.command = lambda msg: vehicle.ack(msg.command, 0)  # type: ignore[method-assign]
    reader = _reader(vehicle.port, recorder)
    started.append(reader)
    reader.start()
    assert recorder.wait(lambda: recorder.state.snapshot().connected)
    with pytest.raises(CommandError, match="not confirmed by HEARTBEAT"):
        reader.submit(SetModeCommand(mode="LOITER", timeout_s=0.5)).result(5)


def test_arm_refused_in_rtl_is_reported(
        vehicle: FakeVehicle, recorder: Recorder, started: list[MavlinkReader]) -> None:
    reader = _reader(vehicle.port, recorder)
    started.append(reader)
    reader.start()
    assert recorder.wait(lambda: recorder.state.snapshot().connected)
    reader.submit(SetModeCommand(mode="RTL")).result(5)
    with pytest.raises(CommandError, match="refused"):
        reader.submit(ArmCommand(arm=True)).result(5)
    reader.submit(SetModeCommand(mode="GUIDED")).result(5)
    assert reader.submit(ArmCommand(arm=True)).result(5) is True


def test_px4_streams_unasked_and_int_params_decode(
        px4_vehicle: FakeVehicle, recorder: Recorder, started: list[MavlinkReader]) -> None:
    reader = _reader(px4_vehicle.port, recorder)
    started.append(reader)
    reader.start()
    assert recorder.wait(lambda: recorder.state.snapshot().lat_deg is not None)
    assert recorder.state.snapshot().autopilot == "px4"
    assert reader.submit(ParamReadCommand(name="MAV_SYS_ID")).result(5) == 1
    assert recorder.state.snapshot().params["MAV_SYS_ID"] == 1


def test_an_unknown_parameter_is_a_read_that_nobody_answers(
        vehicle: FakeVehicle, recorder: Recorder, started: list[MavlinkReader]) -> None:
    """ArduCopter 4.5 SITL does not answer PARAM_REQUEST_READ for a name it lacks; the error
    said "not confirmed by HEARTBEAT", as if a HEARTBEAT could confirm a parameter."""
    reader = _reader(vehicle.port, recorder)
    started.append(reader)
    reader.start()
    assert recorder.wait(lambda: recorder.state.snapshot().connected)
    with pytest.raises(CommandError) as err:
        reader.submit(ParamReadCommand(name="NO_SUCH_PARAM", timeout_s=0.5)).result(5)
    assert str(err.value) == (
        "read parameter NO_SUCH_PARAM: no PARAM_VALUE within 0.5 s (the autopilot has no "
        "such parameter: it answers an unknown name with nothing)")
    assert reader.submit(ParamReadCommand(name="SYSID_THISMAV")).result(5) == 1


def test_heartbeat_loss_and_reconnect_without_restart(
        recorder: Recorder, started: list[MavlinkReader]) -> None:
    vehicle = FakeVehicle(autopilot="ardupilot").start()
    port = vehicle.port
    reader = _reader(port, recorder)
    started.append(reader)
    reader.start()
    assert recorder.wait(lambda: recorder.state.snapshot().lat_deg is not None)
    vehicle.stop()
    assert recorder.wait(lambda: not recorder.state.snapshot().connected, 5)
    with recorder.lock:
        lost = [s for s in recorder.samples if isinstance(s, LinkStateSample)][-1]
    assert "no HEARTBEAT" in lost.reason
    back = FakeVehicle(port=port, autopilot="ardupilot").start()
    try:
        assert recorder.wait(lambda: recorder.state.snapshot().connected, 8)
        assert recorder.wait(lambda: back.rates_hz != {}, 5)  # streams requested again
        snap = recorder.state.snapshot()
        assert snap.reconnects == 1
        assert reader.counters["heartbeat_losses"] == 1 and reader.counters["connects"] >= 2
    finally:
        back.stop()


def test_commands_fail_cleanly_without_a_vehicle(
        recorder: Recorder, started: list[MavlinkReader]) -> None:
    reader = _reader(9, recorder)  # discard port: nobody answers
    started.append(reader)
    reader.start()
    with pytest.raises(CommandError, match="no autopilot connected"):
        reader.submit(ArmCommand(arm=True)).result(5)


@pytest.mark.parametrize("shared", [True, False])
def test_run_logs_who_takes_the_autopilots_datagrams(
        shared: bool, recorder: Recorder, started: list[MavlinkReader],
        caplog: pytest.LogCaptureFixture) -> None:
    """`run` on the default loopback address with another program bound there too (another
    companion, a MAVProxy): both binds succeed (SO_REUSEADDR) and the link stays silent.
    `check` named that program; `run`'s log only said it reopened the link (newcomer walk)."""
    import logging

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as other:
        other.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        other.bind(("127.0.0.1", 0))
        port = other.getsockname()[1]
        if not shared:
            other.close()
        settings = MavlinkSettings(url=f"udpin:127.0.0.1:{port}", heartbeat_timeout_s=0.3,
                                   reconnect_delay_s=0.1, recv_timeout_s=0.05)
        reader = MavlinkReader(settings, clock=time.time, post=recorder.post)
        started.append(reader)
        with caplog.at_level(logging.INFO, logger="companion.mavlink"):
            reader.start()
            deadline = time.monotonic() + 10
            while "reopening" not in caplog.text and time.monotonic() < deadline:
                time.sleep(0.05)
    if shared:
        assert f"another program also listens on 127.0.0.1:{port}" in caplog.text, caplog.text
    else:
        assert f"nothing sent MAVLink to 127.0.0.1:{port}" in caplog.text, caplog.text


def test_time_the_reader_did_not_run_is_not_the_links_silence(
        vehicle: FakeVehicle, recorder: Recorder, started: list[MavlinkReader]) -> None:
    """The reader stops for a second in which its clock moves 6 s (its machine stalled)
    while the vehicle's messages queue in the socket: no link loss, the same connection,
    and commands answered on it after each stall. A stall is forgiven once per HEARTBEAT: a
    vehicle gone is lost at the second stall without one."""
    stall, offset, stalled = threading.Event(), [0.0], [0]

    def clock() -> float:
        if stall.is_set():  # only the reader thread reads this clock
            stall.clear()
            time.sleep(1.0)
            offset[0] += 5.0
            stalled[0] += 1
        return time.time() + offset[0]

    settings = MavlinkSettings(url=f"udpout:127.0.0.1:{vehicle.port}", heartbeat_timeout_s=3.0,
                               reconnect_delay_s=0.1, recv_timeout_s=0.1,
                               stream_ack_timeout_s=0.5)
    reader = MavlinkReader(settings, clock=clock, post=recorder.post)
    started.append(reader)
    reader.start()
    assert recorder.wait(lambda: recorder.state.snapshot().lat_deg is not None)
    for n, mode in enumerate(("GUIDED", "LOITER"), start=1):
        stall.set()
        assert recorder.wait(lambda n=n: reader.counters["stalls"] == n, 3)  # type: ignore[misc]
        assert reader.submit(SetModeCommand(mode=mode, timeout_s=2.0)).result(5) == mode
    time.sleep(1.5)
    assert reader.counters["heartbeat_losses"] == 0 and reader.counters["connects"] == 1
    assert recorder.state.snapshot().connected
    vehicle.stop()
    for _ in range(3):  # stalls again and again
        if not recorder.state.snapshot().connected:
            break
        n = stalled[0]
        stall.set()
        assert recorder.wait(lambda n=n: stalled[0] > n, 3)  # type: ignore[misc]
        time.sleep(0.3)  # a few receive rounds, then the next stall
    # the first was forgiven (a HEARTBEAT came since the last), the second is the silence
    assert recorder.wait(lambda: not recorder.state.snapshot().connected, 1)
    assert reader.counters["stalls"] == 3 and reader.counters["heartbeat_losses"] == 1


def test_a_clock_set_back_does_not_hide_a_lost_link(recorder: Recorder,
                                                    started: list[MavlinkReader]) -> None:
    """The companion's clock is set back an hour (a Pi without a real-time clock taking the
    time from NTP or GPS): the link stays up, and when the vehicle goes away it is lost
    within the timeout, not an hour later."""
    vehicle = FakeVehicle(autopilot="ardupilot").start()
    jump = [0.0]
    settings = MavlinkSettings(url=f"udpout:127.0.0.1:{vehicle.port}", heartbeat_timeout_s=1.0,
                               reconnect_delay_s=0.1, recv_timeout_s=0.1,
                               stream_ack_timeout_s=0.5)
    reader = MavlinkReader(settings, clock=lambda: time.time() + jump[0], post=recorder.post)
    started.append(reader)
    reader.start()
    assert recorder.wait(lambda: recorder.state.snapshot().lat_deg is not None)
    jump[0] = -3600.0
    time.sleep(1.5)
    assert recorder.state.snapshot().connected and reader.counters["heartbeat_losses"] == 0
    vehicle.stop()  # and the clock goes back again, before the timeout
    jump[0] = -7200.0
    assert recorder.wait(lambda: not recorder.state.snapshot().connected, 3)
    assert reader.counters["heartbeat_losses"] == 1
