"""What a newcomer reads in ``--help`` (real console scripts, subprocesses): each option's
default, what a command does and its exit statuses, an example to copy, and every study
named with what it reproduces. Before, ``uav-sitl vehicle --help`` said ``--port PORT  UDP
port of the first vehicle`` without its 14550, ``uav-ground-station run --help`` left
``--udp-port`` and ``-v`` unexplained, ``uav-companion check --help`` did not give the exit
statuses docs/companion.md promises, and ``uav-sitl study --help`` listed bare names."""

from __future__ import annotations

import argparse
import re
import subprocess

import pytest

from companion.cli_help import DefaultsFormatter
from sitl.cli import STUDIES
from tests.companion_process import console_script


def _help(*argv: str) -> str:
    """The command's ``--help`` with its line wrapping undone (exit 0, nothing on stderr)."""
    proc = subprocess.run([console_script(argv[0]), *argv[1:], "--help"], capture_output=True,
                          text=True, timeout=120, check=False)
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    return re.sub(r"\s+", " ", proc.stdout)


# (command, phrases its --help must contain, whitespace collapsed)
CASES = [
    (("uav-companion",), ["--log-level {debug,info,warning,error} least severe log record "
                          "written to stderr (default info)",
                          "uav-companion check --config companion.toml"]),
    (("uav-companion", "run"), ["Exit status: 0 stopped, 1 a service failed"]),
    (("uav-companion", "check"), ["Exit status: 0 all answered, 1 a probe failed (no "
                                  "HEARTBEAT, no frame), 2 bad configuration.",
                                  "--timeout TIMEOUT seconds to wait for the autopilot "
                                  "(default 5)"]),
    (("uav-companion", "install-service"), ["--user USER run the service as this user "
                                            "(default: systemd's, root)"]),
    (("uav-ground-station",), ["uav-ground-station keygen", "uav-ground-station run"]),
    (("uav-ground-station", "run"), ["--udp-port UDP_PORT UDP port the fleet sends to "
                                     "(default: the config's udp_port, 14600)",
                                     "-v, --verbose log DEBUG records too",
                                     "--data-dir DATA_DIR database, images, logs, token and "
                                     "keys/ (default: the config's data_dir, else gs-data in "
                                     "the current folder)",
                                     "2 bad configuration, no keys or an unusable data folder"]),
    (("uav-ground-station", "shell"), ["(default 30.0)", "start [TIME]"]),
    (("uav-ground-station", "keygen"), ["--out OUT folder for fleet.key, command.key, "
                                        "command.pub (default DATA_DIR/keys)",
                                        "never command.key"]),
    (("uav-sitl", "vehicle"), ["(0: any free) (default 14550)", "(default px4)",
                               "uav-sitl vehicle --port 14580 --out 127.0.0.1:14550"]),
    (("uav-sitl", "fleet"), ["--rate RATE camera frames/s per drone (default 5.0)",
                             "--scene SCENE scene name (sitl/scenes) or TOML path "
                             "(default demo)",
                             "--mcts-iterations MCTS_ITERATIONS optimiser iterations per "
                             "decision, as in the thesis (default 300)"]),
    (("uav-sitl", "camera"), ["--out OUT output folder (default frames)",
                              "uav-sitl camera --scene demo --pose 20,30,30 --out frames/"]),
    (("uav-sitl", "study"), [f"{name} {text}" for name, (_, text) in STUDIES.items()]),
    (("uav-utility", "specs"), ['mission.spec = "builtin:NAME"']),
    (("uav-utility", "evaluate"), ["uav-utility evaluate --spec image_streaming out/fleet/"]),
]


@pytest.mark.parametrize(("argv", "phrases"), CASES, ids=[" ".join(c[0]) for c in CASES])
def test_help_says_what_a_newcomer_needs(argv: tuple[str, ...], phrases: list[str]) -> None:
    text = _help(*argv)
    missing = [phrase for phrase in phrases if phrase not in text]
    assert missing == [], text


def _option_help(parser: argparse.ArgumentParser) -> str:
    return re.sub(r"\s+", " ", parser.format_help())


def test_formatter_adds_a_default_only_where_it_is_news() -> None:
    parser = argparse.ArgumentParser(formatter_class=DefaultsFormatter)
    parser.add_argument("--port", type=int, default=14550, help="UDP port")
    parser.add_argument("--size", default="640x480", help="frame size (default 640x480)")
    parser.add_argument("--home", default=None, help="LAT,LON")
    parser.add_argument("--quick", action="store_true", help="short runs")
    parser.add_argument("--param", action="append", default=[], help="NAME=VALUE")
    parser.add_argument("log", nargs="?", default="x.jsonl", help="mission log")
    text = _option_help(parser)
    assert "--port PORT UDP port (default 14550)" in text
    assert "frame size (default 640x480) " in text and "(default 640x480) (default" not in text
    assert "--home HOME LAT,LON " in text  # None: the help says what its absence means
    assert "--quick short runs " in text  # a switch's default is "off"
    assert "--param PARAM NAME=VALUE " in text
    assert "log mission log " in text  # positional: its default is not an option's
