"""docs/architecture.md "Adding a scorer", run as written: module, one line, a scored frame."""

from __future__ import annotations

import asyncio
import importlib.util
import re
import sys
import time
import tomllib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from companion import scoring
from companion.camera import Frame
from companion.config import ConfigError, parse_config
from companion.dispatch import COUNTERS, Dispatcher
from companion.mission import MissionWindow
from companion.mission_log import MissionLogWriter
from companion.pipeline import CameraPipeline
from utility_specs.message import Message

DOC = Path(__file__).resolve().parents[2] / "docs" / "architecture.md"


def _section_blocks(language: str) -> list[str]:
    text = DOC.read_text(encoding="utf-8")
    section = text.split("## Adding a scorer", 1)[1].split("\n## ", 1)[0]
    return re.findall(rf"```{language}\n(.*?)```", section, flags=re.S)


@pytest.fixture
def registry() -> Iterator[dict[str, Any]]:
    """The scorer registry, restored afterwards (a test's scorer must not leak)."""
    before = dict(scoring.SCORERS)
    yield scoring.SCORERS
    scoring.SCORERS.clear()
    scoring.SCORERS.update(before)


@pytest.fixture
def blue_share(tmp_path: Path) -> Iterator[Any]:
    """The doc's module, written to a file and imported as ``blue_share``."""
    module_text, _ = _section_blocks("python")
    path = tmp_path / "blue_share.py"
    path.write_text(module_text, encoding="utf-8")
    spec = importlib.util.spec_from_file_location("blue_share", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["blue_share"] = module
    try:
        spec.loader.exec_module(module)
        yield module
    finally:
        del sys.modules["blue_share"]


@dataclass(frozen=True)
class SendAll:
    send: bool = True
    version: int | None = 0
    reason: str = "send all"


class Recording:
    """A decider that sends everything and keeps what it was asked about."""

    def __init__(self) -> None:
        self.decided: list[Message] = []

    def decide(self, message: Message, now: float) -> SendAll:
        self.decided.append(message)
        return SendAll()

    def get_timer(self) -> float | None:
        return None


def _config(toml_text: str) -> Any:
    return parse_config({"drone": {"id": "d1"}, **tomllib.loads(toml_text)})


def test_the_doc_example_is_one_module_and_one_line(registry: dict[str, Any],
                                                     blue_share: Any) -> None:
    _, line = _section_blocks("python")
    assert line.strip().count("\n") == 0, "the registration is one line"
    (toml_text,) = _section_blocks("toml")
    with pytest.raises(ConfigError, match=r"scoring\.scorers: expected a list of .*red_share"):
        _config(toml_text)  # not registered yet: an unknown name
    exec(line, {"register_scorer": scoring.register_scorer, "blue_share": blue_share})
    assert "blue_share" in scoring.scorer_names()
    config = _config(toml_text)
    assert config.scoring.scorers == ("red_share", "blue_share")
    assert config.scoring.settings["blue_share"].min_saturation == 120
    with pytest.raises(ConfigError, match=r"scoring\.blue_share\.min_saturation: expected an "
                                          r"integer in 0\.\.255, got 300"):
        _config(toml_text.replace("= 120", "= 300"))
    with pytest.raises(ConfigError, match=r"scoring\.blue_share\.hue"):
        _config(toml_text + "hue = 3\n")


async def test_a_frame_is_scored_by_the_new_scorer(registry: dict[str, Any],
                                                   blue_share: Any) -> None:
    _, line = _section_blocks("python")
    exec(line, {"register_scorer": scoring.register_scorer, "blue_share": blue_share})
    (toml_text,) = _section_blocks("toml")
    config = _config(toml_text)
    counters = dict.fromkeys(COUNTERS, 0)
    decider, sent = Recording(), []
    mission = MissionWindow()
    dispatcher = Dispatcher(config, decider=decider, clock=time.time,  # type: ignore[arg-type]
                            send_message=lambda m, p, t: sent.append((m, p)) or 1,
                            mission_log=MissionLogWriter(None), mission=mission,
                            counters=counters)
    pipeline = CameraPipeline(config.camera, drone_id="d1", dispatcher=dispatcher,
                              mission=mission,
                              scorer=scoring.make_scorer(config.scoring.scorers,
                                                         config.scoring.settings))
    image = np.full((120, 160, 3), 128, np.uint8)
    image[0:60, 0:80] = (255, 0, 0)  # a quarter pure blue (BGR)
    image[60:120, 0:40] = (0, 0, 255)  # an eighth pure red
    try:
        async with asyncio.timeout(10):
            await pipeline.on_frame(Frame(image=image, t_capture=time.time(), index=0))
    finally:
        pipeline.close()
        dispatcher.close()
    (message,) = decider.decided
    assert message.type == "image"
    assert message.data["blue"] == pytest.approx(0.25, abs=1e-9)
    assert message.data["red"] == pytest.approx(0.125, abs=0.01)
    assert [m.seq for m, _ in sent] == [0] and sent[0][1][:2] == b"\xff\xd8"  # a JPEG went out
    assert counters["sent"] == 1
