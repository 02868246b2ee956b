"""Refused datagrams of a wrong key or fleet are told at WARNING: the first at once, then at
most one line per minute with the count (a flood cannot fill the journal)."""

from __future__ import annotations

import logging

import pytest

from companion.drop_warnings import DropWarnings


def test_first_then_one_a_minute_with_the_count(caplog: pytest.LogCaptureFixture) -> None:
    now = [100.0]
    warnings = DropWarnings(logging.getLogger("test.drops"), clock=lambda: now[0])
    with caplog.at_level(logging.WARNING, logger="test.drops"):
        for _ in range(5):
            warnings.on_drop("bad_signature", ("127.0.0.1", 14600), "signature does not verify")
            now[0] += 1.0
        assert len(caplog.records) == 1
        assert "refused bad_signature from 127.0.0.1:14600" in caplog.records[0].getMessage()
        assert "the station's command.pub" in caplog.records[0].getMessage()
        now[0] = 160.5
        warnings.on_drop("bad_signature", ("127.0.0.1", 14600), "signature does not verify")
        assert len(caplog.records) == 2
        assert "refused 5 datagram(s) as bad_signature in the last 60 s" in \
            caplog.records[1].getMessage()
        warnings.on_drop("bad_tag", ("10.0.0.9", 5000), "tag mismatch")  # its own limit
        warnings.on_drop("replayed", ("127.0.0.1", 14600), "old")  # not a key problem
        warnings.on_drop("malformed", ("127.0.0.1", 14600), "short")
    assert [r.levelno for r in caplog.records] == [logging.WARNING] * 3
    assert "fleet.key" in caplog.records[2].getMessage()
