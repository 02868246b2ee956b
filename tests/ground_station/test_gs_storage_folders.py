"""Image folders are made once per process, and made again if removed while running."""

from __future__ import annotations

import shutil
from pathlib import Path

from ground_station.storage import Storage, StoreItem
from utility_specs.message import Message

T0 = 1_700_000_000.0


def image(seq: int) -> StoreItem:
    message = Message(sender="d1", seq=seq, type="image", t_gen=T0, size=4, t_rcv=T0)
    return StoreItem(mission="m", message=message, payload=b"jpeg", utility=1.0)


def test_a_folder_removed_while_running_is_made_again(tmp_path: Path) -> None:
    storage = Storage(tmp_path)
    try:
        assert storage.write_batch([image(1)], now=T0).stored == [True]
        folder = tmp_path / storage.image_relpath("m", image(1).message).parent
        shutil.rmtree(folder)
        result = storage.write_batch([image(2)], now=T0)
        assert result.stored == [True] and result.errors == []
        assert (tmp_path / storage.image_relpath("m", image(2).message)).read_bytes() == b"jpeg"
    finally:
        storage.close()
