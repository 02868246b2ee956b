"""The fleet launcher's live line read from the logs the companions and the station really
write (``MissionLogWriter``, the station's ``log_record`` lines), at their real lags.

Before: a companion flushes its log once a second and the station after every batch, so the
line showed more images received than sent (``s1 r2``, ``s4 r6`` in a 40 s ``uav-sitl fleet``
on a terminal).
"""

from __future__ import annotations

import json
from pathlib import Path

from companion.mission_log import MissionLogWriter
from ground_station.storage_records import log_record
from sitl.fleet.live import LogTail, StationTail, progress_line
from sitl.fleet_config import DroneSlot
from utility_specs.message import Message

T0 = 1_700_000_000.0


def _image(seq: int, *, t_rcv: float | None = None) -> Message:
    return Message(sender="drone1", seq=seq, type="image", t_gen=T0 + seq, size=900,
                   t_sent=T0 + seq + 0.01, t_rcv=t_rcv, data={"red": 0.1})


def test_received_never_runs_ahead_of_sent(tmp_path: Path) -> None:
    slot = DroneSlot(index=0, drone_id="drone1", system_id=1, mavlink_port=0,
                     folder=tmp_path / "drone1")
    companion = MissionLogWriter(slot.log_path)
    station_log = tmp_path / "gs.jsonl"
    tail, station = LogTail(slot.log_path), StationTail(station_log)

    def line() -> str:
        tail.poll()
        station.poll()
        return progress_line(3.0, [slot], {"drone1": tail}, station, T0 + 3.0).split("] ", 1)[1]

    for seq in (1, 2):
        companion.write_message(_image(seq), sent=True, decision={"sent": True})
    companion.write_message(_image(3), sent=False, decision={"sent": False})
    companion.flush()
    with station_log.open("a") as f:  # the station stores each batch at once
        for seq in (1, 2, 4):
            f.write(json.dumps(log_record(_image(seq, t_rcv=T0 + seq + 0.05))) + "\n")
    # image 4 was sent and received; the companion's housekeeping has not flushed it yet
    companion.write_message(_image(4), sent=True, decision={"sent": True})
    assert line().startswith("drone1 g3 s2 r2 ")  # was r3: more received than sent
    companion.flush()
    assert line().startswith("drone1 g4 s3 r3 ")
    companion.close()
