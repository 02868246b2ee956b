"""A local cluster that shuts down slowly does not turn a finished sweep into a failure."""
from __future__ import annotations

import pytest

from sitl.study import sweep


class _SlowToClose:
    def __init__(self) -> None:
        self.closed = False

    def close(self) -> None:
        self.closed = True
        raise TimeoutError()


def test_error_text_names_an_exception_without_a_message() -> None:
    assert sweep.error_text(TimeoutError()) == "TimeoutError"
    assert sweep.error_text(OSError("no scheduler at tcp://x:8786\nmore")) == \
        "no scheduler at tcp://x:8786"


def test_slow_shutdown_is_a_note_and_both_are_closed(capsys: pytest.CaptureFixture[str]) -> None:
    client, cluster = _SlowToClose(), _SlowToClose()
    sweep._shut_down(client, cluster)  # must not raise
    assert client.closed and cluster.closed
    err = capsys.readouterr().err
    assert "TimeoutError" in err and "results are complete" in err
