"""More bad input to the console scripts, found by an audit: each was accepted (a unit
written for a config ``run`` refuses, a wait that never ends or ends at once) or a
traceback (a newline in ``--token``), or a default taken for what was asked
(``uav-sitl camera --poses`` of an empty file rendered one frame at the default pose).
Now: one line on stderr, exit 2."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from tests.keys import write_test_keys
from tests.processes import assert_one_line_error

BIN = Path(sys.executable).parent
SHELL = ["uav-ground-station", "shell", "--url", "http://127.0.0.1:1", "-c", "status"]

# (argv with {placeholders}, exit code, a fragment of the one-line error)
CASES = [
    (["uav-companion", "install-service", "--dry-run", "--config", "{no_keys}"], 2,
     "ground_station.fleet_key_file is not set (there is no built-in key)"),
    (["uav-companion", "install-service", "--no-enable", "--unit-dir", "{units}",
      "--config", "{no_keys}"], 2, "ground_station.fleet_key_file is not set"),
    *[(["uav-companion", "check", "--timeout", bad, "--config", "{keyed}"], 2,
       f"argument --timeout: expected a number of seconds > 0, got '{bad}'")
      for bad in ("inf", "nan", "-1", "0", "soon")],
    ([*SHELL, "--token", "t", "--timeout", "inf"], 2,
     "--timeout must be a number of seconds > 0"),
    ([*SHELL, "--token", "a\nb"], 2, "the token must be printable ASCII without spaces"),
    (["uav-sitl", "camera", "--poses", "{empty}", "--out", "{units}/frames"], 2,
     "empty.txt: no poses (one x,y,z per line)"),
    (["uav-ground-station", "shell", "--url", "ftp://x", "--token", "t", "-c", "status"], 2,
     "--url must start with http:// or https://, got 'ftp://x'"),
]


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("audit")
    write_test_keys(root / "keys")
    out = {"no_keys": root / "no_keys.toml", "keyed": root / "keyed.toml",
           "units": root / "units", "empty": root / "empty.txt"}
    out["empty"].write_text("# no pose here\n")
    out["no_keys"].write_text('[drone]\nid = "d1"\n')
    out["keyed"].write_text('[drone]\nid = "d1"\n[ground_station]\nfleet_key_file = '
                            '"keys/fleet.key"\ncommand_public_key_file = "keys/command.pub"\n')
    out["units"].mkdir()
    return out


@pytest.mark.parametrize(("argv", "code", "fragment"), CASES,
                         ids=[" ".join(c[0]).replace("\n", "\\n") for c in CASES])
def test_bad_input_is_one_line_and_exit_2(files: dict[str, Path], argv: list[str], code: int,
                                          fragment: str) -> None:
    script = BIN / argv[0]
    args = [a.format(**{k: str(v) for k, v in files.items()}) for a in argv[1:]]
    result = subprocess.run([str(script), *args], capture_output=True, text=True,
                            timeout=60, check=False)
    assert_one_line_error(result, code, fragment)
    assert not list(files["units"].iterdir())  # no unit written for a refused config
