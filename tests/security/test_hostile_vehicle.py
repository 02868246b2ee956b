"""The shipped ``uav-companion run`` fed by a hostile (or broken) autopilot link
(docs/security.md, 2026-11-24): after a real HEARTBEAT, garbage bytes, messages from another
system id and a STATUSTEXT flood with one EMERGENCY text among hundreds of INFO ones. The
ground station's socket here is a plain UDP socket decoded with the fleet's codec, so the test
sees exactly what the station would show.

Before the fix every STATUSTEXT woke the status publisher: the flood became a status message
per optimiser decision (dozens a second on a radio link meant for about one), and the texts
were joined oldest first and cut at 200 characters while the *worst* severity was reported:
the station raised an error-level alert whose text was INFO chatter, the EMERGENCY text cut
off. ``slow``: a companion starts (its optimiser compiles on a cold cache).
"""

from __future__ import annotations

import asyncio
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from companion.protocol import Decoder, MessageReassembled
from tests.integration.test_peers_e2e import FLEET, KEY, SPEC, companion_config, free_port
from tests.processes import interrupt
from tests.publisher_dispatcher import RecordingDispatcher

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mav

BIN = Path(sys.executable).parent
EMERGENCY = "EMERGENCY: motor 3 failure"


def _vehicle_frames() -> tuple[bytes, list[bytes]]:
    """A HEARTBEAT of system 1, and the flood (a few of it another system's)."""
    ours = mav.MAVLink(None, srcSystem=1, srcComponent=1)
    other = mav.MAVLink(None, srcSystem=42, srcComponent=1)
    heartbeat = ours.heartbeat_encode(mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                      mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 5,
                                      mav.MAV_STATE_STANDBY).pack(ours)
    flood = []
    for i in range(600):
        text = EMERGENCY if i == 300 else f"info chatter {i:04d}"
        severity = mav.MAV_SEVERITY_EMERGENCY if i == 300 else mav.MAV_SEVERITY_INFO
        flood.append(ours.statustext_encode(severity, text.encode()).pack(ours))
        if i % 50 == 0:
            flood.append(os.urandom(200))  # line noise
            flood.append(other.statustext_encode(mav.MAV_SEVERITY_EMERGENCY,
                                                 b"not our vehicle").pack(other))
    return heartbeat, flood


@pytest.mark.slow
@pytest.mark.timeout(180)
def test_a_statustext_flood_neither_floods_the_link_nor_hides_the_emergency(
        tmp_path: Path) -> None:
    vehicle = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    vehicle.bind(("127.0.0.1", 0))
    vehicle.settimeout(60)
    station = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    station.bind(("127.0.0.1", 0))
    station.settimeout(0.2)
    config = companion_config(tmp_path / "drone1.toml", drone="drone1",
                              vehicle_port=vehicle.getsockname()[1],
                              gs_port=station.getsockname()[1],
                              medium=f"broadcast:127.255.255.255:{free_port()}", spec=SPEC)
    err = tmp_path / "drone1.err"
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "MAVLINK20": "1"}
    with err.open("w") as stderr:
        companion = subprocess.Popen([str(BIN / "uav-companion"), "run", "--config",
                                      str(config)], stdout=subprocess.DEVNULL, stderr=stderr,
                                     text=True, env=env)
    decoder = Decoder(FLEET, KEY, local_id="gs")
    statuses: list[tuple[float, dict[str, object]]] = []

    def drain(until: float) -> None:
        while time.monotonic() < until:
            try:
                data, addr = station.recvfrom(65536)
            except TimeoutError:
                continue
            decoder.receive_datagrams([(data, addr)], time.time())
            while (event := decoder.next_event()) is not None:
                if isinstance(event, MessageReassembled) and event.message.type == "status":
                    statuses.append((time.monotonic(), dict(event.message.data)))

    try:
        _, companion_addr = vehicle.recvfrom(4096)  # its first HEARTBEAT: where it listens
        heartbeat, flood = _vehicle_frames()
        vehicle.sendto(heartbeat, companion_addr)
        # its optimiser may still compile: wait for a status that knows the autopilot
        deadline = time.monotonic() + 120
        while not any(d.get("autopilot") == "ardupilot" and d.get("optimiser_ready")
                      for _, d in statuses):
            assert time.monotonic() < deadline and companion.poll() is None, \
                err.read_text()[-3000:]
            drain(time.monotonic() + 0.5)
            vehicle.sendto(heartbeat, companion_addr)
        statuses.clear()
        t0 = time.monotonic()
        for i, frame in enumerate(flood):  # ~2 s of flood, heartbeats kept going
            vehicle.sendto(frame, companion_addr)
            if i % 40 == 39:
                vehicle.sendto(heartbeat, companion_addr)
                time.sleep(0.1)
        drain(time.monotonic() + 3.0)
        flood_s = time.monotonic() - t0
        assert companion.poll() is None, err.read_text()[-3000:]
        texts = [d for _, d in statuses if "statustext" in d]
        assert texts, statuses
        # the station shows the worst severity with that text, never chatter in its place
        worst = [d for d in texts if d.get("severity") == mav.MAV_SEVERITY_EMERGENCY]
        assert len(worst) == 1 and str(worst[0]["statustext"]).startswith(EMERGENCY), worst
        assert "not our vehicle" not in " ".join(str(d["statustext"]) for d in texts)
        # statustexts ride on statuses at most ~3 a second, not one per decision
        assert len(statuses) <= 3 * flood_s + 3, (len(statuses), flood_s)
    finally:
        vehicle.close()
        station.close()
        interrupt(companion, timeout_s=30, sig=signal.SIGTERM)
    assert companion.returncode == 0, err.read_text()[-3000:]
    assert "Traceback" not in err.read_text()


