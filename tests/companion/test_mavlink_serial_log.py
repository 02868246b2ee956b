"""What the companion's log says about a serial autopilot that goes away and comes back.

Seen with ArduCopter 4.5 SITL on a socat pty at 57600 baud (docs/companion.md, round 14): the
SITL killed and started again, the log said "link lost", then that 1 unparsable chunk (the
frame torn by the kill) meant "the baud rate (57600) differs from the autopilot's"; a link
lost and back within one reopening said "link lost" last, with the autopilot long back.
"""

from __future__ import annotations

import contextlib
import logging
import os
import threading
import time
import tty
from collections.abc import Iterator
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.mavlink import MavlinkReader, MavlinkSettings
from companion.mavlink_hint import silence_hint
from companion.telemetry import Sample

TORN = b"\xfd\x09\x00\x00\x05\x01"
"""The head of a MAVLink 2 frame whose rest never came (an autopilot dying mid-frame)."""


class PtyAutopilot:
    """HEARTBEATs at 10 Hz on the master side of a pty while ``beating`` is set."""

    def __init__(self, tmp_path: Path) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.link = tmp_path / "ttyFC"
        self.link.symlink_to(os.ttyname(self.slave))
        os.set_blocking(self.master, False)
        self.beating = threading.Event()
        self._stop = threading.Event()
        self._encoder = mav.MAVLink(None, srcSystem=1, srcComponent=1)
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def write(self, data: bytes) -> None:
        with contextlib.suppress(OSError):
            os.write(self.master, data)

    def _run(self) -> None:
        hb = mav.MAVLink_heartbeat_message(mav.MAV_TYPE_QUADROTOR,
                                           mav.MAV_AUTOPILOT_ARDUPILOTMEGA, 81, 0, 4, 3)
        while not self._stop.wait(0.1):
            with contextlib.suppress(OSError):  # what the companion sends: drained
                while os.read(self.master, 4096):
                    pass
            if self.beating.is_set():
                self.write(hb.pack(self._encoder))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5)
        os.close(self.master)
        os.close(self.slave)


@pytest.fixture
def autopilot(tmp_path: Path) -> Iterator[PtyAutopilot]:
    ap = PtyAutopilot(tmp_path)
    yield ap
    ap.close()


def _reader(link: Path, heartbeat_timeout_s: float) -> MavlinkReader:
    settings = MavlinkSettings(url=str(link), baud=57600, heartbeat_timeout_s=heartbeat_timeout_s,
                               reconnect_delay_s=0.1, recv_timeout_s=0.1)
    samples: list[Sample] = []
    return MavlinkReader(settings, clock=time.time, post=samples.append)


def _until(what: str, cond: object, caplog: pytest.LogCaptureFixture,
           timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not callable(cond) or not cond():
        assert time.monotonic() < deadline, f"{what}: {caplog.text[-2000:]}"
        time.sleep(0.02)


def _said(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records
            if r.name == "companion.mavlink" and r.levelno >= logging.INFO]


def test_a_link_lost_and_back_says_it_is_back(autopilot: PtyAutopilot,
                                              caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO, logger="companion.mavlink")
    reader = _reader(autopilot.link, heartbeat_timeout_s=1.0)
    autopilot.beating.set()
    reader.start()
    try:
        url = str(autopilot.link)
        _until("first HEARTBEAT logged", lambda: f"mavlink: HEARTBEAT from system 1 on {url}"
               in _said(caplog), caplog)
        autopilot.beating.clear()  # a reboot longer than the heartbeat timeout
        _until("link lost", lambda: reader.counters["heartbeat_losses"] == 1, caplog)
        autopilot.beating.set()  # back before the reopened link's own timeout
        _until("link back logged", lambda: any(
            s.startswith(f"mavlink: HEARTBEAT from system 1 on {url}: back after ")
            for s in _said(caplog)), caplog)
    finally:
        reader.stop()
        reader.join(5)
    said = _said(caplog)
    lost = next(i for i, s in enumerate(said) if s.startswith("mavlink link lost"))
    assert any(s.startswith(f"mavlink: HEARTBEAT from system 1 on {url}: back after ")
               for s in said[lost:]), said
    assert not any("closing it and reopening" in s for s in said), said


def test_a_frame_torn_by_the_autopilot_dying_is_no_baud_problem(
        autopilot: PtyAutopilot, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO, logger="companion.mavlink")
    reader = _reader(autopilot.link, heartbeat_timeout_s=0.5)
    autopilot.beating.set()
    reader.start()
    try:
        _until("connected", lambda: reader.counters["connects"] >= 1
               and any(s.startswith("mavlink: HEARTBEAT") for s in _said(caplog)), caplog)
        autopilot.write(TORN)  # a frame cut short: the next HEARTBEAT is read as its rest
        _until("the torn frame read", lambda: reader.counters["bad_messages"] >= 1, caplog)
        autopilot.beating.clear()  # then nothing: the SITL was killed
        _until("the silence said", lambda: any("closing it and reopening" in s
                                               for s in _said(caplog)), caplog)
    finally:
        reader.stop()
        reader.join(5)
    notice = next(s for s in _said(caplog) if "closing it and reopening" in s)
    assert "baud rate (57600) differs" not in notice, notice
    assert "the line is open but silent" in notice, notice


def test_one_or_two_unparsable_chunks_are_no_baud_problem_but_a_stream_of_them_is() -> None:
    assert "differs" not in silence_hint("/dev/ttyAMA9", unparsable=1, baud=57600)
    assert "line is open but silent" in silence_hint("/dev/ttyAMA9", unparsable=2, baud=57600)
    assert "the baud rate (57600) differs" in silence_hint("/dev/ttyAMA9", unparsable=3,
                                                           baud=57600)