def test_the_status_text_begins_with_the_most_severe_and_counts_what_was_dropped() -> None:
    from companion.publisher import STATUSTEXT_CHARS, statustext_field
    from companion.telemetry import StatusTextSample

    texts = [StatusTextSample(t=i, severity=6, text=f"info {i:03d} " * 3) for i in range(30)]
    texts.insert(17, StatusTextSample(t=17.5, severity=0, text=EMERGENCY))
    texts.insert(3, StatusTextSample(t=3.5, severity=4, text="warning"))
    field = statustext_field(texts, dropped=12)
    assert field.startswith(f"{EMERGENCY} | warning | info 000 ")
    assert field.endswith(" (+12 more)") and len(field) == STATUSTEXT_CHARS


async def test_a_statustext_flood_rides_on_a_status_at_most_every_gap() -> None:
    """The unit form of the process test above (it runs in the default, not-slow, suite):
    2 s of STATUSTEXT at ~2 kHz. Before the fix: a status per decision (~150 here)."""
    from companion.config import TelemetryConfig
    from companion.mission import MissionWindow
    from companion.publisher import MAX_PENDING_TEXTS, STATUSTEXT_GAP_S, TelemetryPublisher
    from companion.telemetry import StatusTextSample, TelemetryState

    dispatcher = RecordingDispatcher(decide_s=0.005)  # 5 ms a decision, like a small MCTS
    state = TelemetryState()
    publisher = TelemetryPublisher(TelemetryConfig(status_period_s=5.0), telemetry=state,
                                   dispatcher=dispatcher,  # type: ignore[arg-type]
                                   mission=MissionWindow(), clock=time.time)
    state.add_listener(publisher.on_sample)
    task = asyncio.create_task(publisher.run())
    t0 = time.monotonic()
    i = 0
    while time.monotonic() - t0 < 2.0:
        for _ in range(4):
            i += 1
            state.apply(StatusTextSample(t=time.time(), severity=6, text=f"chatter {i}"))
        await asyncio.sleep(0.002)
    await asyncio.sleep(STATUSTEXT_GAP_S + 0.1)
    publisher.stop()
    await task
    with_text = [s for s in dispatcher.statuses if "statustext" in s]
    assert 2 <= len(dispatcher.statuses) <= 2.0 / STATUSTEXT_GAP_S + 3, len(dispatcher.statuses)
    assert all(str(s["statustext"]).endswith("more)") for s in with_text[1:])
    assert i > 10 * MAX_PENDING_TEXTS
